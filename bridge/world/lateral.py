"""Lateral sign, checked from the data: do a sensor's stationary objects sweep against the turn?

A profile's ``lateral = "left" | "right"`` says which way a sensor's positive lateral distance
(and azimuth) points; a radar DBC rarely says, and a wrong sign mirrors the sensor's whole scene.
:class:`LateralSignCheck` catches it from a drive, without a camera to compare with.

**Physics.** The ego drives at speed v (m/s) and turns at yaw rate ω (rad/s, left positive). An
object standing still in the world at (x, y) in the vehicle frame (x forward, y left) moves in
that frame at ẋ = -v + ω·y, ẏ = -ω·x: turning left, an object ahead sweeps to the right (its y
decreases), turning right to the left. A sensor whose lateral sign is wrong reports -y, so its
stationary objects sweep WITH the turn. Without a yaw rate in the profile, ω is the speed times
the path curvature of the steering wheel angle through ``[vehicle]`` wheelbase and steering ratio
(:func:`bridge.world.model.steering_curvature`); without a speed, nothing is judged.

**Stationary.** An object is taken as standing still when its own motion says so: over its
baseline (below) dx/dt is within ``max(1 m/s, 10 % of v) + |ω·y|`` of -v (the ω·y term allowed
both ways, since y may be the mirrored one). That alone decides for a group without velocity or
class (a post, a guard-rail echo, a parked car; a car driving along moves far less, an oncoming
one twice as fast); it also drops a slot that changed owner (the new object is elsewhere). Where
the group has more, it must agree too, by the first of:

1. a relative velocity ``vx`` (mapped and observed): vx within the same tolerance of -v;
2. a class signal: the object's class is ``stationary``.

The lateral sign changes none of these, so a wrong sign cannot hide its own evidence.

**Samples.** At each scene tick (:meth:`LateralSignCheck.update`, with the world after
:meth:`World.expire <bridge.world.model.World.expire>`) each valid object of each group
(detections or tracks; not the lead vehicle's own messages) is followed by its id. Its motion
is measured over a baseline of ``baseline_s`` of its own observation times (long enough that a
radar's position noise does not decide, short enough that the turn is still the same): at the
end of each baseline, its lateral rate dy/dt over it is compared with the expected -ω·x (x the
mean over the baseline), and the next baseline starts. It counts as a sample only while the ego
moves (``speed ≥ min_speed``), turns clearly (``|ω| ≥ min_yaw_rate``), the object stands still
(above) and the expected sweep is clear (``|ω·x| ≥ min_sweep``); it is *against* the turn (as it
must be) when dy/dt has the expected sign, *with* it when the opposite; a rate smaller than a
quarter of the expected one is no sample either way. An object not observed for ``max_gap_s``,
or whose time jumps back (a clock step), starts its baseline again.

**Verdict** per sensor (all its groups together): ``"unknown"`` below ``min_samples`` samples or
when neither way has ``agreement`` of them; else ``"ok"`` (against the turn: the sign agrees) or
``"flipped"`` (with the turn: the other sign is right). A straight road and a standstill give no
samples, so never a verdict. :meth:`LateralSignCheck.verdicts` gives each sensor's
:class:`LateralVerdict` with a one-line message, e.g.
``radar: stationary objects sweep WITH the turn in 412 of 430 samples: lateral = "left" looks
wrong, try lateral = "right"``.

Use: ``check = LateralSignCheck(profile)``; ``check.update(t_ns, world)`` at every scene tick
(cost: a few float operations per object, no per-frame work); ``check.verdicts()`` at any time,
e.g. at the end. The health monitor (:mod:`bridge.health.monitor`) runs one per drive, says a
``flipped`` verdict on ``/log`` and the drive's metadata carries the final verdicts
(``lateral_sign``, shown by ``tankviz inspect``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bridge.frame import NS
from bridge.profile.model import ObjectClass, Profile
from bridge.world.model import World, steering_curvature

#: where an object's baseline starts (t_ns, x, y), and the time of its latest observation
_Held = tuple[int, float, float, int]


@dataclass(frozen=True)
class LateralSettings:
    """Thresholds of the lateral sign check (see the module documentation)."""

    #: m/s: below it the ego is taken as standing (no sample)
    min_speed: float = 3.0
    #: rad/s (about 3 deg/s): below it the road is taken as straight (no sample)
    min_yaw_rate: float = 0.05
    #: m/s: the expected lateral sweep |ω·x| of an object must be at least this
    min_sweep: float = 0.2
    #: samples needed before any verdict
    min_samples: int = 50
    #: share of the samples one way needs for a verdict
    agreement: float = 0.8
    #: s: an object's motion is measured over this much of its observations (one sample each)
    baseline_s: float = 0.4
    #: s: an object not observed for longer than this starts its baseline again
    max_gap_s: float = 0.5


@dataclass(frozen=True)
class LateralVerdict:
    """What one sensor's stationary objects say about its lateral sign."""

    sensor: str
    #: "ok", "flipped" or "unknown"
    verdict: str
    #: the sensor's ``lateral`` in the profile
    lateral: str
    #: samples that swept against the turn (as they must) and with it (a mirrored scene)
    against: int
    with_turn: int
    message: str

    @property
    def samples(self) -> int:
        return self.against + self.with_turn

    def to_dict(self) -> dict[str, Any]:
        """For a drive's metadata (``lateral_sign``)."""
        return {"sensor": self.sensor, "verdict": self.verdict, "lateral": self.lateral,
                "samples": self.samples, "against_turn": self.against,
                "with_turn": self.with_turn, "message": self.message}


