#!/usr/bin/env python3
"""Benchmark the world part of a scene tick: observing decoded messages into the world (a report,
not a test).

``bridge/sim``'s ecocar drive on three buses (``benchlib.ecocar_frames``: rolling counters and
checksums, traffic coming and going) is decoded once with tankviz's
decoder. Then, in one run, interleaved and best of ``--repeat`` (default 3), it times the world
part of :class:`bridge.pipeline.perception.Perception` over those decoded messages with a scene
tick every 50 ms (20 Hz): :meth:`~Perception.feed` per message, and at each tick the observing of
what came since the last one and the expiry of stale objects (:meth:`~Perception.update_world`
without the lane model, which is not this part's work). It does so twice:

- ``reference``: ``bridge/world/observe.py`` and ``bridge/pipeline/perception.py`` as they are at
  git revision ``--ref`` (default ``HEAD``), from a worktree of it, beside the working tree's
  (with the working tree's ``world/model.py`` over the reference's observations);
- ``current``: the modules of the working tree.

It prints µs per frame of the drive for each, the ratio reference / current (above 1: the current
code is faster), and how many observations each made; then checks that both worlds agree at every
tick (the same objects, lane lines and ego state), and prints a cProfile of the current code's
part: the share of ``observe_latest``.

    python tools/bench_world.py                    # 300k frames
    python tools/bench_world.py --frames 100000 --ref HEAD~3

``--convert`` also times a whole ``tankviz convert`` with the scene of a cached synthetic BLF of
``--frames`` frames (``benchlib.ecocar_log``): the working tree against the working tree with the
reference's observe.py and perception.py, a subprocess per run, interleaved, best of
``--repeat``; and prints µs/frame of each, their ratio, and the share of ``observe_latest`` in
each under cProfile.
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import os
import pstats
import subprocess
import sys
import time
import types
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT))

from benchlib import (  # noqa: E402
    ECOCAR_DBC,
    WORKDIR,
    best_of,
    ecocar_frames,
    ecocar_log,
    interleaved,
    modules_at,
    worktree,
)

from bridge.decode.database import load_database  # noqa: E402
from bridge.decode.decoder import Decoder  # noqa: E402
from bridge.frame import NS  # noqa: E402
from bridge.pipeline import perception as current_perception  # noqa: E402
from bridge.profile.loader import load_profile  # noqa: E402
from bridge.profile.model import Profile  # noqa: E402

Message = tuple[str, Any, int]


#: The modules the reference takes from ``--ref``, and the tree's that import them.
REFERENCE = ("bridge.world.observe", "bridge.pipeline.perception")
OVER_REFERENCE = ("bridge.world.model",)


def load_reference(ref: str) -> types.ModuleType:
    """``bridge/pipeline/perception.py`` at git revision ``ref``, importing ``observe.py`` of the
    same revision and the working tree's ``world/model.py`` (over the reference's observations:
    the world is not this part's work)."""
    name = "bridge.pipeline.perception"
    return modules_at(ref, [name], own=REFERENCE, fresh=OVER_REFERENCE)[name]


def decoded_drive(frames: int, seed: int, profile: Profile) -> list[Message]:
    """The first ``frames`` frames of the synthetic drive, decoded: (message, values, time) of
    each message the profile reads, in order."""
    decoder = Decoder({None: [load_database(ECOCAR_DBC)]})
    wanted = current_perception.Perception(profile).messages
    out: list[Message] = []
    for frame in ecocar_frames(frames, seed):
        decoded = decoder.decode(frame)
        if decoded is not None and decoded.codec.message.name in wanted:
            out.append((decoded.codec.message.name, decoded.signals, frame.timestamp_ns))
    return out


def run_world(module: types.ModuleType, profile: Profile, drive: list[Message],
              snapshots: list[Any] | None = None) -> tuple[float, int]:
    """Seconds the world part of ``module``'s Perception takes over ``drive``, and the number of
    observations it applied."""
    perception = module.Perception(profile, scene_rate=20.0)
    world = perception.world
    applied = 0
    apply = world.apply

    def counting(observation: Any) -> None:
        nonlocal applied
        applied += 1
        apply(observation)

    world.apply = counting
    if hasattr(world, "apply_all"):  # it applies an object's observation itself, others by apply
        apply_all = world.apply_all
        inline = sys.modules[type(world).__module__].ObjectObservation

        def counting_all(observations: Any) -> None:
            nonlocal applied
            observations = list(observations)
            applied += sum(1 for o in observations
                           if o.__class__ is inline and not o.rule_error)
            apply_all(observations)

        world.apply_all = counting_all
    due, feed = perception.due_ticks, perception.feed
    gc.collect()
    started = time.perf_counter()
    for message, values, t in drive:
        for tick in due(t):
            perception.observe_pending()
            world.expire(tick)
            if snapshots is not None:
                snapshots.append(snapshot(world))
        feed(message, values, t)
    return time.perf_counter() - started, applied


def snapshot(world: Any) -> Any:
    return ({g: {i: (o.t_ns, o.x, o.y, o.vx, o.vy, o.probability, o.object_class, o.valid)
                 for i, o in objects.items()} for g, objects in world.objects.items()},
            {n: (o.t_ns, o.coefficients) for n, o in world.lanes.items()},
            (world.ego.t_ns, world.ego.speed, world.ego.yaw_rate,
             world.ego.steering_wheel_angle))


