"""Lateral sign, checked from the data: do a sensor's stationary objects sweep against the turn,
do the vehicles ahead lean into the curves?

:class:`LateralSignCheck` judges each sensor's ``lateral = "left" | "right"`` from a drive, without
a camera, and gives a :class:`LateralVerdict` (``"ok"``, ``"flipped"`` or ``"unknown"``) with a
one-line message; a straight road, lane changes and a standstill never give one.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bridge.frame import NS

if TYPE_CHECKING:  # (made only with a profile: the health monitor of a drive without one imports
    # this module but never loads the profile's model or the world for it)
    from bridge.profile.model import Profile
    from bridge.world.model import World

#: where an object's baseline starts (t_ns, x, y), and the time of its latest observation
_Held = tuple[int, float, float, int]


@dataclass(frozen=True)
class LateralSettings:
    """Thresholds of the lateral sign check (see :class:`LateralSignCheck`)."""

    #: m/s: below it the ego is taken as standing (no sample)
    min_speed: float = 3.0
    #: rad/s (about 3 deg/s): below it the road is taken as straight (no stationary sample)
    min_yaw_rate: float = 0.05
    #: m/s: the expected lateral sweep |ω·x| of an object must be at least this
    min_sweep: float = 0.2
    #: stationary samples needed before a verdict from them
    min_samples: int = 50
    #: share of the samples one way needs for a verdict
    agreement: float = 0.8
    #: s: an object's motion is measured over this much of its observations (one sample each)
    baseline_s: float = 0.4
    #: s: an object not observed for longer than this starts its baseline again
    max_gap_s: float = 0.5
    # vehicles ahead leaning into the curves (:class:`LateralSignCheck`, "Leaning")
    #: m/s: below it no vehicle ahead is taken as following the road's curves
    lean_min_speed: float = 10.0
    #: rad/s (about 0.6 deg/s): one end of a comparison must turn at least this
    lean_min_yaw_rate: float = 0.01
    #: m: the lean a comparison expects to change must change by at least this
    min_lean: float = 0.5
    #: m: vehicles this far ahead at most (beyond, the road ahead may curve otherwise)
    lean_max_x: float = 100.0
    #: rad: ... and at most this much of the curve ahead (x * curvature)
    lean_max_heading: float = 0.2
    #: s: a vehicle's position is averaged over blocks of this much of its observations
    lean_block_s: float = 0.5
    #: s: two blocks of a vehicle this far apart at most are compared
    lean_window_s: float = 10.0
    #: s: a block counts only when the yaw rate held steady for this long before its end ...
    lean_hold_s: float = 2.0
    #: ... within this share of its mean, or this many rad/s (0.3 deg/s) if more
    lean_steady_share: float = 0.3
    lean_steady_rate: float = 0.005
    #: samples needed before a verdict from leaning vehicles
    min_lean_samples: int = 20


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
    #: samples of vehicles ahead that leaned into the curves (as they must) and out of them
    lean_into: int = 0
    lean_out: int = 0

    @property
    def samples(self) -> int:
        """Samples of stationary objects while turning."""
        return self.against + self.with_turn

    @property
    def lean_samples(self) -> int:
        """Samples of vehicles ahead in curves."""
        return self.lean_into + self.lean_out

    def to_dict(self) -> dict[str, Any]:
        """For a drive's metadata (``lateral_sign``)."""
        return {"sensor": self.sensor, "verdict": self.verdict, "lateral": self.lateral,
                "samples": self.samples, "against_turn": self.against,
                "with_turn": self.with_turn, "lean_samples": self.lean_samples,
                "lean_into": self.lean_into, "lean_out": self.lean_out,
                "message": self.message}


class _Lean:
    """One vehicle ahead, followed for the lean: the block of observations being averaged, and
    the earlier blocks' means within the window, (time, y, expected lean, |yaw rate|)."""

    __slots__ = ("n", "points", "sp", "svx", "sw", "sy", "t0", "t1", "vxs", "x0", "x1")

    def __init__(self) -> None:
        self.points: list[tuple[int, float, float, float]] = []
        self.start(0)

    def start(self, t_ns: int) -> None:
        self.t0 = self.t1 = t_ns
        self.n = self.vxs = 0
        self.x0 = self.x1 = self.sy = self.sp = self.sw = self.svx = 0.0

    def add(self, t_ns: int, x: float, y: float, lean: float, turn: float,
            vx: float | None) -> None:
        if self.n == 0:
            self.start(t_ns)
            self.x0 = x
        self.n += 1
        self.t1, self.x1 = t_ns, x
        self.sy += y
        self.sp += lean
        self.sw += turn
        if vx is not None:
            self.vxs += 1
            self.svx += vx


