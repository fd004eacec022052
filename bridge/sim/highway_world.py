"""The highway car's world and its ground truth, as pure functions of time (seconds since the start
of the run; the seed never enters here: :mod:`bridge.sim.highway` adds noise and jitter).

Every function takes the ``highway`` to describe (:data:`ROADS`, default :data:`HIGHWAY`); positions
are in the vehicle frame (x forward, y left, origin on the rear axle), what the radar reports at a
time is what its cycle measured at ``floor(t / 0.05) * 0.05``.
"""

from __future__ import annotations

import bisect
import functools
import itertools
import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field

#: Lane width (m); lateral offsets of the lane centres from the ego lane's, left positive.
LANE_WIDTH_M = 3.6
LEFT_LANE = LANE_WIDTH_M
RIGHT_LANE = -LANE_WIDTH_M
#: The car (a 2017 compact SUV): wheelbase, steering ratio, track width (m), and where the radar
#: is: at the front bumper, this far ahead of the rear axle (the vehicle frame's origin).
WHEELBASE_M = 2.66
STEERING_RATIO = 15.4
TRACK_WIDTH_M = 1.6
RADAR_X_M = 3.6
#: The radar: one cycle of every slot each 50 ms, 16 slots.
RADAR_CYCLE_S = 0.05
SLOT_COUNT = 16


@dataclass(frozen=True)
class Curve:
    """One curve of the road: the ego's rear axle enters its transition (curvature rising
    linearly over ``transition_s`` of driving) at ``begin_s`` and leaves the transition out of it
    at ``end_s``; radius ``radius_m`` in between, positive to the left, negative to the right."""

    begin_s: float
    end_s: float
    radius_m: float
    transition_s: float = 2.0


@dataclass(frozen=True)
class Highway:
    """The scenario's numbers (seconds since the start of the run, metres, m/s).

    The world is made from :data:`HIGHWAY`'s speed, curve, cut-in window and radar coverage; the
    slots, gaps and the time left_far leaves follow from it (the tests check that they do). The one
    thing that may differ is the road's curves (``bends``: :data:`ROADS`); a ``Highway`` made with
    other numbers describes nothing.

    Geometry: three lanes of :data:`LANE_WIDTH_M`, offsets ``d`` from the middle lane's centre, left
    positive. The ego's rear axle follows its lane centre (a few cm of wander, and the weaving
    road's lane changes); its steering wheel angle is ``STEERING_RATIO * atan(WHEELBASE_M *
    curvature)``. A road user's position is the middle of its rear, ``gap`` m along the road ahead
    of the radar (:data:`RADAR_X_M` ahead of the rear axle) and ``d`` aside; relative velocities and
    accelerations are central differences (+-50 ms) in the turning vehicle frame. Radar coverage:
    radar x above 1 m, range up to ``radar_range_m``, azimuth within +-``radar_fov_deg``.
    """

    #: the ego's mean speed; it varies by +-0.25 m/s over 14 s
    ego_speed_mps: float = 30.0
    #: the left-hand curve: the ego's rear axle enters its transition (curvature rising linearly
    #: over curve_transition_s of driving) at curve_begin_s and leaves the transition out of it
    #: at curve_end_s; radius curve_radius_m in between
    curve_begin_s: float = 20.0
    curve_end_s: float = 40.0
    curve_transition_s: float = 2.0
    curve_radius_m: float = 800.0
    #: the road's curves, in time order, not overlapping; None: the one left-hand curve above
    bends: tuple[Curve, ...] | None = None
    #: the ego's lane changes, (begin_s, duration_s, offset_m) each, offset left positive: its
    #: lateral acceleration one sine period (none in the scenario itself)
    ego_lane_changes: tuple[tuple[float, float, float], ...] = ()
    #: the cut-in: the car in the right lane changes into the ego lane over these seconds
    #: (its centre crosses the lane line half way, at 37.5 s) and is the lead from then on
    cut_in_begin_s: float = 36.0
    cut_in_end_s: float = 39.0
    #: the slots of the lead (the car ahead in the ego lane from the start) and of the cut-in car
    lead_slot: int = 2
    cut_in_slot: int = 0
    #: the lead's gap ahead of the radar, and the cut-in car's gap after its lane change
    lead_gap_m: tuple[float, float] = (49.0, 55.0)
    cut_in_gap_m: tuple[float, float] = (31.0, 31.5)
    #: the far car in the left lane drives out of the radar's range at about this time
    left_far_leaves_s: float = 41.7
    #: radar coverage
    radar_range_m: float = 200.0
    radar_fov_deg: float = 30.0
    #: every road user, and those the radar reports twice at times (twin episodes: 1 to 6 s on,
    #: 1 to 5 s off, in steps of 0.5 s, the first after 1 to 5 s; left_far never)
    objects: tuple[str, ...] = ("lead", "cut_in", "left_near", "right_80", "left_120",
                                "left_far", "right_190")
    twinned: tuple[str, ...] = ("lead", "cut_in", "left_near", "right_80", "left_120",
                                "right_190")


    def curves(self) -> tuple[Curve, ...]:
        """The road's curves, in time order."""
        if self.bends is not None:
            return self.bends
        return (Curve(self.curve_begin_s, self.curve_end_s, self.curve_radius_m,
                      self.curve_transition_s),)


