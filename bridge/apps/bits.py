"""``tankviz bits``: the bit-change map of one id, or the bits that switch between two windows
of time across every id.

The map is a grid, a row per byte and a column per bit (bit 7 on the left), each cell the share
of the id's frames that flipped that bit, with a letter per bit naming a known id's signal.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, TextIO

import numpy as np

from bridge.apps.options import Subparsers
from bridge.apps.sources import (
    add_source_options,
    known_buses,
    opened,
    parse_id,
    parse_window,
    window_ns,
)
from bridge.bringup.census import Tally
from bridge.bringup.columns import data_frames, id_text
from bridge.bringup.compare import Steadiness, Switch
from bridge.bringup.layout import message_bits
from bridge.errors import UsageError
from bridge.frame import NS

EXAMPLE = """examples:
  tankviz bits drive.blf --id can0/0x2C4                 the map of one id
  tankviz bits drive.blf --id can0/708 --from 10 --to 20  the same id (decimal), 10 s to 20 s
  tankviz bits drive.blf --compare 12:14 14.5:16.5        bits that switch between two moments
  tankviz bits drive.blf --dbc can0=car.dbc --compare 12:14 14.5:16.5 --unknown
                                                         ... of the ids no database decodes

bit numbering: bit i is byte i // 8, bit i % 8, the least significant first: the DBC start bit
of a little-endian (Intel, @1) signal. Times are seconds from the source's first frame (as
tankviz replay --start takes them)."""

#: Shades of a cell, from no flip to a flip in every frame.
SHADES = " .:-=+*#%@"


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "bits", help="the bit-change map of one CAN id, or the bits that switch between two "
        "windows of time",
        description="With --id: count, for every bit of one id, the frames where it differs "
        "from the id's frame before, and print it as a bytes x bits grid (a known id with the "
        "signal covering each bit). With --compare: across every id, list the bits steady in "
        "the first window and steady at the other value in the second.",
        epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_source_options(parser)
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--id", metavar="BUS/ID",
                      help="the id whose map to print: hex (0x1A0) or decimal (416)")
    what.add_argument("--compare", nargs=2, metavar=("A0:A1", "B0:B1"),
                      help="two windows, seconds from the source's first frame")
    parser.add_argument("--from", dest="start", type=float, metavar="S",
                        help="with --id: from this second of the source (default its start)")
    parser.add_argument("--to", dest="end", type=float, metavar="S",
                        help="with --id: up to this second (default its end)")
    parser.add_argument("--unknown", action="store_true",
                        help="with --compare: only the ids no database decodes")
    parser.add_argument("--json", action="store_true",
                        help='JSON: {"flips": [per bit], ...} for --id; a list of {bus, id, '
                        "bit, before, after, ...} for --compare")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.compare:
        if args.start is not None or args.end is not None:
            raise UsageError("bits", "--from and --to go with --id; --compare names its windows")
        return _compare(args)
    return _map(args)


def _map(args: argparse.Namespace) -> int:
    bus, key = parse_id(args.id)
    start_s = args.start if args.start is not None else 0.0
    end_s = args.end if args.end is not None else float("inf")
    if not end_s > start_s:
        raise UsageError("bits", f"--to {end_s:g} must come after --from {start_s:g}")
    tally = Tally(bus, key)
    buses: set[str] = set()
    frames_of_id = 0
    with opened(args) as source:
        window: tuple[int, int] | None = None
        for pack in source.packs():
            assert source.origin_ns is not None
            window = window or window_ns(source.origin_ns, (start_s, end_s))
            buses.update(pack.buses)
            columns = data_frames(pack)
            b = columns.buses.index(bus) if bus in columns.buses else -1
            rows = np.flatnonzero((columns.bus == b) & (columns.key == key))
            frames_of_id += len(rows)
            t = columns.t[rows]
            rows = rows[(t >= window[0]) & (t < window[1])]
            if len(rows):
                width = int(columns.length[rows].max())
                tally.add(columns.t[rows], columns.payload[rows, :width], columns.length[rows],
                          None)
        known_buses(sorted(buses), bus, "--id", args.id)
        if not frames_of_id:
            raise UsageError("--id", f"bus {bus} has no frame of id {id_text(key)}",
                             value=args.id)
        if not tally.frames:
            raise UsageError("--id", f"no frame of it between {start_s:g} s and "
                             f"{end_s:g} s (an empty window)", value=args.id)
        message = source.message(bus, key)
        assert source.origin_ns is not None
        origin = source.origin_ns
    if args.json:
        print(json.dumps(map_json(tally, message, origin)))
    else:
        print_map(tally, message, origin, sys.stdout, colour=_colour(sys.stdout))
    return 0


def map_json(tally: Tally, message: Any, origin_ns: int) -> dict[str, Any]:
    covered = message_bits(message) if message is not None else {}
    return {"bus": tally.bus, "id": id_text(tally.key), "frames": tally.frames,
            "from_s": (tally.first_ns - origin_ns) / NS, "to_s": (tally.last_ns - origin_ns) / NS,
            "message": None if message is None else message.name,
            "flips": tally.flips.tolist(),
            "signals": {str(bit): names for bit, names in sorted(covered.items())}}


def _colour(out: TextIO) -> bool:
    return out.isatty() and os.environ.get("NO_COLOR") is None and os.environ.get(
        "TERM", "dumb") != "dumb"


def cell(flips: int, frames: int) -> str:
    """A cell of the map: the share of frames that flipped the bit, in %, and '.' for none."""
    if flips == 0:
        return "."
    share = 100 * flips / max(frames - 1, 1)
    return "<1" if share < 1 else f"{share:.0f}"


def print_map(tally: Tally, message: Any, origin_ns: int, out: TextIO, *,
              colour: bool = False) -> None:
    """The bytes x bits grid of one id's flips (see the module's description)."""
    covered = message_bits(message) if message is not None else {}
    names = sorted({name for names in covered.values() for name in names})
    letters = {name: chr(ord("A") + i) if i < 26 else chr(ord("a") + i - 26)
               for i, name in enumerate(names[:52])}
    frames = tally.frames
    name = message.name if message is not None else "unknown"
    print(f"{tally.bus} {id_text(tally.key)} ({name}): {frames:,} frames from "
          f"{(tally.first_ns - origin_ns) / NS:.3f} s to {(tally.last_ns - origin_ns) / NS:.3f} s"
          f"; % of frames that flipped each bit", file=out)
    print("bit i = byte i // 8, bit i % 8 (least significant first: DBC start bits of "
          "little-endian signals)", file=out)
    header = "        " + "".join(f"{b:>5}" for b in range(7, -1, -1))
    if covered:
        header += "    signals"
    print(header, file=out)
    flips = tally.flips
    last = tally.last if tally.last is not None else np.zeros(len(flips) // 8, np.uint8)
    for byte in range(len(flips) // 8):
        cells = []
        for b in range(7, -1, -1):
            bit = byte * 8 + b
            text = f"{cell(int(flips[bit]), frames):>5}"
            if colour and flips[bit]:
                share = flips[bit] / max(frames - 1, 1)
                level = 232 + min(23, 6 + round(17 * min(1.0, share * 2)))
                text = f"\x1b[48;5;{level}m\x1b[38;5;16m{text}\x1b[0m"
            cells.append(text)
        row = f"byte {byte:<2} " + "".join(cells)
        if covered:
            row += "    " + "".join(letters.get(covered.get(byte * 8 + b, ["?"])[0], "-")
                                    if byte * 8 + b in covered else "."
                                    for b in range(7, -1, -1))
        row += f"    last 0x{int(last[byte]):02X}"
        print(row, file=out)
    if names:
        print("signals: " + ", ".join(f"{letters[n]} {n}" for n in names if n in letters),
              file=out)
    changing = np.flatnonzero(flips)
    unexplained = [bit for bit in changing.tolist() if bit not in covered] if message else []
    print(f"{len(changing)} bits change" + (f"; {len(unexplained)} of them no signal covers: "
                                            + ", ".join(map(str, unexplained))
                                            if unexplained else ""), file=out)


def _compare(args: argparse.Namespace) -> int:
    first = parse_window(args.compare[0], "--compare")
    second = parse_window(args.compare[1], "--compare")
    steadiness: Steadiness | None = None
    with opened(args) as source:
        for pack in source.packs():
            if steadiness is None:
                assert source.origin_ns is not None
                steadiness = Steadiness(window_ns(source.origin_ns, first),
                                        window_ns(source.origin_ns, second))
            steadiness.add(data_frames(pack))
        assert steadiness is not None
        for w, text in enumerate(args.compare):
            if not steadiness.frames(w):
                raise UsageError("--compare", "no frame in this window (an empty "
                                 "window)", value=text)
        switches = [s for s in steadiness.switches()
                    if not args.unknown or source.message(s.bus, s.key) is None]
        described = [(s, _signals(source.message(s.bus, s.key), s)) for s in switches]
    if args.json:
        print(json.dumps([switch_json(s, message, signal) for s, (message, signal)
                          in described]))
        return 0
    print(f"bits steady in {args.compare[0]} s and steady at the other value in "
          f"{args.compare[1]} s: {len(switches)}")
    for s, (message, signal) in described:
        where = f"{message}.{signal}" if signal else (f"{message} (no signal)" if message
                                                      else "unknown id")
        print(f"  {s.bus}  {id_text(s.key):>10}  bit {s.bit:>3} (byte {s.bit // 8} bit "
              f"{s.bit % 8})  {s.before} -> {s.after}  {where}")
    return 0


def _signals(message: Any, switch: Switch) -> tuple[str | None, str | None]:
    if message is None:
        return None, None
    names = message_bits(message).get(switch.bit)
    return message.name, "/".join(names) if names else None


def switch_json(s: Switch, message: str | None, signal: str | None) -> dict[str, Any]:
    return {"bus": s.bus, "id": id_text(s.key), "bit": s.bit, "before": s.before,
            "after": s.after, "message": message, "signal": signal}
