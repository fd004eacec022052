"""Command-line options that several commands share, and what they turn into.

Settings come from the command line, else the environment (``TANKVIZ_*``), else a default. The
environment is read when the parser is built: a value that makes no sense there
(``TANKVIZ_PORT=abc``) ends the command at once, even ``--help``, with one line naming the
variable and exit status 1: :func:`check_environment` checks every one before any parser is built.

This module is imported by ``tankviz --help`` itself: it imports what the options turn into
(the decoder, the pipeline, the server) only where an option is turned into it.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import math
import os
import re
import shlex
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bridge.errors import UsageError
from bridge.resources import bundled_database, layouts_dir

if TYPE_CHECKING:
    from bridge.pipeline.drive import Stages
    from bridge.sinks.websocket import LiveServer

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
    return UsageError(f"TANKVIZ_{name}={os.environ.get(f'TANKVIZ_{name}')!r}: "
                      f"expected {expected}")


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
    from bridge.decode.decoder import parse_dbc_option

    bus, path = parse_dbc_option(text)
    if not path.exists() and (bundled := bundled_database(str(path))) is not None:
        return f"{bus}={bundled}" if bus else str(bundled)
    return text


def add_stage_options(parser: argparse.ArgumentParser, *, profile_default: str | None) -> None:
    from bridge.pipeline.perception import DEFAULT_SCENE_RATE

    parser.add_argument("--dbc", action="append", metavar="[BUS=]PATH",
                        help="signal database (DBC, KCD, SYM, ARXML) for BUS, or for every bus "
                        "without BUS=; repeatable; a bundled name such as 'ecocar' works too")
    parser.add_argument("--profile", metavar="NAME|PATH", default=profile_default,
                        help="vehicle profile (TOML) that says what the signals mean: adds the "
                        "scene and perception topics; a bundled name such as 'ecocar' works too; "
                        "without --dbc the profile's own databases are used"
                        + (f" (default {profile_default})" if profile_default else ""))
    parser.add_argument("--scene-rate", type=float, metavar="HZ",
                        help=f"scene updates per second of log time (default "
                        f"{DEFAULT_SCENE_RATE:g}, or a re-derived drive's own; at most 50)")


def scene_rate(args: argparse.Namespace) -> float:
    """``--scene-rate``, else the default."""
    from bridge.pipeline.perception import DEFAULT_SCENE_RATE

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


def start_server(args: argparse.Namespace, *, server_time: bool = False) -> LiveServer:
    from bridge.sinks.websocket import LiveServer

    server = LiveServer(host=args.host, port=args.port, server_time=server_time)
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
                        "has less free space than this, and resume when there is room "
                        "(default 200)")
    parser.add_argument("--no-record", action="store_true", help="view only: record nothing")
    parser.add_argument("--no-server", action="store_true",
                        help="record only: no WebSocket server, no display load")
    add_run_for(parser)


def add_run_for(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--for", dest="run_for", type=float, metavar="S",
                        default=env_seconds("RUN_FOR"),
                        help="stop by itself after this many seconds (env TANKVIZ_RUN_FOR)")


#: The profile the bundled layouts (``layouts/*.json``) are made for, with its bundled database.
BUNDLED_PROFILE = "ecocar"
#: The layout a hint points at (the Tank Viz 3D view), as a file name.
HINT_LAYOUT = "tank-viz.json"
#: How ``layout:`` hints go on: the lines after the first, under its text.
HINT_INDENT = " " * len("layout:   ")


def bundled_layout() -> str:
    """Where the bundled Tank Viz layout to import is."""
    layout = layouts_dir() / HINT_LAYOUT
    return str(layout) if layout.exists() else f"(layouts/{HINT_LAYOUT})"


def is_bundled(stages: Stages) -> bool:
    """Whether the bundled layouts are the ones made for ``stages``: the bundled ecocar profile
    (its bytes, wherever it was read from: a drive's attachment too) with its bundled database
    and no other. (The Tank Viz view a hint points at does not depend on the bus names.)"""
    decoder, profile = stages
    database = bundled_database(BUNDLED_PROFILE)
    if profile is None or database is None or not decoder.files:
        return False
    try:
        same = profile.path.read_bytes() == (database.with_suffix(".toml")).read_bytes()
        digest = hashlib.sha256(database.read_bytes()).hexdigest()
    except OSError:
        return False
    return same and all(f.sha256 == digest for f in decoder.files)


def layout_folder(name: str) -> str:
    """A profile's name as a folder name (``DRIVES/layouts/<name>``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "profile"


def layouts_command(profile: str | Path, dbcs: Sequence[str], export: Path | str,
                    *extra: str) -> str:
    """The ``tankviz layouts`` command that writes the layouts for ``profile`` and ``dbcs``
    (``--dbc`` arguments) into ``export``, quoted for a shell."""
    return shlex.join(["tankviz", "layouts", "--profile", str(profile),
                       *(word for dbc in dbcs for word in ("--dbc", dbc)),
                       "--export", str(export), *extra])


@dataclass
class LayoutHint:
    """What to tell the user about the layout to import: the ``layout:`` lines, warnings
    (printed as ``warning: ...`` on stderr) and whether layouts were written for them."""

    lines: list[str]
    warnings: list[str] = field(default_factory=list)
    written: bool = False

    def text(self) -> str:
        return "\n".join(("layout:   " if i == 0 else HINT_INDENT) + line
                         for i, line in enumerate(self.lines))

    def say(self) -> None:
        for text in self.warnings:
            print(f"warning: {text}", file=sys.stderr)
        if self.lines:
            print(self.text())


#: The layouts made for a profile (:func:`bridge.view.generate.generate_layouts` of the
#: stages on these buses, or the databases' buses for None), as files: ``tank-viz.json`` -> text.
#: (Given by the command: this module, loaded for ``tankviz --help``, does not import the view.)
MakeLayouts = Callable[["Stages", "Sequence[str] | None"], Mapping[str, str]]


def layout_hint(stages: Stages, make: MakeLayouts, *, profile: str | Path | None,
                dbcs: Sequence[str], folder: Path | None = None,
                buses: Sequence[str] | None = None, write: bool = False,
                note: str | None = None) -> LayoutHint:
    """The layout to import for ``stages`` (what ``--profile`` and ``--dbc`` loaded).

    The bundled ecocar profile (:func:`is_bundled`): the bundled layout. Another profile: the
    layouts made for it (``make``, on ``buses``) in
    ``folder`` (default ``<profile>-layouts``) when they are there, else the ``tankviz layouts``
    command that writes them there, naming the profile as ``profile`` and the databases as
    ``dbcs`` (``--dbc`` arguments), with ``note`` (what they are) under it. With ``write``, the
    layouts are written into ``folder`` first: a file that is there already is never
    overwritten (a warning names it when it differs), and a failure is one warning, never an
    error. No profile: the commands that draft one and make its layouts.
    """
    loaded = stages.profile
    if loaded is None:
        return _no_profile_hint(dbcs)
    if is_bundled(stages):
        return LayoutHint([f"import {bundled_layout()} (Layouts menu)"])
    name = loaded.name
    folder = folder if folder is not None else Path(f"{layout_folder(name)}-layouts")
    target = folder / HINT_LAYOUT
    made = f"import {target} (Layouts menu), made for profile {name}"
    command = layouts_command(profile if profile is not None else loaded.path, dbcs, folder)
    warnings: list[str] = []
    try:
        texts = make(stages, buses)
        if write:
            kept = _write_layouts(folder, texts)
            if kept:
                files = ", ".join(str(p) for p in kept)
                one = len(kept) == 1
                warnings.append(
                    f"kept {files}: {'it differs' if one else 'they differ'} from the "
                    f"layout{'' if one else 's'} made for profile {name} now; "
                    f"{command} --force replaces {'it' if one else 'them'}")
            if target in kept:
                return LayoutHint([f"import {target} (Layouts menu)"], warnings, written=True)
            return LayoutHint([made], warnings, written=True)
        if _read(target) == texts[HINT_LAYOUT]:
            return LayoutHint([made])
    except Exception as exc:  # the drive goes on: a layout is never worth stopping it
        if write:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            warnings.append(f"cannot write the layouts into {folder}: "
                            f"{reason or type(exc).__name__}")
    lines = [f"made for profile {name} by: {command}", *([note] if note else []),
             f"then import {target} (Layouts menu)"]
    return LayoutHint(lines, warnings)


def _no_profile_hint(dbcs: Sequence[str]) -> LayoutHint:
    from bridge.decode.decoder import parse_dbc_option

    if not dbcs:
        return LayoutHint(["none: the layouts are made for a vehicle profile (--profile) "
                           "and its databases (--dbc)"])
    paths = list(dict.fromkeys(str(parse_dbc_option(text)[1]) for text in dbcs))
    draft = shlex.join(["tankviz", "profile", "new",
                        *(word for path in paths for word in ("--dbc", path)), "-o", "car.toml"])
    return LayoutHint([f"none without a profile: draft one with: {draft}",
                       f"then: {layouts_command('car.toml', dbcs, 'car-layouts')}"])


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None


def _write_layouts(folder: Path, texts: Mapping[str, str]) -> list[Path]:
    """Write each layout (file name -> text) into ``folder`` (created if needed) where no file
    of its name is; returns the files left as they were because they differ."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocking = next((p for p in (folder, *folder.parents) if p.exists() and not p.is_dir()),
                        folder)
        raise OSError(f"{blocking} is not a folder") from None
    kept = []
    for name, text in texts.items():
        target = folder / name
        try:
            with target.open("x", encoding="utf-8") as stream:  # never over an existing file
                try:
                    stream.write(text)
                except BaseException:
                    stream.close()
                    target.unlink(missing_ok=True)
                    raise
        except FileExistsError:
            if _read(target) != text:
                kept.append(target)
    return kept


def install_stop_signals(stop: Callable[[], None]) -> None:
    """SIGINT and SIGTERM stop the live loop cleanly (files are finished)."""
    def handler(signum: int, frame: object) -> None:
        stop()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)


class Stopped(BaseException):
    """A signal that ends the conversion; like KeyboardInterrupt, not an error of the input."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(f"stopped by {signal.Signals(signum).name}")


#: The signals that stop a command writing a file: a service stopped, the terminal closed.
STOP_SIGNALS = (signal.SIGTERM, *([signal.SIGHUP] if hasattr(signal, "SIGHUP") else []))


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
