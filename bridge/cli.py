"""The ``tankviz`` command line: the top-level parser, with each command's own parser and
handler loaded from its module in :mod:`bridge.apps` (as cantools' subcommands are).

Every user error is a :class:`~bridge.errors.BridgeError`, printed as one ``error: …`` line with
exit status 1; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from collections.abc import Sequence

from bridge import __version__
from bridge.errors import BridgeError

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130

#: The commands, in the order ``tankviz --help`` lists them: modules of :mod:`bridge.apps`.
COMMANDS = ("convert", "inspect", "live", "demo", "simulate", "replay", "recover", "layouts",
            "batch", "catalog", "profile")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tankviz",
        description="CAN buses to Foxglove: decode with DBC files, draw the perception scene, "
        "stream it live and record every drive as MCAP.",
    )
    parser.add_argument("--version", action="version", version=f"tankviz {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"bridge.apps.{name}").add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    arguments = list(argv) if argv is not None else sys.argv[1:]
    try:
        parser = build_parser()  # (reads the TANKVIZ_* settings: one may make no sense)
    except BridgeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    args = parser.parse_args(arguments)
    args.argv = arguments
    try:
        code: int = args.run(args)
        return code
    except BridgeError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0
