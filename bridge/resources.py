"""Files bundled with tankviz: databases, profiles and sample logs (``bridge/data``) and Foxglove
layouts (``layouts/`` beside ``bridge/`` in a source tree, ``bridge/layouts`` in an installed
wheel).
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def data_dir() -> Path:
    """Bundled databases (``*.dbc``), vehicle profiles (``*.toml``) and sample logs."""
    return _PACKAGE / "data"


def layouts_dir() -> Path:
    """The bundled layouts: inside the package when installed, else beside it."""
    inside = _PACKAGE / "layouts"
    return inside if inside.is_dir() else _PACKAGE.parent / "layouts"


def bundled_database(name: str) -> Path | None:
    """The bundled database called ``name`` (``ecocar`` or ``ecocar.dbc``), if there is one."""
    candidate = data_dir() / (name if name.endswith(".dbc") else f"{name}.dbc")
    return candidate if candidate.is_file() and "/" not in name else None
