#!/usr/bin/env python3
"""Benchmark the reading process: LogSource's own work on top of python-can's reader (a report).

On ``bridge/sim``'s ecocar drive on three buses (``benchlib.ecocar_log``, cached), as a BLF of
``--frames`` frames (default 200,000) and its ASC and candump (``.log``) copies, it times,
interleaved, best of ``--runs`` (default 5), in CPU seconds with the garbage collector off:

- ``python-can``: python-can's bare reader iterated (``can.BLFReader(path)``, ``can.ASCReader``,
  ``can.CanutilsLogReader``): the yardstick;
- ``LogSource``: :class:`bridge.io.can_logs.LogSource` iterated to its frames (the damage-safe
  reading and the frame conversion on top of the same reader);
- ``+ packing``: the same, the frames packed into :class:`bridge.packed.PackedFrames` packs of
  the read-ahead's ``BATCH`` frames, as the read-ahead's child does;
- with ``--ref REV``, ``LogSource REV``: ``bridge/io`` as REV has it (``logs.py`` before it was
  named ``can_logs.py``), beside the tree's.

It prints, per format, each contender's µs/frame and issue #36's figure, the overhead
``(LogSource - python-can) / python-can`` (goal ≤ 0.3 on BLF), and that of packing.

    python tools/bench_reading.py
    python tools/bench_reading.py --frames 50000 --runs 3 --format blf --ref main
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from collections.abc import Callable
from functools import partial
from itertools import islice
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import can
from benchlib import add_workdir, ecocar_log, interleaved, log_copy, modules_at, worktree

from bridge.io.can_logs import LogSource
from bridge.io.readahead import BATCH
from bridge.packed import packs

#: The goal of issue #36: LogSource's own CPU at most this share of python-can's reader's.
GOAL = 0.3


def logs(workdir: Path, frames: int, seed: int = 1) -> dict[str, Path]:
    """The ecocar drive of ``frames`` frames as BLF, ASC and candump, by format (cached)."""
    blf, _ = ecocar_log(workdir, frames, seed)
    return {"blf": blf, "asc": log_copy(blf, ".asc"), "log": log_copy(blf, ".log")}


def bare(path: Path) -> int:
    """python-can's own reader of ``path``, iterated."""
    suffix = path.suffix
    reader: Any = (can.BLFReader(str(path)) if suffix == ".blf" else
                   can.ASCReader(str(path), relative_timestamp=False) if suffix == ".asc" else
                   can.CanutilsLogReader(str(path)))
    n = 0
    for _ in reader:
        n += 1
    reader.stop()
    return n


def source(source_type: type[LogSource], path: Path) -> int:
    n = 0
    for _ in source_type(path):
        n += 1
    return n


def packed(path: Path) -> int:
    """LogSource's frames packed as the read-ahead's child packs them."""
    n = 0
    frames = iter(LogSource(path))
    while batch := list(islice(frames, BATCH)):
        for pack in packs(batch):
            n += len(pack)
    return n


def cpu(work: Callable[[], int]) -> Callable[[], tuple[float, int]]:
    def timed() -> tuple[float, int]:
        gc.collect()
        gc.disable()  # as tankviz convert runs
        try:
            started = time.process_time()
            n = work()
            return time.process_time() - started, n
        finally:
            gc.enable()
    return timed


def log_source_at(rev: str) -> type[LogSource]:
    """LogSource as git revision ``rev`` has it (``bridge/io/can_logs.py``, ``bridge/io/logs.py``
    before it was named so), its ``bridge.io`` beside the tree's (``benchlib.modules_at``)."""
    name = ("bridge.io.can_logs" if (worktree(rev) / "bridge" / "io" / "can_logs.py").is_file()
            else "bridge.io.logs")
    found: type[LogSource] = modules_at(rev, [name], own=["bridge.io"])[name].LogSource
    return found


def measure(path: Path, runs: int, old: type[LogSource] | None = None,
            old_name: str = "LogSource before", *, packing: bool = True
            ) -> tuple[dict[str, float], int]:
    """Each contender's best CPU seconds reading ``path`` (``python-can``, ``LogSource``,
    ``+ packing`` unless not ``packing``, and ``old`` as ``old_name``), interleaved, best of
    ``runs``, and the frames each read (the same for all, else AssertionError)."""
    contenders: dict[str, Callable[[], tuple[float, int]]] = {
        "python-can": cpu(partial(bare, path)),
        "LogSource": cpu(partial(source, LogSource, path)),
    }
    if packing:
        contenders["+ packing"] = cpu(partial(packed, path))
    if old is not None:
        contenders[old_name] = cpu(partial(source, old, path))
    done = interleaved(contenders, runs)
    counts = {n for results in done.values() for _, n in results}
    assert len(counts) == 1, f"the contenders read different frame counts: {counts}"
    return {name: min(s for s, _ in results) for name, results in done.items()}, counts.pop()


def overhead(best: dict[str, float], name: str = "LogSource") -> float:
    """Issue #36's figure: ``name``'s own CPU over python-can's, ``(name - python-can) /
    python-can``, from :func:`measure`'s best seconds."""
    return (best[name] - best["python-can"]) / best["python-can"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200_000)
    parser.add_argument("--runs", type=int, default=5, help="interleaved rounds, best of (5)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--format", action="append", choices=("blf", "asc", "log"),
                        help="only these formats (default: all three)")
    parser.add_argument("--ref", help="also time LogSource as this git revision has it")
    add_workdir(parser, "where the logs are cached")
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    paths = logs(args.workdir, args.frames, args.seed)
    old: type[LogSource] | None = log_source_at(args.ref) if args.ref else None
    print(f"reading {args.frames} simulated frames, CPU, best of {args.runs}, interleaved "
          f"(goal: LogSource's own work ≤ {GOAL}x python-can's)")
    for fmt in args.format or list(paths):
        path = paths[fmt]
        best, n = measure(path, args.runs, old, f"LogSource {args.ref}")
        base = best["python-can"]
        print(f"{fmt} ({path.stat().st_size / 1e6:.1f} MB, {n} frames):")
        for name, seconds in best.items():
            extra = ""
            if name.startswith("LogSource"):
                extra = f"   overhead {(seconds - base) / base:5.2f}x"
            elif name == "+ packing":
                extra = f"   packing {(seconds - best['LogSource']) / base:5.2f}x"
            print(f"  {name:18} {seconds:6.3f} s  {seconds / n * 1e6:5.2f} µs/frame{extra}")
        share = overhead(best)
        print(f"  overhead of LogSource ({fmt}): {share:.2f}x   goal ≤ {GOAL}x  "
              f"{'ok' if share <= GOAL else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