HIGHWAY = Highway()
#: The same drive on a winding highway: five curves of 1 to 2 deg/s at 30 m/s, left and right
#: (left 1000 m, right 1600 m, left 1600 m, right 900 m, left 1200 m), straight between them.
WINDING = Highway(bends=(Curve(4.0, 12.0, 1000.0), Curve(16.0, 24.0, -1600.0),
                         Curve(28.0, 35.0, 1600.0), Curve(40.0, 48.0, -900.0),
                         Curve(51.0, 58.0, 1200.0)))
#: ... and on a straight highway: no curve at all.
STRAIGHT = Highway(bends=())
#: ... and on a straight highway where the ego changes lanes four times (left, back, right,
#: back; 4 to 6 s each, up to 2.7 deg/s of yaw rate).
WEAVING = Highway(bends=(), ego_lane_changes=(
    (8.0, 5.0, LANE_WIDTH_M), (20.0, 4.0, -LANE_WIDTH_M), (32.0, 5.0, -LANE_WIDTH_M),
    (46.0, 6.0, LANE_WIDTH_M)))
#: The roads the highway car can drive (``simulate_highway(road=...)``).
ROADS = {"curve": HIGHWAY, "winding": WINDING, "straight": STRAIGHT, "weaving": WEAVING}


# ---------------------------------------------------------------------------------------------
# The ego and the road
# ---------------------------------------------------------------------------------------------

_SPEED_WAVE, _SPEED_OMEGA = 0.25, 2 * math.pi / 14.0
_WANDER = ((0.05, 2 * math.pi / 9.0, 0.0), (0.005, 2 * math.pi / 3.3, 1.0))


def _ego_s(t: float) -> float:
    """Distance driven along the road (m) by the rear axle."""
    w = _SPEED_OMEGA
    return HIGHWAY.ego_speed_mps * t + _SPEED_WAVE / w * (1.0 - math.cos(w * t))


def _smoothstep(t: float, t0: float, duration: float) -> tuple[float, float]:
    """0 to 1 over ``[t0, t0 + duration]``: value and integral from t0."""
    if t <= t0:
        return 0.0, 0.0
    u = (t - t0) / duration
    if u >= 1.0:
        return 1.0, duration / 2 + (t - t0 - duration)
    return u * u * (3 - 2 * u), duration * (u**3 - u**4 / 2)


