"""``tankviz live``: CAN buses in, Foxglove live, every drive recorded.

The pipeline thread reads every bus (python-can's own bus creation: any interface, several at
once) a few times per scene period, just after each scene tick and between, and turns the frames
into the recording (never dropping one) and the live scene (never waiting for a viewer). Each
bus has a thread that opens it. Every bus is opened before anything is printed: a bus that
cannot work at all (an unknown interface, a NAME without python-can configuration) is an error
at once, never retried; a bus that does not open (a socketcand server that is down, an address
that is not one, an interface that is not there) is retried for at most
:data:`~bridge.io.buses.OPEN_WAIT_S` seconds (15; less if the run is stopped first: ``--for``,
Ctrl+C), and if it has never opened by then it is an error: one line, exit 1, nothing recorded.
When a bus that had opened fails (adapter unplugged, interface down) live says so, retries with
backoff for as long as it runs and says when it is back; the pipeline keeps running, viewers get
a ``foxglove.Log`` on ``/log``, and the recording marks the gap (``bus_gaps``; its reason is one
line). python-can's own log lines are said once per cause, then counted
(:class:`~bridge.io.buses.CanLogLimiter`).

What the reading of a bus mends or loses (:class:`~bridge.health.receive.ReceiveCounts`: frames
stamped NaN, kept and stamped when read; what is not a frame; frames the kernel dropped because
live read too late, where python-can exposes the socket) goes to the health monitor (``/log``
warnings, the ``bus.<bus>.bad_timestamps`` and ``bus.<bus>.frames_lost`` alarms on ``/health``),
into the drive's metadata (``bus_receive``: the counts per bus) and into the end-of-run lines.
A full disk (or free space below ``--min-free``) stops the recording, not the drive: the part is
finished, ``recorder.disk_full`` is raised on ``/log`` and ``/health``, viewers are still served
and recording resumes in a new part when there is room (:mod:`bridge.sinks.drives`).

Log time is the frames' clock (:class:`~bridge.io.buses.ReadSchedule` follows it with the wall
clock). When it steps (:mod:`bridge.pipeline.clock`: a frame stamped more than a second before log
time, or more than two seconds after it), the pipeline re-bases its scene ticks, health windows
and lifetimes at once and says so on ``/log``, the schedule takes the new offset at once, and the
drive's metadata lists the step (``clock_steps``); every frame is recorded with its own stamp.
When the pipeline falls behind (a loaded machine), the scenes of every tick it missed are made
and recorded; viewers get the latest. Once started, the garbage collector runs with
:func:`bridge.pipeline.collector.steady_stream`'s settings (start-up frozen, rare young
collections, a full one a minute where the loop waits), and the process's own come back at the
end. At the end it prints how many messages slow viewers lost: which viewers, and of which
topics (the few that lost most, the rest counted); a run that got no frame says so (and, on a
``virtual`` bus, that only the same process can send onto it).

At start it names the layout to import (:func:`layout_hint`): the bundled one for the bundled
ecocar profile; for another profile the layouts made for it and these buses, written into
``DRIVES/layouts/<profile>/`` when recording (never over a file, never failing the drive), else
the ``tankviz layouts`` command that writes them.
"""

from __future__ import annotations

import argparse
import dataclasses
import queue
import shlex
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.apps import hints, options
from bridge.apps.options import (
    Subparsers,
    add_record_options,
    add_server_options,
    add_stage_options,
    install_stop_signals,
)
from bridge.decode.decoder import parse_dbc_option
from bridge.errors import UsageError
from bridge.frame import NS, Frame, timestamp
from bridge.health.alarms import AlarmKind
from bridge.io.buses import (
    OPEN_WAIT_S,
    BusEvent,
    BusLink,
    BusSpec,
    ReadSchedule,
    ReceiveCounts,
    limit_can_logs,
    merge_batches,
)
from bridge.pipeline.clock import LIVE_FORWARD_NS, StepDetector
from bridge.pipeline.collector import steady_stream
from bridge.pipeline.drive import Drive, Stages
from bridge.pipeline.perception import DEFAULT_SCENE_RATE
from bridge.sinks.drives import Gap
from bridge.sinks.server import ClientStats, LiveServer
from bridge.topics import LOG_TOPIC, TopicMessage
from bridge.view.generate import DEFAULT_BUS, generate_layouts, layout_text


def log_message(t_ns: int, level: Any, text: str) -> TopicMessage:
    return TopicMessage(LOG_TOPIC, Log(timestamp=timestamp(t_ns), level=level, message=text,
                                       name="tankviz"), t_ns)


