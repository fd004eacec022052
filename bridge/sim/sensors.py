"""What the sensors see: the world at one measurement time, in the ego frame, with coverage.

:meth:`Snapshots.at` takes a family's measurement tick (not the jittered transmit time) and gives
the true values then (the sensors add noise), cached: a pure function of the tick. An actor is
keyed ``(index, visit)``: a wrapping stream's actor is a new object on each visit.
"""

from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass

from bridge.frame import NS
from bridge.sim.world import (
    CAM_NONE,
    CLASS_FOUR_WHEEL,
    CLASS_PEDESTRIAN,
    CLASS_STATIONARY,
    CLASS_TWO_WHEEL,
    CLASS_UNKNOWN,
    Actor,
    Ego,
    Script,
    make_actors,
)

# Sensor coverage: (max range by radar class, half field of view in degrees, minimum x).
_RADAR_RANGE = {CLASS_FOUR_WHEEL: 200.0, CLASS_TWO_WHEEL: 120.0, CLASS_PEDESTRIAN: 100.0,
                CLASS_STATIONARY: 120.0, CLASS_UNKNOWN: 120.0}
_RADAR_FOV = math.radians(60.0)
_CAMERA_RANGE = {CLASS_FOUR_WHEEL: 120.0, CLASS_TWO_WHEEL: 80.0, CLASS_PEDESTRIAN: 80.0}
_CAMERA_FOV = math.radians(50.0)


class Seen:
    """One actor at one instant, in the ego frame (true values, no noise): position, velocity and
    acceleration relative to the ego (central differences, +-50 ms), lateral offset from the ego
    lane, speed and acceleration along the road, range, and coverage:

    - radar: x > 0.5 m, azimuth within +-60 deg, range up to 200 m (four-wheel), 120 m (two-wheel,
      stationary, unknown) or 100 m (pedestrian);
    - camera: reported types only (not ``CAM_NONE``), x > 2 m, azimuth within +-50 deg, range up to
      120 m (four-wheel) or 80 m (two-wheel, pedestrian).
    """

    __slots__ = ("a_abs", "actor", "ax", "camera", "d", "key", "radar", "range", "v_abs", "vx",
                 "vy", "x", "y")

    def __init__(self, key: Hashable, actor: Actor, x: float, y: float, vx: float, vy: float,
                 ax: float, d: float, v_abs: float, a_abs: float) -> None:
        self.key = key
        self.actor = actor
        self.x, self.y, self.vx, self.vy, self.ax = x, y, vx, vy, ax
        self.d, self.v_abs, self.a_abs = d, v_abs, a_abs
        self.range = math.hypot(x, y)
        azimuth = abs(math.atan2(y, x))
        cls = actor.radar_class
        self.radar = x > 0.5 and azimuth <= _RADAR_FOV and self.range <= _RADAR_RANGE[cls]
        self.camera = (actor.camera_type != CAM_NONE and x > 2.0 and azimuth <= _CAMERA_FOV
                       and self.range <= _CAMERA_RANGE.get(cls, 0.0))


@dataclass(frozen=True)
class Snapshot:
    t: float
    ego: Ego
    objects: list[Seen]


class Snapshots:
    """Snapshots of the scenario at measurement times, cached for the families that share them."""

    _H = 0.05  # step of the central differences (s)

    def __init__(self, duration_s: float) -> None:
        self.scenario = Script(duration_s)
        self.actors = make_actors(self.scenario)
        self._cache: dict[int, Snapshot] = {}

    def at(self, tick_ns: int) -> Snapshot:
        snap = self._cache.get(tick_ns)
        if snap is None:
            snap = self._compute(tick_ns / NS)
            if len(self._cache) > 16:
                del self._cache[next(iter(self._cache))]
            self._cache[tick_ns] = snap
        return snap

    def _compute(self, t: float) -> Snapshot:
        sc, h = self.scenario, self._H
        egos = (sc.ego(t - h), sc.ego(t), sc.ego(t + h))
        ego = egos[1]
        seen = []
        for index, actor in enumerate(self.actors):
            points = []
            for e, tt in zip(egos, (t - h, t, t + h), strict=True):
                ds, d = actor.place(tt, e.s)
                points.append((ds, d, e))
            ds0, d0, _ = points[1]
            shift, visit = 0.0, 0
            if actor.loop_m != math.inf:
                visit = math.floor((ds0 + actor.loop_m / 2) / actor.loop_m)
                shift = visit * actor.loop_m
            (x_m, y_m), (x, y), (x_p, y_p) = (sc.to_ego(e, ds - shift, d) for ds, d, e in points)
            vx, vy = (x_p - x_m) / (2 * h), (y_p - y_m) / (2 * h)
            ax = (x_p - 2 * x + x_m) / (h * h)
            seen.append(Seen((index, visit), actor, x, y, vx, vy, ax, d0, ego.v + vx,
                             ego.a + ax))
        return Snapshot(t, ego, seen)
