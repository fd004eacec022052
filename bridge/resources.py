"""Files bundled with tankviz: databases, profiles and sample logs (``bridge/data``), protobuf
schemas (``schemas/``) and Foxglove layouts (``layouts/``).

In a source tree ``schemas/`` and ``layouts/`` sit beside ``bridge/``; in an installed wheel they
are inside the package (``bridge/schemas``, ``bridge/layouts``), where pyproject.toml puts them.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def _folder(name: str) -> Path:
    inside = _PACKAGE / name
    return inside if inside.is_dir() else _PACKAGE.parent / name


def data_dir() -> Path:
    """Bundled databases (``*.dbc``), vehicle profiles (``*.toml``) and sample logs."""
    return _PACKAGE / "data"


def schemas_dir() -> Path:
    return _folder("schemas")


def layouts_dir() -> Path:
    return _folder("layouts")


def bundled_database(name: str) -> Path | None:
    """The bundled database called ``name`` (``ecocar`` or ``ecocar.dbc``), if there is one."""
    candidate = data_dir() / (name if name.endswith(".dbc") else f"{name}.dbc")
    return candidate if candidate.is_file() and "/" not in name else None
