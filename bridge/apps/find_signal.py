"""``tankviz find-signal``: the field of the ids no database decodes that follows a known
quantity, ranked by fit and printed as DBC lines (:mod:`bridge.bringup.search`).

The reference is a signal of the same source (``BUS/MESSAGE.SIGNAL``, decoded with its
databases) or a CSV of ``time,value`` rows, its times on the source's clock (seconds from its
first frame, or the log's own timestamps: told from their range, or ``--csv-clock``).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bridge.apps.options import Subparsers
from bridge.apps.sources import Source, frame_key_of, opened
from bridge.bringup.columns import Array, Bytes, by_id, data_frames, id_text
from bridge.bringup.dbc import candidate_lines, dbc_file
from bridge.bringup.search import MAX_LENGTH, MAX_ROWS, Reference, Search, search
from bridge.errors import FileError, InputError, UsageError
from bridge.frame import NS

#: A candidate fits this well at least to be written into ``-o`` (the best one always is).
GOOD_FIT = 0.5

EXAMPLE = f"""examples:
  tankviz find-signal drive.blf --dbc can0=car.dbc --like can0/SPEED.SPEED
  tankviz find-signal drive.blf --like speed.csv --top 3 -o found.dbc
  tankviz convert drive.blf -o drive.mcap --dbc can0=car.dbc --dbc can0=found.dbc

Every start bit and length (1 to {MAX_LENGTH} bits), both byte orders, signed and unsigned, of
every id no database decodes, fitted as reference = scale * raw + offset; ranked by R².
Constant fields, counters, checksums (fields that jump across their range from frame to frame)
and flags are refused, and counted. Ids with more than {MAX_ROWS:,} frames are sampled evenly.
A CSV: a time,value row per line (a header line is allowed; its second column names the
quantity); times in seconds from the source's first frame, or on the log's own clock (its
timestamps, e.g. Unix seconds): --csv-clock auto tells which from their range."""


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "find-signal", help="find the field of unknown ids that follows a known quantity, as "
        "DBC lines",
        description="Search every field of the ids that no database decodes for the one that "
        "follows a known quantity (a decoded signal of the source, or a CSV of time,value), "
        "and print the best as DBC lines with the fitted scale and offset.",
        epilog=EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    from bridge.apps.sources import add_source_options

    add_source_options(parser)
    parser.add_argument("--like", required=True, metavar="REF",
                        help="BUS/MESSAGE.SIGNAL of the source's databases, or a CSV file of "
                        "time,value rows")
    parser.add_argument("--top", type=int, default=5, metavar="N",
                        help="how many candidates to print (default 5)")
    parser.add_argument("-o", "--output", type=Path, metavar="FOUND.dbc",
                        help="write the best candidate and those that fit with R² >= "
                        f"{GOOD_FIT:g} (of its bus) as a DBC file, best first, for "
                        "--dbc BUS=FOUND.dbc")
    parser.add_argument("--csv-clock", choices=("auto", "source", "log"), default="auto",
                        help="the CSV's times: seconds from the source's first frame (source), "
                        "the log's own timestamps (log), or told from their range (auto, the "
                        "default)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.top < 1:
        raise UsageError("--top", "expected a number of candidates >= 1", value=args.top)
    output: Path | None = args.output
    if output is not None:
        if output.exists() and not args.force:
            raise FileError(output, "exists already (--force overwrites it)")
        if any(output.resolve() == Path(p).resolve() for p in args.inputs):
            raise FileError(output, "is one of the inputs: find-signal never writes over one")
    csv_path = Path(args.like) if _is_csv(args.like) else None
    table = _read_csv(csv_path) if csv_path is not None else None
    with opened(args) as source:
        wanted = None if table is not None else _signal_reference(source, args.like)
        unknown: dict[tuple[str, int], tuple[list[Array], list[Bytes]]] = {}
        ref_t: list[Array] = []
        ref_payloads: list[Bytes] = []
        last_ns = 0
        for pack in source.packs():
            columns = data_frames(pack)
            if len(columns.t):
                last_ns = max(last_ns, int(columns.t.max()))
            for bus, key, rows in by_id(columns):
                width = int(columns.length[rows].max())
                if wanted is not None and (bus, key) == wanted[:2]:
                    ref_t.append(columns.t[rows])
                    ref_payloads.append(columns.payload[rows, :width])
                if source.message(bus, key) is None:
                    times, payloads = unknown.setdefault((bus, key), ([], []))
                    times.append(columns.t[rows])
                    payloads.append(columns.payload[rows, :width])
        assert source.origin_ns is not None
        if table is not None:
            assert csv_path is not None
            reference = _csv_reference(csv_path, table, source.origin_ns, last_ns,
                                       args.csv_clock)
        else:
            assert wanted is not None
            reference = _decoded_reference(source, args.like, wanted, ref_t, ref_payloads)
    if not unknown:
        raise UsageError("find-signal", f"every id of {args.inputs[0]} is in a database: nothing "
                         "unknown to search")
    samples = {k: (np.concatenate(ts), _stack(ps)) for k, (ts, ps) in unknown.items()}
    found = search(samples, reference, top=args.top)
    lengths = {k: int(p.shape[1]) for k, (_, p) in samples.items()}
    print_found(found, reference, lengths)
    if output is not None and found.candidates:
        good = [c for c in found.candidates if c.r2 >= GOOD_FIT] or found.candidates[:1]
        text = dbc_file(good, reference.name, reference.unit, lengths)
        try:
            output.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise FileError(output, f"cannot write: {exc.strerror or exc}") from None
        bus = found.candidates[0].field.bus
        print(f"wrote {output}: decode with it: --dbc {bus}={output} (beside the bus's own "
              "databases)")
    return 0


def _stack(payloads: list[Bytes]) -> Bytes:
    width = max(p.shape[1] for p in payloads)
    return np.vstack([np.pad(p, ((0, 0), (0, width - p.shape[1]))) for p in payloads])


def _is_csv(text: str) -> bool:
    return text.lower().endswith(".csv") or Path(text).is_file()


def _signal_reference(source: Source, text: str) -> tuple[str, int, Any]:
    """``BUS/MESSAGE.SIGNAL`` checked against the databases: (bus, key, codec)."""
    bus, slash, rest = text.partition("/")
    message, dot, signal = rest.rpartition(".")
    if not slash or not dot or not bus or not message or not signal:
        raise UsageError("--like", "expected BUS/MESSAGE.SIGNAL (e.g. can0/SPEED.SPEED) "
                         "or a CSV file (.csv)", value=text)
    codecs = {c.message.name: c for c in source.decoder.codecs_for(bus)}
    codec = codecs.get(message)
    if codec is None:
        raise UsageError("--like", f"no database of bus {bus} has a message {message}",
                         value=text)
    names = [s.name for s in codec.message.signals]
    if signal not in names:
        raise UsageError("--like", f"message {message} has no signal {signal} (it has "
                         f"{', '.join(names)})", value=text)
    return bus, frame_key_of(codec.message), codec


def _decoded_reference(source: Source, text: str, wanted: tuple[str, int, Any],
                       times: list[Array], payloads: list[Bytes]) -> Reference:
    bus, key, codec = wanted
    signal = text.rpartition(".")[2]
    if not times:
        raise UsageError("--like", f"the source has no frame of {codec.message.name} "
                         f"({id_text(key)}) on bus {bus}", value=text)
    t = np.concatenate(times)
    rows = _stack(payloads)
    values, kept = [], []
    for i, row in enumerate(rows):
        decoded = codec.decode(bytes(row[:codec.length]))
        value = decoded.signals.get(signal)
        if isinstance(value, (int, float)) and math.isfinite(value):
            values.append(float(value))
            kept.append(i)
    if len(values) < 2:
        raise UsageError("--like", "fewer than two frames decode a value of it", value=text)
    order = np.argsort(t[kept], kind="stable")
    unit = next((s.unit or "" for s in codec.message.signals if s.name == signal), "")
    return Reference(text, unit, t[kept][order], np.asarray(values)[order])


def _read_csv(path: Path) -> tuple[str, list[tuple[float, float]]]:
    """The CSV's quantity name and its (time, value) rows; one-line errors naming the line."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            lines = list(csv.reader(f))
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read: {exc}") from None
    name = path.stem
    rows: list[tuple[float, float]] = []
    for number, line in enumerate(lines, 1):
        cells = [c.strip() for c in line]
        if not any(cells) or cells[0].startswith("#"):
            continue
        if len(cells) < 2:
            raise InputError(path, f"expected time,value, got {','.join(cells)!r}",
                             where=str(number))
        try:
            t, v = float(cells[0]), float(cells[1])
        except ValueError:
            if not rows and number == 1:
                name = cells[1] or name
                continue
            raise InputError(path, f"not a number in {','.join(cells[:2])!r}",
                             where=str(number)) from None
        if math.isfinite(t) and math.isfinite(v):
            rows.append((t, v))
    if len(rows) < 2:
        raise InputError(path, "a reference needs at least two time,value rows with numbers")
    return name, rows


