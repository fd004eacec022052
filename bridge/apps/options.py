"""Command-line options that several commands share, and what they turn into.

Settings come from the command line, else the environment (``TANKVIZ_*``), else a default; a
nonsensical environment value ends every command, even ``--help``, with one line and exit status
1 (:func:`check_environment`). Imported by ``tankviz --help`` itself, it imports what the options
turn into only when they are turned.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bridge.errors import UsageError
from bridge.resources import bundled_database

if TYPE_CHECKING:
    from bridge.pipeline.drive import Stages
    from bridge.sinks.server import ViewerServer

    Subparsers = argparse._SubParsersAction[argparse.ArgumentParser]
else:
    Subparsers = Any


#: The WebSocket port without ``--port`` or ``TANKVIZ_PORT``.
DEFAULT_PORT = 8765


def env(name: str, default: str) -> str:
    """Settings: command line > environment (TANKVIZ_*) > default."""
    return os.environ.get(f"TANKVIZ_{name}", default)


def _bad_env(name: str, expected: str) -> UsageError:
    """The one-line error for a setting of the environment that makes no sense."""
    return UsageError(f"TANKVIZ_{name}", f"expected {expected}",
                      value=repr(os.environ.get(f"TANKVIZ_{name}")))


def env_port(name: str, default: int) -> int:
    """A port number from the environment (TANKVIZ_*) or ``default``."""
    text = env(name, str(default)).strip()
    if not text.isdigit() or int(text) > 65535:
        raise _bad_env(name, "a port number (0 to 65535)")
    return int(text)


def env_seconds(name: str) -> float | None:
    """A number of seconds > 0 from the environment (TANKVIZ_*), or None where it is unset."""
    text = env(name, "").strip()
    if not text:
        return None
    try:
        seconds = float(text)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise _bad_env(name, "a number of seconds > 0")
    return seconds


def check_environment() -> None:
    """Every ``TANKVIZ_*`` setting that must be a number, checked at once: the first that makes
    no sense raises its :class:`UsageError` (even for ``--help``, whatever the command)."""
    env_port("PORT", DEFAULT_PORT)
    env_seconds("RUN_FOR")


def dbc_option(text: str) -> str:
    """``--dbc [BUS=]PATH``, where PATH may also name a bundled database (``ecocar``)."""
    from bridge.decode.database import parse_dbc_option

    bus, path = parse_dbc_option(text)
    if not path.exists() and (bundled := bundled_database(str(path))) is not None:
        return f"{bus}={bundled}" if bus else str(bundled)
    return text


def add_stage_options(parser: argparse.ArgumentParser, *, profile_default: str | None) -> None:
    from bridge.pipeline import DEFAULT_SCENE_RATE

    parser.add_argument("--dbc", action="append", metavar="[BUS=]PATH",
                        help="signal database (DBC, KCD, SYM, ARXML) for BUS, or for every bus "
                        "without BUS=; repeatable; a bundled name such as 'ecocar' works too")
    parser.add_argument("--profile", metavar="NAME|PATH", default=profile_default,
                        help="vehicle profile (TOML) that says what the signals mean: adds the "
                        "scene and perception topics; a bundled name such as 'ecocar' works too; "
                        "without --dbc the profile's own databases are used"
                        + (f" (default {profile_default})" if profile_default else ""))
    parser.add_argument("--scene-rate", type=_scene_rate, metavar="HZ",
                        help=f"scene updates per second of log time (default "
                        f"{DEFAULT_SCENE_RATE:g}, or a re-derived drive's own; at most 50)")
    add_bring_up_option(parser)


def add_bring_up_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--no-bring-up", dest="bring_up", action="store_false",
                        help="leave out the bring-up topics (/can/<bus>/ids, /can/<bus>/unknown: "
                        "the frames of ids no database defines, /can/bits: the bit-change map)")


def bring_up(args: argparse.Namespace) -> bool:
    """Whether the drive has the bring-up topics (``--no-bring-up`` leaves them out)."""
    return bool(getattr(args, "bring_up", True))


def _scene_rate(text: str) -> float:
    """``--scene-rate``'s value, checked as it is parsed (0 is no default: it is refused)."""
    from bridge.pipeline.perception import check_scene_rate

    try:
        rate = float(text)
    except ValueError:
        raise UsageError("--scene-rate", "expected a number of Hz", value=text) from None
    return check_scene_rate(rate)


