"""``tankviz ids``: every (bus, id) of a source, a row each: frames, period, jitter, lengths, the
message a database names it, the bits that change and those no signal explains."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TextIO

from bridge.apps.options import Subparsers
from bridge.apps.sources import add_source_options, opened
from bridge.bringup.census import Census, IdRow
from bridge.bringup.columns import data_frames

EXAMPLE = """example:
  tankviz ids drive.blf --dbc can0=car.dbc
  tankviz ids drives/2026-11-25T17-24-39Z.mcap --json | grep '"message": null'

periods are the median gap between an id's frames; jitter is the 5th to the 95th percentile of
the gaps; a changing bit flipped at least once; an unexplained bit is a changing bit of a known
message that none of its signals covers."""


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "ids", help="list every CAN id of a source: rate, lengths, message, changing bits",
        description="List every (bus, id) of CAN logs or a recorded drive, sorted by bus and "
        "id: frames, median period and jitter, lengths seen, the message a database names it "
        "(or unknown), how many bits ever change and, for a known message, how many of those "
        "no signal covers.", epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_source_options(parser)
    parser.add_argument("--json", action="store_true",
                        help="one JSON object per line (bus, id, frames, period_ms, gap_p5_ms, "
                        "gap_p95_ms, dlcs, message, changing_bits, unexplained_bits)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    census = Census()
    with opened(args) as source:
        for pack in source.packs():
            census.add(data_frames(pack))
        rows = census.rows(source.message)
    if args.json:
        for row in rows:
            print(json.dumps(row.as_json()))
    else:
        print_table(rows, sys.stdout)
    return 0


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def print_table(rows: list[IdRow], out: TextIO) -> None:
    """The rows as a table for people, with a line of totals."""
    head = ("bus", "id", "frames", "period ms", "jitter ms (p5-p95)", "DLC", "message",
            "changing bits", "unexplained")
    lines = [head]
    for r in rows:
        jitter = "-" if r.gap_p5_ms is None else f"{_ms(r.gap_p5_ms)}-{_ms(r.gap_p95_ms)}"
        lines.append((r.bus, r.id, f"{r.frames:,}", _ms(r.period_ms), jitter,
                      ",".join(map(str, r.dlcs)), r.message or "unknown", str(r.changing_bits),
                      "-" if r.unexplained_bits is None else str(r.unexplained_bits)))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    right = {2, 3, 4, 7, 8}
    for line in lines:
        print("  ".join(cell.rjust(w) if i in right else cell.ljust(w)
                        for i, (cell, w) in enumerate(zip(line, widths, strict=True))).rstrip(),
              file=out)
    unknown = [r for r in rows if r.message is None]
    print(f"{len(rows)} ids, {sum(r.frames for r in rows):,} frames; {len(unknown)} ids "
          f"({sum(r.frames for r in unknown):,} frames) no database knows", file=out)
