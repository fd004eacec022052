#!/usr/bin/env python3
"""Benchmark the scene tick: :meth:`bridge.pipeline.perception.Perception.tick` on the simulated
drives (a report, not a test).

The simulated ecocar and highway drives (``tankviz simulate``, ``--duration`` seconds, written
to a temporary folder) are converted once with the scene, and every call the convert makes to
its :class:`Perception` (each decoded message fed, each tick) is recorded. Then, in one run,
interleaved and best of ``--repeat`` (default 3), those calls are replayed on a new
``Perception`` of the drive's profile, timing the ticks only, twice:

- ``reference``: ``bridge/pipeline/perception.py`` and every module of ``bridge/scene`` and
  ``bridge/world`` as they are at git revision ``--ref`` (default ``HEAD``), from a worktree of
  it, beside the working tree's (the rest of ``bridge`` is the working tree's);
- ``current``: the modules of the working tree.

It prints ms per tick of each (``--clock wall``, the default, or ``cpu``: the process's CPU
time, which other work on a shared machine disturbs less), their ratio reference / current
(above 1: the current code is faster), and whether every message of every tick serialises to
the same bytes in both.

    python tools/bench_scene.py
    python tools/bench_scene.py --duration 30 --repeat 5 --ref HEAD~2 --clock cpu
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import sys
import tempfile
import time
import types
from collections.abc import Mapping
from functools import partial
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bridge.pipeline import perception as current  # noqa: E402
from bridge.pipeline.convert import convert  # noqa: E402
from bridge.pipeline.drive import load_stages  # noqa: E402
from bridge.profile.model import Profile  # noqa: E402

sys.path.insert(0, str(ROOT / "tools"))
from benchlib import interleaved, modules_at, simulated_logs  # noqa: E402

#: One recorded call: ("feed", message, values, time) or ("tick", time).
Call = tuple[Any, ...]
def reference_perception(ref: str) -> types.ModuleType:
    """``bridge/pipeline/perception.py`` of git revision ``ref``, with every module of its
    ``bridge/scene`` and ``bridge/world`` packages (:func:`benchlib.modules_at`)."""
    name = "bridge.pipeline.perception"
    return modules_at(ref, [name], own=("bridge.scene", "bridge.world"))[name]


def record(log: Path, profile: str, folder: Path) -> list[Call]:
    """Every call a convert of ``log`` with the scene makes to its Perception."""
    calls: list[Call] = []
    feed, tick = current.Perception.feed, current.Perception.tick

    def recording_feed(self: current.Perception, message: str, values: Mapping[str, Any],
                       t_ns: int) -> None:
        calls.append(("feed", message, dict(values), t_ns))
        feed(self, message, values, t_ns)

    def recording_tick(self: current.Perception, t_ns: int) -> list[Any]:
        calls.append(("tick", t_ns))
        return tick(self, t_ns)

    current.Perception.feed = recording_feed  # type: ignore[method-assign]
    current.Perception.tick = recording_tick  # type: ignore[method-assign]
    try:
        convert([log], folder / "out.mcap", [], profile=profile, force=True, read_ahead=False)
    finally:
        current.Perception.feed = feed  # type: ignore[method-assign]
        current.Perception.tick = tick  # type: ignore[method-assign]
    return calls


def replay(module: types.ModuleType, profile: Profile, calls: list[Call],
           clock: Any = time.perf_counter) -> tuple[float, str]:
    """Seconds spent in the ticks of ``calls`` on a new Perception of ``module`` (by
    ``clock``), and a digest of every message they made (topic, time, serialised bytes)."""
    perception = module.Perception(profile)
    digest = hashlib.sha256()
    spent = 0.0
    gc.collect()
    for call in calls:
        if call[0] == "feed":
            perception.feed(call[1], call[2], call[3])
            continue
        start = clock()
        out = perception.tick(call[1])
        spent += clock() - start
        for message in out:
            digest.update(f"{message.topic} {message.t_ns}".encode())
            digest.update(message.message.SerializeToString())
    return spent, digest.hexdigest()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="s of each drive")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--ref", default="HEAD", help="git revision of the reference")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="time the ticks by the wall clock or by this process's CPU time "
                             "(which a loaded shared machine disturbs less)")
    args = parser.parse_args()
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    reference = reference_perception(args.ref)
    same = True
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for car, profile_name, log in simulated_logs(folder, args.duration):
            calls = record(log, profile_name, folder)
            profile = load_stages([], profile_name).profile
            assert profile is not None
            ticks = sum(1 for call in calls if call[0] == "tick")
            runs = interleaved({name: partial(replay, module, profile, calls, clock)
                                for name, module in (("reference", reference),
                                                     ("current", current))}, args.repeat)
            best = {name: min(spent for spent, _ in done) for name, done in runs.items()}
            agree = runs["reference"][-1][1] == runs["current"][-1][1]
            same &= agree
            print(f"{car:8s} {ticks} ticks: reference {best['reference'] / ticks * 1e3:.3f} "
                  f"ms/tick, current {best['current'] / ticks * 1e3:.3f} ms/tick, ratio "
                  f"{best['reference'] / best['current']:.2f}; "
                  f"{'same bytes' if agree else 'BYTES DIFFER'}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
