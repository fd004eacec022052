"""``tankviz convert``: CAN logs to one decoded, self-contained MCAP drive archive.

The conversion is :func:`bridge.pipeline.convert.convert` (``from bridge.apps.convert import
convert`` is that function); this command checks its inputs and output before it prints any
warning, prints the warnings when the databases load and again in its summary
(:func:`format_report`), refuses ``--sample`` with logs, and stopped by SIGTERM or SIGHUP unwinds
as Ctrl+C does: no file left behind, exit status 128 + the signal's number.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bridge.apps.options import (
    Stopped,
    Subparsers,
    add_stage_options,
    dbc_option,
    stopped_by_signals,
)
from bridge.apps.progress import ProgressBar
from bridge.errors import UsageError
from bridge.io.drives import is_drive
from bridge.io.issues import summarize_issues
from bridge.pipeline.convert import (
    ConvertReport,
    check_mcap_output,
    convert,
    refuse_repeated,
)
from bridge.resources import data_dir
from bridge.sinks.outputs import refuse_inputs

__all__ = ["add_parser", "convert", "format_report", "run"]


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "convert", help="convert CAN logs into one decoded MCAP drive archive",
        description="Convert CAN logs (any format python-can reads: .asc .blf .log .trc .csv "
        ".db, their .gz, .mf4 with tankviz[mf4]) into one MCAP with every raw frame, every "
        "decoded message, the statistics and the databases attached. Given a drive (.mcap) "
        "tankviz recorded, re-derive it: its raw frames through the pipeline again, with its "
        "attached databases and profile unless --dbc or --profile give new ones.")
    parser.add_argument("inputs", nargs="*", type=Path, metavar="INPUT",
                        help="log files; several are merged in time order; or one recorded "
                        "drive (.mcap) to re-derive")
    parser.add_argument("-o", "--output", type=Path, required=True, help="the MCAP to write")
    add_stage_options(parser, profile_default=None)
    parser.add_argument("--sample", action="store_true",
                        help="convert the bundled sample drive (with the ecocar profile), "
                        "alone: not with logs")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")
    parser.add_argument("--strict", action="store_true",
                        help="fail on the first unreadable line, damaged object or backwards "
                        "time jump instead of skipping and reporting it")
    parser.add_argument("--no-read-ahead", dest="read_ahead", action="store_false",
                        help="read the inputs in this process (by default a second process "
                        "reads large inputs while this one converts: the same output, sooner)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    inputs: list[Path] = list(args.inputs)
    dbcs = [dbc_option(text) for text in args.dbc or []]
    profile = args.profile
    if args.sample:
        if inputs:
            raise UsageError("convert", "--sample converts the bundled sample drive alone; it "
                             f"cannot be merged into {inputs[0]} (convert each on its own)")
        inputs.append(data_dir() / "ecocar_sample.blf")
        profile = profile or "ecocar"
    if not inputs:
        raise UsageError("convert", "name at least one input log (or --sample)")
    refuse_inputs(args.output, inputs)  # (convert checks them too: here before any warning)
    check_mcap_output(args.output)
    refuse_repeated(inputs)
    if not dbcs and profile is None and not any(is_drive(p) for p in inputs):
        print("warning: no --dbc and no --profile: "
              + ("nothing is decoded: raw frames are recorded, and the bring-up topics with "
                 "every id unknown" if args.bring_up else "only raw frames are recorded"),
              file=sys.stderr)
    bar = ProgressBar(sys.stderr) if not args.quiet else None
    try:
        try:
            with stopped_by_signals():
                report = convert(inputs, args.output, dbcs, profile=profile,
                                 scene_rate=args.scene_rate, force=args.force,
                                 strict=args.strict, progress=bar,
                                 warn=lambda text: print(f"warning: {text}", file=sys.stderr),
                                 read_ahead=args.read_ahead, bring_up=args.bring_up)
        finally:
            if bar is not None:
                bar.close()
    except Stopped as stop:
        print(f"{stop}: {args.output} not written", file=sys.stderr)
        return 128 + stop.signum
    if not args.quiet:
        print(format_report(report))
    return 0


def format_report(report: ConvertReport) -> str:
    """What a conversion wrote, decoded and skipped, for people."""
    stats = report.statistics
    rate = report.frames / report.seconds if report.seconds else 0.0
    lines = [report.rederived] if report.rederived else []
    lines += [f"wrote {report.output}: {report.frames:,} frames, {report.messages:,} messages "
              f"in {report.seconds:.1f} s ({rate:,.0f} frames/s)",
              f"  decoded {sum(stats['decoded'].values()):,}, "
              f"unknown ids {sum(stats['unknown_ids'].values()):,}, "
              f"decode errors {sum(stats['decode_errors'].values()):,}, "
              f"short frames {sum(stats['truncated'].values()):,}, "
              f"longer than their message "
              f"{sum(v['frames'] for v in stats.get('longer', {}).values()):,}, "
              f"error frames {sum(stats['error_frames'].values()):,}"]
    for key, title in (("unknown_ids", "unknown ids"), ("decode_errors", "decode errors"),
                       ("non_finite", "non-finite values (kept out of the scene)"),
                       ("rule_errors", "rule errors (objects left out)")):
        counted = sorted(stats.get(key, {}).items(), key=lambda kv: -kv[1])
        if counted:
            more = f", and {len(counted) - 8} more" if len(counted) > 8 else ""
            lines.append(f"  {title}: " + ", ".join(f"{k} ({n})" for k, n in counted[:8]) + more)
    for group, why in stats.get("last_rule_error", {}).items():
        lines.append(f"    {group}: {why}")
    if report.issues:
        lines.append(f"  skipped in the inputs: {len(report.issues)}")
        told = summarize_issues(report.issues, limit=10)
        if told[-1].startswith("… and "):
            told[-1] += " (tankviz inspect lists them)"
        lines += [f"    {line}" for line in told]
    if report.warnings:
        lines.append(f"  warnings ({len(report.warnings)}):")
        lines += [f"    {text}" for text in report.warnings]
    return "\n".join(lines)
