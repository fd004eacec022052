#!/usr/bin/env python3
"""Benchmark the lanes of a scene tick, old against new, in one run (a report, not a test).

A simulated ecocar drive (:func:`bridge.sim.ecocar.simulate`, ``--seconds`` long, seed 0) is
decoded and observed once with tankviz's own decoder and :class:`~bridge.pipeline.perception.
Perception` (20 Hz scene, the default); at every tick the lane lines and the steering angle of the
world are kept. Then, interleaved and best of ``--repeat`` (default 3), both versions replay those
ticks, each in a world of its own that lives through the drive (as in a convert):
``World.lane_model`` → ``lane_entities`` into a SceneUpdate → ``semantic.lanes``, and once more
with both messages serialized (what a sink does next):

- ``old``: ``bridge/world/model.py``, ``bridge/scene/entities.py`` and ``bridge/scene/semantic.py``
  at git revision ``--ref`` (default ``HEAD``), from a worktree of it, beside the working
  tree's;
- ``new``: the modules of the working tree.

It prints µs per tick of each and the ratio old / new (above 1: the new code is faster); then the
points per drawn line (least, median, most), the largest distance of a drawn line from its cubic
(checked on a 1 cm grid, in the camera's frame), how many lines were made rather than reused,
and the bytes of ``/scene/lanes`` per 600 s of drive (serialized SceneUpdates, and
zstd-compressed in 1 MB pieces like the recorder's chunks).

    python tools/bench_lanes.py                 # 120 s of drive, scaled to 600 s
    python tools/bench_lanes.py --seconds 600 --ref HEAD~2
"""

from __future__ import annotations

import argparse
import gc
import statistics
import sys
import time
import types
from functools import partial
from pathlib import Path
from typing import Any

import zstandard

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bridge.decode.database import load_database  # noqa: E402
from bridge.decode.decoder import Decoder  # noqa: E402
from bridge.pipeline.perception import Perception  # noqa: E402
from bridge.profile.loader import load_profile  # noqa: E402
from bridge.profile.model import Profile  # noqa: E402
from bridge.resources import data_dir  # noqa: E402
from bridge.scene import entities as new_entities  # noqa: E402
from bridge.scene import semantic as new_semantic  # noqa: E402
from bridge.sim.ecocar import simulate  # noqa: E402
from bridge.world import model as new_model  # noqa: E402
from bridge.world.model import polynomial  # noqa: E402

sys.path.insert(0, str(ROOT / "tools"))
from benchlib import best_of, modules_at  # noqa: E402

#: per tick: (time, lane lines of the world, steering wheel angle)
Tick = tuple[int, dict[str, Any], float | None]


def load_old(ref: str) -> tuple[types.ModuleType, types.ModuleType, types.ModuleType]:
    """The world model, scene entities and semantic modules at ``ref``, beside the tree's."""
    names = ("bridge.world.model", "bridge.scene.entities", "bridge.scene.semantic")
    old = modules_at(ref, names)
    return old[names[0]], old[names[1]], old[names[2]]


def drive_ticks(profile: Profile, database: Any, seconds: float) -> list[Tick]:
    """The lane lines and steering angle of the world at each scene tick of a simulated drive."""
    decoder = Decoder({None: [database]})
    perception = Perception(profile)
    world = perception.world
    wanted = perception.messages
    ticks: list[Tick] = []
    for frame in simulate(duration_s=seconds):
        for tick in perception.due_ticks(frame.timestamp_ns):
            perception.update_world(tick)
            ticks.append((tick, dict(world.lanes), world.ego.steering_wheel_angle))
        decoded = decoder.decode(frame)
        if decoded is not None and decoded.codec.message.name in wanted:
            perception.feed(decoded.codec.message.name, decoded.signals, frame.timestamp_ns)
    return ticks


def replay(model: types.ModuleType, entities: types.ModuleType, semantic: types.ModuleType,
           profile: Profile, ticks: list[Tick], *, serialize: bool,
           out: list[bytes] | None = None) -> float:
    """Seconds to make the lanes of every tick in a world of ``model``."""
    world = model.World(profile)
    lane_model, lanes = world.lane_model, semantic.lanes
    # the scene tick's lanes: _lane_wire up to 304ae15, then lane_entities
    lane_entities = getattr(entities, "_lane_wire", entities.lane_entities)
    ego = world.ego
    gc.collect()
    started = time.perf_counter()
    for t, lines, angle in ticks:
        world.lanes = lines
        ego.steering_wheel_angle = angle
        model_now = lane_model(t)
        drawn: list[Any] = []
        lane_entities(drawn, model_now, t)
        update = entities.scene_update(drawn)
        message = lanes(model_now, t)
        if serialize:
            data = update.SerializeToString()
            message.SerializeToString()
            if out is not None:
                out.append(data)
    return time.perf_counter() - started