def scene_rate(args: argparse.Namespace) -> float:
    """``--scene-rate``, else the default."""
    from bridge.pipeline import DEFAULT_SCENE_RATE

    return DEFAULT_SCENE_RATE if args.scene_rate is None else float(args.scene_rate)


def stages(args: argparse.Namespace) -> Stages:
    """The decoder and profile that ``--dbc`` and ``--profile`` name."""
    from bridge.pipeline.drive import load_stages

    return load_stages([dbc_option(text) for text in args.dbc or []], args.profile)


def add_server_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default=env("HOST", "127.0.0.1"),
                        help="address to serve Foxglove on (default 127.0.0.1, env TANKVIZ_HOST; "
                        "0.0.0.0 serves the car network: the protocol has no authentication)")
    parser.add_argument("--port", type=int, default=env_port("PORT", DEFAULT_PORT),
                        help=f"WebSocket port (default {DEFAULT_PORT}, env TANKVIZ_PORT)")


def start_server(args: argparse.Namespace, *, server_time: bool = False,
                 mode: str = "live") -> ViewerServer:
    """The Foxglove server ``--host`` and ``--port`` name, started (``mode``: what it serves,
    told to viewers in serverInfo's metadata)."""
    from bridge.sinks.server import ViewerServer

    server = ViewerServer(host=args.host, port=args.port, server_time=server_time, mode=mode)
    server.start()
    return server


def add_record_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--drives", type=Path, default=Path(env("DRIVES", "drives")),
                        help="folder for the recordings, one MCAP per drive named by its UTC "
                        "start time (default ./drives, env TANKVIZ_DRIVES)")
    parser.add_argument("--split-size", type=float, metavar="MB",
                        help="start a new part when the current one reaches this size")
    parser.add_argument("--split-duration", type=float, metavar="S",
                        help="start a new part after this many seconds")
    parser.add_argument("--min-free", type=float, default=200.0, metavar="MB",
                        help="stop recording (finishing the file) while the drives folder's disk "
                        "has less free space than this, and resume in a new part when more than "
                        "this + 9 MiB is free (default 200)")
    parser.add_argument("--no-record", action="store_true", help="view only: record nothing")
    parser.add_argument("--no-server", action="store_true",
                        help="record only: no WebSocket server, no display load")
    add_run_for(parser)


def add_run_for(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--for", dest="run_for", type=_run_for, metavar="S",
                        default=env_seconds("RUN_FOR"),
                        help="stop by itself after this many seconds (env TANKVIZ_RUN_FOR)")


def seconds_above_zero(option: str, text: str) -> float:
    """An option's value: a finite number of seconds > 0, else one line naming the option."""
    try:
        seconds = float(text)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise UsageError(option, "expected a number of seconds > 0", value=text)
    return seconds


def _run_for(text: str) -> float:
    """``--for``'s value, checked as it is parsed."""
    return seconds_above_zero("--for", text)


#: The signals that stop a command writing a file: a service stopped, the terminal closed.
STOP_SIGNALS = (signal.SIGTERM, *([signal.SIGHUP] if hasattr(signal, "SIGHUP") else []))


def install_stop_signals(stop: Callable[[], None]) -> None:
    """SIGINT, SIGTERM and SIGHUP (the terminal or SSH session went away) stop a live or replay
    loop cleanly: its files are finished."""
    def handler(signum: int, frame: object) -> None:
        stop()

    for signum in (signal.SIGINT, *STOP_SIGNALS):
        signal.signal(signum, handler)


class Stopped(BaseException):
    """A signal that ends the conversion; like KeyboardInterrupt, not an error of the input."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(f"stopped by {signal.Signals(signum).name}")


@contextlib.contextmanager
def stopped_by_signals(*signums: int) -> Iterator[None]:
    """Within the block, these signals (default :data:`STOP_SIGNALS`) raise :class:`Stopped`, so
    the output being written is removed as on Ctrl+C. Only in the main thread."""
    signums = signums or STOP_SIGNALS
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise Stopped(signum)

    previous = {s: signal.signal(s, handler) for s in signums}
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)