class _Bend:
    """One curve of the road by the distance s along it: clothoid in, constant radius, out."""

    def __init__(self, curve: Curve, speed: float) -> None:
        self.k = 1.0 / curve.radius_m
        self.s1 = _ego_s(curve.begin_s)
        self.s2 = _ego_s(curve.end_s)
        self.ramp = speed * curve.transition_s
        self.theta_end = self.k * (self.s2 - self.s1 - self.ramp)

    def curvature(self, s: float) -> float:
        s1, s2, r, k = self.s1, self.s2, self.ramp, self.k
        if s <= s1 or s >= s2:
            return 0.0
        if s < s1 + r:
            return k * (s - s1) / r
        if s > s2 - r:
            return k * (s2 - s) / r
        return k

    def heading(self, s: float) -> float:
        s1, s2, r, k = self.s1, self.s2, self.ramp, self.k
        if s <= s1:
            return 0.0
        if s >= s2:
            return self.theta_end
        if s < s1 + r:
            return k * (s - s1) ** 2 / (2 * r)
        if s <= s2 - r:
            return k * r / 2 + k * (s - s1 - r)
        u = s2 - s
        return self.theta_end - k * u * u / (2 * r)


class _Road:
    """The ego lane's centre line: straight, and for each curve a clothoid into a curve of
    constant radius and a clothoid out of it, straight again; position and heading as functions
    of the distance s."""

    STEP = 1.0

    def __init__(self, h: Highway) -> None:
        self.bends = [_Bend(c, h.ego_speed_mps) for c in h.curves()]
        self.theta_end = 0.0
        for bend in self.bends:
            self.theta_end += bend.theta_end
        if not self.bends:
            self.s1 = self.s2 = 0.0
            self.ss = [0.0]
            self.points = [(0.0, 0.0)]
            return
        self.s1, self.s2 = self.bends[0].s1, self.bends[-1].s2
        self.ss = [self.s1 + i * self.STEP
                   for i in range(math.ceil((self.s2 - self.s1) / self.STEP))] + [self.s2]
        points = [(self.s1, 0.0)]
        for a, b in itertools.pairwise(self.ss):
            x, y = points[-1]
            dx, dy = self._chord(a, b)
            points.append((x + dx, y + dy))
        self.points = points

    def curvature(self, s: float) -> float:
        for bend in self.bends:
            if s < bend.s2:
                return bend.curvature(s)
        return 0.0

    def heading(self, s: float) -> float:
        total = 0.0
        for bend in self.bends:
            total += bend.heading(s)
        return total

    def _chord(self, a: float, b: float) -> tuple[float, float]:
        """Simpson's rule of (cos, sin) of the heading from a to b."""
        m = (a + b) / 2
        ha, hm, hb = self.heading(a), self.heading(m), self.heading(b)
        w = (b - a) / 6
        return (w * (math.cos(ha) + 4 * math.cos(hm) + math.cos(hb)),
                w * (math.sin(ha) + 4 * math.sin(hm) + math.sin(hb)))

    def position(self, s: float) -> tuple[float, float]:
        if s <= self.s1:
            return s, 0.0
        if s >= self.s2:
            x, y = self.points[-1]
            return (x + (s - self.s2) * math.cos(self.theta_end),
                    y + (s - self.s2) * math.sin(self.theta_end))
        i = min(int((s - self.s1) / self.STEP), len(self.ss) - 2)
        x, y = self.points[i]
        dx, dy = self._chord(self.ss[i], s)
        return x + dx, y + dy

    def place(self, s: float, d: float) -> tuple[float, float]:
        """The point ``d`` to the left of the centre line at ``s``."""
        x, y = self.position(s)
        h = self.heading(s)
        return x - d * math.sin(h), y + d * math.cos(h)




@dataclass(frozen=True)
class EgoTruth:
    """The ego at one time: road distance, speed, acceleration, lateral offset from the middle
    lane's centre (left), heading relative to the road, path curvature (1/m, left), yaw rate (rad/s,
    left) and steering wheel angle (rad, left)."""

    t: float
    s: float
    speed: float
    accel: float
    d: float
    psi: float
    curvature: float
    yaw_rate: float
    steering_wheel_angle: float
    lateral_accel: float


