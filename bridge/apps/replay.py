"""``tankviz replay``: a recorded drive (MCAP) or any CAN log, served live in real time.

An MCAP is served as recorded, a CAN log goes through the pipeline as if from the bus, a drive
given ``--profile``, ``--dbc`` or ``--rederive`` is re-derived live. The server publishes its
time, so viewers follow log time; ``--for`` and SIGTERM, SIGINT or SIGHUP (a closed terminal)
end a replay within a twentieth of a second whatever a read does.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import struct
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Attachment, Chunk, DataEnd, Footer, Message
from mcap.stream_reader import StreamReader

from bridge.apps import hints, options
from bridge.apps.live import output_may_vanish
from bridge.apps.options import (
    Subparsers,
    add_run_for,
    add_server_options,
    add_stage_options,
    install_stop_signals,
)
from bridge.decode.database import parse_dbc_option
from bridge.errors import BridgeError, InputError, UsageError, check_input_path
from bridge.frame import NS
from bridge.io.can_logs import LogSource, merge, supported_suffixes
from bridge.io.drives import (
    METADATA_NAME,
    ArchiveContents,
    ArchiveSource,
    drive_marks,
    read_drive,
)
from bridge.io.readahead import read_in_thread
from bridge.io.unreadable import MAGIC, why_unreadable
from bridge.pb.bringup_pb2 import CanPayload
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline import DEFAULT_SCENE_RATE
from bridge.pipeline.convert import Source
from bridge.pipeline.drive import PROFILE_PREFIX, Drive, Stages
from bridge.pipeline.marks import describe
from bridge.pipeline.rederive import (
    CarriedMarks,
    describe_rederive,
    recorded_scene_rate,
    rederive_stages,
)
from bridge.resources import layouts_dir
from bridge.sinks.server import ViewerServer
from bridge.view.bringup import bringup_layout
from bridge.view.generate import DEFAULT_BUS, database_buses, generate_layouts, layout_text

#: Server time is published at least this often (ns of log time).
TIME_EVERY_NS = 50_000_000
#: ``--start mark:N`` starts this many seconds before the mark: what led to it is seen.
MARK_LEAD_S = 5.0
#: How ``--start`` names a mark.
MARK_PREFIX = "mark:"
#: How many marks an error lists (the rest: ``… and N more``).
MARKS_LISTED = 10


@dataclass
class Clock:
    """Maps log time to wall time at ``speed``, waiting until each message is due."""

    speed: float
    stopping: threading.Event
    #: called before each wait (to send what was published meanwhile)
    before_waiting: Callable[[], None] = lambda: None
    _origin_ns: int | None = None
    _origin_wall: float = 0.0

    def start(self, log_ns: int) -> None:
        self._origin_ns, self._origin_wall = log_ns, time.monotonic()

    def wait(self, log_ns: int) -> bool:
        """Sleep until ``log_ns`` is due; False when stopped meanwhile."""
        if self._origin_ns is None:
            self.start(log_ns)
        assert self._origin_ns is not None
        due = self._origin_wall + (log_ns - self._origin_ns) / NS / self.speed
        delay = due - time.monotonic()
        if delay > 0:
            self.before_waiting()
            return not self.stopping.wait(delay)
        return not self.stopping.is_set()


@dataclass
class ReplayReport:
    messages: int
    loops: int


def _check(speed: float, start_s: float) -> None:
    if not speed > 0:
        raise UsageError("--speed", "must be above 0", value=f"{speed:g}")
    if start_s < 0:
        raise UsageError("--start", "must not be negative", value=f"{start_s:g}")


def start_seconds(text: str) -> float | None:
    """``--start``'s seconds; None for a mark (``mark:N``, ``mark:TEXT``)."""
    if text.startswith(MARK_PREFIX):
        if not text[len(MARK_PREFIX):].strip():
            raise UsageError("--start", "name a mark: mark:N (its number) or mark:TEXT (the "
                             "first whose text contains TEXT)", value=text)
        return None
    try:
        return float(text)
    except ValueError:
        raise UsageError("--start", "expected SECONDS, mark:N or mark:TEXT", value=text) from None


def find_mark(marks: Sequence[Mark], wanted: str) -> Mark | None:
    """The mark numbered ``wanted``, or else the first (by number) whose text contains it, in
    any case; None if there is none."""
    if wanted.isdigit():
        return next((m for m in marks if m.number == int(wanted)), None)
    folded = wanted.casefold()
    return next((m for m in marks if folded in m.text.casefold()), None)


