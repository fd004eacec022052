"""The drive catalogue: what an archive of recorded drives holds, as one DuckDB file.

:func:`read_drive` is a pure function from one tankviz MCAP drive to the rows of every table,
from its summary, metadata, perception topics and marks (nothing is decoded again);
:func:`index` (re)indexes a catalogue incrementally, this process alone writing it.

Tables (:data:`SCHEMA`; times are log times: ``*_ns`` integer nanoseconds since the epoch,
``*_s`` seconds since the drive's first message, which is ``tankviz replay --start``):

- ``drives``: one row per drive, keyed by its resolved ``path``;
- ``databases``: the databases a drive was decoded with (name, SHA-256, buses);
- ``alarms``: one row per time an alarm was raised (``cleared`` NULL: still raised at the end);
- ``topics``: every channel with its schema, message count and mean rate over the drive;
- ``objects_summary``: per object group (``/perception/<group>``, and ``lead`` for the lead
  vehicle): messages, valid objects seen in them, the largest count at once, the smallest
  distance and when;
- ``lead_changes``: every real lead change (``/perception/lead``'s ``lead_number`` goes up; in
  a drive without that field, every change of the lead's id), with its distance; ``cut_in`` when
  it replaced a lead that was present a moment before and is closer;
- ``marks``: every mark (``mark`` its number in the drive; ``marked_by`` the Mark's ``by``).
"""

from __future__ import annotations

import glob
import importlib
import json
import os
import re
import struct
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader

from bridge.errors import (
    BridgeError,
    FileError,
    InputError,
    UsageError,
    name_too_long,
    not_a_file,
    shown,
)
from bridge.fleet.held import RECOVER_RECORD, held_metadata
from bridge.frame import NS
from bridge.io.drives import mark_time, raw_frame_counts, read_marks
from bridge.io.unreadable import why_unreadable
from bridge.pb import perception_pb2
from bridge.sinks.mcap import METADATA_NAME
from bridge.sinks.outputs import being_written
from bridge.topics import LOG_TOPIC, MARKS_TOPIC

#: The one-line advice when Dask or DuckDB is missing.
FLEET_EXTRA = "pip install 'tankviz[fleet]'"

OBJECTS_SCHEMA = "tankviz.PerceivedObjects"
LEAD_SCHEMA = "tankviz.LeadVehicle"
HEALTH_SCHEMA = "tankviz.Health"
#: The object group name of the lead vehicle in ``objects_summary``.
LEAD = "lead"

#: Every table: its columns and their DuckDB types, in the order of the rows.
SCHEMA: dict[str, tuple[tuple[str, str], ...]] = {
    "drives": (
        ("path", "VARCHAR PRIMARY KEY"), ("size", "BIGINT"), ("mtime_ns", "BIGINT"),
        ("start_time", "TIMESTAMP"), ("end_time", "TIMESTAMP"), ("start_ns", "BIGINT"),
        ("end_ns", "BIGINT"), ("duration_s", "DOUBLE"), ("messages", "BIGINT"),
        ("profile", "VARCHAR"), ("databases", "VARCHAR"), ("buses", "VARCHAR[]"),
        ("frames", "BIGINT"), ("error_frames", "BIGINT"), ("unknown_ids", "BIGINT"),
        ("decode_errors", "BIGINT"), ("truncated", "BIGINT"), ("statistics", "VARCHAR"),
        ("tankviz_version", "VARCHAR"), ("created", "VARCHAR")),
    "databases": (
        ("drive", "VARCHAR"), ("name", "VARCHAR"), ("sha256", "VARCHAR"), ("buses", "VARCHAR[]")),
    "alarms": (
        ("drive", "VARCHAR"), ("alarm", "VARCHAR"), ("raised", "TIMESTAMP"),
        ("cleared", "TIMESTAMP"), ("raised_ns", "BIGINT"), ("cleared_ns", "BIGINT"),
        ("raised_s", "DOUBLE"), ("cleared_s", "DOUBLE"), ("message", "VARCHAR")),
    "topics": (
        ("drive", "VARCHAR"), ("topic", "VARCHAR"), ("schema", "VARCHAR"), ("encoding", "VARCHAR"),
        ("count", "BIGINT"), ("rate_hz", "DOUBLE")),
    "objects_summary": (
        ("drive", "VARCHAR"), ("object_group", "VARCHAR"), ("topic", "VARCHAR"),
        ("messages", "BIGINT"), ("valid_objects", "BIGINT"), ("max_count", "BIGINT"),
        ("min_distance_m", "DOUBLE"), ("min_distance_ns", "BIGINT"),
        ("min_distance_s", "DOUBLE")),
    "lead_changes": (
        ("drive", "VARCHAR"), ("time", "TIMESTAMP"), ("t_ns", "BIGINT"), ("t_s", "DOUBLE"),
        ("previous_id", "BIGINT"), ("lead_id", "BIGINT"), ("distance_m", "DOUBLE"),
        ("previous_distance_m", "DOUBLE"), ("cut_in", "BOOLEAN")),
    "marks": (
        ("drive", "VARCHAR"), ("mark", "BIGINT"), ("time", "TIMESTAMP"), ("t_ns", "BIGINT"),
        ("t_s", "DOUBLE"), ("text", "VARCHAR"), ("category", "VARCHAR"), ("source", "VARCHAR"),
        ("marked_by", "VARCHAR")),
}
#: The topic of each table that came after the others: a catalogue made before it has no rows
#: of the drives that hold it, which are read again (:func:`index`).
ADDED_TABLES = {"marks": MARKS_TOPIC}