def ego_at(t: float, highway: Highway = HIGHWAY) -> EgoTruth:
    """The ego at ``t`` on ``highway``'s road."""
    v0, w = highway.ego_speed_mps, _SPEED_OMEGA
    v = v0 + _SPEED_WAVE * math.sin(w * t)
    a = _SPEED_WAVE * w * math.cos(w * t)
    s = _ego_s(t)
    d = sum(amp * math.sin(om * t + ph) for amp, om, ph in _WANDER)
    d_dot = sum(amp * om * math.cos(om * t + ph) for amp, om, ph in _WANDER)
    d_ddot = -sum(amp * om * om * math.sin(om * t + ph) for amp, om, ph in _WANDER)
    for begin, duration, offset in highway.ego_lane_changes:
        u = min(max((t - begin) / duration, 0.0), 1.0)
        d += offset * (u - math.sin(2 * math.pi * u) / (2 * math.pi))
        if 0.0 < u < 1.0:
            d_dot += offset / duration * (1.0 - math.cos(2 * math.pi * u))
            d_ddot += offset * 2 * math.pi / duration**2 * math.sin(2 * math.pi * u)
    kappa = _world(highway).road.curvature(s) + d_ddot / (v * v)
    return EgoTruth(t, s, v, a, d, d_dot / v, kappa, v * kappa,
                    STEERING_RATIO * math.atan(WHEELBASE_M * kappa), v * v * kappa)


def _ego_pose(t: float, h: Highway) -> tuple[float, float, float]:
    """The rear axle's position and heading in the road's fixed frame."""
    e = ego_at(t, h)
    road = _world(h).road
    x, y = road.place(e.s, e.d)
    return x, y, road.heading(e.s) + e.psi


# ---------------------------------------------------------------------------------------------
# The traffic: gap ahead of the radar along the road, and lateral offset, as functions of time
# ---------------------------------------------------------------------------------------------

def _wave(mean: float, amplitude: float, period: float, phase: float) -> Callable[[float], float]:
    return lambda t: mean + amplitude * math.sin(2 * math.pi * t / period + phase)


def _cut_in_gap(t: float) -> float:
    # closing the distance to the lead at 0.55 m/s, then matching the ego's speed (36..42 s)
    _, integral = _smoothstep(t, HIGHWAY.cut_in_begin_s, 6.0)
    return 10.0 + 0.55 * (t - integral)


def _cut_in_d(t: float) -> float:
    h = HIGHWAY
    r, _ = _smoothstep(t, h.cut_in_begin_s, h.cut_in_end_s - h.cut_in_begin_s)
    return RIGHT_LANE + LANE_WIDTH_M * r


_TRAFFIC: dict[str, tuple[Callable[[float], float], Callable[[float], float]]] = {
    "lead": (_wave(52.0, 3.0, 23.0, 0.0), _wave(0.0, 0.1, 6.1, 0.0)),
    "cut_in": (_cut_in_gap, _cut_in_d),
    "left_near": (_wave(18.0, 4.0, 31.0, 0.5), _wave(LEFT_LANE, 0.08, 7.3, 1.0)),
    "right_80": (_wave(80.0, 5.0, 37.0, 1.0), _wave(RIGHT_LANE, 0.08, 8.1, 2.0)),
    "left_120": (_wave(120.0, 6.0, 43.0, 2.0), _wave(LEFT_LANE, 0.1, 9.7, 0.3)),
    "left_far": (lambda t: 150.0 + 1.2 * t, _wave(LEFT_LANE, 0.1, 6.7, 2.2)),
    "right_190": (_wave(185.0, 8.0, 53.0, 3.0), _wave(RIGHT_LANE, 0.1, 11.3, 1.4)),
}


def _positions(t: float, h: Highway) -> dict[str, tuple[float, float, float]]:
    """Each road user's vehicle-frame (x, y) and lateral offset d at ``t``."""
    ex, ey, eh = _ego_pose(t, h)
    road = _world(h).road
    c, s = math.cos(eh), math.sin(eh)
    s_radar = _ego_s(t) + RADAR_X_M
    out = {}
    for name, (gap, lateral) in _TRAFFIC.items():
        d = lateral(t)
        gx, gy = road.place(s_radar + gap(t), d)
        dx, dy = gx - ex, gy - ey
        out[name] = (c * dx + s * dy, -s * dx + c * dy, d)
    return out