@dataclass
class LiveReport:
    frames: int
    files: list[Path]
    gaps: list[Gap]
    dropped: int
    #: every viewer, with what it lost
    viewers: list[ClientStats] = field(default_factory=list)
    #: what each bus's reading mended or lost
    receive: dict[str, ReceiveCounts] = field(default_factory=dict)


def dropped_report(viewers: Sequence[ClientStats], *, most: int = 3) -> str:
    """How many messages slow viewers lost: the ``most`` viewers that lost most, each with the
    ``most`` topics it lost most of, the rest counted (``and N more``)."""
    lost = sorted((v for v in viewers if v.dropped), key=lambda v: -v.dropped)
    text = f"{sum(v.dropped for v in lost):,} messages dropped for slow viewers"
    if not lost:
        return text

    def viewer(v: ClientStats) -> str:
        topics = v.topics.most_common()
        shown = [f"{topic} {n:,}" for topic, n in topics[:most]]
        if len(topics) > most:
            shown.append(f"and {len(topics) - most} more topics")
        return f"{v.address} lost {v.dropped:,} (" + ", ".join(shown) + ")"

    text += ": " + "; ".join(viewer(v) for v in lost[:most])
    if len(lost) > most:
        text += f"; and {len(lost) - most} more viewers"
    return text


def nothing_came(buses: Sequence[BusSpec], *, recording: bool, files: bool) -> list[str]:
    """What a run that got no frame says at its end (``files``: whether a file was made all
    the same, for the lines on ``/log``)."""
    lines = ["no frame came on any bus" + (
        "" if not recording else ": nothing was recorded" if not files else
        ": the recording has no frame")]
    lines += [f"{b.name} is a python-can virtual bus: only this same process can send onto it "
              "(another program's virtual bus is not this one)"
              for b in buses if b.interface == "virtual"]
    return lines


def receive_report(receive: dict[str, ReceiveCounts]) -> list[str]:
    """The end-of-run lines of what the buses' reading mended or lost (nothing if nothing)."""
    lines = []
    for bus, c in receive.items():
        said = []
        if c.bad_timestamps:
            said.append(f"{c.bad_timestamps:,} frames stamped {c.last_bad_timestamp} s (kept, "
                        "stamped when received)")
        if c.kernel_drops:
            said.append(f"{c.kernel_drops:,} frames lost in the receive buffer (the kernel "
                        "dropped them)")
        if c.unreadable:
            said.append(f"{c.unreadable:,} messages that are not CAN frames (skipped; the "
                        f"latest: {c.last_unreadable})")
        if said:
            lines.append(f"bus {bus}: " + "; ".join(said))
    return lines


_NOTHING = ReceiveCounts()