class LateralSignCheck:
    """Per sensor with object groups: is its lateral sign right? (see the module documentation)"""

    def __init__(self, profile: Profile, settings: LateralSettings | None = None) -> None:
        self.profile = profile
        self.settings = settings or LateralSettings()
        #: group name -> its sensor's name, for every object group
        self._sensor_of = {name: g.sensor.name for name, g in profile.groups.items()}
        self._classified = {name for name, g in profile.groups.items()
                            if g.class_signal is not None}
        self._lateral = {g.sensor.name: g.sensor.lateral for g in profile.groups.values()}
        #: sensor -> [against, with]
        self._counts = {sensor: [0, 0] for sensor in self._lateral}
        #: (group, object id) -> where its baseline starts, and its latest observation's time
        self._held: dict[tuple[str, int], _Held] = {}
        self._max_gap_ns = round(self.settings.max_gap_s * NS)
        self._baseline_ns = round(self.settings.baseline_s * NS)
        vehicle = profile.vehicle
        self._wheelbase, self._ratio = vehicle.wheelbase_m, vehicle.steering_ratio

    def yaw_rate(self, world: World) -> float | None:
        """The ego's yaw rate (rad/s, left +): measured, or from the steering and speed."""
        ego = world.ego
        if ego.yaw_rate is not None:
            return ego.yaw_rate
        if ego.steering_wheel_angle is None or ego.speed is None:
            return None
        return ego.speed * steering_curvature(ego.steering_wheel_angle, self._wheelbase,
                                              self._ratio)

    def update(self, t_ns: int, world: World) -> None:
        """Look at the world of one scene tick (``t_ns`` is the tick's log time)."""
        del t_ns  # the objects' own times measure their motion
        s = self.settings
        speed = world.ego.speed
        omega = self.yaw_rate(world)
        judging = (speed is not None and omega is not None and speed >= s.min_speed
                   and abs(omega) >= s.min_yaw_rate)
        held = self._held
        seen: dict[tuple[str, int], _Held] = {}
        for group, sensor in self._sensor_of.items():
            counts = self._counts[sensor]
            classified = group in self._classified
            for obs in world.objects.get(group, {}).values():
                key = (group, obs.object_id)
                t = obs.t_ns
                found = held.get(key)
                if found is None or not 0 <= t - found[3] <= self._max_gap_ns:
                    seen[key] = (t, obs.x, obs.y, t)  # new, lost for a while, or a clock step
                    continue
                anchor_t, anchor_x, anchor_y, _ = found
                if t - anchor_t < self._baseline_ns:
                    seen[key] = (anchor_t, anchor_x, anchor_y, t)
                    continue
                seen[key] = (t, obs.x, obs.y, t)  # the next baseline starts here
                if not judging:
                    continue
                assert speed is not None and omega is not None
                dt = (t - anchor_t) / NS
                tolerance = max(1.0, 0.1 * speed) + abs(omega * obs.y)
                stationary = abs((obs.x - anchor_x) / dt + speed) <= tolerance  # its own motion
                if obs.vx is not None:
                    stationary = stationary and abs(obs.vx + speed) <= tolerance
                elif classified:
                    stationary = stationary and obs.object_class is ObjectClass.STATIONARY
                expected = -omega * (obs.x + anchor_x) / 2
                if not stationary or abs(expected) < s.min_sweep:
                    continue
                rate = (obs.y - anchor_y) / dt
                if abs(rate) < 0.25 * abs(expected):
                    continue
                counts[0 if (rate > 0) == (expected > 0) else 1] += 1
        self._held = seen

    def verdicts(self) -> list[LateralVerdict]:
        """Each sensor's verdict so far, in the profile's order."""
        return [self.verdict(sensor) for sensor in self._counts]

    def verdict(self, sensor: str) -> LateralVerdict:
        """One sensor's verdict so far."""
        s = self.settings
        against, with_turn = self._counts[sensor]
        lateral = self._lateral[sensor]
        other = "right" if lateral == "left" else "left"
        n = against + with_turn
        if n < s.min_samples:
            return LateralVerdict(sensor, "unknown", lateral, against, with_turn, (
                f"{sensor}: lateral sign not judged: {n} samples of stationary objects while "
                f"turning, {s.min_samples} needed (drive a curve past posts, guard rails or "
                "parked cars)"))
        if with_turn >= s.agreement * n:
            return LateralVerdict(sensor, "flipped", lateral, against, with_turn, (
                f"{sensor}: stationary objects sweep WITH the turn in {with_turn} of {n} "
                f'samples: lateral = "{lateral}" looks wrong, try lateral = "{other}"'))
        if against >= s.agreement * n:
            return LateralVerdict(sensor, "ok", lateral, against, with_turn, (
                f"{sensor}: stationary objects sweep against the turn in {against} of {n} "
                f'samples: lateral = "{lateral}" agrees'))
        return LateralVerdict(sensor, "unknown", lateral, against, with_turn, (
            f"{sensor}: lateral sign not judged: stationary objects sweep against the turn in "
            f"{against} and with it in {with_turn} of {n} samples (no clear majority)"))