class LateralSignCheck:
    """Per sensor with object groups: is its lateral sign right?

    **Physics.** The ego drives at speed v (m/s) and turns at yaw rate ω (rad/s, left positive). An
    object standing still in the world at (x, y) in the vehicle frame (x forward, y left) moves in
    that frame at ẋ = -v + ω·y, ẏ = -ω·x: turning left, an object ahead sweeps to the right (its y
    decreases), turning right to the left. A sensor whose lateral sign is wrong reports -y, so its
    stationary objects sweep WITH the turn. Without a yaw rate in the profile, ω is the speed times
    the path curvature of the steering wheel angle through ``[vehicle]`` wheelbase and steering
    ratio (:func:`bridge.world.model.steering_curvature`); without a speed, nothing is judged.

    **Stationary.** An object is taken as standing still when its own motion says so: over its
    baseline (below) dx/dt is within ``max(1 m/s, 10 % of v) + |ω·y|`` of -v (the ω·y term allowed
    both ways, since y may be the mirrored one). That alone decides for a group without velocity or
    class (a post, a guard-rail echo, a parked car; a car driving along moves far less, an oncoming
    one twice as fast); it also drops a slot that changed owner (the new object is elsewhere). Where
    the group has more, it must agree too, by the first of:

    1. a relative velocity ``vx`` (mapped and observed): vx within the same tolerance of -v; 2. a
    class signal: the object's class is ``stationary``.

    The lateral sign changes none of these, so a wrong sign cannot hide its own evidence.

    **Sweeping.** At each scene tick (:meth:`LateralSignCheck.update`, with the world after
    :meth:`World.expire <bridge.world.model.World.expire>`) each valid object of each group
    (detections or tracks; not the lead vehicle's own messages) is followed by its id. Its motion is
    measured over a baseline of ``baseline_s`` of its own observation times (long enough that a
    radar's position noise does not decide, short enough that the turn is still the same): at the
    end of each baseline, its lateral rate dy/dt over it is compared with the expected -ω·x (x the
    mean over the baseline), and the next baseline starts. It counts as a sample only while the ego
    moves (``speed ≥ min_speed``), turns clearly (``|ω| ≥ min_yaw_rate``), the object stands still
    (above) and the expected sweep is clear (``|ω·x| ≥ min_sweep``); it is *against* the turn (as it
    must be) when dy/dt has the expected sign, *with* it when the opposite; a rate smaller than a
    quarter of the expected one is no sample either way. An object not observed for ``max_gap_s``,
    or whose time jumps back (a clock step), starts its baseline again.

    **Leaning.** A vehicle driving along the road x metres ahead, ``d`` to the side of the ego's
    lane, sits at y = d + κ·x²/2 in the vehicle frame, κ = ω/v the road's curvature (the ego
    following its lane): on the inside of the curve. Its d is not known, but it keeps it: as the
    curve comes or goes, its y changes by the change of κ·x²/2, towards the inside of the new curve
    (*into* the curve, as it must); a sensor whose sign is wrong shows it leaning *out* of every
    curve. While the ego drives at ``lean_min_speed`` or more, each valid object with ``0 < x ≤
    lean_max_x`` and ``|κ|·x ≤ lean_max_heading`` (the parabola holds) is followed by its id; its
    observations are averaged over blocks of ``lean_block_s`` (y, the expected lean κ·x²/2 and |ω|).
    A block counts when the object drives along (its dx/dt over the block, and its vx when mapped,
    at least -v/2: not standing, not oncoming) and the yaw rate held steady over the last
    ``lean_hold_s`` (within ``lean_steady_share`` of its mean or ``lean_steady_rate``, whichever is
    more: a curve's or a straight road's turn, not a lane change's, whose heading swing would move
    every vehicle ahead). Each block is compared with the latest earlier one of the object within
    ``lean_window_s`` whose expected lean differs by ``min_lean`` or more, one of the two turning at
    ``lean_min_yaw_rate`` or more: a sample *into* the curve when the object's y moved the expected
    way, *out of* it when the other, none when it moved less than a quarter of the expected change;
    the object's comparisons then start again from this block. An object not observed for
    ``max_gap_s`` (or a clock step), one not driving along, and every object while the ego is slower
    or without a yaw rate, start again.

    **Verdict** per sensor (all its groups together), from each kind of evidence: ``"ok"`` when
    ``agreement`` of at least ``min_samples`` stationary samples are against the turn, or of at
    least ``min_lean_samples`` lean samples into the curves; ``"flipped"`` when as many are with the
    turn, or out of the curves. The two together give the verdict when one of them has one, or both
    the same; ``"unknown"`` when neither has one, or they disagree. A straight road (turns below
    ``lean_min_yaw_rate``, or not held: lane changes) and a standstill give no samples, so never a
    verdict. :meth:`LateralSignCheck.verdicts` gives each sensor's :class:`LateralVerdict` with a
    one-line message, e.g. ``radar: stationary objects sweep WITH the turn in 412 of 430 samples:
    lateral = "left" looks wrong, try lateral = "right"``, ``radar: vehicles ahead lean into the
    curves in 44 of 44 samples: lateral = "right" agrees``, and when it cannot judge, why, with the
    figures: ``radar: lateral sign not judged: 0 samples of stationary objects while turning (50
    needed): turned at most 2.3°/s (2.9°/s needed) over 60 s; 4 samples of vehicles ahead in curves
    (20 needed)`` (or ``...: no vehicle ahead in a curve (a turn of 0.6°/s or more held for 2 s)``,
    ``...: no vehicle driving ahead within 100 m at 10 m/s or more``).

    What a verdict not given says of the turns is over the ticks at ``min_speed`` or more: the
    fastest yaw rate then, and their time.

    Turning at yaw rate ω (or the speed times the steering's curvature,
    :func:`bridge.world.model.steering_curvature`), an object standing still at (x, y) must move at
    dy/dt = -ω·x (against the turn), and a vehicle driving ahead in a curve of curvature κ sits at y
    = d + κ·x²/2 (leaning into it); a flipped sensor shows the opposite. ``update(t_ns, world)``
    runs at every scene tick (no per-frame work); ``verdicts()`` says ``"ok"`` or ``"flipped"`` when
    ``agreement`` of at least ``min_samples`` stationary or ``min_lean_samples`` lean samples say
    so, else ``"unknown"``, always with the figures (what was missing when not judged).
    """

    def __init__(self, profile: Profile, settings: LateralSettings | None = None) -> None:
        from bridge.profile.model import ObjectClass
        from bridge.world.model import steering_curvature

        self._stationary = ObjectClass.STATIONARY
        self._curvature = steering_curvature
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
        #: sensor -> [into, out of] the curves; blocks of vehicles ahead driving along
        self._lean_counts = {sensor: [0, 0] for sensor in self._lateral}
        self._lean_blocks = dict.fromkeys(self._lateral, 0)
        #: (group, object id) -> the vehicle ahead followed for the lean
        self._leaning: dict[tuple[str, int], _Lean] = {}
        self._block_ns = round(self.settings.lean_block_s * NS)
        self._window_ns = round(self.settings.lean_window_s * NS)
        #: the drive so far: the latest tick, time driven (speed >= min_speed) and the fastest
        #: turn then (rad/s), for what a verdict not given says
        self._last_tick: int | None = None
        self._moving_ns = 0
        self._max_turn = 0.0
        #: the yaw rates of the ticks within lean_hold_s, (t_ns, rad/s)
        self._turns: deque[tuple[int, float]] = deque()
        self._hold_ns = round(self.settings.lean_hold_s * NS)
        vehicle = profile.vehicle
        self._wheelbase, self._ratio = vehicle.wheelbase_m, vehicle.steering_ratio

    def yaw_rate(self, world: World) -> float | None:
        """The ego's yaw rate (rad/s, left +): measured, or from the steering and speed."""
        ego = world.ego
        if ego.yaw_rate is not None:
            return ego.yaw_rate
        if ego.steering_wheel_angle is None or ego.speed is None:
            return None
        return ego.speed * self._curvature(ego.steering_wheel_angle, self._wheelbase,
                                           self._ratio)

    def update(self, t_ns: int, world: World) -> None:
        """Look at the world of one scene tick (``t_ns`` is the tick's log time; the objects'
        own times measure their motion)."""
        s = self.settings
        speed = world.ego.speed
        omega = self.yaw_rate(world)
        moving = speed is not None and speed >= s.min_speed
        last, self._last_tick = self._last_tick, t_ns
        if moving:
            if last is not None and 0 < t_ns - last <= NS:
                self._moving_ns += t_ns - last
            if omega is not None:
                self._max_turn = max(self._max_turn, abs(omega))
        self._lean(world, speed, omega, self._steady(t_ns, omega))
        judging = (speed is not None and omega is not None and speed >= s.min_speed
                   and abs(omega) >= s.min_yaw_rate)
        held = self._held
        seen: dict[tuple[str, int], _Held] = {}
        max_gap, baseline = self._max_gap_ns, self._baseline_ns
        # an observation already looked at (its time that of the last): its baseline as then,
        # where a baseline is longer than no time and a gap of none is no gap
        again = baseline > 0 and max_gap >= 0
        objects = world.objects
        for group, sensor in self._sensor_of.items():
            counts = self._counts[sensor]
            classified = group in self._classified
            found_group = objects.get(group)
            if not found_group:
                continue
            for obs in found_group.values():
                key = (group, obs.object_id)
                t = obs.t_ns
                found = held.get(key)
                if found is None or not 0 <= t - found[3] <= max_gap:
                    seen[key] = (t, obs.x, obs.y, t)  # new, lost for a while, or a clock step
                    continue
                if again and t == found[3]:
                    seen[key] = found
                    continue
                anchor_t, anchor_x, anchor_y, _ = found
                if t - anchor_t < baseline:
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
                    stationary = stationary and obs.object_class is self._stationary
                expected = -omega * (obs.x + anchor_x) / 2
                if not stationary or abs(expected) < s.min_sweep:
                    continue
                rate = (obs.y - anchor_y) / dt
                if abs(rate) < 0.25 * abs(expected):
                    continue
                counts[0 if (rate > 0) == (expected > 0) else 1] += 1
        self._held = seen

    def _steady(self, t_ns: int, omega: float | None) -> bool:
        """Whether the yaw rate held steady over the last lean_hold_s (a curve's or a straight
        road's, not a lane change's)."""
        turns = self._turns
        if omega is None or (turns and not 0 < t_ns - turns[-1][0] <= self._max_gap_ns):
            turns.clear()  # no yaw rate, a gap or a clock step: the hold starts again
        if omega is None:
            return False
        turns.append((t_ns, omega))
        while t_ns - turns[0][0] > self._hold_ns:
            turns.popleft()
        if t_ns - turns[0][0] < self._hold_ns * 0.9:
            return False
        rates = [r for _, r in turns]
        mean = sum(rates) / len(rates)
        band = max(self.settings.lean_steady_share * abs(mean), self.settings.lean_steady_rate)
        return max(rates) - mean <= band and mean - min(rates) <= band

    def _lean(self, world: World, speed: float | None, omega: float | None,
              steady: bool) -> None:
        """Follow the vehicles ahead; compare their lateral offsets as the curve changes."""
        s = self.settings
        if speed is None or omega is None or speed < s.lean_min_speed:
            self._leaning = {}
            return
        kappa = omega / speed
        held = self._leaning
        seen: dict[tuple[str, int], _Lean] = {}
        for group, sensor in self._sensor_of.items():
            for obs in world.objects.get(group, {}).values():
                x = obs.x
                if not 0.0 < x <= s.lean_max_x or abs(kappa) * x > s.lean_max_heading:
                    continue
                key = (group, obs.object_id)
                t = obs.t_ns
                state = held.get(key)
                if state is not None and t == state.t1:
                    seen[key] = state  # the same observation, a tick later
                    continue
                if state is None or not 0 < t - state.t1 <= self._max_gap_ns:
                    state = _Lean()  # new, lost for a while, or a clock step
                state.add(t, x, obs.y, kappa * x * x / 2, abs(omega), obs.vx)
                if t - state.t0 >= self._block_ns and state.n >= 3:
                    self._close_block(state, speed, sensor, steady)
                seen[key] = state
        self._leaning = seen

    def _close_block(self, state: _Lean, speed: float, sensor: str, steady: bool) -> None:
        """A vehicle's block is complete: compare it with an earlier one of another lean."""
        s = self.settings
        n = state.n
        rate = (state.x1 - state.x0) / ((state.t1 - state.t0) / NS)
        along = rate >= -0.5 * speed and (state.vxs == 0 or state.svx / state.vxs >= -0.5 * speed)
        point = (state.t1, state.sy / n, state.sp / n, state.sw / n)
        state.n = 0  # the next observation starts the next block
        points = state.points
        if not along:  # standing, oncoming or crossing: not a vehicle following the road
            points.clear()
            return
        self._lean_blocks[sensor] += 1
        if not steady:  # the ego changing lanes, or entering or leaving a curve
            return
        t, y, lean, turn = point
        for earlier_t, earlier_y, earlier_lean, earlier_turn in reversed(points):
            if t - earlier_t > self._window_ns:
                break
            expected = lean - earlier_lean
            if abs(expected) < s.min_lean or max(turn, earlier_turn) < s.lean_min_yaw_rate:
                continue
            moved = y - earlier_y
            if abs(moved) >= 0.25 * abs(expected):
                self._lean_counts[sensor][0 if (moved > 0) == (expected > 0) else 1] += 1
            points.clear()
            break
        points.append(point)
        while t - points[0][0] > self._window_ns:
            del points[0]

    def verdicts(self) -> list[LateralVerdict]:
        """Each sensor's verdict so far, in the profile's order."""
        return [self.verdict(sensor) for sensor in self._counts]

    def verdict(self, sensor: str) -> LateralVerdict:
        """One sensor's verdict so far."""
        s = self.settings
        against, with_turn = self._counts[sensor]
        into, out = self._lean_counts[sensor]
        lateral = self._lateral[sensor]
        other = "right" if lateral == "left" else "left"
        n, m = against + with_turn, into + out
        swept = _majority(against, with_turn, s.min_samples, s.agreement)
        leaned = _majority(into, out, s.min_lean_samples, s.agreement)

        def verdict(word: str, message: str) -> LateralVerdict:
            return LateralVerdict(sensor, word, lateral, against, with_turn, message, into, out)

        sweep = (f"stationary objects sweep against the turn in {against} of {n} samples"
                 if swept == "ok" else
                 f"stationary objects sweep WITH the turn in {with_turn} of {n} samples")
        lean = (f"vehicles ahead lean into the curves in {into} of {m} samples" if leaned == "ok"
                else f"vehicles ahead lean OUT of the curves in {out} of {m} samples")
        if swept is not None and leaned is not None and swept != leaned:
            return verdict("unknown", f"{sensor}: lateral sign not judged: {sweep}, but {lean}")
        found = swept or leaned
        if found is not None:
            said = (f"{sweep} and {lean.replace(' samples', '')}" if swept and leaned
                    else sweep if swept else lean)
            if found == "flipped":
                return verdict("flipped", f'{sensor}: {said}: lateral = "{lateral}" looks wrong, '
                                          f'try lateral = "{other}"')
            return verdict("ok", f'{sensor}: {said}: lateral = "{lateral}" agrees')
        return verdict("unknown", f"{sensor}: lateral sign not judged: "
                                  f"{self._why_not_swept(against, with_turn)}; "
                                  f"{self._why_not_leaned(sensor, into, out)}")

    def _why_not_swept(self, against: int, with_turn: int) -> str:
        """Why the stationary objects gave no verdict, with the figures."""
        s = self.settings
        n = against + with_turn
        if n >= s.min_samples:
            return (f"stationary objects sweep against the turn in {against} and with it in "
                    f"{with_turn} of {n} samples (no clear majority)")
        moving = self._moving_ns / NS
        if moving == 0:
            how = f"never drove at {s.min_speed:g} m/s or more"
        elif self._max_turn < s.min_yaw_rate:
            how = (f"turned at most {math.degrees(self._max_turn):.1f}°/s "
                   f"({math.degrees(s.min_yaw_rate):.1f}°/s needed) over {moving:.0f} s")
        else:
            how = (f"turned up to {math.degrees(self._max_turn):.1f}°/s over {moving:.0f} s, "
                   "with too few stationary objects in view")
        return (f"{n} samples of stationary objects while turning ({s.min_samples} needed): "
                f"{how}")

    def _why_not_leaned(self, sensor: str, into: int, out: int) -> str:
        """Why the vehicles ahead gave no verdict, with the figures."""
        s = self.settings
        m = into + out
        if m >= s.min_lean_samples:
            return (f"vehicles ahead lean into the curves in {into} and out of them in {out} of "
                    f"{m} samples (no clear majority)")
        text = f"{m} samples of vehicles ahead in curves ({s.min_lean_samples} needed)"
        if self._lean_blocks[sensor] == 0:
            return (f"{text}: no vehicle driving ahead within {s.lean_max_x:g} m at "
                    f"{s.lean_min_speed:g} m/s or more")
        if m == 0:
            return (f"{text}: no vehicle ahead in a curve (a turn of "
                    f"{math.degrees(s.lean_min_yaw_rate):.1f}°/s or more held for "
                    f"{s.lean_hold_s:g} s)")
        return text


def _majority(right: int, wrong: int, needed: int, agreement: float) -> str | None:
    """``"ok"`` or ``"flipped"`` when enough samples agree enough, else None."""
    n = right + wrong
    if n < needed:
        return None
    if wrong >= agreement * n:
        return "flipped"
    if right >= agreement * n:
        return "ok"
    return None
