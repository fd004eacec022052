"""The highway car: a production car at highway range, its factory radar and its chassis bus.

:func:`simulate_highway` yields, in non-decreasing timestamp order, every frame of a simulated
drive of a compact SUV with a factory radar on two buses, encoded against the bundled databases:

- ``can1``, the radar (``highway_radar.dbc``): every 50 ms the 16 track slots ``TRACK_A_0..15``
  (0x210..0x21F: LONG_DIST, LAT_DIST, REL_SPEED, VALID, NEW_TRACK) then ``TRACK_B_0..15``
  (0x220..0x22F: SCORE, REL_ACCEL), 32 frames 250 to 289 us apart, every slot every cycle (an
  empty or dropped slot: VALID = 0, every signal 0 but counter and checksum); a cycle whose last
  frame would fall at or after the end of the run is not sent. Cycle k measures at ``k * 50 ms``
  and is sent 2 to 6.3 ms later, its last frame within 15.3 ms of the measurement.
- ``can0``, the car (``highway_car.dbc``): ``KINEMATICS`` and ``STEER_ANGLE_SENSOR`` every 10 ms
  (STEER_BUTTON 1 while pressed: :data:`BUTTON_PRESSES`, 10.0-10.3 s and 40.0-40.3 s),
  ``WHEEL_SPEEDS`` (km/h) every 12 ms, ``SPEED`` (km/h, 1.5 % high) every 20 ms.
- ids the databases do not define: 0x2C4, 0x3B7, 0x4C8 on ``can0``, 0x2E0 on ``can1``
  (:mod:`bridge.sim.highway_body`; brake pressed 14-17 s and 45-48 s).

Other families send at their DBC cycle time: cycle k measures at ``k * cycle`` and is sent at the
start + the family's phase + ``k * cycle`` + jitter; every timestamp is ``start_ns`` plus whole
microseconds. Checksums (TRACK_A/B, SPEED): ``(id & 0xFF) + (id >> 8) + length + every byte before
it``, & 0xFF. LAT_DIST is positive to the RIGHT: vehicle y = ``-LAT_DIST`` (profile: ``lateral =
"right"``).

The scenario (:data:`HIGHWAY`, :mod:`bridge.sim.highway_world`), in seconds since the start (after
60 s the traffic drives on, twins and dropouts go on, nothing else happens):

- the ego at 30 m/s (+-0.25) in the middle of three 3.6 m lanes; a left curve from 20 s (curvature
  rising over 2 s to 1/(800 m), falling over 2 s to 0 at 40 s); steering wheel angle = 15.4 *
  atan(2.66 m * curvature);
- seven cars (metres ahead of the radar): ``lead`` in the ego lane 49-55; ``cut_in`` right lane,
  10 at the start, closing at 0.55 m/s; ``left_near`` 14-22; ``right_80`` 75-85; ``left_120``
  114-126; ``left_far`` 150, pulling away at 1.2 m/s, out of range (200 m) at 41.7 s; ``right_190``
  177-193;
- the cut-in: 36 to 39 s into the ego lane (crossing the line at 37.5 s), slowing to the ego's speed
  by 42 s, about 31 m ahead: the lead from 37.5 s (``lead`` before), 17.5 to 24 m nearer;
- slots: at the first cycle ``cut_in`` 0, ``left_near`` 1, ``lead`` 2, ``right_80`` 3,
  ``left_120`` 4, ``left_far`` 5, ``right_190`` 6; an object keeps its slot while in view; a new
  one takes the slot free longest, with NEW_TRACK = 1 on its first cycle;
- twins: every car but ``left_far`` is at times also in a second slot (1 to 6 s on, 1 to 5 s off,
  0.5 s steps, fixed per car; the lead's comes six times as the lead), within 1.5 m (nearly always
  1 m) and 0.3 m/s of the car, score 58-85 % (the car's own 91-100 %);
- dropouts: once every 10 s each car's own slot is invalid for 1 to 3 cycles (no NEW_TRACK after);
- noise (sd, cut at 2.5): position 0.06 m + 0.05 % (longitudinal) or 0.07 % (lateral) of range,
  relative speed 0.04 m/s, acceleration 0.15 m/s^2; a new track's score starts at 40 %, +15 % a
  cycle.

Other roads (``road=``, :data:`ROADS`), same traffic and events: ``"winding"`` (left 1000 m
4-12 s, right 1600 m 16-24 s, left 1600 m 28-35 s, right 900 m 40-48 s, left 1200 m 51-58 s),
``"straight"``, and ``"weaving"`` (straight; the ego changes lanes left 8-13 s, back 20-24 s,
right 32-37 s, back 46-52 s). Ground truth: :func:`slots_at`, :func:`twins_at`, :func:`lead_at`,
:func:`objects_at`, :func:`ego_at` (``highway=ROADS[...]``). The same seed gives byte-identical
frames; the seed changes noise, jitter, phases and counter starts, never the scenario.
"""

