#!/usr/bin/env python3
"""Benchmark the read-ahead's hand-over: frames/s through ReadAhead, new against old (a report).

On ``bridge/sim``'s ecocar drive on three buses (``benchlib.ecocar_log``, cached), as a BLF
and its ASC copy of ``--frames`` frames (default 400,000), it reads every frame through
:class:`bridge.io.readahead.ReadAhead` (a forked child reads the log with python-can and hands
the frames over) and times, interleaved, best of ``--runs`` (default 3):

- ``old frames``: the module as ``--ref`` has it (default ``HEAD``, from a worktree of it, beside
  the working tree's): iterating its frames (pickled tuples made into frames here);
- ``new frames``: this checkout's module, iterating its frames (made here from the packs);
- ``new packs``: this checkout's module, iterating :meth:`ReadAhead.packs` (no frame made here:
  what the pack engine reads).

It does the same for the hand-over alone (``memory``): the BLF's frames read once, before the
clock starts, into a list the forked child iterates (a source that costs nothing to read), so
that only packing, the pipe and unpacking are timed.

And it times the child's work alone, in this process (``child old`` / ``child new``: the
module's reading function with a pipe that discards what it is sent): reading, merging and
packing, without the fork, the pipe or the other process.

For each it prints frames/s in wall time (what a user waits: the child reads while this process
takes the frames) and the CPU time of this process and of the child (user + system), and the
ratios old / new (above 1: new is faster). The child's CPU is python-can's reading plus the
packing; this process's is the hand-over's other half.

With ``--groups`` it also times grouping a pack's rows by (bus, key), PackedFrames.groups (a dict
of ``array('I')``) against a numpy ``argsort`` split (when numpy is installed), on packs of
4,096 and 16,384 frames of the same drive: the measurement behind bridge/packed.py's choice of
the standard library.

    python tools/bench_readahead.py
    python tools/bench_readahead.py --frames 100000 --runs 5 --groups
    python tools/bench_readahead.py --input memory --runs 7
"""

from __future__ import annotations

import argparse
import gc
import resource
import signal
import sys
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from types import ModuleType
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchlib import (
    add_workdir,
    best_of,
    cpu_seconds,
    ecocar_frames,
    ecocar_log,
    interleaved,
    log_copy,
    modules_at,
)

from bridge.frame import Frame
from bridge.io import readahead as new_module
from bridge.io.can_logs import LogSource, SourceIssue
from bridge.packed import PackedFrames

ROOT = Path(__file__).resolve().parents[1]


def old_module(ref: str) -> ModuleType:
    """bridge/io/readahead.py as ``ref`` has it."""
    return modules_at(ref, ["bridge.io.readahead"])["bridge.io.readahead"]


class MemorySource:
    """Frames read before the clock starts: what the child reads costs nothing."""

    def __init__(self, frames: list[Frame]) -> None:
        self.frames_read = frames
        self.issues: list[SourceIssue] = []
        self.frames = self.backwards = 0
        self.size = 1 << 30  # read ahead whatever its size

    def progress(self) -> tuple[int, int]:
        return self.frames, self.size

    def __iter__(self) -> Iterator[Frame]:
        for frame in self.frames_read:
            self.frames += 1
            yield frame


def source(path: Path | list[Frame]) -> LogSource | MemorySource:
    return MemorySource(path) if isinstance(path, list) else LogSource(path)


def count_frames(module: ModuleType, path: Path | list[Frame]) -> int:
    reading = module.ReadAhead([source(path)])
    assert reading.ahead, "the log is read ahead (a process without threads, a large log)"
    n = 0
    for _ in reading:
        n += 1
    return n


def count_blocks(module: ModuleType, path: Path | list[Frame]) -> int:
    reading = module.ReadAhead([source(path)])
    assert reading.ahead
    n = 0
    for pack in reading.packs():
        n += len(pack)
    return n


def _cpu(who: int) -> float:
    """User + system seconds of this process or of its ended children (µs resolution)."""
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


class _Discard:
    """A pipe end that takes what it is sent and drops it."""

    def send_bytes(self, data: bytes) -> None:
        pass

    def close(self) -> None:
        pass


def child_alone(module: ModuleType, path: Path | list[Frame]) -> int:
    """The module's child function, run here on a discarding pipe; its frame count."""
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, set())
    reading = source(path)
    try:
        module._read([reading], _Discard(), _Discard())
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    return reading.frames


class Timing:
    """Best wall, this process's CPU and the children's CPU seconds of a contender."""

    def __init__(self) -> None:
        self.wall = self.cpu = self.child = float("inf")

    def run(self, work: Callable[[], int]) -> int:
        gc.collect()
        gc.disable()  # as tankviz convert runs
        here, children = _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
        started = time.perf_counter()
        n = work()
        wall = time.perf_counter() - started
        self.wall = min(self.wall, wall)
        self.cpu = min(self.cpu, _cpu(resource.RUSAGE_SELF) - here)
        self.child = min(self.child, _cpu(resource.RUSAGE_CHILDREN) - children)
        gc.enable()
        return n