def mark_start_s(path: Path, text: str) -> tuple[float, Mark]:
    """Where ``--start mark:N`` (``text``) starts a replay of the drive at ``path``: seconds
    from its first message, :data:`MARK_LEAD_S` before the mark (0 at the most), and the mark.
    A mark that is not there is a :class:`~bridge.errors.UsageError` naming the drive's marks."""
    wanted = text[len(MARK_PREFIX):].strip()
    found = drive_marks(path)
    if not found.marks:
        raise UsageError("--start", f"{path.name} has no marks", value=text)
    mark = find_mark(found.marks, wanted)
    if mark is None:
        what = (f"mark {wanted}" if wanted.isdigit()
                else f"mark whose text contains {wanted!r}")
        listed = [f"{m.number} {m.text} ({found.seconds(m):.1f} s)"
                  for m in found.marks[:MARKS_LISTED]]
        more = len(found.marks) - len(listed)
        raise UsageError("--start", f"{path.name} has no {what}; its marks: "
                         + ", ".join(listed) + (f", … and {more} more" if more else ""),
                         value=text)
    return max(0.0, found.seconds(mark) - MARK_LEAD_S), mark


def _span_ns(path: Path) -> int | None:
    """How far apart an MCAP's first and last messages are, from its summary (None without
    one: a drive cut short tells only as it is read)."""
    try:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
    except Exception:  # a file cut short or damaged: mcap raises many types
        return None
    if summary is None or summary.statistics is None:
        return None
    return int(summary.statistics.message_end_time - summary.statistics.message_start_time)


def _past_end(start_s: float, span_ns: int) -> UsageError:
    """``--start`` past the end of a drive whose first and last messages are ``span_ns`` apart."""
    return UsageError("--start", f"the drive is only {span_ns / NS:.1f} s long",
                      value=f"{start_s:g}")


def replay_mcap(path: Path, server: ViewerServer, *, speed: float = 1.0, loop: bool = False,
                start_s: float = 0.0, stopping: threading.Event | None = None,
                on_loop: Callable[[int], None] | None = None,
                on_unknown: Callable[[str, str], None] | None = None) -> ReplayReport:
    """Serve every message of an MCAP at its log time (from ``start_s`` into the drive);
    ``on_unknown`` is told ``(bus, id)`` of the first message of each bus's
    ``/can/<bus>/unknown`` (an id no database of the drive knew, ``0x2C4``)."""
    watched: set[str] = set()
    _check(speed, start_s)
    stopping = stopping or threading.Event()
    sent, loops = 0, 0
    while not stopping.is_set():
        clock = Clock(speed, stopping, server.flush)
        last_time_ns = 0
        for topic, schema_name, encoding, schema, data, log_ns in read_in_thread(
                _mcap_messages(path, start_s), stopping, name="tankviz-replay-read"):
            if not clock.wait(log_ns):
                break
            if log_ns - last_time_ns >= TIME_EVERY_NS:
                server.broadcast_time(log_ns)
                last_time_ns = log_ns
            channel = server.channel_for_schema(
                topic, schema_name, schema, encoding=encoding,
                schema_encoding="protobuf" if encoding == "protobuf" else "jsonschema")
            server.publish(channel, log_ns, data)
            if on_unknown is not None and topic not in watched:
                watched.add(topic)
                _first_unknown(topic, schema_name, data, on_unknown)
            sent += 1
        server.flush()
        loops += 1
        if on_loop is not None:
            on_loop(loops)
        if not loop:
            break
    return ReplayReport(sent, loops)


#: A bus's ``/can/<bus>/unknown`` topic (:func:`bridge.topics.unknown_topic`).
_UNKNOWN_TOPIC = re.compile(r"/can/([^/]+)/unknown")


def _first_unknown(topic: str, schema_name: str, data: bytes,
                   on_unknown: Callable[[str, str], None]) -> None:
    """Tell ``on_unknown`` the bus and id of a ``/can/<bus>/unknown`` message (the first of
    its topic)."""
    match = _UNKNOWN_TOPIC.fullmatch(topic)
    if match is None or schema_name != "tankviz.CanPayload":
        return
    with contextlib.suppress(Exception):  # (a message that does not parse: no line)
        on_unknown(match[1], CanPayload.FromString(data).id)