Row = tuple[Any, ...]


@dataclass(frozen=True)
class DriveRows:
    """The rows one drive gives each table (tuples in :data:`SCHEMA`'s column order)."""

    path: str
    tables: dict[str, list[Row]]


def _utc(ns: int) -> datetime:
    return datetime.fromtimestamp(ns // 1000 / 1e6, tz=timezone.utc).replace(tzinfo=None)


def _json(values: dict[str, str], key: str, default: Any) -> Any:
    try:
        return json.loads(values[key])
    except (KeyError, ValueError):
        return default


_RAISED = re.compile(r"ALARM (?P<id>.+?): (?P<message>.*)")
_CLEARED = re.compile(r"cleared (?P<id>.+?)(?: \(the condition ended [^)]*\))?: was (?P<m>.*)")


def alarm_events_from_log(messages: Iterable[tuple[int, str, str]]) -> list[dict[str, Any]]:
    """Alarm events (as in the metadata record) from ``/log`` messages ``(t_ns, name, text)`` of
    the health monitor (``tankviz.health``)."""
    events: list[dict[str, Any]] = []
    for t_ns, name, text in messages:
        if name != "tankviz.health":
            continue
        if (raised := _RAISED.fullmatch(text)) is not None:
            events.append({"alarm": raised["id"], "event": "raised", "t_ns": t_ns,
                           "message": raised["message"]})
        elif (cleared := _CLEARED.fullmatch(text)) is not None:
            events.append({"alarm": cleared["id"], "event": "cleared", "t_ns": t_ns,
                           "message": cleared["m"]})
    return events


def alarm_rows(drive: str, start_ns: int, events: Iterable[dict[str, Any]]) -> list[Row]:
    """One row per raise of an alarm, with the clear that ended it (None: raised at the end)."""
    open_: dict[str, tuple[int, str]] = {}
    done: list[tuple[str, int, int | None, str]] = []
    for e in sorted(events, key=lambda e: int(e["t_ns"])):
        alarm, t_ns = str(e["alarm"]), int(e["t_ns"])
        if e["event"] == "raised":
            if alarm in open_:  # raised twice without a clear between: the first one ends here
                raised_ns, message = open_.pop(alarm)
                done.append((alarm, raised_ns, None, message))
            open_[alarm] = (t_ns, str(e.get("message", "")))
        elif e["event"] == "cleared" and alarm in open_:
            raised_ns, message = open_.pop(alarm)
            done.append((alarm, raised_ns, t_ns, message))
    done += [(alarm, raised_ns, None, message) for alarm, (raised_ns, message) in open_.items()]
    done.sort(key=lambda r: (r[1], r[0]))
    return [(drive, alarm, _utc(raised), None if cleared is None else _utc(cleared), raised,
             cleared, (raised - start_ns) / NS,
             None if cleared is None else (cleared - start_ns) / NS, message)
            for alarm, raised, cleared, message in done]


@dataclass
class _Objects:
    topic: str
    messages: int = 0
    valid: int = 0
    max_count: int = 0
    min_distance: float | None = None
    min_distance_ns: int | None = None

    def see(self, t_ns: int, distances: Sequence[float]) -> None:
        self.messages += 1
        self.valid += len(distances)
        self.max_count = max(self.max_count, len(distances))
        if distances:
            nearest = min(distances)
            if self.min_distance is None or nearest < self.min_distance:
                self.min_distance, self.min_distance_ns = nearest, t_ns


@dataclass
class _Lead:
    rows: list[Row] = field(default_factory=list)
    last_id: int | None = None
    last_number: int = 0
    last_distance: float | None = None
    present_before: bool = False

    def see(self, drive: str, start_ns: int, t_ns: int, present: bool, lead_id: int,
            distance: float, number: int = 0) -> None:
        """One /perception/lead message. ``number``: its lead_number, which counts the real
        lead changes (a twin taking over the lead's slot changes the id, not the number);
        drives recorded before it (0) count every change of id."""
        changed = number != self.last_number if number else lead_id != self.last_id
        if present and (not self.present_before or changed):
            cut_in = (self.present_before and self.last_distance is not None
                      and distance < self.last_distance)
            self.rows.append((drive, _utc(t_ns), t_ns, (t_ns - start_ns) / NS, self.last_id,
                              lead_id, distance, self.last_distance, cut_in))
        if present:
            self.last_id, self.last_distance, self.last_number = lead_id, distance, number
        self.present_before = present


def read_drive(path: Path | str) -> DriveRows:
    """Every table's rows for one tankviz MCAP drive (:class:`~bridge.errors.InputError` saying why
    if it is none), keyed by its resolved path as shown (:func:`~bridge.errors.shown`).

    A drive without the metadata record (recovered) takes what it holds from the file instead
    (:mod:`bridge.fleet.held`); one being recorded is :class:`BeingRecorded`, indexed on a later
    run.
    """
    if (why := not_a_file(path)) is not None and not os.path.isdir(path):
        raise InputError(path, why)
    path = Path(path).resolve()
    drive = shown(path)
    try:
        stat = path.stat()
        with path.open("rb") as stream:
            return _read(drive, stat.st_size, stat.st_mtime_ns, stream)
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, "is a folder, not an MCAP drive") from None
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    except (McapError, ValueError, EOFError, KeyError, struct.error, RuntimeError) as exc:
        raise InputError(path, why_unreadable(path, exc)) from None