def _covered(x: float, y: float, h: Highway) -> bool:
    xr = x - RADAR_X_M
    return (xr > 1.0 and math.hypot(xr, y) <= h.radar_range_m
            and abs(math.degrees(math.atan2(y, xr))) <= h.radar_fov_deg)


@dataclass(frozen=True)
class ObjectTruth:
    """One road user at one time, true values: vehicle-frame position (rear axle origin, y
    left), velocity and longitudinal acceleration relative to the ego, lateral offset from the
    ego lane centre, and whether the radar covers it."""

    name: str
    x: float
    y: float
    vx: float
    vy: float
    ax: float
    d: float
    in_view: bool


_H = 0.05


def objects_at(t: float, highway: Highway = HIGHWAY) -> tuple[ObjectTruth, ...]:
    """Every road user at ``t`` on ``highway``'s road."""
    h = highway
    before, now, after = _positions(t - _H, h), _positions(t, h), _positions(t + _H, h)
    out = []
    for name in h.objects:
        (xm, ym, _), (x, y, d), (xp, yp, _) = before[name], now[name], after[name]
        out.append(ObjectTruth(name, x, y, (xp - xm) / (2 * _H), (yp - ym) / (2 * _H),
                               (xp - 2 * x + xm) / (_H * _H), d, _covered(x, y, h)))
    return tuple(out)


# ---------------------------------------------------------------------------------------------
# Twins, dropouts and slots
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TwinEpisode:
    """The object is reported in a second slot for ``begin <= t < end``, offset from it by
    ``dx``, ``dy`` (m, vehicle frame) and ``dv`` (m/s, relative speed): another reflection."""

    begin: float
    end: float
    dx: float
    dy: float
    dv: float


@dataclass
class _Schedule:
    """An object's twin episodes, drawn from its own fixed random sequence as far as asked."""

    rng: random.Random
    episodes: list[TwinEpisode] = field(default_factory=list)
    begins: list[float] = field(default_factory=list)
    until: float = 0.0

    def at(self, t: float) -> TwinEpisode | None:
        while self.until <= t:
            begin = self.until + self.rng.randint(2, 10) * 0.5
            end = begin + self.rng.randint(2, 12) * 0.5
            dx = self.rng.choice((-1, 1)) * self.rng.uniform(0.2, 0.5)
            self.episodes.append(TwinEpisode(begin, end, dx, self.rng.uniform(-0.25, 0.25),
                                             self.rng.uniform(-0.1, 0.1)))
            self.begins.append(begin)
            self.until = end
        i = bisect.bisect_right(self.begins, t) - 1
        return self.episodes[i] if i >= 0 and t < self.episodes[i].end else None


_SCHEDULES = {name: _Schedule(random.Random(f"tankviz-highway-twins:{name}"))
              for name in HIGHWAY.twinned}


def twin_episode(name: str, t: float) -> TwinEpisode | None:
    """The twin episode of ``name`` at ``t``, if it has one then."""
    schedule = _SCHEDULES.get(name)
    return schedule.at(t) if schedule is not None else None


#: Dropouts: in every block of this many radar cycles (10 s), each object's own slot is sent
#: invalid once, for 1 to 3 cycles.
_DROPOUT_BLOCK = 200


@functools.lru_cache(maxsize=256)
def _dropout(name: str, block: int) -> range:
    rng = random.Random(f"tankviz-highway-dropout:{name}:{block}")
    start = block * _DROPOUT_BLOCK + rng.randrange(_DROPOUT_BLOCK - 3)
    return range(start, start + rng.randint(1, 3))


