#!/usr/bin/env python3
"""Benchmark the health monitor's work at each scene tick (a report, not a test).

The simulated ecocar and highway drives (``tankviz simulate``, ``--duration`` seconds, written to
a temporary folder) are converted once with the scene, and every call the convert makes to its
:class:`~bridge.pipeline.perception.Perception` (each decoded message fed, each tick) and to its
:class:`~bridge.health.monitor.HealthMonitor` (each frame, each check, each scene tick's world,
each clock step) is recorded, in order (as ``tools/bench_scene.py`` records the scene's). Then,
in one run, best of ``--repeat`` (default 3), those calls are replayed on a new ``Perception``
and on two new monitors fed the same calls, interleaved (which of the two goes first is drawn
at random at every timed call):

- ``reference``: every module of ``bridge/health`` as it is at git revision ``--ref`` (default
  ``HEAD``), from a worktree of it, beside the working tree's (as ``tools/bench_health.py``
  does), and ``bridge/world/lateral.py`` with them (the lateral sign check the monitor runs at
  each tick); the rest of the world, the scene and of ``bridge`` are the working tree's;
- ``current``: the modules of the working tree.

Timed, per monitor: at each scene tick what the pipeline's health scene does
(``on_world`` with the tick's world and lanes, ``active_alarms``, and the overlay's
``alarm_entities`` + ``fov_entities``), and, apart, the checks (``advance``, ``finish``). The
frames (``on_frame``) and the perception are not timed. It prints µs per scene tick of each,
the ratios reference / current (above 1: the current code is cheaper), and whether every
message of the checks and every entity of the health scene serialise to the same bytes in both.

    python tools/bench_health_tick.py
    python tools/bench_health_tick.py --duration 30 --repeat 5 --ref HEAD~2 --profile
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import hashlib
import pstats
import random
import sys
import tempfile
import time
import types
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench_health import reference_package  # noqa: E402
from benchlib import simulated_logs  # noqa: E402

from bridge.health import monitor as current_monitor  # noqa: E402
from bridge.health import overlay as current_overlay  # noqa: E402
from bridge.pipeline import perception as perception_module  # noqa: E402
from bridge.pipeline.convert import convert  # noqa: E402
from bridge.pipeline.pipeline import Pipeline  # noqa: E402

#: One recorded call: ("feed", message, values, t), ("tick", t) of the perception; ("frame",
#: frame, decoded), ("world", t), ("advance", t), ("finish", t), ("rebase", shift, t) of health.
Call = tuple[Any, ...]
def reference_health(ref: str) -> dict[str, types.ModuleType]:
    """Every module of ``bridge/health`` at git revision ``ref``, with the lateral sign check
    it runs at each tick (``bridge/world/lateral.py``), beside the working tree's
    (``tools/bench_health.py``'s loader), by module name."""
    return reference_package(ref, also=("bridge.world.lateral",))


def record(log: Path, profile: str, folder: Path) -> tuple[list[Call], dict[str, Any]]:
    """Every call a convert of ``log`` with the scene makes to its Perception and its health
    monitor, in order, and the monitor's set-up (profile, decoder, bitrates, settings)."""
    calls: list[Call] = []
    setup: dict[str, Any] = {}
    P, H = perception_module.Perception, current_monitor.HealthMonitor
    originals = {(P, "feed"): P.feed, (P, "tick"): P.tick, (H, "on_frame"): H.on_frame,
                 (H, "on_world"): H.on_world, (H, "advance"): H.advance,
                 (H, "finish"): H.finish, (H, "rebase"): H.rebase}

    def feed(self: Any, message: str, values: Any, t_ns: int) -> None:
        calls.append(("feed", message, dict(values), t_ns))
        originals[P, "feed"](self, message, values, t_ns)

    def tick(self: Any, t_ns: int) -> Any:
        calls.append(("tick", t_ns))
        return originals[P, "tick"](self, t_ns)

    def on_frame(self: Any, frame: Any, decoded: Any) -> None:
        if not setup:
            setup.update(profile=self.profile, decoder=self.decoder, bitrates=self.bitrates,
                         data_bitrates=self.data_bitrates, settings=self.settings)
        calls.append(("frame", frame, decoded))
        originals[H, "on_frame"](self, frame, decoded)

    def on_world(self: Any, t_ns: int, world: Any, lanes: Any = None) -> None:
        calls.append(("world", t_ns))
        originals[H, "on_world"](self, t_ns, world, lanes)

    def advance(self: Any, t_ns: int) -> Any:
        calls.append(("advance", t_ns))
        return originals[H, "advance"](self, t_ns)

    def finish(self: Any, t_ns: int) -> Any:
        calls.append(("finish", t_ns))
        return originals[H, "finish"](self, t_ns)

    def rebase(self: Any, shift_ns: int, t_ns: int) -> None:
        calls.append(("rebase", shift_ns, t_ns))
        originals[H, "rebase"](self, shift_ns, t_ns)

    def frame_by_frame(self: Pipeline, block: Any) -> None:
        # The block engine counts a block's frames at once (not through on_frame, which the
        # reference monitor may lack a block counterpart of): the recording takes the per-frame
        # path, which makes the same drive (tests/test_packed_pipeline.py).
        for frame in block:
            self.process(frame)

    patches = {(P, "feed"): feed, (P, "tick"): tick, (H, "on_frame"): on_frame,
               (H, "on_world"): on_world, (H, "advance"): advance, (H, "finish"): finish,
               (H, "rebase"): rebase, (Pipeline, "process_packed"): frame_by_frame}
    originals[Pipeline, "process_packed"] = Pipeline.process_packed
    for (cls, name), function in patches.items():
        setattr(cls, name, function)
    try:
        convert([log], folder / "out.mcap", [], profile=profile, force=True, read_ahead=False)
    finally:
        for (cls, name), function in originals.items():
            setattr(cls, name, function)
    return calls, setup


class Contender:
    """One monitor and its overlay, with what it spent and a digest of what it made."""

    def __init__(self, monitor_module: types.ModuleType, overlay: types.ModuleType,
                 setup: dict[str, Any]) -> None:
        self.monitor = monitor_module.HealthMonitor(
            setup["profile"], setup["decoder"], bitrates=setup["bitrates"],
            data_bitrates=setup["data_bitrates"], settings=setup["settings"])
        self.overlay = overlay
        self.profile = setup["profile"]
        self.scene_s = 0.0
        self.checks_s = 0.0
        self.digest = hashlib.sha256()

    def scene_tick(self, t_ns: int, perception: Any) -> None:
        """What the pipeline's health scene asks of the monitor at a scene tick (timed)."""
        overlay = self.overlay
        started = time.perf_counter()
        self.monitor.on_world(t_ns, perception.world, perception.lanes)
        alarms = self.monitor.active_alarms()
        entities = (overlay.alarm_entities(alarms, t_ns)
                    + overlay.fov_entities(self.profile, alarms, t_ns))
        self.scene_s += time.perf_counter() - started
        self.digest.update(f"scene {t_ns} {len(entities)}".encode())
        for e in entities:
            self.digest.update(e.SerializeToString())

    def checks(self, name: str, t_ns: int) -> None:
        started = time.perf_counter()
        out = getattr(self.monitor, name)(t_ns)
        self.checks_s += time.perf_counter() - started
        for message in out:
            self.digest.update(f"{message.topic} {message.t_ns}".encode())
            self.digest.update(message.message.SerializeToString())


def replay(calls: list[Call], setup: dict[str, Any], reference: dict[str, types.ModuleType],
           profiler: cProfile.Profile | None = None) -> dict[str, Contender]:
    """The calls replayed on a new Perception and on a reference and a current monitor."""
    perception = perception_module.Perception(setup["profile"])
    contenders = {
        "reference": Contender(reference["monitor"], reference["overlay"], setup),
        "current": Contender(current_monitor, current_overlay, setup)}
    order = list(contenders.values())
    # Who goes first is drawn at every timed call: going first costs more (the perception's tick
    # has just run), and health checks come at every other scene tick, so a strict alternation
    # would always put the same monitor first at the checks.
    coin = random.Random(1)
    gc.collect()
    gc.disable()
    try:
        for call in calls:
            kind = call[0]
            if kind == "frame":
                for c in order:
                    c.monitor.on_frame(call[1], call[2])
            elif kind == "feed":
                perception.feed(call[1], call[2], call[3])
            elif kind == "tick":
                perception.tick(call[1])
            elif kind == "world":
                if coin.random() < 0.5:  # interleaved: who goes first, at random
                    order.reverse()
                for c in order:
                    if profiler is not None and c is contenders["current"]:
                        profiler.enable()
                    c.scene_tick(call[1], perception)
                    if profiler is not None:
                        profiler.disable()
            elif kind in ("advance", "finish"):
                if coin.random() < 0.5:
                    order.reverse()
                for c in order:
                    if profiler is not None and c is contenders["current"]:
                        profiler.enable()
                    c.checks(kind, call[1])
                    if profiler is not None:
                        profiler.disable()
            elif kind == "rebase":
                for c in order:
                    c.monitor.rebase(call[1], call[2])
    finally:
        gc.enable()
    return contenders


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="s of each drive")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--ref", default="HEAD", help="git revision of the reference")
    parser.add_argument("--profile", action="store_true", help="cProfile the current code")
    args = parser.parse_args()
    reference = reference_health(args.ref)
    same = True
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for car, profile_name, log in simulated_logs(folder, args.duration):
            calls, setup = record(log, profile_name, folder)
            ticks = sum(1 for call in calls if call[0] == "world")
            best = {(name, part): float("inf") for name in ("reference", "current")
                    for part in ("scene", "checks")}
            digests: set[str] = set()
            profiler = cProfile.Profile() if args.profile else None
            for i in range(args.repeat):
                got = replay(calls, setup, reference, profiler if i == 0 else None)
                for name, c in got.items():
                    best[name, "scene"] = min(best[name, "scene"], c.scene_s)
                    best[name, "checks"] = min(best[name, "checks"], c.checks_s)
                    digests.add(c.digest.hexdigest())
            agree = len(digests) == 1
            same &= agree
            print(f"{car} ({ticks} scene ticks, best of {args.repeat}, interleaved):")
            for part, words in (("scene", "on_world + active_alarms + overlay"),
                                ("checks", "advance (checks, /health, /log)")):
                ref_s, cur_s = best["reference", part], best["current", part]
                print(f"  {words:38s} reference {ref_s / ticks * 1e6:8.1f} µs/tick   "
                      f"current {cur_s / ticks * 1e6:8.1f} µs/tick   ratio {ref_s / cur_s:.2f}")
            ref_s = best["reference", "scene"] + best["reference", "checks"]
            cur_s = best["current", "scene"] + best["current", "checks"]
            print(f"  {'both':38s} reference {ref_s / ticks * 1e6:8.1f} µs/tick   "
                  f"current {cur_s / ticks * 1e6:8.1f} µs/tick   ratio {ref_s / cur_s:.2f}")
            print(f"  {'same bytes' if agree else 'BYTES DIFFER'} (every /health and /log "
                  "message, every health scene entity)")
            if profiler is not None:
                pstats.Stats(profiler).sort_stats("tottime").print_stats(15)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