def _mcap_messages(path: Path, start_s: float) -> Iterator[tuple[str, str, str, bytes, bytes,
                                                                  int]]:
    """The messages of an MCAP from ``start_s`` into it: found through its summary, else (a
    drive cut short) by reading past those before. Nothing after ``start_s`` is
    :func:`_past_end`."""
    skip_ns = round(start_s * NS)
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            start_ns = None
            if summary is not None and summary.statistics is not None and start_s:
                first = summary.statistics.message_start_time
                span = summary.statistics.message_end_time - first
                if skip_ns > span:
                    raise _past_end(start_s, span)
                start_ns = first + skip_ns
            first_ns: int | None = None
            last_ns = given = 0
            for schema, channel, message in reader.iter_messages(starting_at=start_ns,
                                                                 log_time_order=True):
                if start_ns is None and start_s:  # no summary: skip to the start here
                    first_ns = message.log_time if first_ns is None else first_ns
                    last_ns = max(last_ns, message.log_time)
                    if message.log_time - first_ns < skip_ns:
                        continue
                given += 1
                yield (channel.topic, schema.name if schema else "", channel.message_encoding,
                       schema.data if schema else b"", message.data, message.log_time)
            if not given and first_ns is not None:
                raise _past_end(start_s, last_ns - first_ns)
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except (McapError, ValueError, struct.error, EOFError, RuntimeError) as exc:
        raise InputError(path, why_unreadable(path, exc)) from None


def replay_log(paths: list[Path], stages: Stages, server: ViewerServer, *,
               scene_rate: float = DEFAULT_SCENE_RATE,
               speed: float = 1.0, loop: bool = False, start_s: float = 0.0,
               stopping: threading.Event | None = None,
               on_unknown: Callable[[str, int], None] | None = None,
               bring_up: bool = True) -> ReplayReport:
    """Run CAN logs through the pipeline in real time and serve what it makes; ``on_unknown``
    is told ``(bus, frame key)`` of the first id no database knows on each bus; ``bring_up``:
    the bring-up topics too."""
    return _replay_frames(lambda: [LogSource(p) for p in paths], stages, server,
                          scene_rate=scene_rate, speed=speed, loop=loop, start_s=start_s,
                          stopping=stopping, on_unknown=on_unknown, bring_up=bring_up)


def replay_drive(path: Path, stages: Stages, server: ViewerServer, *,
                 scene_rate: float = DEFAULT_SCENE_RATE,
                 speed: float = 1.0, loop: bool = False, start_s: float = 0.0,
                 stopping: threading.Event | None = None,
                 on_unknown: Callable[[str, int], None] | None = None,
                 bring_up: bool = True) -> ReplayReport:
    """Re-derive a recorded drive live: its raw frames through the pipeline in real time
    (``on_unknown``, ``bring_up``: as :func:`replay_log`)."""
    return _replay_frames(lambda: [ArchiveSource(path)], stages, server, scene_rate=scene_rate,
                          speed=speed, loop=loop, start_s=start_s, stopping=stopping,
                          on_unknown=on_unknown, bring_up=bring_up,
                          marks=drive_marks(path).marks)


