#!/usr/bin/env python3
"""Benchmark the health monitor's per-frame hook, ``HealthMonitor.on_frame`` (a report, not a test).

Two kinds of traffic, turned into :class:`bridge.frame.Frame` (and decoded) a chunk at a time
before the chunk is timed, so that only ``on_frame`` is:

- ``synthetic``: ``bridge/sim``'s ecocar drive on three buses (``benchlib.ecocar_frames``:
  rolling counters, checksums, CAN FD radar frames; 1.5M frames are about 650 s), decoded
  with the ecocar databases and watched with the ecocar profile (500 kbit/s, 2 Mbit/s data phase);
- ``candump``: a candump-like log of a car tankviz has no profile for (:func:`candump_frames`:
  ~100 ids, 11- and 29-bit, 10 ms to 1 s cycles, counters, checksums, noisy and random bytes,
  CAN FD frames with and without bit rate switch, some remote and error frames; 59 % and 43 %
  bus load), without a profile or databases (every frame undecoded), as ``tankviz convert``
  of a foreign log.

Each chunk goes through ``--repeat`` (3) monitors of the checkout (``new``) and as many of a
reference (``old``: by default the committed ``bridge/health`` package, from a worktree of
``--ref``, each monitor with a copy of its own, so that none shares another's caches),
interleaved; it prints µs/frame of the best of each and the ratio
old/new. It then compares the bits each counted on each bus (the bus load) with the exact count
(the reference's ``frame_bits`` summed over every frame). ``--profile`` adds a cProfile of the
first new monitor.

    python tools/bench_health.py                  # 1.5M synthetic + 600k candump frames
    python tools/bench_health.py --frames 300000 --candump-frames 300000 --profile
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import pstats
import random
import sys
import time
import types
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bridge.decode.codec import Decoded  # noqa: E402
from bridge.decode.decoder import Decoder  # noqa: E402
from bridge.frame import NS, Frame  # noqa: E402
from bridge.health import monitor as new_monitor  # noqa: E402
from bridge.pipeline.drive import load_stages  # noqa: E402

sys.path.insert(0, str(ROOT / "tools"))
from benchlib import ecocar_frames, package_at  # noqa: E402

T0_NS = 1_700_000_000 * NS


def candump_frames(n: int, seed: int = 7) -> list[Frame]:
    """``n`` frames of a candump-like log of a car without a profile, in time order.

    About 100 ids on two buses (a fifth of them 29-bit), each with its own cycle time (10 ms to
    1 s, ±5 % jitter), length and payload habits: a rolling counter in the low nibble of byte 0, a
    checksum in the last byte, slowly changing signals, constant bytes, and random bytes; one
    bus is CAN FD (12- to 64-byte frames, most with bit rate switch, some without, one with the
    error state indicator). Now and then a remote frame and an error frame.
    """
    rng = random.Random(seed)
    kinds: list[dict[str, Any]] = []
    for i in range(100):
        fd = i % 4 == 0
        extended = i % 5 == 1
        kinds.append({
            "bus": "can1" if fd else "can0",
            "id": rng.randrange(1 << 29) if extended else rng.randrange(0x7FF),
            "extended": extended, "fd": fd, "brs": fd and i % 8 != 4, "esi": i == 8,
            "length": (rng.choice((12, 16, 20, 24, 32, 48, 64, 13, 40)) if fd
                       else rng.choice((8, 8, 8, 8, 6, 4, 2, 5, 3, 7, 1, 0))),
            "period": rng.choice((10, 10, 20, 20, 20, 50, 100, 100, 200, 1000)) * 1_000_000,
            "phase": rng.randrange(10_000_000),
            "counter": rng.random() < 0.6, "checksum": rng.random() < 0.5,
            "random_bytes": rng.randrange(0, 4), "state": bytearray(rng.randbytes(64)),
            "k": 0,
        })
    out: list[Frame] = []
    due = sorted((k["phase"], i) for i, k in enumerate(kinds))
    import heapq
    heapq.heapify(due)
    while len(out) < n:
        t, i = heapq.heappop(due)
        k = kinds[i]
        length = k["length"]
        state = k["state"]
        for j in range(min(length, 64)):  # slowly changing signals
            if rng.random() < 0.05:
                state[j] = (state[j] + rng.choice((-1, 1))) & 0xFF
        data = bytearray(state[:length])
        for j in rng.sample(range(length), min(k["random_bytes"], length)):
            data[j] = rng.randrange(256)
        if length and k["counter"]:
            data[0] = (data[0] & 0xF0) | (k["k"] & 0x0F)
        if length > 1 and k["checksum"]:
            data[-1] = sum(data[:-1]) & 0xFF
        k["k"] += 1
        out.append(Frame(T0_NS + t, k["bus"], k["id"], bytes(data), k["extended"], k["fd"],
                         False, False, k["brs"], k["esi"], length))
        if rng.random() < 0.001:
            out.append(Frame(T0_NS + t + 1000, "can0", k["id"] & 0x7FF, b"", False, False,
                             False, True, False, False, 8))
        if rng.random() < 0.0005:
            out.append(Frame(T0_NS + t + 2000, "can0", 0, b"", False, False, True, False, False,
                             False, 0))
        jitter = rng.randrange(-k["period"] // 20, k["period"] // 20 + 1)
        heapq.heappush(due, (t + k["period"] + jitter, i))
    return out[:n]


def reference_modules(ref: str) -> tuple[types.ModuleType, types.ModuleType]:
    """The wire and monitor modules of git revision ``ref``, with every module of its
    ``bridge/health`` package (the reference monitor counts with the reference's own counters
    and wire module, however the package was split then); each call makes a copy of its own,
    so that no two reference monitors share the wire module's caches."""
    modules = reference_package(ref)
    return modules["wire"], modules["monitor"]