def _read(drive: str, size: int, mtime_ns: int, stream: Any) -> DriveRows:
    reader = make_reader(stream)
    summary = reader.get_summary()
    if summary is None or summary.statistics is None:
        raise InputError(drive, why_unreadable(drive))
    stats = summary.statistics
    start_ns, end_ns = stats.message_start_time, stats.message_end_time
    duration_s = (end_ns - start_ns) / NS if stats.message_count else 0.0
    schemas = {i: s.name for i, s in summary.schemas.items()}
    channels = sorted(summary.channels.values(), key=lambda c: c.topic)
    schema_of = {c.topic: schemas.get(c.schema_id, "") for c in channels}
    records = {m.name: dict(m.metadata) for m in reversed(list(reader.iter_metadata()))}
    meta = records.get(METADATA_NAME)
    if meta is None and HEALTH_SCHEMA not in schema_of.values():
        raise InputError(drive, f"not a tankviz drive: no {METADATA_NAME!r} metadata record and "
                         f"no {HEALTH_SCHEMA} channel")
    counts = stats.channel_message_counts
    if meta is None:  # cut short (and recovered): what the file holds
        meta = held_metadata(reader, raw_frame_counts(reader), records.get(RECOVER_RECORD))
    elif RECOVER_RECORD in records:  # recovered: its frames are those it holds, not all it had
        held = _json(held_metadata(None, raw_frame_counts(reader), records[RECOVER_RECORD]),
                     "statistics", {})
        meta = {**meta, "statistics": json.dumps({**_json(meta, "statistics", {}), **held})}
    topics = [(drive, c.topic, schemas.get(c.schema_id, ""), c.message_encoding,
               counts.get(c.id, 0), counts.get(c.id, 0) / duration_s if duration_s else None)
              for c in channels]

    objects = {t: _Objects(t) for t, s in schema_of.items() if s in (OBJECTS_SCHEMA, LEAD_SCHEMA)}
    lead = _Lead()
    logs: list[tuple[int, str, str]] = []
    from_log = "alarms" not in meta
    wanted = [*objects, *([LOG_TOPIC] if from_log and LOG_TOPIC in schema_of else [])]
    if wanted:
        for _, channel, message in reader.iter_messages(topics=wanted, log_time_order=True):
            t_ns = message.log_time
            if channel.topic == LOG_TOPIC and channel.topic not in objects:
                logs.append(_log_entry(t_ns, message.data))
            elif schema_of[channel.topic] == LEAD_SCHEMA:
                v = perception_pb2.LeadVehicle.FromString(message.data)
                objects[channel.topic].see(t_ns, [v.object.distance] if v.present else [])
                lead.see(drive, start_ns, t_ns, v.present, v.object.id, v.object.distance,
                         v.lead_number)
            else:
                o = perception_pb2.PerceivedObjects.FromString(message.data)
                objects[channel.topic].see(t_ns, [x.distance for x in o.objects])
    objects_rows = [(drive, LEAD if schema_of[o.topic] == LEAD_SCHEMA else _group(o.topic),
                     o.topic, o.messages, o.valid, o.max_count, o.min_distance, o.min_distance_ns,
                     None if o.min_distance_ns is None else (o.min_distance_ns - start_ns) / NS)
                    for o in objects.values()]

    events = (_json(meta, "alarms", []) if "alarms" in meta else alarm_events_from_log(logs))
    statistics = _json(meta, "statistics", {})
    databases = _json(meta, "databases", [])
    profile = _json(meta, "profile", None)

    def total(key: str) -> int:
        values = statistics.get(key, {})
        return int(sum(values.values())) if isinstance(values, dict) else 0

    drives_row = (
        drive, size, mtime_ns, _utc(start_ns), _utc(end_ns), start_ns, end_ns, duration_s,
        stats.message_count, profile.get("name") if isinstance(profile, dict) else None,
        json.dumps([{"name": d.get("name"), "sha256": d.get("sha256"), "buses": d.get("buses")}
                    for d in databases]),
        sorted(statistics.get("frames", {})), total("frames"), total("error_frames"),
        total("unknown_ids"), total("decode_errors"), total("truncated"),
        json.dumps(statistics, sort_keys=True), meta.get("tankviz_version"), meta.get("created"))
    return DriveRows(drive, {
        "drives": [drives_row],
        "databases": [(drive, d.get("name"), d.get("sha256"), list(d.get("buses", [])))
                      for d in databases],
        "alarms": alarm_rows(drive, start_ns, events),
        "topics": topics,
        "objects_summary": objects_rows,
        "lead_changes": lead.rows,
        "marks": [(drive, m.number, _utc(t), t, (t - start_ns) / NS, m.text, m.category,
                   m.source, m.by) for m in read_marks(reader)[0] for t in (mark_time(m),)],
    })


