"""``tankviz live``: CAN buses in, Foxglove live, every drive recorded.

This command builds the engine, :class:`bridge.pipeline.live_engine.Live`, from its options,
runs it and prints what it did. Every bus is opened before anything is printed: a bus that
cannot work at all is an error at once; one that does not open within
:data:`~bridge.io.buses.OPEN_WAIT_S` is an error too (one line, exit 1, nothing recorded); one
that fails later is said, and when it is back. Enter in a terminal marks the moment
(:class:`TerminalMarks`), and every mark is said on the console. SIGINT, SIGTERM and SIGHUP stop
the run and finish the drive; an output that is gone (EIO, EPIPE) never stops either
(:func:`output_may_vanish`). It names the layout to import at start (:func:`layout_hint`,
:func:`bringup_hint`) and at the end the files recorded, what the buses' reading mended or lost
(:func:`receive_report`) and what slow viewers lost (:func:`dropped_report`). """

from __future__ import annotations

import argparse
import contextlib
import os
import select
import shlex
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO

from bridge.apps import hints, options
from bridge.apps.options import (
    Subparsers,
    add_record_options,
    add_server_options,
    add_stage_options,
    install_stop_signals,
)
from bridge.decode.database import parse_dbc_option
from bridge.errors import UsageError
from bridge.io.buses import BusSpec, ReceiveCounts, limit_can_logs
from bridge.pipeline.drive import Stages
from bridge.pipeline.live_engine import Live
from bridge.pipeline.marks import MarkAsked
from bridge.resources import layouts_dir
from bridge.sinks.server import ClientStats
from bridge.sinks.server.viewer_input import TEXT_CHARS, UNNAMED
from bridge.view.bringup import bringup_layout
from bridge.view.generate import DEFAULT_BUS, generate_layouts, layout_text


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
        if c.missed_estimate:
            said.append(f"about {c.missed_estimate:,} frames missed while the bus was down (an "
                        "estimate: its frame rate before times how long it was down)")
        if said:
            lines.append(f"bus {bus}: " + "; ".join(said))
    return lines


class VanishingOutput:
    """A standard stream whose terminal or pipe may go away during the run (a closed window, an
    ended SSH session): a write that fails for that (EIO, EPIPE, any ``OSError`` but a full
    non-blocking pipe) makes this and every later write go nowhere, the descriptor included (it
    becomes ``/dev/null``: the interpreter's last flush, a thread's line)."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.gone = False

    def write(self, text: str) -> int:
        if not self.gone:
            try:
                return self.stream.write(text)
            except (BlockingIOError, InterruptedError):
                pass  # this text is lost, the output is not
            except OSError:
                self._went()
        return len(text)

    def flush(self) -> None:
        if not self.gone:
            try:
                self.stream.flush()
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                self._went()

    def _went(self) -> None:
        self.gone = True
        with contextlib.suppress(Exception):  # (a stream without a descriptor: nothing to do)
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, self.stream.fileno())
            os.close(null)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


@contextlib.contextmanager
def output_may_vanish() -> Iterator[None]:
    """Within the block, standard output and error are :class:`VanishingOutput`: a terminal
    that went away never stops the run nor the drive's finishing."""
    out, err = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = VanishingOutput(out), VanishingOutput(err)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = out, err


def terminal_text(line: str) -> str:
    """A mark's text from a line typed in the terminal: what was typed, without control
    characters (an arrow key's escape), at most ``TEXT_CHARS``; nothing (or just ``m``) is
    ``mark``."""
    text = "".join(c for c in line if c.isprintable()).strip()[:TEXT_CHARS].strip()
    return UNNAMED if text in ("", "m") else text


class TerminalMarks:
    """Marks from live's terminal: each line typed (Enter) marks the moment, named by
    :func:`terminal_text`. Nothing is read unless standard input (``fd``) is a terminal, and
    only while this process is in its foreground (``tankviz live &`` would stop at a read); the
    descriptor is read directly, never through ``sys.stdin`` (whose lock a thread blocked in a
    read would hold when the interpreter exits). The input's end (Ctrl+D, a terminal gone) ends
    the reading."""

    def __init__(self, ask: Callable[[MarkAsked], None], fd: int = 0) -> None:
        self.ask = ask
        self.fd = fd
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> bool:
        """Start reading, if standard input is a terminal (whether it is)."""
        if not os.isatty(self.fd):
            return False
        self._thread = threading.Thread(target=self._run, name="tankviz-terminal", daemon=True)
        self._thread.start()
        return True

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)

    def _foreground(self) -> bool:
        try:
            return os.tcgetpgrp(self.fd) == os.getpgrp()
        except OSError:  # not this process's controlling terminal: reading it stops nobody
            return True

    def _run(self) -> None:
        pending = b""
        while not self._stop.is_set():
            try:
                if not self._foreground():
                    self._stop.wait(0.5)
                    continue
                if not select.select([self.fd], [], [], 0.2)[0]:
                    continue
                chunk = os.read(self.fd, 4096)
            except (OSError, ValueError):  # the terminal went away
                return
            if not chunk:
                if not self._stop.is_set():
                    print("the terminal's input ended: Enter marks no more", flush=True)
                return
            *lines, pending = (pending + chunk).split(b"\n")
            for line in lines:
                text = terminal_text(line.decode("utf-8", errors="replace"))
                self.ask(MarkAsked(text, "", "terminal", "terminal"))


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
        raise UsageError("live", "name at least one --bus NAME=INTERFACE:CHANNEL[@BITRATE]")
    return run_live(args, [BusSpec.parse(text) for text in args.bus])


