"""What a drive without its ``tankviz`` metadata record holds, as the catalogue reads it.

:func:`held_metadata` makes the entries the catalogue reads of that record (missing from a drive
cut short and recovered) from what the file holds: frames per bus from its raw-frame channels,
databases (buses unknown) and profile from its attachments, and the ``tankviz.recover`` record
into ``statistics.recovered``.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


#: The metadata record ``tankviz recover`` writes (:mod:`bridge.apps.recover`).
RECOVER_RECORD = "tankviz.recover"
#: The name prefix of a drive's profile attachment (``bridge.pipeline.drive.PROFILE_PREFIX``).
_PROFILE_PREFIX = "profile-"


def held_metadata(reader: Any, frames: dict[str, int],
                  recovered: dict[str, str] | None) -> dict[str, str]:
    """The metadata entries the catalogue reads, made from what a drive without its ``tankviz``
    record holds: ``frames`` per bus (:func:`bridge.io.drives.raw_frame_counts`), databases and
    profile (its attachments, unless ``reader`` is None), and the ``tankviz.recover`` record
    (``statistics.recovered``)."""
    statistics: dict[str, Any] = {"frames": dict(sorted(frames.items()))}
    if recovered is not None:
        statistics["recovered"] = {k: _value(recovered[k]) for k in (
            "source", "complete", "stopped", "bytes_read", "bytes_total") if k in recovered}
    databases: list[dict[str, Any]] = []
    profile: dict[str, Any] | None = None
    for a in reader.iter_attachments() if reader is not None else ():
        if a.name.startswith(_PROFILE_PREFIX):
            if profile is None:
                profile = {"name": _profile_name(a.data) or Path(
                    a.name[len(_PROFILE_PREFIX):]).stem, "attachment": a.name}
        elif not any(d["attachment"] == a.name for d in databases):
            databases.append({"name": Path(a.name).stem, "attachment": a.name,
                              "sha256": hashlib.sha256(a.data).hexdigest(), "buses": []})
    return {"statistics": json.dumps(statistics), "databases": json.dumps(databases),
            "profile": json.dumps(profile)}


def _profile_name(data: bytes) -> str | None:
    """The ``[profile] name`` of an attached profile, if it has one."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    try:
        section = tomllib.loads(data.decode()).get("profile")
    except (ValueError, UnicodeDecodeError):
        return None
    name = section.get("name") if isinstance(section, dict) else None
    return name if isinstance(name, str) else None