from __future__ import annotations

import functools
import heapq
import math
import random
from collections.abc import Callable, Iterator

import cantools

from bridge.frame import NS, Frame
from bridge.resources import data_dir
from bridge.sim.frames import US, Codec, Out, ticks
from bridge.sim.highway_body import body_families
from bridge.sim.highway_world import (
    HIGHWAY,
    RADAR_X_M,
    ROADS,
    SLOT_COUNT,
    TRACK_WIDTH_M,
    EgoTruth,
    Highway,
    ObjectTruth,
    SlotTruth,
    ego_at,
    lead_at,
    objects_at,
    slots_at,
    twin_episode,
    twins_at,
)
from bridge.sim.scenario import DEFAULT_START_NS

__all__ = ["BUTTON_PRESSES", "CAR_BUS", "HIGHWAY", "RADAR_BUS", "ROADS", "EgoTruth", "Highway",
           "ObjectTruth", "SlotTruth", "button_at", "ego_at", "lead_at", "objects_at",
           "simulate_highway", "slots_at", "twins_at"]

#: The buses of the highway car: the radar's and the car's own.
RADAR_BUS = "can1"
CAR_BUS = "can0"
#: The speedometer reads this much high.
SPEEDOMETER_GAIN = 1.015
#: Each wheel's rolling radius against the mean (FL, FR, RL, RR): their mean is 1.
_TYRES = (1.002, 0.999, 1.001, 0.998)
KMH = 3.6
#: The button on the wheel (STEER_ANGLE_SENSOR.STEER_BUTTON) is pressed from the first to the
#: second time (seconds after the start): the engineer marks two moments (``[marks]`` of the
#: highway profile).
BUTTON_PRESSES: tuple[tuple[float, float], ...] = ((10.0, 10.3), (40.0, 40.3))


def button_at(t: float) -> bool:
    """Whether the button on the wheel is pressed at ``t`` seconds after the start."""
    return any(start <= t < end for start, end in BUTTON_PRESSES)


@functools.lru_cache(maxsize=2)
def highway_database(name: str) -> cantools.database.can.Database:
    """A bundled highway database, ``radar`` or ``car`` (``highway_<name>.dbc``), loaded once."""
    path = data_dir() / f"highway_{name}.dbc"
    database = cantools.database.load_file(path)
    if not isinstance(database, cantools.database.can.Database):
        raise TypeError(f"{path} is not a CAN database")
    return database


def _with_checksum(codec: Codec, data: bytes) -> bytes:
    """``data`` with its last byte the checksum of the others (Toyota's rule)."""
    fid = codec.frame_id
    total = (fid & 0xFF) + (fid >> 8) + len(data) + sum(data[:-1])
    return data[:-1] + bytes((total & 0xFF,))


def _noise(rng: random.Random, sigma: float) -> float:
    """Gaussian measurement noise, cut at 2.5 sigma (a radar's errors have no long tails)."""
    return max(-2.5 * sigma, min(2.5 * sigma, rng.gauss(0.0, sigma)))


class _Run:
    """The timing and randomness the families of one run share."""

    def __init__(self, seed: int, start_ns: int, duration_s: float,
                 highway: Highway = HIGHWAY) -> None:
        self.seed = seed
        self.highway = highway
        self.start_ns = start_ns
        self.end_ns = start_ns + round(duration_s * NS)

    def rng(self, family: str) -> random.Random:
        return random.Random(f"tankviz-simulate-highway:{self.seed}:{family}")

    def ticks(self, rng: random.Random, cycle_ms: int, phase_us: tuple[int, int],
              jitter_us: int = 200) -> Iterator[tuple[int, int]]:
        """:func:`bridge.sim.frames.ticks` of this run."""
        return ticks(rng, self.start_ns, self.end_ns, cycle_ms, phase_us, jitter_us)


