"""World: the latest observations with their times, expiring in log time, and what follows.

:class:`World` keeps the newest valid observation of each object, lane line and ego state,
expiring in log time so convert, replay and live agree; from it come the lane model and the MIO
check. Nothing non-finite enters or leaves it.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

from bridge.frame import NS
from bridge.profile.model import LaneSpec, Profile, Sensor
from bridge.world.lead import Key, LeadKeeper, SteadyLead, key
from bridge.world.observe import (
    LEAD_GROUP,
    EgoObservation,
    LaneObservation,
    ObjectObservation,
    Observation,
)


def polynomial(c: Sequence[float], x: float) -> float:
    return c[0] + x * (c[1] + x * (c[2] + x * c[3]))


def lane_to_vehicle(sensor: Sensor, c: Sequence[float]) -> tuple[float, float, float, float]:
    """Sensor-frame lane coefficients as a vehicle-frame polynomial in x.

    Exact for the mount offset and lateral sign; the mount's yaw is applied to first order.
    """
    a = sensor.mount.x
    c0, c1, c2, c3 = c
    shifted = (c0 - c1 * a + c2 * a * a - c3 * a**3, c1 - 2 * c2 * a + 3 * c3 * a * a,
               c2 - 3 * c3 * a, c3)
    s = sensor.lateral_sign
    return (s * shifted[0] + sensor.mount.y, s * shifted[1] + math.tan(
        math.radians(sensor.mount.yaw_deg)), s * shifted[2], s * shifted[3])


#: The drawn polyline of a lane line stays within this (m, laterally) of the line's cubic.
LANE_TOLERANCE_M = 0.01
#: The closest its points come (m): the spacing of old, kept for bends too tight for the
#: tolerance (a radius under 12.5 m, a steering angle near full lock).
LANE_MIN_STEP_M = 1.0


#: A line is drawn in this many equal pieces, each with points evenly spaced as its bend needs.
LANE_PIECES = 4


def lane_xs(c2: float, c3: float, length: float) -> tuple[float, ...]:
    """Where to draw the line y = c0 + c1 x + c2 x² + c3 x³ from x = 0 to ``length`` - 1 m.

    A chord from a to b strays at most (b - a)² / 8 · max|y''| from the curve on [a, b], and
    y'' = 2 c2 + 6 c3 x is linear in x, so its largest size on [a, b] is at an end. The line is
    cut into :data:`LANE_PIECES` equal pieces (one for a parabola: its bend is the same all
    along), each with as few evenly spaced points as keep that bound within
    :data:`LANE_TOLERANCE_M`, but no closer than :data:`LANE_MIN_STEP_M`: two points for a
    straight line, about 20 for the bends of a main road (radius 300 m), more where it bends more.
    Costs a few operations per piece: no point is placed one by one.
    """
    end = float(int(length) - 1)
    if not (math.isfinite(c2) and math.isfinite(c3)) or end <= 0:
        return tuple(float(x) for x in range(int(length)))
    budget = 8.0 * LANE_TOLERANCE_M
    pieces = LANE_PIECES if c3 else 1
    knots, spans = _knots(end, pieces)
    bends = [abs(2.0 * c2 + 6.0 * c3 * x) for x in knots]
    if end * end * max(bends) <= budget:
        return (0.0, end)
    sqrt, ceil = math.sqrt, math.ceil
    steps = []  # each piece's: max(1, min(ceil(span * sqrt(max(a, b) / budget)), allowed))
    for (span, allowed), a, b in zip(spans, bends[:-1], bends[1:], strict=True):
        wanted = ceil(span * sqrt((b if b > a else a) / budget))
        taken = allowed if allowed < wanted else wanted
        steps.append(taken if taken > 1 else 1)
    return _spaced(end, pieces, tuple(steps))


@lru_cache(maxsize=64)
def _knots(end: float, pieces: int) -> tuple[tuple[float, ...], tuple[tuple[float, int], ...]]:
    """The ends of ``pieces`` equal pieces of [0, ``end``], and each piece's span with the
    most steps :data:`LANE_MIN_STEP_M` allows on it."""
    knots = tuple(end * i / pieces for i in range(pieces + 1))
    spans = [knots[i + 1] - knots[i] for i in range(pieces)]
    return knots, tuple((span, int(span / LANE_MIN_STEP_M)) for span in spans)


@lru_cache(maxsize=1024)
def _spaced(end: float, pieces: int, steps: tuple[int, ...]) -> tuple[float, ...]:
    """The points of :func:`lane_xs` that cut [0, ``end``] into ``pieces`` equal pieces, each
    in its number of ``steps``: the same places whatever the line, held once."""
    knots, _ = _knots(end, pieces)
    xs: tuple[float, ...] = (0.0,)
    for i in range(pieces):
        xs += _evenly(knots[i], knots[i + 1], steps[i])
    return xs


def _evenly(start: float, stop: float, steps: int) -> tuple[float, ...]:
    """``steps`` even steps from ``start`` (left out) to ``stop``."""
    return (*(start + (stop - start) * k / steps for k in range(1, steps)), stop)


@dataclass(frozen=True)
class LaneCurve:
    """One lane line to draw, as vehicle-frame points from x = 0 to length-1 m ahead of where
    its coefficients start (the camera, or the vehicle origin), as few as :func:`lane_xs` needs."""

    name: str
    points: tuple[tuple[float, float], ...]
    coefficients: tuple[float, float, float, float]

    def lateral_at(self, x: float) -> float:
        return polynomial(self.coefficients, x)

    def finite(self) -> bool:
        """Whether every point and coefficient is a finite number (drawable)."""
        isfinite = math.isfinite
        return (all(map(isfinite, self.coefficients))
                and all([isfinite(y) for _, y in self.points]))


@dataclass(frozen=True)
class LaneModel:
    """The lanes of the moment: from the camera, extrapolated from the steering, or none."""

    source: str  # "camera", "steering" or "none"
    lines: tuple[LaneCurve, ...] = ()
    camera_age_s: float = -1.0

    def line(self, name: str) -> LaneCurve | None:
        return next((line for line in self.lines if line.name == name), None)

    @cached_property
    def ego_lines(self) -> tuple[LaneCurve | None, LaneCurve | None]:
        """The ego lane's left and right lines (None where missing), looked up once."""
        return self.line("left"), self.line("right")

    def in_ego_lane(self, x: float, y: float) -> bool:
        left, right = self.ego_lines
        if left is None or right is None or x < 0:
            return False
        return right.lateral_at(x) < y < left.lateral_at(x)

    def outside_by(self, x: float, y: float) -> float | None:
        """How far (m) the point lies outside the ego lane's lines (0 inside); None where there
        is no ego lane (no lines, or behind the vehicle)."""
        left, right = self.ego_lines
        if left is None or right is None or x < 0:
            return None
        return max(0.0, right.lateral_at(x) - y, y - left.lateral_at(x))