def dropped(name: str, cycle: int) -> bool:
    """Whether the radar sends ``name``'s own slot invalid at ``cycle`` (VALID = 0, the slot
    kept for it): 1 to 3 cycles once in every 10 s, from a fixed sequence per object."""
    return cycle in _dropout(name, cycle // _DROPOUT_BLOCK)


@dataclass(frozen=True)
class SlotTruth:
    """What one slot holds at one radar cycle: the object, whether it is the object's twin (its
    second slot), whether it is sent valid (a dropout sends VALID = 0 and keeps the slot), and
    whether this is the slot's first cycle with this object (NEW_TRACK = 1)."""

    name: str
    twin: bool
    valid: bool
    new: bool


class _SlotPlan:
    """Which object each slot holds at each radar cycle, from the first cycle on (cached).

    Every cycle the objects in view (nearest first), then the twins of those in a twin episode
    (nearest first), keep the slot they have; a newcomer takes the slot free for longest (never
    used slots first, lowest index first)."""

    def __init__(self, h: Highway) -> None:
        self.highway = h
        self.owners: list[tuple[tuple[str, bool] | None, ...]] = []
        self.where: dict[tuple[str, bool], int] = {}
        self.freed = [-1] * SLOT_COUNT

    def at(self, cycle: int) -> tuple[tuple[str, bool] | None, ...]:
        while len(self.owners) <= cycle:
            self._step(len(self.owners))
        return self.owners[cycle]

    def _step(self, cycle: int) -> None:
        t = cycle * RADAR_CYCLE_S
        h = self.highway
        seen = sorted(((math.hypot(x - RADAR_X_M, y), name)
                       for name, (x, y, _) in _positions(t, h).items() if _covered(x, y, h)))
        keys = [(name, False) for _, name in seen]
        keys += [(name, True) for _, name in seen if twin_episode(name, t) is not None]
        keys = keys[:SLOT_COUNT]
        keep = set(keys)
        for key in [k for k in self.where if k not in keep]:
            self.freed[self.where.pop(key)] = cycle
        owners: list[tuple[str, bool] | None] = [None] * SLOT_COUNT
        for key, slot in self.where.items():
            owners[slot] = key
        for key in keys:
            if key not in self.where:
                slot = min((i for i in range(SLOT_COUNT) if owners[i] is None),
                           key=lambda i: (self.freed[i], i))
                self.where[key] = slot
                owners[slot] = key
        self.owners.append(tuple(owners))


@dataclass(frozen=True)
class _World:
    """A road and the slots its traffic takes (made once per :class:`Highway`)."""

    road: _Road
    plan: _SlotPlan


@functools.lru_cache(maxsize=8)
def _world(h: Highway) -> _World:
    return _World(_Road(h), _SlotPlan(h))


def radar_cycle(t: float) -> int:
    """The radar cycle measured at or before ``t`` (cycle k measures at k * 50 ms)."""
    return max(0, math.floor(t / RADAR_CYCLE_S + 1e-9))


def slots_at(t: float, highway: Highway = HIGHWAY) -> tuple[SlotTruth | None, ...]:
    """Each of the 16 slots of the radar cycle measured at or before ``t`` (None: empty)."""
    cycle = radar_cycle(t)
    plan = _world(highway).plan
    owners = plan.at(cycle)
    before = plan.at(cycle - 1) if cycle else (None,) * SLOT_COUNT
    out: list[SlotTruth | None] = []
    for slot, key in enumerate(owners):
        if key is None:
            out.append(None)
            continue
        name, twin = key
        valid = twin or not dropped(name, cycle)
        out.append(SlotTruth(name, twin, valid, before[slot] != key))
    return tuple(out)


def twins_at(t: float, highway: Highway = HIGHWAY) -> set[frozenset[int]]:
    """The pairs of slots that hold one object, both sent valid, at the radar cycle measured at
    or before ``t``."""
    slots = slots_at(t, highway)
    where: dict[str, list[int]] = {}
    for i, s in enumerate(slots):
        if s is not None and s.valid:
            where.setdefault(s.name, []).append(i)
    return {frozenset(v) for v in where.values() if len(v) == 2}


def lead_at(t: float) -> str:
    """The name of the lead (the old lead until the cut-in car's centre crosses into the ego
    lane half way through its lane change, the cut-in car from then on)."""
    h = HIGHWAY
    return "lead" if t < (h.cut_in_begin_s + h.cut_in_end_s) / 2 else "cut_in"
