"""The front radar: RadarHeader, RadarObj0..31 (A and B) and RadarStatus, y positive LEFT.

Every actor the radar covers plus spurious detections from the seed, nearest first, each keeping
its slot while visible; the faults of :class:`bridge.sim.scenario.Faults` (dropout, misalignment,
blindness, slowness) act on transmit times.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterator
from dataclasses import dataclass

from bridge.frame import NS, Frame
from bridge.sim.frames import MS, US, Codec, Run, Slots
from bridge.sim.scenario import MISALIGNMENT_DEG, RADAR_SLOW_EVERY
from bridge.sim.sensors import Seen
from bridge.sim.world import CLASS_STATIONARY, CLASS_UNKNOWN


def _quantize_prob(value: float) -> float:
    return round(value / 3.125) * 3.125


def _moving_state(seen: Seen) -> int:
    if seen.actor.radar_class == CLASS_STATIONARY:
        return 4  # standing
    if seen.v_abs < -1.0:
        return 2  # oncoming
    return 1 if abs(seen.v_abs) > 0.5 else 3  # moving / stopped


@dataclass(frozen=True)
class _Ghost:
    key: Hashable
    t0: float
    t1: float
    x: float
    y: float
    prob: float


def _ghosts(run: Run) -> list[_Ghost]:
    """Spurious radar detections: short-lived, low existence probability, random places."""
    rng = run.rng("ghosts")
    count = max(6, round(1.2 * run.duration_s))
    ghosts = []
    for j in range(count):
        t0 = rng.uniform(0.0, run.duration_s)
        ghosts.append(_Ghost(("ghost", j), t0, t0 + rng.uniform(0.3, 1.2),
                             rng.uniform(8.0, 90.0), rng.uniform(-14.0, 14.0),
                             rng.choice([6.25, 9.375, 12.5, 15.625, 18.75, 21.875, 25.0, 28.125])))
    return ghosts


# A sensor pointing MISALIGNMENT_DEG to the left sees the world rotated clockwise by that angle.
_MISALIGNED_COS = math.cos(math.radians(-MISALIGNMENT_DEG))
_MISALIGNED_SIN = math.sin(math.radians(-MISALIGNMENT_DEG))


def radar(run: Run) -> Iterator[Frame]:
    """RadarHeader (CAN-FD) then RadarObj0..31 A and B every 50 ms, back to back.

    Every actor the radar covers (:mod:`bridge.sim.sensors`), then spurious detections from the seed
    (:func:`_ghosts`: short-lived, low existence probability, class unknown, stationary, in about 60
    % of cycles), nearest first; an object keeps its slot while visible, an unused slot is invalid
    (every signal 0 but the counter). Real objects have their actor's class, size and cross section,
    existence probability above 80 % and ``Tracked`` from their third cycle, noise growing with
    range. The header carries the object count and valid mask, a cycle counter, a microsecond
    timestamp since power-up, the ego speed and yaw rate used, and the latency.

    Faults (on transmit times): ``radar_dropout`` (nothing sent in the window; after it new slots);
    ``radar_misalignment`` (detections rotated :data:`~bridge.sim.scenario.MISALIGNMENT_DEG`
    clockwise); ``radar_blind`` (every slot "no object"); ``radar_slow`` (one cycle in
    :data:`~bridge.sim.scenario.RADAR_SLOW_EVERY`).
    """
    rng = run.rng("Radar")
    header = run.codec("RadarHeader")
    objs = [(run.codec(f"RadarObj{i}_A"), run.codec(f"RadarObj{i}_B")) for i in range(32)]
    counter = rng.randrange(16)
    cycle_counter = rng.randrange(65536)
    power_up_us = rng.randrange(60_000_000, 900_000_000)
    ghosts = sorted(_ghosts(run), key=lambda g: g.t0)
    next_ghost = 0
    active: list[_Ghost] = []
    slots = Slots(32)
    age: dict[Hashable, int] = {}
    empty_cache: dict[tuple[int, int], bytes] = {}
    faults = run.faults
    dropout = faults.radar_dropout
    misaligned = faults.radar_misalignment
    blind, slow = faults.radar_blind, faults.radar_slow
    n_frames = 1 + 2 * len(objs)
    for tick, ts in run.ticks(rng, 50, (2000, 8000), 300):
        times = run.burst(rng, ts, n_frames)
        if times[0] >= run.end_ns:
            return
        if times[0] < dropout[1] and times[-1] >= dropout[0]:
            slots.clear()  # the radar restarts its tracker after the outage
            age.clear()
            continue
        if slow[0] <= times[0] < slow[1] and (tick // (50 * MS)) % RADAR_SLOW_EVERY:
            continue
        snap = run.world.at(tick)
        t = snap.t
        ego = snap.ego
        # Measurements: (key, x, y, vx, vy, ax, seen or None, prob)
        detections: list[tuple[Hashable, float, float, float, float, float, Seen | None,
                               float]] = []
        for o in snap.objects:
            if o.radar:
                detections.append((o.key, o.x, o.y, o.vx, o.vy, o.ax, o, 0.0))
        while next_ghost < len(ghosts) and ghosts[next_ghost].t0 <= t:
            active.append(ghosts[next_ghost])
            next_ghost += 1
        active = [g for g in active if t < g.t1]
        for g in active:  # ground clutter: it stays where it is while the ego passes
            if rng.random() < 0.6:
                x = g.x - ego.v * (t - g.t0)
                if x > 1.0:
                    detections.append((g.key, x, g.y, -ego.v, 0.0, 0.0, None, g.prob))
        detections.sort(key=lambda m: (m[6] is None, m[1] * m[1] + m[2] * m[2]))
        by_key = {m[0]: m for m in detections}
        owners = slots.assign([m[0] for m in detections])
        if blind[0] <= times[0] < blind[1]:
            owners = [None] * len(objs)  # blocked: every slot reports "no object"
        for key in [k for k in age if k not in by_key]:
            del age[key]
        rotate = misaligned[0] <= times[0] < misaligned[1]
        ca, sa = _MISALIGNED_COS, _MISALIGNED_SIN
        mask = 0
        frames: list[tuple[Codec, bytes]] = []
        for slot, (codec_a, codec_b) in enumerate(objs):
            key = owners[slot]
            if key is None:
                for codec in (codec_a, codec_b):
                    cache_key = (codec.frame_id, counter)
                    data = empty_cache.get(cache_key)
                    if data is None:
                        values: dict[str, float] = {s.name: 0 for s in codec.message.signals}
                        values["Counter"] = counter
                        data = empty_cache[cache_key] = codec.encode(values)
                    frames.append((codec, data))
                continue
            mask |= 1 << slot
            _, x, y, vx, vy, ax, seen, prob = by_key[key]
            n = age[key] = age.get(key, 0) + 1
            r = math.hypot(x, y)
            x += rng.gauss(0, 0.08 + 0.0015 * r)
            y += rng.gauss(0, 0.08 + 0.0026 * r)
            vx += rng.gauss(0, 0.06)
            vy += rng.gauss(0, 0.15)
            ax += rng.gauss(0, 0.1)
            if rotate:
                x, y = x * ca - y * sa, x * sa + y * ca
                vx, vy = vx * ca - vy * sa, vx * sa + vy * ca
            if seen is None:  # a ghost
                cls, prob_class, moving, rcs = CLASS_UNKNOWN, 25.0, 0, -12.0
                length, width, obstacle = 0.5, 0.5, 9.375
            else:
                actor = seen.actor
                prob = 84.375 if n < 3 else _quantize_prob(rng.uniform(90.0, 96.875))
                cls, moving, rcs = actor.radar_class, _moving_state(seen), actor.rcs
                prob_class = _quantize_prob(rng.uniform(75.0, 96.875))
                length, width = actor.length, actor.width
                obstacle = 40.625 if cls == CLASS_STATIONARY else 90.625
            frames.append((codec_a, codec_a.encode({
                "LongDist": x, "LongSpeed": vx, "LatDist": y, "ProbExist": prob,
                "LongAccel": ax, "Valid": 1, "Meas": 0 if rng.random() < 0.04 else 1,
                "Tracked": 1 if n >= 3 else 0, "ProbObstacle": obstacle, "Counter": counter})))
            frames.append((codec_b, codec_b.encode({
                "LatSpeed": vy, "Length": length, "Width": width, "MovingState": moving,
                "ProbClass": prob_class, "Class": cls, "RCS": rcs + rng.gauss(0, 1.5),
                "Counter": counter})))
        run.radar_object_count = bin(mask).count("1")
        head = header.encode({
            "CycleCounter": cycle_counter, "ObjectCount": run.radar_object_count, "RadarMode": 1,
            "Timestamp": (power_up_us + tick // US) % 2**32,
            "EgoSpeedUsed": ego.v + rng.gauss(0, 0.02),
            "EgoYawRateUsed": math.degrees(ego.v * ego.kappa) + rng.gauss(0, 0.03),
            "ObjValidMask": mask, "Latency": 22.0 + rng.uniform(0.0, 6.0)})
        out = run.out
        yield out.frame(times[0], header, head)
        for when, (codec, data) in zip(times[1:], frames, strict=True):
            if when >= run.end_ns:
                return
            yield out.frame(when, codec, data)
        counter = (counter + 1) % 16
        cycle_counter = (cycle_counter + 1) % 65536


def radar_status(run: Run) -> Iterator[Frame]:
    """``RadarStatus`` every 100 ms: misalignment, state, temperature, the latest cycle's object
    count. After ``radar_dropout`` it reports init and no objects for 300 ms;
    ``HorizontMisalignment`` says the misalignment only if ``misalignment_reported``.
    """
    rng = run.rng("RadarStatus")
    codec = run.codec("RadarStatus")
    counter = rng.randrange(codec.counter_mod)
    dropout = run.faults.radar_dropout
    misaligned = run.faults.misalignment_reported
    for tick, ts in run.ticks(rng, 100, (40_000, 60_000)):
        if ts >= run.end_ns:
            return
        if dropout[0] <= ts < dropout[1]:
            continue
        t = tick / NS
        bias = MISALIGNMENT_DEG if misaligned[0] <= ts < misaligned[1] else 0.0
        restarting = dropout[1] <= ts < dropout[1] + 300 * MS
        values: dict[str, float] = {
            "HorizontMisalignment": bias + rng.choice((-0.05, 0.0, 0.0, 0.05)),
            "VerticalMisalignment": rng.choice((0.0, 0.1)),
            "SensorDirty": 0, "HWFail": 0, "Blocked": 0, "AlignmentInProgress": 0,
            "Interference": 0,
            "RadarState": 0 if restarting else 1,  # init after the outage, else ok
            "Temperature": 41.0 + 0.02 * t,
            "ObjectCount": 0 if restarting else run.radar_object_count,
            "Counter": counter,
        }
        yield run.out.frame(ts, codec, codec.encode(values))
        counter = (counter + 1) % codec.counter_mod
