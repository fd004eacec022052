#!/usr/bin/env python3
"""Benchmark decoding + protobuf encoding per frame (a report, not a test).

On the frames of a log, decoded and serialised as the decoded topics need them, it times in one
process, interleaved, best of ``--repeat`` (default 3):

(a) a fixed naive reference: cantools ``Database.decode_message(id, data,
    decode_choices=False)``, then the generated protobuf message (the very types of
    :class:`bridge.decode.proto_schema.MessageSchema`) built from keyword arguments and
    ``SerializeToString()``;
(b) tankviz's :class:`bridge.decode.decoder.Decoder` (a new one per round, so its caches start
    cold; with ``--warm``, it has prepared every message before the clock starts);
(c) optionally, each ``--compare NAME=PATH``: another decoder module (a file), or with
    ``--compare NAME=@REV`` the decoder of git revision REV (``benchlib.modules_at``), timed
    the same way as (b);
(d) with ``--pack N``: tankviz's column decode, :meth:`Decoder.decode_packed` on the same frames
    as :class:`bridge.packed.PackedFrames` s of N frames (made before the clock starts: they are
    what the read-ahead hands over), also printed as a ratio to (b);

and prints µs/frame of each (CPU time of this process, which a loaded machine disturbs less than
wall time; the garbage collector off, as in ``tankviz convert``) and the ratios to (a) (lower is
faster). It also checks that (b)
gives the same payload bytes as (a) for every frame, and prints the share of frames whose
``(id, payload)`` was seen before (what an ``(id, payload)`` cache can hit at best), overall and
for the ten busiest ids.

Logs:

- ``synthetic`` (default): ``bridge/sim``'s ecocar drive on three buses
  (``benchlib.ecocar_frames``), ``--frames`` frames (default 200,000);
- ``real-like``: traffic on the public ``ford_fusion_2018_pt.dbc`` (../shared/data/dbc) the way a
  production power-train bus looks: every message at its cycle, most status messages repeating
  unchanged, a 4-bit rolling counter and a checksum byte in a third of them, noisy measured
  values in the rest (a stand-in for a real candump log, which is not in the repository).

    python tools/bench_decode.py
    python tools/bench_decode.py --log real-like
    python tools/bench_decode.py --compare old=@HEAD~3
    python tools/bench_decode.py --pack 4096 --pack 16384 [--warm]
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import random
import sys
import time
from collections import Counter
from collections.abc import Callable
from functools import partial
from pathlib import Path
from types import ModuleType
from typing import Any, cast

import cantools
from cantools.database.can.database import Database
from google.protobuf import descriptor_pool

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchlib import ECOCAR_DBC, best_of, ecocar_frames, modules_at

from bridge.decode import decoder as tankviz_decoder
from bridge.decode.database import load_database
from bridge.decode.proto_schema import MessageSchema
from bridge.frame import Frame
from bridge.packed import PackedFrames

SHARED_DBC = Path(__file__).resolve().parents[2] / "shared" / "data" / "dbc"
REAL_LIKE_DBC = SHARED_DBC / "ford_fusion_2018_pt.dbc"


def synthetic_frames(n: int, seed: int) -> list[Frame]:
    return list(ecocar_frames(n, seed))


def real_like_frames(n: int, seed: int) -> list[Frame]:
    """Production-bus-like traffic on a public DBC (see the module docstring)."""
    db = cantools.database.load_file(str(REAL_LIKE_DBC), strict=False)
    assert isinstance(db, Database)
    rng = random.Random(seed)
    kinds: list[tuple[int, int, str, bytearray]] = []  # (id, period ms, kind, payload)
    for m in db.messages:
        if m.length == 0:
            continue
        period = int(m.cycle_time or rng.choice((10, 20, 50, 100, 1000)))
        kind = rng.choices(("static", "counter", "varying"), weights=(5, 3, 2))[0]
        payload = bytearray(rng.randbytes(m.length))
        kinds.append((m.frame_id, period, kind, payload))
    out: list[Frame] = []
    t_ms = 0
    while len(out) < n:
        for frame_id, period, kind, payload in kinds:
            if t_ms % period:
                continue
            if kind == "counter":  # a rolling counter in byte 0's low nibble, a sum in the last
                payload[0] = (payload[0] & 0xF0) | ((payload[0] + 1) & 0x0F)
                payload[-1] = sum(payload[:-1]) & 0xFF
            elif kind == "varying":  # a measured value with noise in its low byte
                payload[0], payload[1] = rng.randrange(256), rng.randrange(256)
            out.append(Frame(t_ms * 1_000_000, "can0", frame_id, bytes(payload)))
        t_ms += 1
    return out[:n]


class Naive:
    """(a): decode_message + protobuf from keyword args + SerializeToString, nothing cached."""

    def __init__(self, path: Path) -> None:
        db = cantools.database.load_file(str(path), strict=False)
        assert isinstance(db, Database)
        self.db = db
        pool = descriptor_pool.DescriptorPool()
        self.schemas = {(m.frame_id, bool(m.is_extended_frame)): MessageSchema(m, "db", pool)
                        for m in db.messages}

    def run(self, frames: list[Frame]) -> list[bytes | None]:
        out: list[bytes | None] = []
        decode, schemas = self.db.decode_message, self.schemas
        for f in frames:
            schema = schemas.get((f.arbitration_id, f.is_extended))
            if schema is None or f.is_error or f.is_remote:
                out.append(None)
                continue
            try:
                signals = cast(dict[str, Any], decode(f.arbitration_id, f.data,
                                                      decode_choices=False, allow_truncated=True))
            except Exception:
                out.append(None)
                continue
            if schema.renamed:
                signals = {schema.renamed.get(k, k): v for k, v in signals.items()}
            out.append(schema.message_class(**signals).SerializeToString())
        return out


class Fresh:
    """A new decoder of ``module`` for each round, made before the clock starts by
    :meth:`setup`; with ``warm``, it has also decoded one frame of every ``(bus, id)``, so that
    preparing each message (its protobuf type, compiled decoder and encoder: about 1 ms each, 1.3
    µs/frame of 100k frames of the simulated drive) is not timed."""

    def __init__(self, module: ModuleType, path: Path, warm: bool) -> None:
        self.module, self.warm = module, warm
        self.database = load_database(path)
        self.decoder: Any = None

    def setup(self, frames: list[Frame]) -> None:
        self.decoder = self.module.Decoder({None: [self.database]})
        if self.warm:
            first: dict[tuple[str, int, bool], Frame] = {}
            for f in frames:
                first.setdefault((f.bus, f.arbitration_id, f.is_extended), f)
            for f in first.values():
                self.decoder.decode(f)

    def __call__(self, frames: list[Frame]) -> list[bytes | None]:
        decode = self.decoder.decode
        out: list[bytes | None] = []
        for f in frames:
            d = decode(f)
            out.append(getattr(d, "payload", None))  # (None: not decoded, old or new)
        return out


def decoder_runner(module: ModuleType, path: Path, warm: bool = False) -> Fresh:
    return Fresh(module, path, warm)


class FreshBlocks(Fresh):
    """(d): Decoder.decode_packed on packs of ``size`` frames (made once per list of frames,
    outside the timing), with a new decoder per round as :class:`Fresh` makes it."""

    def __init__(self, path: Path, size: int, warm: bool) -> None:
        super().__init__(tankviz_decoder, path, warm)
        self.size = size
        self.made: dict[int, list[PackedFrames]] = {}

    def __call__(self, frames: list[Frame]) -> list[bytes | None]:
        packs = self.made.get(id(frames))
        if packs is None:
            packs = self.made[id(frames)] = [PackedFrames.from_frames(frames[i:i + self.size])
                                              for i in range(0, len(frames), self.size)]
        decode = self.decoder.decode_packed
        out: list[bytes | None] = []
        for pack in packs:
            out += [getattr(d, "payload", None) for d in decode(pack)]
        return out


def load_module(name: str, path: Path) -> ModuleType:
    """The decoder module at ``path``, or with ``@REV`` the one of git revision REV."""
    if str(path).startswith("@"):
        module = "bridge.decode.decoder"
        return modules_at(str(path)[1:], [module])[module]
    sys.path.insert(0, str(path.parent))
    spec = importlib.util.spec_from_file_location(f"bench_decode_{name}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def timed(run: Callable[[list[Frame]], object], frames: list[Frame]) -> float:
    """CPU seconds of ``run`` on ``frames`` (set up first, not timed), the garbage collector off
    as in ``tankviz convert``."""
    setup = getattr(run, "setup", None)
    if setup is not None:
        setup(frames)
    gc.collect()
    gc.disable()
    started = time.process_time()
    run(frames)
    spent = time.process_time() - started
    gc.enable()
    return spent


def repeats(frames: list[Frame]) -> tuple[float, list[tuple[str, int, float]]]:
    seen: set[tuple[str, int, bytes]] = set()
    per_id: Counter[tuple[str, int]] = Counter()
    hits: Counter[tuple[str, int]] = Counter()
    for f in frames:
        key = (f.bus, f.arbitration_id, f.data)
        per_id[key[:2]] += 1
        if key in seen:
            hits[key[:2]] += 1
        else:
            seen.add(key)
    total = sum(hits.values()) / max(1, len(frames))
    busiest = [(f"{bus}/0x{i:X}", n, hits[(bus, i)] / n) for (bus, i), n in per_id.most_common(10)]
    return total, busiest


def frames_of(log: str, n: int, seed: int) -> tuple[list[Frame], Path]:
    if log == "synthetic":
        return synthetic_frames(n, seed), ECOCAR_DBC
    if not REAL_LIKE_DBC.is_file():
        raise SystemExit(f"error: {REAL_LIKE_DBC} not found: the public DBCs come from "
                         "../shared/data/dbc (opendbc, MIT)")
    return real_like_frames(n, seed), REAL_LIKE_DBC


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", choices=("synthetic", "real-like"), default="synthetic")
    parser.add_argument("--frames", type=int, default=200_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--compare", action="append", default=[], metavar="NAME=PATH",
                        help="another decoder module to time like (b)")
    parser.add_argument("--pack", action="append", type=int, default=[], metavar="N",
                        help="also time Decoder.decode_packed on packs of N frames (d)")
    parser.add_argument("--warm", action="store_true",
                        help="tankviz's decoders have prepared every message before the clock "
                        "starts (one frame of each id decoded): the steady state")
    args = parser.parse_args(argv)

    frames, dbc = frames_of(args.log, args.frames, args.seed)
    runners: dict[str, Callable[[list[Frame]], list[bytes | None]]] = {
        "a naive": Naive(dbc).run, "b tankviz": decoder_runner(tankviz_decoder, dbc, args.warm)}
    for spec in args.compare:
        name, _, path = spec.partition("=")
        runners[f"c {name}"] = decoder_runner(load_module(name, Path(path)), dbc, args.warm)
    for size in args.pack:
        runners[f"d packs of {size}"] = FreshBlocks(dbc, size, args.warm)

    reference = runners["a naive"](frames)
    for name, run in runners.items():
        setup = getattr(run, "setup", None)
        if setup is not None:
            setup(frames)
        got = run(frames)
        differ = sum(1 for x, y in zip(reference, got, strict=True) if x != y)
        if differ:
            print(f"MISMATCH: {name} gives other payload bytes than (a) for {differ} frames")

    best = best_of({name: partial(timed, run, frames) for name, run in runners.items()},
                   args.repeat)

    decodable = sum(1 for r in reference if r is not None)
    print(f"log: {args.log}, {len(frames)} frames ({decodable} decodable), {dbc.name}; "
          f"best of {args.repeat}, interleaved")
    base = best["a naive"]
    for name, seconds in best.items():
        to_b = (f"   ratio to (b) {seconds / best['b tankviz']:.3f}"
                if name.startswith("d ") else "")
        print(f"  ({name}): {seconds / len(frames) * 1e6:6.2f} µs/frame   "
              f"ratio to (a) {seconds / base:.3f}{to_b}")
    total, busiest = repeats(frames)
    print(f"(id, payload) seen before: {total:.1%} of frames; busiest ids:")
    for key, n, rate in busiest:
        print(f"  {key:>14}  {n:7d} frames  {rate:6.1%} repeat")
    return 0


if __name__ == "__main__":
    sys.exit(main())
