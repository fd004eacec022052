"""The ``tankviz`` command line: the top-level parser, with each command's own parser and
handler loaded from its module in :mod:`bridge.apps`.

Only the chosen command's module is imported (``--help`` imports none: :data:`SUMMARIES`), after
the ``TANKVIZ_*`` settings are checked (:func:`bridge.apps.options.check_environment`). Every
user error (a :class:`~bridge.errors.BridgeError`, or an ``OSError`` naming a file) is one
``error: …`` line with exit status 1 (``--debug``: the traceback); a name that is not UTF-8 is
shown with its bytes as ``\\xNN`` in every line (:func:`~bridge.errors.shown`). When tankviz is
the program (``main()`` without arguments), numpy's OpenBLAS runs on one thread unless
``OPENBLAS_NUM_THREADS`` says otherwise, and the garbage collector waits until the command's
modules are loaded, then leaves them out (``gc.freeze``).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import os
import sys
import traceback
from collections.abc import Sequence

from bridge import __version__
from bridge.apps.options import check_environment
from bridge.errors import SHOWN_ERRORS, BridgeError, os_error_text, shown

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130

#: The commands, in the order ``tankviz --help`` lists them: modules of :mod:`bridge.apps`.
COMMANDS = ("convert", "inspect", "live", "demo", "simulate", "replay", "recover", "layouts",
            "batch", "catalog", "profile", "ids", "bits", "find-signal")

#: What ``tankviz --help`` says of each command without importing it: the ``help`` each module
#: gives its parser (tests/test_startup.py checks that they agree).
SUMMARIES = {
    "convert": "convert CAN logs into one decoded MCAP drive archive",
    "inspect": "show what a drive archive (MCAP) holds",
    "live": "CAN buses in, Foxglove live, every drive recorded",
    "demo": "the simulated ecocar drive, live: open Foxglove and watch",
    "simulate": "write a simulated drive (ecocar, or the highway car) as a CAN log or an MCAP",
    "replay": "serve a recorded drive or CAN logs to Foxglove in real time",
    "recover": "salvage a drive (MCAP) cut short by a power loss or a crash",
    "layouts": "list the bundled Foxglove layouts, or copy them out to import them",
    "batch": "convert many drives at once, on Dask (local cores or a cluster)",
    "catalog": "index drives into a DuckDB catalogue, or query it",
    "profile": "start a vehicle profile from the databases, or check one",
    "ids": "list every CAN id of a source: rate, lengths, message, changing bits",
    "bits": "the bit-change map of one CAN id, or the bits that switch between two windows of "
            "time",
    "find-signal": "find the field of unknown ids that follows a known quantity, as DBC lines",
}


def module_of(command: str) -> str:
    """The module of :mod:`bridge.apps` that holds ``command`` (``find-signal``: find_signal)."""
    return f"bridge.apps.{command.replace('-', '_')}"


def chosen_command(arguments: Sequence[str]) -> str | None:
    """The command named in ``arguments``: the first word that is not an option (tankviz's own
    options take no value), or None (``tankviz --help``, a mistyped command)."""
    for argument in arguments:
        if argument == "--":
            break
        if not argument.startswith("-"):
            return argument if argument in COMMANDS else None
    return None


def build_parser(command: str | None = None, *, every: bool = False) -> argparse.ArgumentParser:
    """The parser, with the full parser of ``command`` (of every command with ``every``); the
    others are listed by their summary and loaded when chosen."""
    parser = argparse.ArgumentParser(
        prog="tankviz",
        description="CAN buses to Foxglove: decode with DBC files, draw the perception scene, "
        "stream it live and record every drive as MCAP.",
    )
    parser.add_argument("--version", action="version", version=f"tankviz {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        if every or name == command:
            importlib.import_module(module_of(name)).add_parser(sub)
        else:
            sub.add_parser(name, help=SUMMARIES[name])
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    arguments = list(argv) if argv is not None else sys.argv[1:]
    for stream in (sys.stdout, sys.stderr):  # a name that is not UTF-8 prints as \xNN
        with contextlib.suppress(AttributeError, ValueError):
            stream.reconfigure(errors=SHOWN_ERRORS)  # type: ignore[union-attr]
    # When tankviz is the program (the console script, ``python -m bridge``; DEVELOPING.md):
    # numpy's OpenBLAS would start a thread per core at import, for linear algebra tankviz does
    # not do (read-ahead and Dask workers inherit the setting), and importing the command makes
    # no garbage worth a collection.
    program = argv is None
    collecting = gc.isenabled()
    if program:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        gc.disable()
    try:
        check_environment()  # a TANKVIZ_* setting may make no sense
        parser = build_parser(chosen_command(arguments))
    except BridgeError as exc:
        print(f"error: {shown(str(exc))}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        if program:
            gc.freeze()  # (what start-up made lives as long as the process)
            if collecting:
                gc.enable()
    try:
        args = parser.parse_args(arguments)  # an option's value may be a one-line error
    except BridgeError as exc:
        print(f"error: {shown(str(exc))}", file=sys.stderr)
        return EXIT_ERROR
    args.argv = arguments
    try:
        code: int = args.run(args)
        return code
    except BridgeError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"error: {shown(str(exc))}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0
    except OSError as exc:
        if exc.filename is None:
            raise
        if args.debug:
            traceback.print_exc()
        print(f"error: {os_error_text(exc)}", file=sys.stderr)
        return EXIT_ERROR