def _group(topic: str) -> str:
    return topic.rsplit("/", 1)[-1]


def _log_entry(t_ns: int, data: bytes) -> tuple[int, str, str]:
    from foxglove_schemas_protobuf.Log_pb2 import Log

    log = Log.FromString(data)
    return t_ns, log.name, log.message


@dataclass(frozen=True)
class BeingRecorded:
    """A drive that a recording is writing (it holds its lock: :mod:`bridge.sinks.drives`)."""

    path: str


def read_drive_or_error(path: str) -> DriveRows | BeingRecorded | str:
    """:func:`read_drive`, its error as its one-line message: what a Dask task returns; a drive
    being recorded is not read."""
    if being_written(path):
        return BeingRecorded(shown(path))
    try:
        return read_drive(path)
    except BridgeError as exc:
        return str(exc)
    except Exception as exc:
        return shown(f"{path}: cannot index: {type(exc).__name__}: {exc}")


# ---------------------------------------------------------------------------------------------
# Which files are drives

_GLOB = re.compile(r"[*?\[]")


def find_drives(inputs: Sequence[str]) -> list[Path]:
    """The files ``inputs`` name: files as given, folders searched recursively for ``*.mcap``
    (hidden files left out: a recorder's partial output), globs expanded (``**`` recursive);
    each resolved (links and ``..`` followed) and named once."""
    found: dict[Path, None] = {}
    for text in inputs:
        path = Path(text)
        if _GLOB.search(text):
            matches = sorted(Path(p) for p in glob.glob(text, recursive=True))
            if not matches:
                raise InputError(text, "no file matches this pattern")
            for m in matches:
                if m.is_dir():
                    found.update(dict.fromkeys(_in_folder(m)))
                else:
                    found[m.resolve()] = None
        elif path.is_dir():
            found.update(dict.fromkeys(_in_folder(path)))
        elif os.path.lexists(path):
            found[_resolved(path)] = None
        else:
            raise InputError(path, "no such file or folder")
    return list(found)


