"""Re-deriving a recorded drive: the stages that decode and draw its raw frames again.

The ``--dbc`` databases, else the attached ones on the buses recorded; the profile given, else the
attached one. The new drive's metadata keeps its source's ``created``, so the same drive with the
same databases and profile gives the same bytes, and its recorded marks are carried over.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

from bridge.decode.database import DatabaseFile, database_warnings, load_database
from bridge.decode.decoder import Decoder
from bridge.errors import DatabaseError, InputError
from bridge.io.drives import ArchiveContents, mark_time
from bridge.packed import PackedFrames
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline import DEFAULT_SCENE_RATE
from bridge.pipeline.drive import PROFILE_PREFIX, Stages, build_decoder
from bridge.pipeline.marks import Marks, mark_messages
from bridge.pipeline.pipeline import Pipeline


def _attached_database(drive: ArchiveContents, folder: Path, name: str, data: bytes,
                       db_name: str | None) -> DatabaseFile:
    """An attached database, loaded as cantools loads its file, named ``DRIVE.mcap/NAME``."""
    where = Path(drive.path.name) / name
    file = folder / name
    file.write_bytes(data)
    try:
        loaded = load_database(file, name=db_name)
    except DatabaseError as exc:
        raise DatabaseError(where, f"(attached to {drive.path}) {exc.reason}") from None
    return DatabaseFile(where, loaded.name, loaded.sha256, loaded.content, loaded.db,
                        database_warnings(where, loaded.db), loaded.code)


def attached_decoder(drive: ArchiveContents, folder: Path) -> Decoder:
    """A decoder of the databases attached to ``drive``, on the buses its metadata records
    (on every bus where it records none: a drive cut short before its end). Each attachment is
    written into ``folder`` for cantools to load."""
    entries = drive.metadata.get("databases")
    if not isinstance(entries, list):
        entries = [{"attachment": n, "buses": ["*"]} for n in drive.attachments
                   if not n.startswith(PROFILE_PREFIX)]
    by_bus: dict[str | None, list[DatabaseFile]] = {}
    loaded: dict[str, DatabaseFile] = {}
    for entry in entries:
        name = str(entry.get("attachment"))
        data = drive.attachments.get(name)
        if data is None:
            raise InputError(drive.path, f"its metadata names the database attachment {name!r}, "
                             "which the file does not hold; give the databases with --dbc")
        if name not in loaded:
            loaded[name] = _attached_database(drive, folder, name, data, entry.get("name"))
        for bus in entry.get("buses") or ["*"]:
            by_bus.setdefault(None if bus == "*" else str(bus), []).append(loaded[name])
    return Decoder(by_bus)


def attached_profile(drive: ArchiveContents, folder: Path) -> Path | None:
    """The profile attached to ``drive``, written into ``folder`` under its own file name (so
    the re-derived drive attaches it under the same name); None if the drive has none."""
    name: str | None = None
    if "profile" in drive.metadata:
        described = drive.metadata["profile"]
        if isinstance(described, dict) and isinstance(described.get("attachment"), str):
            name = described["attachment"]
    else:  # no metadata (cut short): the attachment tells
        name = next((n for n in drive.attachments if n.startswith(PROFILE_PREFIX)), None)
    if not name or name not in drive.attachments:
        return None
    path = folder / name[len(PROFILE_PREFIX):]
    path.write_bytes(drive.attachments[name])
    return path


def rederive_stages(drive: ArchiveContents, dbc_options: Sequence[str],
                    profile: str | Path | None, folder: Path) -> Stages:
    """The stages that re-derive ``drive``: the databases of ``dbc_options``, else the attached
    ones; the ``profile``, else the attached one (if any). Attachments are written into
    ``folder``, which must last as long as the drive is recorded (its profile is attached)."""
    from bridge.profile.loader import load_profile, resolve_profile
    from bridge.profile.model import ProfileError

    databases, profiles = folder / "databases", folder / "profile"
    databases.mkdir(exist_ok=True)
    profiles.mkdir(exist_ok=True)
    decoder = build_decoder(dbc_options) if dbc_options else attached_decoder(drive, databases)
    path = resolve_profile(profile) if profile is not None else attached_profile(drive, profiles)
    if path is None:
        return Stages(decoder, None)
    try:
        return Stages(decoder, load_profile(path, [f.db for f in decoder.files],
                                            own_databases=False))
    except ProfileError as exc:
        if profile is not None:
            raise
        # the attached profile was written into a temporary folder: name the drive instead
        raise ProfileError(f"{drive.path} (attached {PROFILE_PREFIX}{path.name})", exc.key,
                           exc.reason) from None


def describe_rederive(drive: ArchiveContents, stages: Stages, dbc_options: Sequence[str],
                      profile: str | Path | None) -> str:
    """What a drive is re-derived with, for people."""
    decoder, loaded = stages
    names = ", ".join(f.path.name for f in decoder.files) or "none"
    databases = f"databases {names}" + ("" if dbc_options else " (attached)")
    with_profile = ("no profile" if loaded is None else
                    f"profile {loaded.path.name}" + ("" if profile is not None else " (attached)"))
    return f"re-deriving {drive.path} with {databases}, {with_profile}"


def source_record(drive: ArchiveContents) -> dict[str, Any]:
    """What the metadata of a re-derived drive says of the drive it was re-derived from."""
    record: dict[str, Any] = {
        "source": {"file": drive.path.name, "size": drive.size, "sha256": drive.sha256,
                   "complete": drive.complete, "metadata": drive.metadata}}
    if drive.metadata.get("created"):  # a drive cut before its metadata has none: now, then
        record["created"] = drive.metadata["created"]
    return record


def recorded_scene_rate(drive: ArchiveContents) -> float:
    """The scene rate a drive was recorded at (its metadata), else the default."""
    described = drive.metadata.get("profile")
    rate = described.get("scene_rate_hz") if isinstance(described, dict) else None
    return float(rate) if isinstance(rate, (int, float)) and rate > 0 else DEFAULT_SCENE_RATE


def unreadable_marks(drive: ArchiveContents) -> list[str]:
    """The warning of a drive whose ``/marks`` messages are not all a ``tankviz.Mark``."""
    if not drive.unreadable_marks:
        return []
    return [f"{drive.path}: {drive.unreadable_marks} /marks messages are not a tankviz.Mark: "
            "left out of the re-derived drive"]


class CarriedMarks:
    """The marks of a drive re-derived by ``pipeline``, given back to it in time order, with their
    numbers and texts, where its frames reach them (the pipeline's
    :attr:`~bridge.pipeline.pipeline.Pipeline.marks` then lists them); the profile's ``[marks]``
    rules then make none again, unless the drive has no marks.
    """

    def __init__(self, marks: Sequence[Mark], pipeline: Pipeline) -> None:
        self._pending = deque(marks)
        self._pipeline = pipeline
        self._made = Marks()
        pipeline.marks = self._made
        pipeline.mark_watch = None  # (the car's marks are among those recorded)

    def before(self, t_ns: int, *, emit: bool = True) -> None:
        """Every mark still to come that is at or before ``t_ns`` (a frame's time), made now;
        not ``emit``: passed over (a replay that starts later)."""
        pending = self._pending
        while pending and mark_time(pending[0]) <= t_ns:
            mark = pending.popleft()
            if emit:
                self._made.made.append(mark)
                self._pipeline.emit(mark_messages(mark, mark_time(mark)))

    def packs(self, packs: Iterable[PackedFrames]) -> Iterator[PackedFrames]:
        """``packs`` cut where a mark comes, each mark made between the two parts (when the
        pipeline asks for the part after it: the frames before it have gone through)."""
        pending = self._pending
        for pack in packs:
            ts, i, n = pack.t, 0, len(pack)
            while pending and i < n:
                due = mark_time(pending[0])
                if max(ts) < due:  # (most packs: no frame reaches the mark)
                    break
                j = next((k for k in range(i, n) if ts[k] >= due), n)
                if j == n:
                    break
                if j > i:
                    yield pack.slice(i, j)
                self.before(ts[j])
                i = j
            if i < n:
                yield pack if i == 0 else pack.slice(i, n)

    def finish(self) -> None:
        """The marks after the last frame (live took them as it stopped)."""
        while self._pending:
            self.before(mark_time(self._pending[-1]))