def _replay_frames(make_sources: Callable[[], Sequence[Source]], stages: Stages,
                   server: ViewerServer, *, scene_rate: float, speed: float, loop: bool,
                   start_s: float, stopping: threading.Event | None,
                   on_unknown: Callable[[str, int], None] | None = None,
                   bring_up: bool = True, marks: Sequence[Mark] = ()) -> ReplayReport:
    """Frames through a pipeline in real time, served (``marks``: a re-derived drive's, made
    again where its frames reach them, those before ``start_s`` left out)."""
    _check(speed, start_s)
    stopping = stopping or threading.Event()
    skip_ns = round(start_s * NS)
    frames, loops = 0, 0
    while not stopping.is_set():
        sources = make_sources()
        drive = Drive(stages, [server], scene_rate=scene_rate, bring_up=bring_up)
        if on_unknown is not None:
            hints.watch_unknown(drive, on_unknown)
        process = drive.pipeline.process
        carried = CarriedMarks(marks, drive.pipeline) if marks else None
        clock = Clock(speed, stopping, server.flush)
        first_ns: int | None = None
        last_ns = last_time_ns = 0
        given = 0
        for frame in read_in_thread(merge(sources), stopping, name="tankviz-replay-read"):
            t = frame.timestamp_ns
            if first_ns is None:
                first_ns = t
            if t - first_ns < skip_ns:
                last_ns = max(last_ns, t)
                if carried is not None:
                    carried.before(t, emit=False)
                continue
            if not clock.wait(t):
                break
            if t - last_time_ns >= TIME_EVERY_NS:
                server.broadcast_time(t)
                last_time_ns = t
            if carried is not None:
                carried.before(t)
            process(frame)
            given += 1
        if carried is not None and not stopping.is_set():
            carried.finish()
        drive.finish()
        if not given and first_ns is not None and not stopping.is_set():
            raise _past_end(start_s, last_ns - first_ns)
        frames += given
        loops += 1
        if not loop:
            break
    return ReplayReport(frames, loops)


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "replay", help="serve a recorded drive or CAN logs to Foxglove in real time",
        description="Serve a recorded drive (MCAP) as recorded, or CAN logs decoded through the "
        "pipeline, in real time; the server publishes log time so Foxglove follows it.")
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE",
                        help="a recorded drive (one .mcap), or CAN logs, merged in time order "
                        f"({' '.join(s for s in supported_suffixes() if not s.endswith('.gz'))}"
                        ", and those gzipped)")
    parser.add_argument("--speed", type=float, default=1.0, help="playback speed (default 1)")
    parser.add_argument("--loop", action="store_true", help="start again at the end")
    parser.add_argument("--start", default="0", metavar="SECONDS|mark:N|mark:TEXT",
                        help="skip this many seconds of the drive; or start "
                        f"{MARK_LEAD_S:g} s before a mark of a recorded drive: its number, or "
                        "the first whose text contains TEXT")
    add_run_for(parser)
    add_stage_options(parser, profile_default=None)
    parser.add_argument("--rederive", action="store_true",
                        help="a drive (MCAP): run its raw frames through the pipeline again "
                        "with its attached databases and profile (implied by --dbc or "
                        "--profile, which replace them) instead of serving it as recorded")
    add_server_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    for path in args.files:  # a FIFO would be waited on: one line instead
        check_input_path(path)
    mcap = [p for p in args.files if p.suffix.lower() == ".mcap"]
    if mcap and len(args.files) > 1:
        raise UsageError("replay", "one MCAP at a time (CAN logs can be several)")
    named, seconds = args.start, start_seconds(args.start)
    note = None
    if seconds is None:  # a mark
        if not mcap:
            raise UsageError("--start", "CAN logs have no marks (a drive tankviz "
                             "recorded, .mcap, has)", value=named)
        seconds, mark = mark_start_s(mcap[0], named)
        note = f"starting {MARK_LEAD_S:g} s before {describe(mark)}, at {seconds:.3f} s"
    args.start, args.start_note = seconds, note
    if not mcap:
        stages = options.stages(args)
        return _serve(args, mcap, stages, hints.layout_hint(
            stages, layout_files, profile=args.profile, dbcs=args.dbc or []),
            bringup_hint(stages, None))
    with tempfile.TemporaryDirectory(prefix="tankviz-rederive-") as folder:
        if not (args.rederive or args.profile or args.dbc):
            recorded = _recorded_stages(mcap[0], Path(folder))
            return _serve(args, mcap, None, _recorded_hint(*recorded) if recorded else None,
                          bringup_hint(*recorded) if recorded else
                          hints.BringupHint(Path(hints.BRINGUP_FOLDER), [], bringup_file))
        drive = read_drive(mcap[0])
        dbcs = [options.dbc_option(text) for text in args.dbc or []]
        stages = rederive_stages(drive, dbcs, args.profile, Path(folder))
        print(describe_rederive(drive, stages, dbcs, args.profile))
        if args.scene_rate is None:
            args.scene_rate = recorded_scene_rate(drive)
        try:
            hint: hints.LayoutHint | None = drive_layout_hint(drive, stages, args.profile,
                                                                args.dbc or [])
        except BridgeError:  # (a recorded path that is no path): no hint, the replay goes on
            hint = None
        return _serve(args, mcap, stages, hint, bringup_hint(stages, drive))