def compressed(messages: list[bytes]) -> int:
    """Bytes of ``messages`` zstd-compressed (level 3) in pieces of about 1 MB."""
    total, piece = 0, bytearray()
    compressor = zstandard.ZstdCompressor(level=3)
    for data in messages:
        piece += data
        if len(piece) >= 1 << 20:
            total += len(compressor.compress(bytes(piece)))
            piece.clear()
    return total + (len(compressor.compress(bytes(piece))) if piece else 0)


def deviation(profile: Profile, world: Any, ticks: list[Tick]) -> tuple[list[int], float, int]:
    """Points per drawn line, the largest distance of a drawn camera line from its cubic, and
    how many lines were made (the rest were the line of the tick before, reused)."""
    counts: list[int] = []
    made: dict[int, Any] = {}
    worst = 0.0
    spec = profile.lanes
    assert spec is not None and spec.sensor is not None
    mount, sign = spec.sensor.mount, spec.sensor.lateral_sign
    for t, lines, angle in ticks:
        world.lanes, world.ego.steering_wheel_angle = lines, angle
        model = world.lane_model(t)
        for line in model.lines:
            counts.append(len(line.points))
            made[id(line)] = line
            if model.source != "camera" or mount.yaw_deg:
                continue
            c = lines[line.name].coefficients
            xs = [x - mount.x for x, _ in line.points]
            ys = [(y - mount.y) * sign for _, y in line.points]
            for x0, y0, x1, y1 in zip(xs, ys, xs[1:], ys[1:], strict=False):
                steps = max(1, round((x1 - x0) / 0.01))
                for i in range(steps + 1):
                    x = x0 + (x1 - x0) * i / steps
                    drawn = y0 + (y1 - y0) * (x - x0) / (x1 - x0)
                    worst = max(worst, abs(drawn - polynomial(c, x)))
    return counts, worst, len(made)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="simulated drive length")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--ref", default="HEAD", help="git revision of the old code")
    args = parser.parse_args(argv)

    database = load_database(data_dir() / "ecocar.dbc")
    profile = load_profile("ecocar", [database.db])
    old = load_old(args.ref)
    new = (new_model, new_entities, new_semantic)
    started = time.perf_counter()
    ticks = drive_ticks(profile, database, args.seconds)
    print(f"{len(ticks)} ticks of a {args.seconds:g} s simulated drive "
          f"(observed in {time.perf_counter() - started:.1f} s)")

    for serialize in (False, True):
        best = best_of({
            "old": partial(replay, *old, profile, ticks, serialize=serialize),
            "new": partial(replay, *new, profile, ticks, serialize=serialize)}, args.repeat)
        what = "make + serialize" if serialize else "make"
        per_tick = {name: seconds / len(ticks) * 1e6 for name, seconds in best.items()}
        print(f"lanes per tick ({what}): old {per_tick['old']:.1f} µs, new "
              f"{per_tick['new']:.1f} µs, ratio old/new {best['old'] / best['new']:.2f}")

    sizes: dict[str, list[bytes]] = {"old": [], "new": []}
    replay(*old, profile, ticks, serialize=True, out=sizes["old"])
    replay(*new, profile, ticks, serialize=True, out=sizes["new"])
    scale = 600.0 / args.seconds
    for name, messages in sizes.items():
        raw = sum(len(m) for m in messages) * scale / 1e6
        print(f"/scene/lanes per 600 s, {name}: {raw:.1f} MB serialized, "
              f"{compressed(messages) * scale / 1e6:.1f} MB zstd")
    for name, (model, _, _) in (("old", old), ("new", new)):
        counts, worst, made = deviation(profile, model.World(profile), ticks)
        print(f"points per line, {name}: least {min(counts)}, median "
              f"{statistics.median(counts):g}, most {max(counts)}; farthest from the cubic "
              f"{worst * 100:.2f} cm; {made} of {len(counts)} lines made, the rest reused")
    return 0


if __name__ == "__main__":
    sys.exit(main())