def _in_folder(folder: Path) -> Iterator[Path]:
    """The drives in a folder; a link to nothing too, which is told (:func:`read_drive`)."""
    for p in sorted(folder.rglob("*.mcap")):
        if not p.is_dir() and not any(part.startswith(".")
                                      for part in p.relative_to(folder).parts):
            yield _resolved(p)


def _resolved(path: Path) -> Path:
    """The path resolved; a link to nothing is kept (in its resolved folder) to be told."""
    return path.resolve() if path.exists() else path.parent.resolve() / path.name


def drive_file(drive: str) -> Path | None:
    """The file of a catalogued drive (whose path may show bytes as ``\\xNN``), or None."""
    if os.path.exists(drive):
        return Path(drive)
    raw = re.sub(rb"\\x([0-9a-f]{2})", lambda m: bytes([int(m[1], 16)]), os.fsencode(drive))
    path = Path(os.fsdecode(raw))
    return path if shown(path) == drive and path.exists() else None


# ---------------------------------------------------------------------------------------------
# Reading many drives: here or on Dask workers

Reader = Callable[[Sequence[str]], Iterator[DriveRows | BeingRecorded | str]]


def read_here(paths: Sequence[str]) -> Iterator[DriveRows | BeingRecorded | str]:
    """Read drives one after the other in this process."""
    for p in paths:
        yield read_drive_or_error(p)


def dask_reader(*, workers: int | None = None, scheduler: str | None = None) -> Reader:
    """Read drives on Dask workers: a local cluster of ``workers`` processes, or the cluster of
    ``scheduler`` (whose workers must see the same paths)."""
    try:  # (untyped: used through Any)
        distributed: Any = importlib.import_module("dask.distributed")
    except ImportError:
        raise UsageError("--workers and --scheduler", "read drives on Dask, which is not "
                         f"installed: {FLEET_EXTRA}") from None
    if workers is not None and workers < 1:
        raise UsageError("--workers", "expected at least 1", value=workers)

    def read(paths: Sequence[str]) -> Iterator[DriveRows | BeingRecorded | str]:
        if not paths:
            return
        if scheduler is not None:
            try:
                client = distributed.Client(scheduler, timeout="10s")
            except OSError as exc:
                raise UsageError("--scheduler", f"cannot connect ({exc})",
                                 value=scheduler) from None
            cluster = None
        else:
            cluster = distributed.LocalCluster(n_workers=workers or 1, threads_per_worker=1,
                                   processes=True, dashboard_address=None)
            client = distributed.Client(cluster)
        try:
            futures = client.map(read_drive_or_error, list(paths), pure=False)
            for future in distributed.as_completed(futures):
                yield future.result()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()

    return read


# ---------------------------------------------------------------------------------------------
# The DuckDB file

def connect(catalog: Path | str, *, create: bool = False) -> Any:
    """A DuckDB connection to ``catalog`` (made and written when ``create``; its tables:
    :func:`make_tables`)."""
    try:
        import duckdb
    except ImportError:
        raise UsageError(str(catalog), "is a DuckDB catalogue, and duckdb is not installed: "
                         f"{FLEET_EXTRA}") from None
    catalog = Path(catalog)
    if (why := name_too_long(catalog)) is not None:  # (DuckDB's error would be pages)
        raise (FileError if create else InputError)(catalog, why)
    if not create and not catalog.is_file():
        raise InputError(catalog, "no such catalogue (make one with tankviz catalog DRIVES... "
                         f"-o {catalog})")
    try:
        con = duckdb.connect(str(catalog), read_only=not create)
    except duckdb.Error as exc:
        raise InputError(catalog, f"cannot open as a DuckDB catalogue: "
                         f"{' '.join(str(exc).split())}") from None
    return con