def drive_layout_hint(drive: ArchiveContents, stages: Stages, profile: str | None,
                      dbcs: Sequence[str]) -> hints.LayoutHint:
    """The layout to import for a recorded drive decoded with ``stages``: those made for its
    profile in ``layouts/<profile>/`` beside it (where ``tankviz live`` writes them) when they
    are there, else the command that writes them there, naming the profile and databases
    given, else those the drive was recorded with (it holds them as attachments)."""
    loaded = stages.profile
    if loaded is None or hints.is_bundled(stages):
        return hints.layout_hint(stages, layout_files, profile=profile,
                                   dbcs=dbcs or recorded_dbcs(drive))
    recorded = [] if dbcs else recorded_dbcs(drive)
    missing = any(not parse_dbc_option(text)[1].exists() for text in recorded)
    what = (f"{loaded.path.name} and the databases: those" if profile is None and missing else
            f"{loaded.path.name}: the profile" if profile is None else
            "the databases: those" if missing else None)
    note = f"({what} {drive.path} was recorded with, attached to it)" if what else None
    return hints.layout_hint(
        stages, layout_files, profile=profile if profile is not None else loaded.path.name,
        dbcs=list(dbcs) or recorded,
        folder=drive.path.parent / "layouts" / hints.layout_folder(loaded.name), note=note)


def layout_files(stages: Stages, buses: Sequence[str] | None) -> dict[str, str]:
    """The layouts made for the profile of ``stages`` on ``buses``, as files (name -> text)."""
    assert stages.profile is not None
    return {f"{name}.json": layout_text(data) for name, data
            in generate_layouts(stages.profile, stages.decoder, buses).items()}


def recorded_dbcs(drive: ArchiveContents) -> list[str]:
    """The ``--dbc`` arguments a drive was recorded with (its metadata: each database's path
    and buses), else the names of its database attachments."""
    entries = drive.metadata.get("databases")
    if not isinstance(entries, list):
        return [name for name in drive.attachments if not name.startswith(PROFILE_PREFIX)]
    return [str(entry.get("path")) if bus == "*" else f"{bus}={entry.get('path')}"
            for entry in entries if isinstance(entry, dict)
            for bus in entry.get("buses") or ["*"]]


def _recorded_stages(path: Path, folder: Path) -> tuple[Stages, ArchiveContents] | None:
    """The attached profile and databases of a drive served as recorded, loaded for it (read
    through the file's indexes: a drive of hours is not read through); None for a file whose
    profile cannot be told."""
    try:
        drive = _attached(path)
        if not (drive.metadata or drive.attachments):
            return None  # not a drive tankviz recorded: nothing tells its profile
        return rederive_stages(drive, [], None, folder), drive
    except Exception:  # an MCAP tankviz did not write, a profile of another version: no hint
        return None


def _recorded_hint(stages: Stages, drive: ArchiveContents) -> hints.LayoutHint | None:
    """The layout hint of a drive served as recorded (:func:`_recorded_stages`)."""
    try:
        return drive_layout_hint(drive, stages, None, [])
    except Exception:  # a profile of another version: no hint
        return None


def bringup_hint(stages: Stages, drive: ArchiveContents | None) -> hints.BringupHint:
    """What replay says when a bus first carries an id no database knows
    (:class:`bridge.apps.hints.BringupHint`): for a recorded drive, the bring-up layout where
    ``tankviz live`` writes it beside the drive (``layouts/<profile>/``, ``layouts/`` without
    a profile) made for the buses it was recorded from; for logs, the one in
    ``<profile>-layouts`` (or ``bring-up-layouts``) made for the databases' buses; else the
    command that writes it there. The bundled one for the bundled profile on can0 alone."""
    profile = stages.profile
    name = hints.layout_folder(profile.name) if profile is not None else None
    if drive is not None:
        folder = drive.path.parent / "layouts"
        folder = folder / name if name else folder
    else:
        folder = Path(f"{name}-layouts" if name else hints.BRINGUP_FOLDER)
    buses = recorded_buses(drive) if drive is not None else []
    buses = buses or database_buses(stages.decoder)
    bundled = (layouts_dir() / hints.BRINGUP_LAYOUT
               if hints.is_bundled(stages) and buses == [DEFAULT_BUS] else None)
    return hints.BringupHint(folder, buses, bringup_file, bundled=bundled)