# ---------------------------------------------------------------------------------------------
# The radar bus
# ---------------------------------------------------------------------------------------------


def _radar(run: _Run, db: cantools.database.can.Database) -> Iterator[Frame]:
    rng = run.rng("radar")
    out = Out(RADAR_BUS)
    codecs_a = [Codec(db, f"TRACK_A_{i}") for i in range(SLOT_COUNT)]
    codecs_b = [Codec(db, f"TRACK_B_{i}") for i in range(SLOT_COUNT)]
    counter = rng.randrange(256)
    empty: dict[tuple[int, int], bytes] = {}
    age = [0] * SLOT_COUNT
    top = [100] * SLOT_COUNT

    def blank(codec: Codec) -> bytes:
        data = empty.get((codec.frame_id, counter))
        if data is None:
            values: dict[str, float] = {s.name: 0 for s in codec.message.signals}
            values["COUNTER"] = counter
            data = empty[(codec.frame_id, counter)] = _with_checksum(codec, codec.encode(values))
        return data

    for tick, ts in run.ticks(rng, 50, (2000, 6000), 300):
        times = [ts]
        for _ in range(2 * SLOT_COUNT - 1):
            times.append(times[-1] + (250 + rng.randrange(40)) * US)
        if times[-1] >= run.end_ns:
            return
        t = tick / NS
        slots = slots_at(t, run.highway)
        truth = {o.name: o for o in objects_at(t, run.highway)}
        part_a: list[bytes] = []
        part_b: list[bytes] = []
        for i, slot in enumerate(slots):
            if slot is None or not slot.valid:
                if slot is None:
                    age[i] = 0
                part_a.append(blank(codecs_a[i]))
                part_b.append(blank(codecs_b[i]))
                continue
            if slot.new:
                age[i] = 0
                top[i] = rng.randint(60, 85) if slot.twin else rng.randint(93, 100)
            age[i] += 1
            o = truth[slot.name]
            x, y, vx, ax = o.x - RADAR_X_M, o.y, o.vx, o.ax
            if slot.twin:
                episode = twin_episode(slot.name, t)
                if episode is not None:
                    x, y, vx = x + episode.dx, y + episode.dy, vx + episode.dv
            r = math.hypot(x, y)
            x += _noise(rng, 0.06 + 0.0005 * r)
            y += _noise(rng, 0.06 + 0.0007 * r)
            vx += _noise(rng, 0.04)
            ax += rng.gauss(0.0, 0.15)
            score = min(top[i], 25 + 15 * age[i]) - rng.randrange(3)
            a, b = codecs_a[i], codecs_b[i]
            part_a.append(_with_checksum(a, a.encode({
                "COUNTER": counter, "LONG_DIST": x, "LAT_DIST": -y,  # positive to the RIGHT
                "REL_SPEED": vx, "VALID": 1, "NEW_TRACK": int(slot.new), "CHECKSUM": 0})))
            part_b.append(_with_checksum(b, b.encode({
                "COUNTER": counter, "SCORE": score, "REL_ACCEL": ax, "CHECKSUM": 0})))
        codecs = codecs_a + codecs_b
        for when, codec, data in zip(times, codecs, part_a + part_b, strict=True):
            yield out.frame(when, codec, data)
        counter = (counter + 1) % 256


# ---------------------------------------------------------------------------------------------
# The car bus
# ---------------------------------------------------------------------------------------------

Values = Callable[[EgoTruth, random.Random, Highway], dict[str, float]]


def _kinematics(ego: EgoTruth, rng: random.Random, highway: Highway) -> dict[str, float]:
    return {"YAW_RATE": math.degrees(ego.yaw_rate) + rng.gauss(0.0, 0.03),
            "ACCEL_X": ego.accel + rng.gauss(0.0, 0.03),
            "ACCEL_Y": ego.lateral_accel + rng.gauss(0.0, 0.03)}