def steering_curvature(steering_wheel_angle: float, wheelbase: float, ratio: float) -> float:
    """Path curvature (1/m, left positive) of a bicycle model from the steering wheel angle."""
    return math.tan(steering_wheel_angle / ratio) / wheelbase


def camera_curve(name: str, sensor: Sensor, c: Sequence[float], length: float) -> LaneCurve:
    # to_vehicle(sensor, x, polynomial(c, x)) at each of lane_xs, spelled out
    c0, c1, c2, c3 = c
    sign = sensor.lateral_sign
    mount = sensor.mount
    cos, sin = sensor.rotation
    xs = lane_xs(c2, c3, length)
    if mount.yaw_deg:
        ys = [(c0 + x * (c1 + x * (c2 + x * c3))) * sign for x in xs]
        points = tuple((cos * x - sin * y + mount.x, sin * x + cos * y + mount.y)
                       for x, y in zip(xs, ys, strict=True))
    else:  # (x + mount.x, y + mount.y), the same sums, each coordinate in one pass
        mx, my = mount.x, mount.y
        # x + 0.0 (or -0.0) is x for each x of lane_xs (0.0 and positive): no pass for it
        points = tuple(zip(xs if mx == 0.0 else [x + mx for x in xs],
                           [(c0 + x * (c1 + x * (c2 + x * c3))) * sign + my for x in xs],
                           strict=True))
    return LaneCurve(name, points, lane_to_vehicle(sensor, c))