def recorded_buses(drive: ArchiveContents) -> list[str]:
    """The names of the buses a drive was recorded from, as its metadata says (``tankviz
    live``: ``can0=socketcan:can0``, ``car (python-can config)``); none if it does not."""
    buses = drive.metadata.get("buses")
    if not isinstance(buses, list):
        return []
    return list(dict.fromkeys(re.split(r"[= ]", str(b), maxsplit=1)[0] for b in buses))


def bringup_file(buses: Sequence[str]) -> str:
    """The bring-up layout for ``buses`` as its file's text."""
    return layout_text(bringup_layout(buses))


def _attached(path: Path) -> ArchiveContents:
    """The attachments and ``tankviz`` metadata of an MCAP, read through its summary (a drive
    cut short has none: its attachments are read at its start, where tankviz writes them)."""
    attachments: dict[str, bytes] = {}
    metadata: dict[str, Any] = {}
    with path.open("rb") as stream:
        reader = make_reader(stream)
        try:
            summary = reader.get_summary()
        except Exception:  # a file cut short: mcap raises many types
            summary = None
        if summary is None:
            stream.seek(0)
            with contextlib.suppress(Exception):  # (where the file was cut)
                for record in StreamReader(stream, emit_chunks=True).records:
                    if isinstance(record, Attachment):
                        attachments.setdefault(record.name, bytes(record.data))
                    elif isinstance(record, (Chunk, Message, DataEnd, Footer)):
                        break
            return ArchiveContents(path, 0, "", metadata, attachments, complete=False)
        for a in reader.iter_attachments():
            attachments.setdefault(a.name, bytes(a.data))
        for m in reader.iter_metadata():
            if m.name == METADATA_NAME:
                metadata = {key: json.loads(text) if text[:1] in "[{" or text == "null" else text
                            for key, text in m.metadata.items()}
    return ArchiveContents(path, 0, "", metadata, attachments)


def _serve(args: argparse.Namespace, mcap: list[Path], stages: Stages | None,
           hint: hints.LayoutHint | None, unknown: hints.BringupHint) -> int:
    with output_may_vanish():  # (a closed terminal ends the replay as SIGTERM does, quietly)
        return _serving(args, mcap, stages, hint, unknown)


def _serving(args: argparse.Namespace, mcap: list[Path], stages: Stages | None,
             hint: hints.LayoutHint | None, unknown: hints.BringupHint) -> int:
    _check(args.speed, args.start)  # before a word is printed or a port taken
    for path in mcap:  # a file that is no MCAP at all (a drive cut as it was created)
        with path.open("rb") as stream:
            if stream.read(len(MAGIC)) != MAGIC:
                raise InputError(path, why_unreadable(path))
    if mcap and args.start:
        span = _span_ns(mcap[0])
        if span is not None and round(args.start * NS) > span:
            raise _past_end(args.start, span)
    stopping = threading.Event()
    server = options.start_server(args, server_time=True, mode="replay")
    install_stop_signals(stopping.set)
    timer = threading.Timer(args.run_for or 0, stopping.set)
    timer.daemon = True  # (a replay that ends first does not wait for it)
    if args.run_for:
        timer.start()
    print(*hints.connection_lines(server.host, server.urls), sep="\n")
    if hint is not None:
        hint.say()
    if getattr(args, "start_note", None):  # --start mark:N
        print(args.start_note)
    sys.stdout.flush()
    try:
        if stages is None:
            report = replay_mcap(mcap[0], server, speed=args.speed, loop=args.loop,
                                 start_s=args.start, stopping=stopping,
                                 on_unknown=unknown.tell_text)
        elif mcap:
            report = replay_drive(mcap[0], stages, server, scene_rate=options.scene_rate(args),
                                  speed=args.speed, loop=args.loop, start_s=args.start,
                                  stopping=stopping, on_unknown=unknown.tell,
                                  bring_up=options.bring_up(args))
        else:
            report = replay_log(list(args.files), stages, server,
                                scene_rate=options.scene_rate(args),
                                speed=args.speed, loop=args.loop, start_s=args.start,
                                stopping=stopping, on_unknown=unknown.tell,
                                bring_up=options.bring_up(args))
    finally:
        timer.cancel()
        server.stop()
    what = "frames" if stages is not None and mcap else "messages"
    print(f"replayed {report.messages:,} {what} ({report.loops} pass"
          f"{'es' if report.loops != 1 else ''})")
    return 0