class Live:
    """The live pipeline: the buses, the pipeline thread's loop, recorder and server."""

    def __init__(self, buses: Sequence[BusSpec], stages: Stages, *,
                 scene_rate: float = DEFAULT_SCENE_RATE,
                 drives: Path | None = Path("drives"), server: LiveServer | None = None,
                 split_size: int | None = None, split_duration_s: float | None = None,
                 min_free: int = 0,
                 open_bus: Callable[[BusSpec], can.BusABC] = BusSpec.open,
                 open_wait_s: float = OPEN_WAIT_S,
                 say: Callable[[str], None] = print) -> None:
        names = [b.name for b in buses]
        if len(set(names)) != len(names):
            raise UsageError(f"--bus: a bus name is used twice ({', '.join(names)})")
        self.buses = list(buses)
        self.scene_rate = scene_rate
        self.server = server
        self.say = say
        self.open_wait_s = open_wait_s
        self.events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
        self.links = [BusLink(spec, self.events, open_bus=open_bus) for spec in buses]
        self.drive = Drive(stages, scene_rate=scene_rate,
                           bitrates={b.name: b.bitrate for b in buses if b.bitrate is not None},
                           extra={"buses": [str(b) for b in self.buses]})
        #: what each bus's reading mended or lost, as last told (in the metadata: bus_receive)
        self.receive: dict[str, ReceiveCounts] = {}
        self._receive_record: dict[str, dict[str, Any]] = {}
        self.drive.extra["bus_receive"] = self._receive_record
        # Live knows log time from the wall clock too: a step a few seconds ahead is one.
        self.drive.pipeline.clock = StepDetector(forward_ns=LIVE_FORWARD_NS)
        if server is not None:
            # first: viewers wait for a scene, the recorder does not; and viewers may get fewer
            # scenes when the pipeline catches up, the recording gets every one
            self.drive.pipeline.add_viewer(server)
        self.recorder = (self.drive.record_parts(drives, split_size=split_size,
                                                 split_duration_s=split_duration_s)
                         if drives is not None else None)
        if self.recorder is not None:
            self.recorder.min_free = min_free
            self.recorder.check_space()
        self.pipeline = self.drive.pipeline
        self.pipeline.advertise(names)
        self.stopping = threading.Event()
        self._down: dict[str, Gap] = {}

    def stop(self) -> None:
        self.stopping.set()

    def start(self) -> None:
        """Open the buses (each by its opener thread); returns once each is open. A bus that
        cannot work (:func:`bridge.io.buses.configuration_error`) raises its ``UsageError`` at
        once; a bus that has not opened after :attr:`open_wait_s` seconds (or when the run is
        stopped first) raises one saying so. Then the buses are closed and nothing is
        recorded."""
        for link in self.links:
            link.start()
        began = time.monotonic()
        while True:
            error = next((link.error for link in self.links if link.error is not None), None)
            waiting = [link for link in self.links if not link.opened.is_set()]
            if (error is not None or not waiting or self.stopping.is_set()
                    or time.monotonic() - began >= self.open_wait_s):
                break
            self.stopping.wait(0.02)
        if error is None and not waiting:
            return
        took = time.monotonic() - began
        for link in self.links:
            link.stop()
            link.close()
        if self.recorder is not None:
            self.recorder.finish()
        if error is None:
            link = waiting[0]
            when = (f"in {self.open_wait_s:g} s" if took >= self.open_wait_s else
                    f"before the run was stopped after {took:.1f} s")
            tries = f"{link.tries} tr{'y' if link.tries == 1 else 'ies'}"
            why = (f"{link.failure} ({tries})" if link.failure else
                   "python-can's first try to open it had not ended")
            error = UsageError(f"--bus {link.spec}: did not open {when}: {why}")
        raise error

    def _poll(self) -> list[Frame]:
        """Every bus's new frames, in time order."""
        polled = [frames for link in self.links if (frames := link.poll())]
        return merge_batches(polled) if polled else []

    def run(self) -> LiveReport:
        """Until :meth:`stop`: read, record, serve. Files are finished cleanly on the way out."""
        self.start()
        # What is loaded by now (databases, profile, schemas) lives as long as the process:
        # frozen out of the collector's way; full collections only at quiet moments.
        collector = steady_stream()
        pipeline, events = self.pipeline, self.events
        process = pipeline.process
        schedule = ReadSchedule(round(NS / self.scene_rate))
        try:
            while not self.stopping.is_set():
                collector.quiet()  # (where the loop waits: a full collection when one is due)
                schedule.wait()
                while True:
                    try:
                        self._bus_event(events.get_nowait(), schedule.offset_ns or 0)
                    except queue.Empty:
                        break
                frames = self._poll()
                if frames:
                    read_ns = time.time_ns()
                    schedule.saw(frames[-1].timestamp_ns, read_ns)
                    steps = len(pipeline.steps)
                    for frame in frames:
                        process(frame)
                    if len(pipeline.steps) != steps:  # the clock stepped: log time with it
                        schedule.restart(frames[-1].timestamp_ns, read_ns)
                # Every frame stamped before this was read: the scenes due go out now, whether
                # or not a later frame came (a quiet or silent bus).
                log_now = schedule.log_time(time.time_ns())
                if log_now is not None:
                    pipeline.advance(log_now)
                if self.server is not None:
                    self.server.flush()  # raw frames and signals for who subscribed to them
                if self.recorder is not None:
                    self.recorder.tick()
                    self._recorder_state()
                self._receive_state()
        finally:
            for link in self.links:
                link.stop()
            # What the interfaces have already received (a bounded while: a busy bus never
            # runs dry).
            until = time.monotonic() + 0.25
            while time.monotonic() < until and (frames := self._poll()):
                for frame in frames:
                    process(frame)
            for link in self.links:
                link.close()
            self._receive_state()
            self.drive.finish()
            if self.recorder is not None:
                for text in self.recorder.take_notices():
                    self.say(text)
            collector.restore()
        viewers = self.server.client_stats() if self.server else []
        return LiveReport(pipeline.frames, self.recorder.files if self.recorder else [],
                          self.recorder.gaps if self.recorder else [],
                          sum(s.dropped for s in viewers), viewers, dict(self.receive))

    def _receive_state(self) -> None:
        """What each bus's reading mended or lost, when it changed: to the health monitor
        (``/log``, ``/health``) and into the metadata (``bus_receive``)."""
        for link in self.links:
            counts = link.receive
            if counts != self.receive.get(link.spec.name, _NOTHING):
                copy = self.receive[link.spec.name] = dataclasses.replace(counts)
                self.drive.health.note_receive(link.spec.name, copy)
                self._receive_record[link.spec.name] = copy.to_dict()

    def _recorder_state(self) -> None:
        """What the recorder says (the disk filled, recording resumed) on ``/log``, and its
        ``recorder.disk_full`` condition to the health monitor."""
        assert self.recorder is not None
        for notice in self.recorder.take_notices():
            t = max(time.time_ns(), self.pipeline.last_ns or 0)
            self.pipeline.emit([log_message(t, notice.level, notice)])
            self.say(notice)
        self.drive.health.hold(AlarmKind.DISK_FULL, "recorder", self.recorder.disk_full)

    def _bus_event(self, event: BusEvent, offset_ns: int) -> None:
        """A bus lost or back, noted at the log time it happened (its wall time plus the
        offset the frames tell: an adapter's own clock, a clock step), never before the last
        frame."""
        t = max(event.t_ns + offset_ns, self.pipeline.last_ns or 0)
        if not event.up:
            gap = self._down[event.bus] = Gap(event.bus, t, None, event.reason)
            if self.recorder is not None:
                self.recorder.gaps.append(gap)
            text = f"bus {event.bus} lost: {event.reason}; retrying"
            self.pipeline.emit([log_message(t, Log.WARNING, text)])
        else:
            gap = self._down.pop(event.bus, Gap(event.bus, t, None, ""))
            gap.end_ns = t
            text = f"bus {event.bus} is back after {(t - gap.start_ns) / 1e9:.1f} s"
            self.pipeline.emit([log_message(t, Log.INFO, text)])
        self.say(text)


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "live", help="CAN buses in, Foxglove live, every drive recorded",
        description="Read CAN buses live (any python-can interface, several at once), decode, "
        "draw the scene, serve it to Foxglove and record every drive as MCAP.")
    parser.add_argument("--bus", action="append", metavar="NAME=INTERFACE:CHANNEL[@BITRATE]",
                        help="a bus to read, e.g. radar=socketcan:can0 or car=pcan:PCAN_USBBUS1"
                        "@500000; or NAME: that section of python-can's config file; repeatable")
    add_stage_options(parser, profile_default=None)
    add_server_options(parser)
    add_record_options(parser)
    parser.add_argument("--print-systemd-unit", action="store_true",
                        help="print a systemd service running this command at boot, then exit")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.print_systemd_unit:
        print(systemd_unit(args.argv))
        return 0
    if not args.bus:
        raise UsageError("live: name at least one --bus NAME=INTERFACE:CHANNEL[@BITRATE]")
    return run_live(args, [BusSpec.parse(text) for text in args.bus])