def steering_curve(name: str, offset: float, curvature: float, length: float) -> LaneCurve:
    c = (offset, 0.0, curvature / 2.0, 0.0)
    return LaneCurve(name, tuple((x, polynomial(c, x)) for x in lane_xs(c[2], 0.0, length)), c)


@dataclass
class EgoState:
    t_ns: int | None = None
    speed: float | None = None
    yaw_rate: float | None = None
    steering_wheel_angle: float | None = None


@dataclass(frozen=True)
class MioCheck:
    """The lead vehicle against the closest valid track inside the ego lane."""

    lead: ObjectObservation | None
    expected: ObjectObservation | None
    ok: bool
    reason: str


@dataclass
class World:
    """Everything known at the current log time.

    Objects expire after their group's lifetime in log time, and a clock step shifts every time held
    (:meth:`shift`). The lane model is the camera lanes while fresh, else lanes extrapolated from
    the steering angle, drawn within :data:`LANE_TOLERANCE_M` of their cubic (:func:`lane_xs`). An
    observation whose rule could not be evaluated is applied as invalid and counted in
    :attr:`rule_errors`.
    """

    profile: Profile
    objects: dict[str, dict[int, ObjectObservation]] = field(default_factory=dict)
    lanes: dict[str, LaneObservation] = field(default_factory=dict)
    ego: EgoState = field(default_factory=EgoState)
    last_camera_lanes_ns: int | None = None
    #: validity rules that could not be evaluated, per group ("lanes" for lane lines)
    rule_errors: Counter[str] = field(default_factory=Counter)
    #: the latest reason per group
    last_rule_error: dict[str, str] = field(default_factory=dict)
    #: each line drawn last (by name; "steering " + name for the fallback), with what made it
    #: (coefficients, or the curvature) and whether it is drawable: an unchanged line is the
    #: same LaneCurve tick after tick, so the scene draws it once (:meth:`_held`)
    _curves: dict[str, tuple[object, LaneCurve, bool]] = field(
        default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.lifetimes_ns = {name: round(g.lifetime_s * NS)
                             for name, g in self.profile.groups.items()}
        if self.profile.lead is not None:
            self.lifetimes_ns[LEAD_GROUP] = round(self.profile.lead.lifetime_s * NS)
        for name in self.lifetimes_ns:
            self.objects.setdefault(name, {})
        #: the lead chosen from tracks, kept steady (``[lead] source = "tracks"``)
        self.keeper = LeadKeeper()
        #: the reported lead's id and serial (``[lead]`` from its own message)
        self._reported: tuple[int | None, int] = (None, 0)

    def apply(self, observation: Observation) -> None:
        if isinstance(observation, ObjectObservation):
            group = self.objects.setdefault(observation.group, {})
            if observation.rule_error:
                self._rule_error(observation.group, observation.rule_error)
            if observation.valid:
                group[observation.object_id] = observation
            else:
                group.pop(observation.object_id, None)
        elif isinstance(observation, LaneObservation):
            if observation.rule_error:
                self._rule_error("lanes", observation.rule_error)
            if observation.valid:
                self.lanes[observation.name] = observation
            else:
                self.lanes.pop(observation.name, None)
        elif isinstance(observation, EgoObservation):
            ego = self.ego
            ego.t_ns = observation.t_ns
            if observation.speed is not None:
                ego.speed = observation.speed
            if observation.yaw_rate is not None:
                ego.yaw_rate = observation.yaw_rate
            if observation.steering_wheel_angle is not None:
                ego.steering_wheel_angle = observation.steering_wheel_angle

    def apply_all(self, observations: Iterable[Observation]) -> None:
        """:meth:`apply` each of ``observations``, in order (an object's without a rule error
        inline: most of a tick's)."""
        objects, apply = self.objects, self.apply
        for observation in observations:
            if observation.__class__ is ObjectObservation and not observation.rule_error:
                group = objects.get(observation.group)
                if group is None:
                    group = objects.setdefault(observation.group, {})
                if observation.valid:
                    group[observation.object_id] = observation
                else:
                    group.pop(observation.object_id, None)
            else:
                apply(observation)

    def _rule_error(self, group: str, why: str) -> None:
        self.rule_errors[group] += 1
        self.last_rule_error[group] = why

    def expire(self, now_ns: int) -> None:
        """Forget objects older than their group's lifetime."""
        lifetimes = self.lifetimes_ns
        for name, objects in self.objects.items():
            if not objects:
                continue
            oldest = now_ns - lifetimes.get(name, 0)
            stale = [i for i, o in objects.items() if o.t_ns < oldest]
            for i in stale:
                del objects[i]

    def shift(self, shift_ns: int) -> None:
        """The clock stepped: every log time held moves by ``shift_ns``, so lifetimes and
        staleness go on from the new time as if no time had passed."""
        for objects in self.objects.values():
            for o in objects.values():
                o.t_ns += shift_ns
        for lane in self.lanes.values():
            lane.t_ns += shift_ns
        if self.ego.t_ns is not None:
            self.ego.t_ns += shift_ns
        if self.last_camera_lanes_ns is not None:
            self.last_camera_lanes_ns += shift_ns
        self.keeper.shift(shift_ns)

    def lane_model(self, now_ns: int) -> LaneModel:
        spec: LaneSpec | None = self.profile.lanes
        if spec is None:
            return LaneModel("none")
        stale_ns = round(spec.stale_after_s * NS)
        fresh = {name: obs for name, obs in self.lanes.items() if now_ns - obs.t_ns <= stale_ns}
        camera: tuple[LaneCurve, ...] = ()
        if spec.sensor is not None and "left" in fresh and "right" in fresh:
            made = []
            for name in ("left", "right", "next_left", "next_right"):
                if name in fresh:
                    c = fresh[name].coefficients
                    made.append(self._held(name, c) or self._hold(
                        name, c, camera_curve(name, spec.sensor, c, spec.length_m)))
            if made[0][1] and made[1][1]:  # left and right
                camera = tuple(c for c, ok in made if ok)
                self.last_camera_lanes_ns = max(fresh["left"].t_ns, fresh["right"].t_ns)
        age = ((now_ns - self.last_camera_lanes_ns) / NS
               if self.last_camera_lanes_ns is not None else -1.0)
        if camera:
            return LaneModel("camera", camera, age)
        if self.ego.steering_wheel_angle is None:
            return LaneModel("none", (), age)
        vehicle = self.profile.vehicle
        curvature = steering_curvature(self.ego.steering_wheel_angle, vehicle.wheelbase_m,
                                       vehicle.steering_ratio)
        left, left_ok = self._held("steering left", curvature) or self._hold(
            "steering left", curvature,
            steering_curve("left", spec.fallback_left_m, curvature, spec.length_m))
        right, right_ok = self._held("steering right", curvature) or self._hold(
            "steering right", curvature,
            steering_curve("right", spec.fallback_right_m, curvature, spec.length_m))
        if not (left_ok and right_ok):
            return LaneModel("none", (), age)
        return LaneModel("steering", (left, right), age)

    def _held(self, name: str, key: object) -> tuple[LaneCurve, bool] | None:
        """The line ``name`` of an earlier tick and whether it is drawable, if it was made from
        the same ``key`` (its coefficients, or the curvature)."""
        held = self._curves.get(name)
        return (held[1], held[2]) if held is not None and held[0] == key else None

    def _hold(self, name: str, key: object, curve: LaneCurve) -> tuple[LaneCurve, bool]:
        drawable = curve.finite()
        self._curves[name] = (key, curve, drawable)
        return curve, drawable

    def track_groups(self) -> tuple[str, ...]:
        return self._track_groups

    @cached_property
    def _track_groups(self) -> tuple[str, ...]:
        return tuple(name for name, g in self.profile.groups.items() if g.is_tracks)

    def closest_in_lane(self, lanes: LaneModel) -> ObjectObservation | None:
        """The closest valid track ahead inside the ego lane (the first of the closest)."""
        left, right = lanes.ego_lines
        if left is None or right is None:
            return None
        # lanes.in_ego_lane of each track, its lines' coefficients once
        l0, l1, l2, l3 = left.coefficients
        r0, r1, r2, r3 = right.coefficients
        closest = None
        for name in self._track_groups:
            for o in self.objects[name].values():
                x = o.x
                if (x >= 0 and r0 + x * (r1 + x * (r2 + x * r3)) < o.y
                        < l0 + x * (l1 + x * (l2 + x * l3))
                        and (closest is None or x < closest.x)):
                    closest = o
        return closest

    def lead(self, lanes: LaneModel, t_ns: int) -> SteadyLead:
        """The lead vehicle at the tick at log time ``t_ns`` (call once per tick): chosen from
        the tracks and kept steady (:class:`bridge.world.lead.LeadKeeper`), or the one its own
        message reports (the closest, if several), whose serial goes up when its id changes."""
        spec = self.profile.lead
        if spec is None:
            return SteadyLead(None, 0)
        if spec.source == "tracks":
            tracks = {key(o): o for name in self.track_groups()
                      for o in self.objects[name].values()}
            # lanes.outside_by and lanes.in_ego_lane of each track, its lines' places once
            outside: dict[Key, float] = {}
            in_lane: list[Key] = []
            left, right = lanes.ego_lines
            if left is not None and right is not None:
                l0, l1, l2, l3 = left.coefficients
                r0, r1, r2, r3 = right.coefficients
                for k, o in tracks.items():
                    x, y = o.x, o.y
                    if x < 0:
                        continue
                    # right.lateral_at(x), left.lateral_at(x)
                    low = r0 + x * (r1 + x * (r2 + x * r3))
                    high = l0 + x * (l1 + x * (l2 + x * l3))
                    outside[k] = max(0.0, low - y, y - high)
                    if low < y < high:
                        in_lane.append(k)
            return self.keeper.update(tracks, in_lane, outside, t_ns)
        objects = self.objects.get(LEAD_GROUP, {})
        reported = min(objects.values(), key=lambda o: o.x, default=None)
        last_id, serial = self._reported
        now_id = None if reported is None else reported.object_id
        if now_id is not None and now_id != last_id:
            serial += 1
        self._reported = (now_id, serial)
        return SteadyLead(reported, serial)

    def mio_check(self, lanes: LaneModel, lead: ObjectObservation | None) -> MioCheck:
        """The ``lead`` of this tick (:meth:`lead`) against the closest valid track in the ego
        lane. A lead chosen from the tracks is the check's own choice: always ok."""
        spec = self.profile.lead
        if spec is not None and spec.source == "tracks":
            return MioCheck(lead, lead, True, "no track in the ego lane" if lead is None
                            else f"lead is track #{lead.object_id} (chosen from the tracks)")
        if spec is None or not self.track_groups() or lanes.source == "none":
            return MioCheck(lead, None, True, "not checked (needs lead, tracks and lanes)")
        expected = self.closest_in_lane(lanes)
        if lead is None and expected is None:
            return MioCheck(None, None, True, "no lead vehicle, no track in the ego lane")
        if lead is None and expected is not None:
            return MioCheck(None, expected, False, f"no lead vehicle reported, but track "
                            f"#{expected.object_id} is in the ego lane at {expected.x:.1f} m")
        assert lead is not None
        if expected is None:
            return MioCheck(lead, None, False, f"lead #{lead.object_id} at {lead.x:.1f} m, but "
                            "no valid track is in the ego lane")
        same = (lead.object_id == expected.object_id
                or (abs(lead.x - expected.x) < 1.0 and abs(lead.y - expected.y) < 0.5))
        if same:
            return MioCheck(lead, expected, True, f"lead is track #{expected.object_id}")
        return MioCheck(lead, expected, False, f"lead #{lead.object_id} at {lead.x:.1f} m is "
                        f"not the closest in-lane track #{expected.object_id} at "
                        f"{expected.x:.1f} m")