def _csv_reference(path: Path, table: tuple[str, list[tuple[float, float]]], origin_ns: int,
                   last_ns: int, clock: str) -> Reference:
    name, rows = table
    t = np.asarray([r[0] for r in rows])
    v = np.asarray([r[1] for r in rows])
    span = (origin_ns / NS, last_ns / NS)
    if clock == "auto":
        on_log = t.max() >= span[0] and t.min() <= span[1]
        clock = "log" if on_log else "source"
    t_ns = np.round(t * NS).astype(np.int64) + (0 if clock == "log" else origin_ns)
    if t_ns.max() < origin_ns or t_ns.min() > last_ns:
        raise InputError(path, f"its times ({t.min():g} to {t.max():g} s, {clock} clock) do not "
                         f"meet the source's ({0:g} to {(last_ns - origin_ns) / NS:g} s from its "
                         f"first frame, {span[0]:.3f} to {span[1]:.3f} on the log's clock)")
    order = np.argsort(t_ns, kind="stable")
    if len(np.unique(v)) < 2:
        raise InputError(path, "its values never change: nothing to follow")
    named, _, unit = name.replace("(", "[").partition("[")
    return Reference(named.strip() or path.stem, unit.rstrip("])").strip(), t_ns[order],
                     v[order])


def print_found(found: Search, reference: Reference, lengths: dict[tuple[str, int], int]) -> None:
    out = sys.stdout
    print(f"searched {found.ids} unknown ids ({found.frames:,} frames looked at) for fields "
          f"that follow {reference.name}", file=out)
    if found.refused:
        print("refused: " + ", ".join(f"{n} {why}" for why, n in sorted(found.refused.items())),
              file=out)
    if not found.candidates:
        print("no field follows it", file=out)
        return
    unit = f" {reference.unit}" if reference.unit else ""
    for rank, c in enumerate(found.candidates, 1):
        print(f"\n#{rank}  {c.field.describe()}: R² {c.r2:.6f}, residual {c.rms:.4g}{unit} RMS "
              f"over {c.frames:,} frames, raw {c.raw_min}..{c.raw_max}", file=out)
        for line in candidate_lines(c, rank, reference.name, reference.unit,
                                    lengths[(c.field.bus, c.field.key)]):
            print(f"  {line}", file=out)