def profile_share(run: Callable[[], object], names: tuple[str, ...]) -> dict[str, float]:
    """The cumulative share of each function in ``names`` in ``run``, under cProfile."""
    profiler = cProfile.Profile()
    profiler.enable()
    run()
    profiler.disable()
    stats = pstats.Stats(profiler, stream=io.StringIO())
    total = stats.total_tt  # type: ignore[attr-defined]
    shares: dict[str, float] = {}
    for (_, _, function), (_, _, _, cumulative, _) in stats.stats.items():  # type: ignore
        if function in names:
            shares[function] = shares.get(function, 0.0) + cumulative / total
    return shares


_CONVERT = f"""
import cProfile, pstats, sys, time
from pathlib import Path
if sys.argv[1] != "-":  # the reference: REFERENCE from that worktree, OVER_REFERENCE afresh
    import benchlib
    benchlib.take_modules(Path(sys.argv[1]), {REFERENCE!r}, {OVER_REFERENCE!r})
from bridge.cli import main
args = sys.argv[3:]
if sys.argv[2] == "profile":
    profiler = cProfile.Profile()
    profiler.enable()
    main(args)
    profiler.disable()
    stats = pstats.Stats(profiler)
    share = sum(cum for (_, _, name), (_, _, _, cum, _) in stats.stats.items()
                if name == "observe_latest") / stats.total_tt
    print(share)
else:
    started = time.perf_counter()
    main(args)
    print(time.perf_counter() - started)
"""
#: The subprocess's PYTHONPATH: the working tree and tools/ (benchlib).
PATH = (str(ROOT), str(ROOT / "tools"))


def convert_figures(frames: int, seed: int, ref: str, repeat: int) -> None:
    """A whole ``tankviz convert`` with the scene of a cached synthetic BLF, in a subprocess
    per run (import time excluded): the working tree against the same tree with observe.py and
    perception.py of ``ref``, interleaved, best of ``repeat``; then each under cProfile, for the
    share of ``observe_latest``."""
    workdir = WORKDIR
    workdir.mkdir(exist_ok=True)
    path, _ = ecocar_log(workdir, frames, seed)
    trees = {"reference": str(worktree(ref)), "current": "-"}

    def run(tree: str, mode: str) -> float:
        output = workdir / f"bench_world_{mode}.mcap"
        args = ["convert", str(path), "-o", str(output), "--profile", "ecocar", "--force",
                "--quiet"]
        done = subprocess.run([sys.executable, "-c", _CONVERT, tree, mode, *args],
                              check=True, capture_output=True, text=True, cwd=ROOT,
                              env=os.environ | {"PYTHONPATH": os.pathsep.join(PATH)})
        return float(done.stdout.strip().splitlines()[-1])

    best = best_of({name: partial(run, tree, "time") for name, tree in trees.items()}, repeat)
    for name, seconds in best.items():
        share = run(trees[name], "profile")
        print(f"convert with the scene, {name}: {seconds / frames * 1e6:.2f} µs/frame; "
              f"observe_latest {share:.1%} of it under cProfile")
    print(f"convert ratio reference / current: {best['reference'] / best['current']:.3f} "
          f"(best of {repeat}, interleaved)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=300_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--ref", default="HEAD", help="git revision of the reference modules")
    parser.add_argument("--convert", action="store_true",
                        help="also profile a whole convert with the scene")
    args = parser.parse_args(argv)

    profile = load_profile("ecocar", [load_database(ECOCAR_DBC).db])
    reference = load_reference(args.ref)
    drive = decoded_drive(args.frames, args.seed, profile)
    seconds = (drive[-1][2] - drive[0][2]) / NS
    print(f"synthetic drive: {args.frames} frames, {len(drive)} messages the profile reads, "
          f"{seconds:.1f} s of driving, scene at 20 Hz")

    old, new = [], []  # type: ignore[var-annotated]
    run_world(reference, profile, drive, old)
    run_world(current_perception, profile, drive, new)
    agree = old == new
    print(f"worlds at every tick ({len(new)} ticks): {'the same' if agree else 'DIFFERENT'}")

    runs = interleaved({
        "reference": lambda: run_world(reference, profile, drive),
        "current": lambda: run_world(current_perception, profile, drive),
    }, args.repeat)
    best = {name: min(done) for name, done in runs.items()}
    for name, (t, applied) in best.items():
        print(f"{name:>9} ({args.ref if name == 'reference' else 'working tree'}): "
              f"{t / args.frames * 1e6:.3f} µs/frame, {applied} observations applied")
    ratio = best["reference"][0] / best["current"][0]
    print(f"ratio reference / current: {ratio:.2f} times (best of {args.repeat}, interleaved)")

    shares = profile_share(lambda: run_world(current_perception, profile, drive),
                                  ("observe_latest", "observe_pending", "feed", "expire"))
    for name, share in sorted(shares.items()):
        print(f"  current, cProfile: {name} {share:.1%} of the world part")
    if args.convert:
        convert_figures(args.frames, args.seed, args.ref, args.repeat)
    return 0 if agree else 1


if __name__ == "__main__":
    sys.exit(main())