def run_live(args: argparse.Namespace, buses: list[BusSpec], *,
             start_feed: Callable[[], None] | None = None,
             stop_feed: Callable[[], None] | None = None) -> int:
    """Live on ``buses``; ``start_feed``/``stop_feed`` run a frame source beside it (demo)."""
    stages = options.stages(args)
    decoder, names = stages.decoder, {b.name for b in buses}
    unread = [f"--dbc {bus}={f.path}: no --bus {bus}, so nothing is decoded with it"
              for f in decoder.files for bus in decoder.buses_for(f)
              if bus != "*" and bus not in names]
    for text in [*decoder.warnings(), *unread]:  # what would silence messages, said at once
        print(f"warning: {text}", file=sys.stderr)
    if args.no_record and args.no_server:
        raise UsageError("--no-record and --no-server: nothing would be done")
    if args.split_size is not None and args.split_size <= 0:
        raise UsageError(f"--split-size {args.split_size:g}: must be above 0")
    if args.split_duration is not None and args.split_duration <= 0:
        raise UsageError(f"--split-duration {args.split_duration:g}: must be above 0")
    if not args.min_free >= 0:
        raise UsageError(f"--min-free {args.min_free:g}: must be 0 or more (MB)")
    server = None if args.no_server else options.start_server(args)
    limiter = limit_can_logs(lambda text: print(text, file=sys.stderr, flush=True))
    try:
        live = Live(buses, stages, scene_rate=options.scene_rate(args),
                    drives=None if args.no_record else args.drives, server=server,
                    split_size=(round(args.split_size * 1e6) if args.split_size else None),
                    split_duration_s=args.split_duration,
                    min_free=round(args.min_free * 1e6))

        def stop() -> None:
            if stop_feed is not None:
                stop_feed()  # first, so that every frame it sent is read and recorded
            live.stop()

        install_stop_signals(stop)
        if args.run_for:
            timer = threading.Timer(args.run_for, stop)
            timer.daemon = True  # an error at start ends the process at once
            timer.start()
        # Every bus open (or the one line why not) before anything is printed; the layouts are
        # written after it: a bus that cannot work records nothing.
        live.start()
        print(f"buses: {', '.join(str(b) for b in buses)}")
        if server is not None:
            print(f"Foxglove: open connection {' or '.join(server.urls)} (Foxglove WebSocket)",
                  flush=True)
        try:
            hint = layout_hint(args, stages, [b.name for b in buses],
                               recording=live.recorder is not None)
        except Exception as exc:  # the buses are open: a layout never stops the drive
            hint = hints.LayoutHint([], [f"no layout to name: {exc}"])
        if server is not None or hint.written:
            hint.say()
        if live.recorder is not None:
            print(f"recording into {args.drives}/")
        print("Ctrl+C stops and finishes the recording." if live.recorder is not None else
              "Ctrl+C stops.", flush=True)
        if start_feed is not None:
            start_feed()
        report = live.run()
    finally:
        if server is not None:
            server.stop()
        limiter.finish()
    for path in report.files:
        print(f"recorded {path}")
    if not report.frames:
        for line in nothing_came(buses, recording=live.recorder is not None,
                                 files=bool(report.files)):
            print(line)
    for line in receive_report(report.receive):
        print(line)
    print(f"{report.frames:,} frames; {len(report.gaps)} bus gaps; "
          f"{dropped_report(report.viewers)}")
    return 0