def _steering(ego: EgoTruth, rng: random.Random, highway: Highway) -> dict[str, float]:
    tenths = round((math.degrees(ego.steering_wheel_angle) + rng.gauss(0.0, 0.04)) * 10)
    coarse = round(tenths / 15)
    rate = math.degrees(ego_at(ego.t + 0.01, highway).steering_wheel_angle
                        - ego_at(ego.t - 0.01, highway).steering_wheel_angle) / 0.02
    return {"STEER_ANGLE": coarse * 1.5, "STEER_FRACTION": (tenths - 15 * coarse) / 10,
            "STEER_RATE": rate + rng.gauss(0.0, 0.5), "STEER_BUTTON": int(button_at(ego.t))}


def _wheel_speeds(ego: EgoTruth, rng: random.Random, highway: Highway) -> dict[str, float]:
    side = ego.curvature * TRACK_WIDTH_M / 2  # the outer wheels run faster
    out = {}
    for name, lateral, tyre in (("FL", -side, _TYRES[0]), ("FR", side, _TYRES[1]),
                                ("RL", -side, _TYRES[2]), ("RR", side, _TYRES[3])):
        kmh = ego.speed * (1.0 + lateral) / tyre * KMH
        out[f"WHEEL_SPEED_{name}"] = kmh + rng.gauss(0.0, 0.04)
    return out


def _speed(ego: EgoTruth, rng: random.Random, highway: Highway) -> dict[str, float]:
    return {"SPEED": ego.speed * KMH * SPEEDOMETER_GAIN + rng.gauss(0.0, 0.02), "CHECKSUM": 0}


def _car(run: _Run, db: cantools.database.can.Database, name: str, cycle_ms: int,
         values: Values, checksum: bool = False) -> Iterator[Frame]:
    rng = run.rng(name)
    codec = Codec(db, name)
    out = Out(CAR_BUS)
    for tick, ts in run.ticks(rng, cycle_ms, (0, cycle_ms * 1000 // 2)):
        if ts >= run.end_ns:
            return
        data = codec.encode(values(ego_at(tick / NS, run.highway), rng, run.highway))
        yield out.frame(ts, codec, _with_checksum(codec, data) if checksum else data)


def simulate_highway(*, duration_s: float = 60.0, seed: int = 0,
                     start_ns: int = DEFAULT_START_NS, road: str = "curve") -> Iterator[Frame]:
    """Frames of the simulated highway drive on ``can1`` (radar) and ``can0`` (car), in
    non-decreasing timestamp order, ``start_ns <= timestamp < start_ns + duration``.

    - ``duration_s``: seconds of driving; the scenario's events are at fixed seconds (module
      docstring), so a run shorter than 60 s has only those before its end.
    - ``seed``: noise, jitter, phases and counters; the same seed gives identical frames.
    - ``start_ns``: the start of the run (default: 2026-01-01T12:00:00Z).
    - ``road``: ``"curve"`` (the scenario's one left-hand curve), ``"winding"`` (five curves of
      1 to 2 deg/s, left and right), ``"straight"``, or ``"weaving"`` (straight, the ego
      changing lanes): the same traffic on another road.
    """
    return _simulate(duration_s, seed, start_ns, road, unknown=True)


def _simulate(duration_s: float, seed: int, start_ns: int, road: str, *,
              unknown: bool) -> Iterator[Frame]:
    """:func:`simulate_highway`; ``unknown=False`` leaves out the ids the databases do not
    define (:mod:`bridge.sim.highway_body`), which change no other frame (tests compare)."""
    if not duration_s > 0 or not math.isfinite(duration_s):
        raise ValueError(f"duration_s must be a positive number of seconds, not {duration_s!r}")
    if road not in ROADS:
        raise ValueError(f"road must be one of {', '.join(ROADS)}, not {road!r}")
    run = _Run(seed, start_ns, duration_s, ROADS[road])
    car = highway_database("car")
    families = [
        _radar(run, highway_database("radar")),
        _car(run, car, "KINEMATICS", 10, _kinematics),
        _car(run, car, "STEER_ANGLE_SENSOR", 10, _steering),
        _car(run, car, "WHEEL_SPEEDS", 12, _wheel_speeds),
        _car(run, car, "SPEED", 20, _speed, checksum=True),
    ]
    if unknown:
        families += body_families(run, car_bus=CAR_BUS, radar_bus=RADAR_BUS,
                                  speedometer_gain=SPEEDOMETER_GAIN)
    return heapq.merge(*families)