def make_tables(con: Any) -> set[str]:
    """Every table of :data:`SCHEMA` that the catalogue lacks, made; their names."""
    had = {name for (name,) in con.execute(
        "SELECT table_name FROM information_schema.tables").fetchall()}
    for table, columns in SCHEMA.items():
        con.execute(f"CREATE TABLE IF NOT EXISTS {table} ("
                    + ", ".join(f'"{name}" {kind}' for name, kind in columns) + ")")
    return set(SCHEMA) - had


@dataclass
class IndexReport:
    """What :func:`index` did."""

    new: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)
    unchanged: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    #: ``(path, one-line error)`` of every drive that could not be indexed
    failed: list[tuple[str, str]] = field(default_factory=list)
    #: drives a recording is writing: not read (nor failed), indexed once they are finished
    recording: list[str] = field(default_factory=list)

    @property
    def read(self) -> list[str]:
        """Every drive read this time (new or changed), indexed or failed."""
        return [*self.new, *self.changed, *(p for p, _ in self.failed)]

    def summary(self, catalog: Path | str) -> str:
        return (f"{catalog}: {len(self.new)} new, {len(self.changed)} changed, "
                f"{len(self.unchanged)} unchanged, {len(self.removed)} removed, "
                f"{len(self.failed)} not indexed"
                + (f", {len(self.recording)} being recorded" if self.recording else ""))


def index(catalog: Path | str, inputs: Sequence[str], *, reader: Reader = read_here
          ) -> IndexReport:
    """(Re)index the drives ``inputs`` name into ``catalog``: only new or changed drives (size
    or modification time) are read; drives whose file is gone are removed (and those indexed
    under a path that was not resolved, which are read again under their resolved path); a
    catalogue missing newer tables gets them.

    Drives are read by ``reader`` (here or on Dask workers); this process alone writes the DuckDB
    file, one transaction per drive. A drive that cannot be read is reported with its one-line
    error and the others are indexed.
    """
    files = find_drives(inputs)
    con = connect(catalog, create=True)
    report = IndexReport()
    try:
        added = make_tables(con)
        known = {p: (size, mtime) for p, size, mtime in
                 con.execute("SELECT path, size, mtime_ns FROM drives").fetchall()}
        # a table an older catalogue lacked: the drives that hold its topic are read again
        again = {p for table in added & set(ADDED_TABLES) for (p,) in con.execute(
            "SELECT drive FROM topics WHERE topic = ? AND count > 0", [ADDED_TABLES[table]]
        ).fetchall()}
        to_read: list[str] = []  # (the files' own paths: the keys show them, :func:`shown`)
        for f in files:
            key = shown(f)
            try:
                stat = f.stat()
            except OSError:  # (a link to nothing: reading it says so)
                stat = None
            if (stat is None or known.get(key) != (stat.st_size, stat.st_mtime_ns)
                    or key in again):
                to_read.append(str(f))
            else:
                report.unchanged.append(key)
        for p in sorted(known):
            file = drive_file(p)
            if file is None or shown(file.resolve()) != p:  # gone, or not resolved
                _delete(con, p)  # (indexed before paths were: the resolved one is read now)
                report.removed.append(p)
        for result in reader(to_read):
            if isinstance(result, BeingRecorded):
                report.recording.append(result.path)
                continue
            if isinstance(result, str):
                path = next((shown(p) for p in to_read if result.startswith(shown(p) + ":")),
                            result)
                report.failed.append((path, result))
                if path in known:  # changed into something unreadable: not what it was
                    _delete(con, path)
                continue
            _write(con, result)
            (report.changed if result.path in known else report.new).append(result.path)
    finally:
        con.close()
    return report


def _delete(con: Any, drive: str) -> None:
    con.begin()
    for table in SCHEMA:
        con.execute(f"DELETE FROM {table} WHERE {'path' if table == 'drives' else 'drive'} = ?",
                    [drive])
    con.commit()


def _write(con: Any, rows: DriveRows) -> None:
    con.begin()
    try:
        for table in SCHEMA:
            con.execute(f"DELETE FROM {table} WHERE {'path' if table == 'drives' else 'drive'}"
                        " = ?", [rows.path])
            if rows.tables[table]:
                marks = ", ".join("?" * len(SCHEMA[table]))
                con.executemany(f"INSERT INTO {table} VALUES ({marks})", rows.tables[table])
        con.commit()
    except BaseException:
        con.rollback()
        raise