def hand_over(args: argparse.Namespace) -> None:
    old = old_module(args.ref)
    blf, _ = ecocar_log(args.workdir, args.frames, args.seed)
    asc = log_copy(blf, ".asc")
    print(f"read-ahead hand-over: {args.frames} simulated frames, old = {args.ref}'s "
          f"readahead.py, best of {args.runs}, interleaved (BATCH {new_module.BATCH})")
    inputs: dict[str, Path | list[Frame]] = {"memory": list(LogSource(blf)), "BLF": blf,
                                             "ASC": asc}
    for fmt in args.input or list(inputs):
        path = inputs[fmt]
        contenders: dict[str, tuple[Timing, Callable[[], int]]] = {
            "old frames": (Timing(), partial(count_frames, old, path)),
            "new frames": (Timing(), partial(count_frames, new_module, path)),
            "new packs": (Timing(), partial(count_blocks, new_module, path)),
            "child old": (Timing(), partial(child_alone, old, path)),
            "child new": (Timing(), partial(child_alone, new_module, path)),
        }
        runs = interleaved({name: partial(timing.run, work)
                            for name, (timing, work) in contenders.items()}, args.runs)
        counts = {n for done in runs.values() for n in done}
        assert len(counts) == 1, f"the contenders read different frame counts: {counts}"
        n = counts.pop()
        size = f"{path.stat().st_size / 1e6:.1f} MB, " if isinstance(path, Path) else ""
        print(f"{fmt} ({size}{n} frames):")
        base = contenders["old frames"][0]
        for name, (t, _) in contenders.items():
            if name.startswith("child"):
                alone = contenders["child old"][0].cpu
                print(f"  {name:10}  {t.cpu / n * 1e6:5.2f} µs/frame (its work alone, here)"
                      f"   old/new {alone / t.cpu:4.2f}x")
                continue
            print(f"  {name:10}  {n / t.wall / 1e3:7.1f} kframes/s wall   "
                  f"here {t.cpu / n * 1e6:5.2f} µs/frame   child {t.child / n * 1e6:5.2f} µs/frame"
                  f"   old/new: wall {base.wall / t.wall:4.2f}x  here {base.cpu / t.cpu:4.2f}x  "
                  f"child {base.child / t.child:4.2f}x")


def groups(args: argparse.Namespace) -> None:
    np: Any
    try:
        import numpy as np
    except ImportError:  # not a dependency of tankviz
        np = None
    frames = list(ecocar_frames(20_000, args.seed))

    def numpy_groups(pack: PackedFrames) -> dict[tuple[int, int], Any]:
        from array import array

        assert np is not None
        combined = (np.frombuffer(pack.key, dtype=np.uint32).astype(np.uint64)
                    | (np.frombuffer(pack.bus, dtype=np.uint8).astype(np.uint64)
                       << np.uint64(32)))
        order = np.argsort(combined, kind="stable")
        ordered = combined[order]
        cuts = np.flatnonzero(ordered[1:] != ordered[:-1]) + 1
        out = {}
        for rows in np.split(order.astype(np.uint32), cuts):
            k = int(combined[rows[0]])
            out[(k >> 32, k & 0xFFFFFFFF)] = array("I", rows.tobytes())
        return dict(sorted(out.items(), key=lambda kv: kv[1][0]))  # in first-row order

    print("grouping a pack's rows by (bus, key), best of 20:")
    for size in (4096, 16384):
        pack = PackedFrames.from_frames(frames[:size])
        ways: dict[str, Callable[[], Any]] = {"PackedFrames.groups": pack.groups}
        if np is not None:
            assert {k: list(v) for k, v in numpy_groups(pack).items()} == \
                {k: list(v) for k, v in pack.groups().items()}
            ways["numpy argsort"] = partial(numpy_groups, pack)
        best = best_of({name: cpu_seconds(way) for name, way in ways.items()}, 20)
        print(f"  packs of {size}: " + "   ".join(
            f"{name} {seconds / size * 1e9:.0f} ns/frame" for name, seconds in best.items()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=400_000)
    parser.add_argument("--runs", type=int, default=3, help="interleaved rounds, best of (3)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--ref", default="HEAD", help="the git revision of the old module")
    parser.add_argument("--input", action="append", choices=("memory", "BLF", "ASC"),
                        help="only these inputs (default: all three)")
    parser.add_argument("--groups", action="store_true",
                        help="also time grouping rows by (bus, key), stdlib against numpy")
    add_workdir(parser, "where bench_convert's logs are cached")
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    hand_over(args)
    if args.groups:
        groups(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