def run_live(args: argparse.Namespace, buses: list[BusSpec], *,
             start_feed: Callable[[], None] | None = None,
             stop_feed: Callable[[], None] | None = None) -> int:
    """Live on ``buses``; ``start_feed``/``stop_feed`` run a frame source beside it (demo)."""
    with output_may_vanish():
        return _run_live(args, buses, start_feed=start_feed, stop_feed=stop_feed)


def _run_live(args: argparse.Namespace, buses: list[BusSpec], *,
              start_feed: Callable[[], None] | None,
              stop_feed: Callable[[], None] | None) -> int:
    stages = options.stages(args)
    decoder, names = stages.decoder, {b.name for b in buses}
    unread = [f"--dbc {bus}={f.path}: no --bus {bus}, so nothing is decoded with it"
              for f in decoder.files for bus in decoder.buses_for(f)
              if bus != "*" and bus not in names]
    for text in [*decoder.warnings(), *unread]:  # what would silence messages, said at once
        print(f"warning: {text}", file=sys.stderr)
    if args.no_record and args.no_server:
        raise UsageError("--no-record and --no-server", "nothing would be done")
    if args.split_size is not None and args.split_size <= 0:
        raise UsageError("--split-size", "must be above 0", value=f"{args.split_size:g}")
    if args.split_duration is not None and args.split_duration <= 0:
        raise UsageError("--split-duration", "must be above 0", value=f"{args.split_duration:g}")
    if not args.min_free >= 0:
        raise UsageError("--min-free", "must be 0 or more (MB)", value=f"{args.min_free:g}")
    server = None if args.no_server else options.start_server(args)
    limiter = limit_can_logs(lambda text: print(text, file=sys.stderr, flush=True))
    terminal = TerminalMarks(lambda asked: live.marks.ask(asked))
    try:
        live = Live(buses, stages, scene_rate=options.scene_rate(args),
                    drives=None if args.no_record else args.drives, server=server,
                    split_size=(round(args.split_size * 1e6) if args.split_size else None),
                    split_duration_s=args.split_duration,
                    min_free=round(args.min_free * 1e6), bring_up=options.bring_up(args))

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
            print(*hints.connection_lines(server.host, server.urls), sep="\n", flush=True)
        try:
            hint = layout_hint(args, stages, [b.name for b in buses],
                               recording=live.recorder is not None)
        except Exception as exc:  # the buses are open: a layout never stops the drive
            hint = hints.LayoutHint([], [f"no layout to name: {exc}"])
        if server is not None or hint.written:
            hint.say()
        unknown = bringup_hint(args, stages, [b.name for b in buses],
                               recording=live.recorder is not None)
        if server is not None or (unknown.folder / hints.BRINGUP_LAYOUT).exists():
            hints.watch_unknown(live.drive, unknown.tell)
        if live.recorder is not None:
            print(f"recording into {args.drives}/")
        print("Ctrl+C stops and finishes the recording." if live.recorder is not None else
              "Ctrl+C stops.", flush=True)
        if start_feed is not None:
            start_feed()
        if terminal.start():
            print("Enter marks the moment (type a word first to name it).", flush=True)
        report = live.run()
    finally:
        terminal.stop()
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
    if report.failure is not None:
        print(f"error: {report.failure}", file=sys.stderr)
        return 1
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


def bringup_hint(args: argparse.Namespace, stages: Stages, buses: Sequence[str], *,
                 recording: bool) -> hints.BringupHint:
    """What live says when a bus first carries an id no database knows
    (:class:`bridge.apps.hints.BringupHint`): the bring-up layout in the drives folder's layouts
    (``DRIVES/layouts/<profile>/``, where :func:`layout_hint` writes it with the others, or
    ``DRIVES/layouts/`` without a profile: written here, never over a file, a failure
    silent: the line then names the command), else the command that writes it (into
    ``<profile>-layouts`` or ``bring-up-layouts``); the bundled one for the bundled profile on
    can0 alone."""
    profile = stages.profile
    name = hints.layout_folder(profile.name) if profile is not None else None
    if recording:
        folder = args.drives / "layouts" / name if name else args.drives / "layouts"
    else:
        folder = Path(f"{name}-layouts" if name else hints.BRINGUP_FOLDER)
    bundled = (layouts_dir() / hints.BRINGUP_LAYOUT
               if hints.is_bundled(stages) and list(buses) == [DEFAULT_BUS] else None)
    if recording and profile is None:
        with contextlib.suppress(Exception):  # the drive goes on; the line names the command
            hints.write_layouts(folder, {hints.BRINGUP_LAYOUT: bringup_file(buses)})
    return hints.BringupHint(folder, list(buses), bringup_file, bundled=bundled)


def bringup_file(buses: Sequence[str]) -> str:
    """The bring-up layout for ``buses`` as its file's text."""
    return layout_text(bringup_layout(buses))


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