def layout_hint(args: argparse.Namespace, stages: Stages, buses: Sequence[str], *,
                recording: bool) -> hints.LayoutHint:
    """The layout to import (:func:`bridge.apps.hints.layout_hint`): the layouts made for a
    profile other than the bundled one are written into ``DRIVES/layouts/<profile>/`` when
    recording (for these buses), else the command that writes them is printed."""
    profile = stages.profile
    folder = (args.drives / "layouts" / hints.layout_folder(profile.name)
              if recording and profile is not None else None)
    return hints.layout_hint(stages, layout_files, profile=args.profile,
                               dbcs=command_dbcs(args.dbc or [], stages, buses),
                               folder=folder, buses=buses, write=folder is not None)


def layout_files(stages: Stages, buses: Sequence[str] | None) -> dict[str, str]:
    """The layouts made for the profile of ``stages`` on ``buses``, as files (name -> text)."""
    assert stages.profile is not None
    return {f"{name}.json": layout_text(data) for name, data
            in generate_layouts(stages.profile, stages.decoder, buses).items()}


def command_dbcs(given: Sequence[str], stages: Stages, buses: Sequence[str]) -> list[str]:
    """The ``--dbc`` arguments of ``tankviz layouts`` for the databases live decodes these
    buses with: as given, but a database for every bus (which ``tankviz layouts`` shows on
    ``can0``) on each bus live reads, unless that is just ``can0``; without ``--dbc``, the
    profile's own databases, named the same way where they are for every bus."""
    if list(buses) == [DEFAULT_BUS]:
        return list(given)
    if given:
        return [word for text in given
                for word in ([text] if parse_dbc_option(text)[0] else
                             [f"{bus}={text}" for bus in buses])]
    own = stages.profile.databases if stages.profile is not None else {}
    if "*" not in own:
        return []  # (a profile's databases, each for its bus: `tankviz layouts` reads them)
    return [f"{name}={path}" for bus, paths in own.items() for path in paths
            for name in (buses if bus == "*" else [bus])]


def systemd_unit(argv: Sequence[str]) -> str:
    """A systemd service that runs ``tankviz live`` with these arguments at boot."""
    kept = [a for a in argv if a != "--print-systemd-unit"]
    command = " ".join(shlex.quote(a) for a in [sys.executable, "-m", "bridge", *kept])
    return "\n".join([
        "# tankviz live at boot. Install: sudo cp tankviz.service /etc/systemd/system/ &&",
        "#   sudo systemctl daemon-reload && sudo systemctl enable --now tankviz",
        "[Unit]",
        "Description=tankviz: CAN to Foxglove bridge and drive recorder",
        "After=network-online.target",
        "Wants=network-online.target",
        "",
        "[Service]",
        f"WorkingDirectory={Path.cwd()}",
        f"ExecStart={command}",
        "KillSignal=SIGTERM",
        "TimeoutStopSec=15",
        "Restart=on-failure",
        "RestartSec=2",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
        "",
    ])
