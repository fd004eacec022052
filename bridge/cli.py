"""The ``tankviz`` command line.

Every user error is a :class:`~bridge.errors.BridgeError`, printed as one ``error: …`` line with
exit status 1; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path

from bridge import __version__
from bridge.errors import BridgeError

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


def _dbc_option(text: str) -> str:
    """``--dbc [BUS=]PATH``, where PATH may also name a bundled database (``ecocar``)."""
    from bridge.decode import parse_dbc_option
    from bridge.resources import bundled_database

    bus, path = parse_dbc_option(text)
    if not path.exists() and (bundled := bundled_database(str(path))) is not None:
        return f"{bus}={bundled}" if bus else str(bundled)
    return text


def _cmd_convert(args: argparse.Namespace) -> int:
    from bridge.convert import convert
    from bridge.progress import ProgressBar
    from bridge.resources import data_dir

    inputs: list[Path] = list(args.inputs)
    dbcs = [_dbc_option(text) for text in args.dbc or []]
    profile = args.profile
    if args.sample:
        inputs.append(data_dir() / "ecocar_sample.blf")
        profile = profile or "ecocar"
    if not inputs:
        raise BridgeError("convert: name at least one input log (or --sample)")
    if not dbcs and profile is None:
        print("warning: no --dbc and no --profile: only raw frames are recorded", file=sys.stderr)
    bar = ProgressBar(sys.stderr) if not args.quiet else None
    try:
        report = convert(inputs, args.output, dbcs, profile=profile, scene_rate=args.scene_rate,
                         force=args.force, strict=args.strict, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        stats = report.statistics
        rate = report.frames / report.seconds if report.seconds else 0.0
        print(f"wrote {report.output}: {report.frames:,} frames, {report.messages:,} messages "
              f"in {report.seconds:.1f} s ({rate:,.0f} frames/s)")
        print(f"  decoded {sum(stats['decoded'].values()):,}, "
              f"unknown ids {sum(stats['unknown_ids'].values()):,}, "
              f"decode errors {sum(stats['decode_errors'].values()):,}, "
              f"short frames {sum(stats['truncated'].values()):,}, "
              f"error frames {sum(stats['error_frames'].values()):,}")
        for key, title in (("unknown_ids", "unknown ids"), ("decode_errors", "decode errors")):
            top = sorted(stats[key].items(), key=lambda kv: -kv[1])[:8]
            if top:
                print(f"  {title}: " + ", ".join(f"{k} ({n})" for k, n in top))
        if report.issues:
            print(f"  skipped in the inputs: {len(report.issues)}")
            for issue in report.issues[:10]:
                print(f"    {issue}")
            if len(report.issues) > 10:
                print(f"    … {len(report.issues) - 10} more (tankviz inspect lists them)")
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from bridge.inspection import format_summary, summarize_file

    for path in args.files:
        print(format_summary(str(path), summarize_file(path)))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tankviz",
        description="CAN buses to Foxglove: decode with DBC files, draw the perception scene, "
        "stream it live and record every drive as MCAP.",
    )
    parser.add_argument("--version", action="version", version=f"tankviz {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    convert = sub.add_parser(
        "convert", help="convert CAN logs into one decoded MCAP drive archive",
        description="Convert CAN logs (any format python-can reads: .asc .blf .log .trc .csv "
        ".db, their .gz, .mf4 with tankviz[mf4]) into one MCAP with every raw frame, every "
        "decoded message, the statistics and the databases attached.")
    convert.add_argument("inputs", nargs="*", type=Path, metavar="INPUT",
                         help="log files; several are merged in time order")
    convert.add_argument("-o", "--output", type=Path, required=True, help="the MCAP to write")
    convert.add_argument("--dbc", action="append", metavar="[BUS=]PATH",
                         help="signal database (DBC, KCD, SYM, ARXML) for BUS, or for every bus "
                         "without BUS=; repeatable; a bundled name such as 'ecocar' works too")
    convert.add_argument("--profile", metavar="NAME|PATH",
                         help="vehicle profile (TOML) that says what the signals mean: adds the "
                         "scene and perception topics; a bundled name such as 'ecocar' works too; "
                         "without --dbc the profile's own databases are used")
    convert.add_argument("--scene-rate", type=float, default=20.0, metavar="HZ",
                         help="scene updates per second of log time (default 20, at most 50)")
    convert.add_argument("--sample", action="store_true",
                         help="also convert the bundled sample drive (with the ecocar profile)")
    convert.add_argument("--force", action="store_true", help="overwrite an existing output")
    convert.add_argument("--strict", action="store_true",
                         help="fail on the first unreadable line, damaged object or backwards "
                         "time jump instead of skipping and reporting it")
    convert.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    convert.set_defaults(run=_cmd_convert)

    inspect = sub.add_parser("inspect", help="show what a drive archive (MCAP) holds",
                             description="Duration, start and end, topics with schemas and "
                             "counts, metadata, attachments and decode statistics of MCAP files.")
    inspect.add_argument("files", nargs="+", type=Path, metavar="FILE.mcap")
    inspect.set_defaults(run=_cmd_inspect)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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