def reference_package(ref: str, also: tuple[str, ...] = ()) -> dict[str, types.ModuleType]:
    """Every module of ``bridge/health`` at git revision ``ref``, by module name, and the modules
    ``also`` (e.g. ``"bridge.world.lateral"``) of ``ref`` that they import; the rest of
    ``bridge`` is the working tree's (:func:`benchlib.package_at`)."""
    return package_at(ref, "bridge.health", own=also)


@dataclass
class Case:
    """One kind of traffic: its frames in chunks (decoded), databases, profile and bitrates."""

    name: str
    chunks: Callable[[], Iterator[tuple[list[Frame], list[Decoded | None]]]]
    decoder: Decoder
    profile: Any
    bitrates: dict[str, int]
    data_bitrates: dict[str, int]


def chunked(frames: Iterator[Frame], decoder: Decoder | None, size: int = 50_000
            ) -> Iterator[tuple[list[Frame], list[Decoded | None]]]:
    while chunk := list(islice(frames, size)):
        yield chunk, ([decoder.decode(f) for f in chunk] if decoder is not None
                      else [None] * len(chunk))


def synthetic_case(n: int) -> Case:
    decoder, profile = load_stages([], "ecocar")
    return Case("synthetic (ecocar profile, decoded)",
                lambda: chunked(ecocar_frames(n), decoder),
                decoder, profile, {bus: 500_000 for bus in ("can0", "can1", "can2")},
                {"can0": 2_000_000})


def candump_case(n: int) -> Case:
    return Case("candump (no profile, undecoded)",
                lambda: chunked(iter(candump_frames(n)), None), Decoder({}), None,
                {"can0": 500_000, "can1": 500_000}, {"can1": 2_000_000})


def feed(monitor: Any, frames: list[Frame], decoded: list[Decoded | None]) -> float:
    """Seconds of the monitor's on_frame over the frames (the collector off, as convert has it)."""
    on_frame = monitor.on_frame
    gc.disable()
    try:
        started = time.perf_counter()
        for frame, d in zip(frames, decoded, strict=True):
            on_frame(frame, d)
        return time.perf_counter() - started
    finally:
        gc.enable()


def bus_seconds(bits: dict[str, list[float]], case: Case) -> dict[str, float]:
    """Bus time of (arbitration, data phase) bits per bus, at the case's bitrates."""
    out = {}
    for bus, (a, d) in bits.items():
        rate, data_rate = case.bitrates[bus], case.data_bitrates.get(bus)
        out[bus] = a / rate + (d / data_rate if data_rate else 0.0)
    return out


def measure(case: Case, repeat: int, ref: str, profile: bool) -> None:
    print(f"\n{case.name}")
    pairs = []
    for _ in range(repeat):
        _, ref_monitor = reference_modules(ref)
        pairs.append([(label, module.HealthMonitor(case.profile, case.decoder,
                                                   bitrates=case.bitrates,
                                                   data_bitrates=case.data_bitrates))
                      for label, module in (("old", ref_monitor), ("new", new_monitor))])
    exact_wire, _ = reference_modules(ref)
    totals = {(i, label): 0.0 for i in range(repeat) for label in ("old", "new")}
    exact: dict[str, list[float]] = {}
    profiler = cProfile.Profile() if profile else None
    prepared = 0.0
    n = 0
    started = time.perf_counter()
    for frames, decoded in case.chunks():
        prepared = time.perf_counter() - started - sum(totals.values())
        n += len(frames)
        for i, pair in enumerate(pairs):
            for label, monitor in pair if i % 2 == 0 else pair[::-1]:  # interleaved
                if profiler is not None and label == "new" and i == 0:
                    profiler.enable()
                totals[i, label] += feed(monitor, frames, decoded)
                if profiler is not None:
                    profiler.disable()
        for f in frames:
            a, d = exact_wire.frame_bits(f)
            bits = exact.setdefault(f.bus, [0.0, 0.0])
            bits[0] += a
            bits[1] += d
    best = {label: min(totals[i, label] for i in range(repeat)) for label in ("old", "new")}
    print(f"  {n} frames (prepared and checked in {prepared:.0f} s)")
    print(f"  old {best['old'] / n * 1e6:.3f} µs/frame   new {best['new'] / n * 1e6:.3f} µs/frame"
          f"   ratio old/new {best['old'] / best['new']:.2f}x   (best of {repeat}, interleaved)")
    want = bus_seconds(exact, case)
    for label, monitor in pairs[0]:
        got = bus_seconds({name: [bus.bits, bus.brs_bits]
                           for name, bus in monitor._buses.items()}, case)
        print(f"  {label}: bus time vs exact: " + ", ".join(
            f"{bus} {(got[bus] - want[bus]) / want[bus]:+.4%}" for bus in sorted(want)))
    if profiler is not None:
        pstats.Stats(profiler).sort_stats("tottime").print_stats(10)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=1_500_000,
                        help="frames of the synthetic drive (1.5M: ~600 s)")
    parser.add_argument("--candump-frames", type=int, default=600_000,
                        help="frames of the candump-like log (600k: ~150 s)")
    parser.add_argument("--repeat", type=int, default=3, help="monitors of each (best counts)")
    parser.add_argument("--ref", default="HEAD", help="git revision of the reference code")
    parser.add_argument("--profile", action="store_true", help="cProfile the new code")
    args = parser.parse_args(argv)
    print(f"HealthMonitor.on_frame: reference {args.ref} (old) vs this checkout (new), "
          "in one run")
    measure(synthetic_case(args.frames), args.repeat, args.ref, args.profile)
    measure(candump_case(args.candump_frames), args.repeat, args.ref, args.profile)
    return 0


if __name__ == "__main__":
    sys.exit(main())
