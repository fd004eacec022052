#!/usr/bin/env python3
"""Benchmark ``tankviz convert`` against fixed references in the same run (a report, not a test).

Issue #15's yardstick: every figure is a ratio against reference code that runs in the same
process run, interleaved with tankviz (round-robin, ``--runs`` rounds, default 3, the best of
them counts), never an absolute time. The times compared are elapsed times (what a user waits:
the fair measure now that tankviz reads ahead on a second core); ``--clock cpu`` compares CPU
times instead (user + system of the contender's process and its children, or of this process
for the in-process references), which a loaded shared machine disturbs far less, and which
counts the second core's work as a cost. Each ratio of a convert shows the other clock's in
brackets, and the details print both. tankviz's sources are compiled to bytecode first (pip
does it when it installs tankviz; a source tree under ``PYTHONDONTWRITEBYTECODE`` would compile
them again in every run, about 0.2 s). The contenders, on the simulated drive (below) as BLF and
as ASC (the same frames, python-can's ``ASCWriter``):

- bare ``can.LogReader`` iteration (the floor: python-can's reading alone);
- the naive converter, raw + decoded: LogReader → cantools ``decode_message`` →
  ``mcap_protobuf.writer.Writer`` (zstd), writing raw frames on the same topics
  (``/can/<bus>/frames``, one :class:`bridge.pb.can_frame_pb2.CanFrame` a frame, as tankviz did
  before it wrote them in blocks, :mod:`bridge.sinks.raw`) and decoded messages
  (``/can/<bus>/<Message>``, the very protobuf types tankviz generates, from
  :class:`bridge.decode.proto_schema.MessageSchema`);
- the naive converter with the scene: the same, plus :func:`naive_scene` at 20 Hz of log time,
  the ecocar categories drawn the straightforward way into ``foxglove.SceneUpdate`` on tankviz's
  topics ``/scene/{ego,lanes,radar,camera,tracks,lead}`` (ego box; each valid camera lane as a
  100-point line of its cubic; radar/camera detections, fusion tracks and the lead as labelled
  boxes) from the newest decoded values. It never imports tankviz's pipeline; tankviz writes
  more (``/scene/mio``, ``/scene/health``, ``/perception/*``, ``/ego``, ``/health``, ``/tf``),
  so this comparison flatters the reference;
- ``tankviz convert --dbc ecocar`` (raw + decoded) and ``tankviz convert --profile ecocar``
  (with the scene), each in a subprocess timed from outside (interpreter start-up included),
  with the peak RSS of that process alone (``os.wait4``).

The naive and tankviz outputs must hold the same number of messages on every topic the naive
converter writes (a scene topic may differ by one tick); a difference prints ``WARNING``.

Also measured in the same run:

- a public real-format log: a candump (``.log``) of a production car's bus, generated from a
  public DBC in ``../shared/data/dbc`` (default ``gm_global_a_object.dbc``, GM's object bus:
  it has rolling counters and checksums; the Ford DBCs have neither, nor any
  ``GenMsgCycleTime``; ``--real-dbc`` picks another), see :func:`real_frames`; bare reading,
  naive and tankviz raw + decoded, interleaved; skipped with a note when the DBC is absent;
- start-up: ``python -c pass``, importing what ``convert`` imports, ``tankviz --help``, and a 1 s
  log (2,400 frames) converted with the scene; the share of that convert spent importing;
- archive size / BLF size for tankviz raw only (one more run, no ``--dbc``), raw + decoded and
  with the scene (and the naive converter's, for comparison), and how much of each is message
  indexes (:func:`index_bytes`: the floor no compression lowers);
- memory: tankviz with the scene on a longer drive (``--frames2``, one run): peak RSS against
  the main drive's, and the time of one hour of driving, extrapolated.

Output: first the ratios of issue #15's table (measure, now, goal, ok/MISSED), then
``TARGET MISSED: ...`` lines, then the details (frames/s and peak RSS of every contender, sizes,
start-up, load average). Progress goes to stderr as it comes. ``--json FILE`` writes the rows
and the details for ``tools/bench_report.py``. The exit status is 0 regardless: a report.

The synthetic drive uses the bundled ecocar DBC on three buses (python-can channel N is tankviz
bus ``canN`` in a BLF):

- ``can0`` radar (CAN FD): RadarHeader (64-byte FD frame) + RadarObj0..31 _A/_B every 50 ms,
  RadarStatus every 100 ms;
- ``can1`` camera: CamObstacle0..9 _A/_B and CamLane* every 66 ms;
- ``can2`` vehicle: EgoMotion, Steering (10 ms), DriverInputs (20 ms), EgoPosition (100 ms),
  FusionTrack0..19 + LeadVehicle (50 ms), the multiplexed SensorDiag (1 s) and one id that the
  DBC does not define (20 ms), as every real vehicle bus has.

Cycle times are the DBC's ``GenMsgCycleTime``; frames of a burst are serialised on their bus at
the bus bit rate (500 kbit/s, 2 Mbit/s data phase for FD) with ±0.1 ms jitter per cycle.
Payloads repeat the way real traffic does, only partly: every message with a ``Counter`` signal
carries a rolling counter, EgoMotion/Steering a checksum over bytes 0..6; physical values come from
a small world model (ego speed profile with stops, road curvature, traffic appearing and leaving,
stationary roadside targets, pedestrians) plus sensor noise, quantised by each signal's
resolution. So moving objects change every cycle, an empty radar/fusion slot is all zero but its
counter, a static status message repeats exactly apart from its counter, and a standing car
repeats more than a moving one. The generator prints how often payloads repeat.

Generated logs (BLF, its ASC copy, the candump log) are cached in ``--workdir`` (default:
``$TMPDIR/tankviz-bench``), keyed by frame count, seed and generator version, so re-runs do not
regenerate them; the outputs go to ``--workdir/out``.

    python tools/bench_convert.py --quick      # 200k / 400k simulated, 50k real frames
    python tools/bench_convert.py              # 1.44M (about 600 s) / 2.88M, 135k real frames
    python tools/bench_convert.py --frames 5000 --frames2 10000 --real-frames 5000 --runs 1
"""

from __future__ import annotations

import argparse
import compileall
import heapq
import json
import math
import os
import random
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import can
import cantools
from cantools.database.can.database import Database
from cantools.database.can.message import Message as DbcMessage

from bridge.decode.decoder import load_database
from bridge.resources import data_dir

#: Bumped whenever the generated traffic changes, so cached logs are not reused.
GENERATOR_VERSION = 1
ECOCAR_DBC = data_dir() / "ecocar.dbc"
#: Absolute start of the synthetic drive (python-can float seconds).
T0 = 1_700_000_000.0
MB = 1024 * 1024

RADAR, CAMERA, VEHICLE = 0, 1, 2
BUS_NAMES = {RADAR: "radar", CAMERA: "camera", VEHICLE: "vehicle"}
#: An id on the vehicle bus that the DBC does not define.
UNKNOWN_ID = 0x3F0



# --------------------------------------------------------------------------------------------
# Payloads: physical values → raw (quantised) → bytes, with rolling counter and checksum


class Encoder:
    """One DBC message: physical values to payloads, quantised by each signal's resolution.

    Signals not given are raw 0. The ``Counter`` signal (if any) rolls on every payload; a
    ``Checksum`` signal (byte 7) is the sum of bytes 0..6, as the DBC comments define it. Each
    distinct raw value set is encoded by cantools once (bounded memo).
    """

    def __init__(self, message: DbcMessage, rng: random.Random) -> None:
        self.message = message
        self.frame_id: int = message.frame_id
        self.is_fd: bool = bool(message.is_fd)
        self._zero: dict[str, int | float] = {s.name: 0 for s in message.signals}
        self._limits: dict[str, tuple[float, float, float, float, bool]] = {}
        for s in message.signals:
            if s.is_float:
                lo, hi = -math.inf, math.inf
            elif s.is_signed:
                lo, hi = -(2 ** (s.length - 1)), 2 ** (s.length - 1) - 1
            else:
                lo, hi = 0, 2**s.length - 1
            self._limits[s.name] = (float(s.scale), float(s.offset), lo, hi, bool(s.is_float))
        names = {s.name: s for s in message.signals}
        self._counter_mask = (1 << names["Counter"].length) - 1 if "Counter" in names else 0
        self.counter = rng.randrange(self._counter_mask + 1) if self._counter_mask else 0
        self._checksum = "Checksum" in names
        if self._checksum:
            probe = message.encode(self._zero | {"Checksum": 0xFF}, scaling=False,
                                   padding=False, strict=False)
            assert probe == bytes(7) + b"\xff", f"{message.name}: checksum is not byte 7"
        self._memo: dict[tuple[Any, ...], bytes] = {}

    def raw(self, physical: dict[str, float]) -> dict[str, int | float]:
        out: dict[str, int | float] = {}
        for name, value in physical.items():
            scale, offset, lo, hi, is_float = self._limits[name]
            if is_float:
                out[name] = value
                continue
            r = round((value - offset) / scale)
            out[name] = int(lo if r < lo else hi if r > hi else r)
        return out

    def payload(self, physical: dict[str, float]) -> bytes:
        values = self.raw(physical)
        if self._counter_mask:
            values["Counter"] = self.counter
            self.counter = (self.counter + 1) & self._counter_mask
        key = tuple(values.items())
        data = self._memo.get(key)
        if data is None:
            data = bytes(self.message.encode(self._zero | values, scaling=False, padding=False,
                                             strict=False))
            if self._checksum:
                data = data[:7] + bytes([sum(data[:7]) & 0xFF]) + data[8:]
            if len(self._memo) >= 64:
                self._memo.clear()
            self._memo[key] = data
        return data


# --------------------------------------------------------------------------------------------
# The world: ego motion, road, traffic


@dataclass
class Target:
    """Something the sensors see, relative to the ego vehicle (x forward, y left)."""

    ident: int
    cls: int  # 1 four-wheel, 2 two-wheel, 3 pedestrian, 4 stationary
    x: float
    y: float
    speed: float  # absolute longitudinal speed, m/s
    vy: float
    ax: float
    length: float
    width: float
    rcs: float
    prob_obstacle: float
    prob_class: float
    life: float  # seconds left before it turns off / leaves
    age: float = 0.0
    alive: bool = True


@dataclass
class World:
    rng: random.Random
    t: float = 0.0  # seconds since the start
    v: float = 0.0  # ego speed m/s
    a: float = 0.0
    target_v: float = 20.0
    next_target_change: float = 5.0
    yaw_rate: float = 0.0  # rad/s
    kappa: float = 0.0
    heading: float = 0.3
    lat: float = 48.7758
    lon: float = 9.1829
    lane_offset: float = 0.0  # ego lateral position in its lane, + left
    multi_lane: bool = True
    next_lane_change: float = 40.0
    targets: list[Target] = field(default_factory=list)
    next_ident: int = 1

    def advance(self, t: float) -> None:
        dt = t - self.t
        if dt <= 0:
            return
        self.t = t
        rng = self.rng
        if t >= self.next_target_change:  # traffic lights, limits, queues
            r = rng.random()
            self.target_v = 0.0 if r < 0.2 else rng.choice((8.0, 14.0, 22.0, 27.0, 33.0))
            self.next_target_change = t + (rng.uniform(10, 25) if self.target_v == 0
                                           else rng.uniform(20, 60))
        if t >= self.next_lane_change:
            self.multi_lane = not self.multi_lane
            self.next_lane_change = t + rng.uniform(30, 90)
        a = max(-3.0, min(1.5, 0.4 * (self.target_v - self.v)))
        self.a = a
        self.v = max(0.0, self.v + a * dt)
        if self.v == 0.0:
            self.a = 0.0
        self.kappa = 0.002 * math.sin(2 * math.pi * t / 90) + 0.001 * math.sin(2 * math.pi * t / 37)
        self.yaw_rate = self.v * self.kappa
        self.heading += self.yaw_rate * dt
        self.lat += self.v * dt * math.cos(self.heading) / 111_111
        self.lon += self.v * dt * math.sin(self.heading) / 73_000
        self.lane_offset = 0.3 * math.sin(2 * math.pi * t / 23) + 0.1 * math.sin(t / 3.1)
        for o in self.targets:
            o.ax += (-0.5 * o.ax) * dt + rng.gauss(0, 0.3) * math.sqrt(dt)
            if o.cls in (1, 2):
                o.speed = max(0.0, o.speed + o.ax * dt)
                if self.v == 0.0 and o.x > 0:  # the queue in front stops too
                    o.speed = max(0.0, o.speed - 3 * dt)
            o.x += (o.speed - self.v) * dt
            o.y += o.vy * dt
            o.age += dt
            o.life -= dt
            if o.life <= 0 or o.x < -10 or o.x > 230 or abs(o.y) > 40:
                o.alive = False
        self.targets = [o for o in self.targets if o.alive]
        if rng.random() < 0.8 * dt and len(self.targets) < 40:
            self._spawn()

    def _spawn(self) -> None:
        rng = self.rng
        r = rng.random()
        ident = self.next_ident
        self.next_ident += 1
        lane = rng.choice((-3.6, 0.0, 3.6)) if self.multi_lane else 0.0
        if r < 0.35 and self.v > 3:  # roadside: poles, signs, parked cars
            o = Target(ident, 4, rng.uniform(150, 200), rng.choice((-1, 1)) * rng.uniform(5, 12),
                       0.0, 0.0, 0.0, 0.5, 0.5, rng.uniform(-5, 15), 40.0, 60.0,
                       rng.uniform(10, 30))
        elif r < 0.45:  # pedestrian near the road
            o = Target(ident, 3, rng.uniform(20, 70), rng.choice((-1, 1)) * rng.uniform(4, 8),
                       0.0, rng.uniform(-1.2, 1.2), 0.0, 0.5, 0.6, rng.uniform(-15, -5), 70.0,
                       75.0, rng.uniform(5, 15))
        elif r < 0.55:  # two-wheeler
            o = Target(ident, 2, rng.uniform(20, 120), lane + rng.gauss(0, 0.3),
                       max(0.0, self.v + rng.uniform(-4, 4)), 0.0, 0.0, 2.0, 0.8,
                       rng.uniform(-5, 5), 80.0, 65.0, rng.uniform(20, 60))
        else:  # car or truck in a lane
            o = Target(ident, 1, rng.uniform(15, 150), lane + rng.gauss(0, 0.3),
                       max(0.0, self.v + rng.uniform(-5, 5)), rng.gauss(0, 0.05), 0.0,
                       rng.choice((4.5, 4.8, 12.0)), rng.choice((1.8, 1.9, 2.5)),
                       rng.uniform(5, 25), 90.0, 85.0, rng.uniform(20, 120))
        self.targets.append(o)


class Slots:
    """Sensor object slots: a target keeps its slot while the sensor sees it."""

    def __init__(self, n: int, sees: Callable[[Target], bool]) -> None:
        self.slots: list[Target | None] = [None] * n
        self.sees = sees

    def update(self, targets: list[Target]) -> list[Target | None]:
        held = set()
        for i, o in enumerate(self.slots):
            if o is not None and (not o.alive or not self.sees(o)):
                self.slots[i] = None
            elif o is not None:
                held.add(o.ident)
        free = [i for i, o in enumerate(self.slots) if o is None]
        for o in sorted(targets, key=lambda o: o.x):
            if not free:
                break
            if o.ident not in held and self.sees(o):
                self.slots[free.pop(0)] = o
        return self.slots


# --------------------------------------------------------------------------------------------
# Bursts: what each node sends in one cycle


Out = list[tuple[Encoder, bytes]]


class Traffic:
    """The three buses' bursts, reading the world at the time they fire."""

    def __init__(self, db: Database, rng: random.Random) -> None:
        self.rng = rng
        self.world = World(rng)
        self.enc = {m.name: Encoder(m, rng) for m in db.messages}
        self.radar = Slots(32, lambda o: 0.5 < o.x < 250 and abs(o.y) < 0.8 * o.x + 5)
        self.camera = Slots(10, lambda o: o.cls != 4 and 2 < o.x < 120 and abs(o.y) < 20)
        self.fusion = Slots(20, lambda o: 0 < o.x < 150 and abs(o.y) < 20)
        self.radar_cycle = 0
        self.camera_age: dict[int, int] = {}
        self.unknown_counter = 0

    def g(self, sigma: float) -> float:
        return self.rng.gauss(0.0, sigma)

    def _send(self, out: Out, name: str, physical: dict[str, float]) -> None:
        e = self.enc[name]
        out.append((e, e.payload(physical)))

    # -- vehicle bus
    def ego_motion(self) -> Out:
        w, g = self.world, self.g
        moving = w.v > 0
        out: Out = []
        self._send(out, "EgoMotion", {
            "VehicleSpeed": w.v * 3.6 + g(0.03) if moving else 0.0,
            "YawRate": math.degrees(w.yaw_rate) + g(0.05) if moving else 0.0,
            "LongAccel": w.a + g(0.04),
            "LatAccel": w.v * w.yaw_rate + g(0.04),
        })
        return out

    def steering(self) -> Out:
        w, g = self.world, self.g
        angle = math.degrees(math.atan(2.8 * w.kappa)) * 15 + 2 * w.lane_offset
        out: Out = []
        self._send(out, "Steering", {
            "SteeringWheelAngle": angle + g(0.15),
            "SteeringWheelRate": g(0.6),
            "DriverTorque": 0.02 * angle + g(0.05),
            "AngleValid": 1, "RateValid": 1,
        })
        return out

    def driver_inputs(self) -> Out:
        w, g = self.world, self.g
        braking = w.a < -0.3 or w.v == 0.0
        out: Out = []
        self._send(out, "DriverInputs", {
            "Gear": 3, "TurnSignal": 0, "BrakePedalPressed": int(braking), "AccMainSwitch": 1,
            "AccCancel": 0,
            "AccelPedalPosition": 0.0 if braking else max(0.0, 15 + 20 * w.a + g(0.3)),
            "BrakePressure": (max(0.0, -8 * w.a + g(0.15)) if w.v > 0 else 12.0) if braking
            else 0.0,
            "AccGapSetting": 2, "AccSetSpeed": 100,
        })
        return out

    def ego_position(self) -> Out:
        w = self.world
        out: Out = []
        self._send(out, "EgoPosition", {"Latitude": w.lat, "Longitude": w.lon})
        return out

    def fusion_burst(self) -> Out:
        w, g = self.world, self.g
        out: Out = []
        for i, o in enumerate(self.fusion.update(w.targets)):
            name = f"FusionTrack{i}"
            if o is None:
                self._send(out, name, {})
                continue
            self._send(out, name, {
                "TrackID": o.ident & 0xFF, "PosX": o.x + g(0.03), "PosY": o.y + g(0.03),
                "RelVelX": o.speed - w.v + g(0.03), "RelVelY": o.vy + g(0.03), "Class": o.cls,
                "Status": 2 if o.age > 0.3 else 1, "Confidence": min(96.875, 20 + o.age * 15),
            })
        lead = min((o for o in self.fusion.slots if o is not None and abs(o.y) < 1.6),
                   key=lambda o: o.x, default=None)
        if lead is None:
            self._send(out, "LeadVehicle", {"AccState": 2 if w.v > 1 else 1, "TimeGap": 6.3,
                                            "TTC": 102.3})
        else:
            rel = lead.speed - w.v
            self._send(out, "LeadVehicle", {
                "Valid": 1, "AccState": 2 if w.v > 1 else 1, "TrackID": lead.ident & 0xFF,
                "PosX": lead.x + g(0.03), "PosY": lead.y + g(0.03), "RelVelX": rel + g(0.03),
                "TimeGap": min(6.3, lead.x / w.v) if w.v > 0.1 else 6.3,
                "TTC": min(102.3, lead.x / -rel) if rel < -0.1 else 102.3,
            })
        return out

    def sensor_diag(self) -> Out:
        w, g = self.world, self.g
        k = int(w.t)
        page = k % 4
        values: dict[str, float] = {"DiagPage": page, "DiagSource": (k // 4) % 3}
        if page == 0:
            values |= {"FwVersionMajor": 2, "FwVersionMinor": 4, "FwVersionPatch": 1,
                       "HwRevision": 3, "SerialNumber": 4711}
        elif page == 1:
            temp = min(70.0, 30 + w.t / 30)
            values |= {"TempCore": temp + 8, "TempBoard": temp + 4, "TempHousing": temp}
        elif page == 2:
            values |= {"SupplyVoltage": 13.8 + g(0.03), "SupplyCurrent": 0.85 + g(0.005),
                       "PowerMode": 1}
        else:
            values |= {"ActiveDtcCount": 1, "LastDtc": 0x5A1F12, "UptimeMinutes": w.t / 60}
        out: Out = []
        self._send(out, "SensorDiag", values)
        return out

    def unknown(self) -> list[tuple[int, bytes]]:
        self.unknown_counter = (self.unknown_counter + 1) & 0xFF
        speed = int(self.world.v * 100) & 0xFFFF
        return [(UNKNOWN_ID, bytes([self.unknown_counter, speed & 0xFF, speed >> 8, 0x20,
                                    0, 0, 0, 0]))]

    # -- radar bus
    def radar_burst(self) -> Out:
        w, g = self.world, self.g
        slots = self.radar.update(w.targets)
        self.radar_cycle += 1
        mask = sum(1 << i for i, o in enumerate(slots) if o is not None)
        count = bin(mask).count("1")
        out: Out = []
        self._send(out, "RadarHeader", {
            "CycleCounter": self.radar_cycle & 0xFFFF, "ObjectCount": count, "RadarMode": 1,
            "Timestamp": (12_345_678 + int(w.t * 1e6)) % 2**32, "EgoSpeedUsed": w.v + g(0.01),
            "EgoYawRateUsed": math.degrees(w.yaw_rate) + g(0.02), "ObjValidMask": mask,
            "Latency": 25 + g(0.5),
        })
        for i, o in enumerate(slots):
            if o is None:  # an empty slot: all zero but the counter
                self._send(out, f"RadarObj{i}_A", {})
                self._send(out, f"RadarObj{i}_B", {})
                continue
            self._send(out, f"RadarObj{i}_A", {
                "LongDist": o.x + g(0.05), "LongSpeed": o.speed - w.v + g(0.03),
                "LatDist": o.y + g(0.05), "ProbExist": min(96.875, 30 + o.age * 20),
                "LongAccel": o.ax + g(0.05), "Valid": 1,
                "Meas": 1 if self.rng.random() < 0.92 else 0, "Tracked": int(o.age > 0.15),
                "ProbObstacle": o.prob_obstacle,
            })
            self._send(out, f"RadarObj{i}_B", {
                "LatSpeed": o.vy + g(0.05), "Length": o.length, "Width": o.width,
                "MovingState": 4 if o.cls == 4 else (3 if o.speed < 0.1 else 1),
                "ProbClass": o.prob_class, "Class": o.cls, "RCS": o.rcs + g(0.7),
            })
        return out

    def radar_status(self) -> Out:
        w = self.world
        out: Out = []
        self._send(out, "RadarStatus", {
            "HorizontMisalignment": 0.35, "VerticalMisalignment": -0.2, "RadarState": 1,
            "Temperature": min(65.0, 25 + w.t / 40),
            "ObjectCount": sum(o is not None for o in self.radar.slots),
        })
        return out

    # -- camera bus
    def camera_burst(self) -> Out:
        w, g = self.world, self.g
        out: Out = []
        for i, o in enumerate(self.camera.update(w.targets)):
            if o is None:
                self._send(out, f"CamObstacle{i}_A", {})
                self._send(out, f"CamObstacle{i}_B", {})
                continue
            age = self.camera_age[o.ident] = min(255, self.camera_age.get(o.ident, 0) + 1)
            ident = o.ident & 0xFF
            self._send(out, f"CamObstacle{i}_A", {
                "ObstacleID": ident, "PosX": o.x - 1.5 + g(0.1), "PosY": -o.y + g(0.05),
                "RelVelX": o.speed - w.v + g(0.1),
                "Type": {1: 0 if o.length < 6 else 1, 2: 2, 3: 3}[o.cls],
                "Status": 3 if o.speed > 0.5 else 2, "Valid": 1, "BrakeLights": int(o.ax < -1),
                "CutInOut": 1 if abs(o.y) < 1.8 else 2, "Blinker": 1,
            })
            self._send(out, f"CamObstacle{i}_B", {
                "ObstacleID": ident, "Width": o.width, "Length": o.length, "Age": age,
                "Lane": 1 if abs(o.y) < 1.8 else (2 if o.y > 0 else 3),
                "RelAccelX": o.ax + g(0.05),
            })
        if len(self.camera_age) > 512:
            alive = {o.ident for o in w.targets}
            self.camera_age = {k: v for k, v in self.camera_age.items() if k in alive}
        d = w.lane_offset
        view = min(127.0, 80 + 15 * math.sin(w.t / 7) + g(1))
        for name, offset, kind, present in (
            ("CamLaneLeft", -(1.8 - d), 0, True),
            ("CamLaneRight", 1.8 + d, 1, True),
            ("CamLaneNextLeft", -(5.4 - d), 0, w.multi_lane),
            ("CamLaneNextRight", 5.4 + d, 3, w.multi_lane),
        ):
            if not present:
                self._send(out, name, {})
                continue
            self._send(out, name, {
                "C0_Offset": offset + g(0.01), "C1_Heading": -0.003 * math.sin(w.t / 5)
                + g(0.0005), "C2_Curvature": -w.kappa / 2 + g(2e-6),
                "C3_CurvatureDerivative": g(2e-8), "Quality": 3 if abs(offset) < 3 else 2,
                "LaneType": kind, "Source": 1, "ViewRange": view,
            })
        return out


@dataclass
class Burst:
    channel: int
    period_ns: int
    phase_ns: int
    emit: Callable[[], list[tuple[Encoder, bytes]] | list[tuple[int, bytes]]]


def _cycle_ns(db: Database, name: str) -> int:
    cycle = db.get_message_by_name(name).cycle_time
    assert cycle, f"{name} has no GenMsgCycleTime"
    return int(cycle) * 1_000_000


def _frame_ns(length: int, fd: bool) -> int:
    """Time one frame occupies its bus: 500 kbit/s, FD data phase at 2 Mbit/s, with stuffing."""
    if fd:
        return int((29 / 500e3 + (length * 8 + 60) * 1.1 / 2e6) * 1e9)
    return int((47 + 8 * length) * 1.2 / 500e3 * 1e9)


def generate_frames(db: Database, seed: int) -> Iterator[can.Message]:
    """An endless, time-ordered stream of synthetic frames on the three buses."""
    rng = random.Random(seed)
    tr = Traffic(db, rng)
    ms = 1_000_000
    bursts = [
        Burst(RADAR, _cycle_ns(db, "RadarObj0_A"), 3 * ms, tr.radar_burst),
        Burst(RADAR, _cycle_ns(db, "RadarStatus"), 41 * ms, tr.radar_status),
        Burst(CAMERA, _cycle_ns(db, "CamObstacle0_A"), 7 * ms, tr.camera_burst),
        Burst(VEHICLE, _cycle_ns(db, "EgoMotion"), 0, tr.ego_motion),
        Burst(VEHICLE, _cycle_ns(db, "Steering"), 2 * ms, tr.steering),
        Burst(VEHICLE, _cycle_ns(db, "DriverInputs"), 5 * ms, tr.driver_inputs),
        Burst(VEHICLE, _cycle_ns(db, "EgoPosition"), 13 * ms, tr.ego_position),
        Burst(VEHICLE, _cycle_ns(db, "FusionTrack0"), 17 * ms, tr.fusion_burst),
        Burst(VEHICLE, _cycle_ns(db, "SensorDiag"), 500 * ms, tr.sensor_diag),
        Burst(VEHICLE, 20 * ms, 9 * ms, tr.unknown),
    ]
    for name in ("RadarHeader", "RadarObj31_B", "CamLaneNextRight", "FusionTrack19",
                 "LeadVehicle"):
        assert _cycle_ns(db, name) in {b.period_ns for b in bursts}, name
    pending = [(b.phase_ns, i, 0) for i, b in enumerate(bursts)]
    heapq.heapify(pending)
    out: list[tuple[int, int, can.Message]] = []
    free = [0, 0, 0]  # when each bus is idle again
    seq = 0
    while True:
        t, i, k = heapq.heappop(pending)
        while out and out[0][0] <= t:
            yield heapq.heappop(out)[2]
        b = bursts[i]
        tr.world.advance(t / 1e9)
        for what, data in b.emit():
            fd = isinstance(what, Encoder) and what.is_fd
            frame_id = what.frame_id if isinstance(what, Encoder) else what
            tx = max(t, free[b.channel])
            tx -= tx % 1000  # whole microseconds, as loggers stamp them
            free[b.channel] = tx + _frame_ns(len(data), fd)
            seq += 1
            msg = can.Message(timestamp=T0 + tx / 1e9, arbitration_id=frame_id, data=data,
                              channel=b.channel, is_extended_id=False, is_fd=fd,
                              bitrate_switch=fd, dlc=len(data))
            heapq.heappush(out, (tx, seq, msg))
        k += 1
        jitter = rng.randint(-100, 100) * 1000  # whole microseconds
        heapq.heappush(pending, (b.phase_ns + k * b.period_ns + jitter, i, k))


def synthetic_log(workdir: Path, frames: int, seed: int) -> tuple[Path, dict[str, Any]]:
    """The cached synthetic BLF of ``frames`` frames and its statistics (generated if absent)."""
    stem = f"ecocar-3bus-{frames}f-seed{seed}-g{GENERATOR_VERSION}"
    path, meta_path = workdir / f"{stem}.blf", workdir / f"{stem}.json"
    if path.is_file() and meta_path.is_file():
        meta: dict[str, Any] = json.loads(meta_path.read_text())
        meta["cached"] = True
        return path, meta
    db = load_database(ECOCAR_DBC).db
    started = time.perf_counter()
    partial = workdir / f".{stem}.blf.partial"
    per_bus = [0, 0, 0]
    same_as_last = 0
    in_last_16 = 0
    recent: dict[tuple[int, int], deque[bytes]] = {}
    last_t = 0.0
    with can.BLFWriter(str(partial)) as writer:
        for n, msg in enumerate(generate_frames(db, seed)):
            if n >= frames:
                break
            writer.on_message_received(msg)
            ch = msg.channel
            assert isinstance(ch, int)
            per_bus[ch] += 1
            key = (ch, msg.arbitration_id)
            history = recent.get(key)
            if history is None:
                history = recent[key] = deque(maxlen=16)
            data = bytes(msg.data)
            if history:
                same_as_last += history[-1] == data
                in_last_16 += data in history
            history.append(data)
            last_t = msg.timestamp
    os.replace(partial, path)
    meta = {
        "frames": frames, "seed": seed, "generator": GENERATOR_VERSION,
        "seconds_of_driving": last_t - T0,
        "frames_per_bus": {f"can{ch} ({BUS_NAMES[ch]})": n for ch, n in enumerate(per_bus)},
        "repeat_previous_payload_of_id": same_as_last / frames,
        "repeat_one_of_last_16_payloads_of_id": in_last_16 / frames,
        "generation_seconds": time.perf_counter() - started,
        "bytes": path.stat().st_size,
    }
    meta_path.write_text(json.dumps(meta, indent=1))
    meta["cached"] = False
    return path, meta

def asc_copy(blf: Path) -> Path:
    """The same frames as ``blf`` in Vector ASC (python-can's ASCWriter), cached beside it."""
    path = blf.with_suffix(".asc")
    if path.is_file():
        return path
    partial = blf.with_name(f".{blf.stem}.asc.partial")
    with can.ASCWriter(str(partial)) as writer:
        for msg in can.LogReader(str(blf)):
            writer.on_message_received(msg)
    os.replace(partial, path)
    return path


# --------------------------------------------------------------------------------------------
# A public real-format log: candump of a production car's bus, from a public DBC


#: The public DBCs beside the project (opendbc, MIT), as the tests find them.
SHARED_DBC_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "dbc"
#: A production GM car's object bus: counters and checksums (it has no GenMsgCycleTime).
REAL_DBC = "gm_global_a_object.dbc"
REAL_GENERATOR_VERSION = 1
#: Ids on the bus that the DBC does not define (gateways, diagnostics), 100 ms each.
REAL_UNKNOWN_IDS = (0x1F1, 0x3C9, 0x4D1)


def _is_counter(name: str) -> bool:
    lower = name.lower()
    return "rolling" in lower or lower.endswith("counter") or (
        lower.endswith("count") and ("roll" in lower or "alive" in lower))


def _is_checksum(name: str) -> bool:
    lower = name.lower()
    return "checksum" in lower or "crc" in lower


def real_frames(db: Database, seed: int, channel: str = "can0") -> Iterator[can.Message]:
    """An endless candump-like stream of ``db``'s messages on one bus, as a production car sends.

    Each message comes at its ``GenMsgCycleTime`` where the DBC has one, else at a cycle drawn
    once from 10..1000 ms (±0.2 ms jitter); multiplexed messages are left out. About a quarter of
    the signals of a message change now and then (a small random walk of the raw value), the rest
    hold a value for the whole drive; a rolling counter/count signal rolls on every frame, and a
    checksum/CRC signal is the byte sum of the rest of the payload: so most payloads repeat except
    for their counter and checksum, as on a real bus.
    """
    rng = random.Random(seed)
    ms = 1_000_000
    plans: list[tuple[int, DbcMessage | int, dict[str, int], list[str], list[str], str | None]] = []
    for m in sorted(db.messages, key=lambda m: m.frame_id):
        if m.is_multiplexed():
            continue
        period = int(m.cycle_time or rng.choice((10, 20, 25, 50, 50, 100, 100, 100, 200, 1000)))
        values: dict[str, int] = {}
        moving: list[str] = []
        counters: list[str] = []
        checksum = None
        for s in m.signals:
            top = 2 ** min(s.length, 12) - 1
            values[s.name] = 0 if s.is_float else rng.randint(0, top) if not s.is_signed else \
                rng.randint(-(top // 2), top // 2)
            if _is_checksum(s.name):
                checksum = s.name
            elif _is_counter(s.name):
                counters.append(s.name)
            elif not s.is_float and s.length > 1 and rng.random() < 0.25:
                moving.append(s.name)
        plans.append((period * ms, m, values, moving, counters, checksum))
    for ident in REAL_UNKNOWN_IDS:
        plans.append((100 * ms, ident, {}, [], [], None))
    pending = [(rng.randrange(p[0]), i) for i, p in enumerate(plans)]
    heapq.heapify(pending)
    limits = {(dm.name, s.name): s for _, dm, *_ in plans if not isinstance(dm, int)
              for s in dm.signals}
    free = 0
    alive = 0
    while True:
        t, i = heapq.heappop(pending)
        period, what, values, moving, counters, checksum = plans[i]
        heapq.heappush(pending, (t + period + rng.randint(-200, 200) * 1000, i))
        frame_id: int
        if isinstance(what, int):
            alive = (alive + 1) & 0xFF
            data = bytes([alive, 0x10, 0, 0, 0, 0, 0, 0])
            frame_id = what
        else:
            for name in moving:
                if rng.random() < 0.3:
                    s = limits[(what.name, name)]
                    lo, hi = (-(2 ** (s.length - 1)), 2 ** (s.length - 1) - 1) if s.is_signed \
                        else (0, 2**s.length - 1)
                    values[name] = max(lo, min(hi, values[name] + rng.randint(-3, 3)))
            for name in counters:
                values[name] = (values[name] + 1) % 2 ** limits[(what.name, name)].length
            if checksum is not None:
                values[checksum] = 0
            data = bytes(what.encode(values, scaling=False, padding=False, strict=False))
            if checksum is not None:
                values[checksum] = sum(data) % 2 ** limits[(what.name, checksum)].length
                data = bytes(what.encode(values, scaling=False, padding=False, strict=False))
            frame_id = what.frame_id
        tx = max(t, free)
        tx -= tx % 1000
        free = tx + _frame_ns(len(data), False)
        yield can.Message(timestamp=T0 + tx / 1e9, arbitration_id=frame_id, data=data,
                          channel=channel, is_extended_id=frame_id > 0x7FF, dlc=len(data))


def real_log(workdir: Path, frames: int, seed: int,
             dbc: Path | None = None) -> tuple[Path, Path, dict[str, Any]]:
    """The cached candump (.log) of ``frames`` frames from a public DBC: (log, DBC, statistics).

    Raises :class:`FileNotFoundError` naming the folder when the public DBCs are absent."""
    dbc = dbc or SHARED_DBC_DIR / REAL_DBC
    if not dbc.is_file():
        raise FileNotFoundError(f"{dbc}: not found (the public DBCs come from ../shared/data/dbc, "
                                "opendbc, MIT)")
    stem = f"real-{dbc.stem}-{frames}f-seed{seed}-g{REAL_GENERATOR_VERSION}"
    path, meta_path = workdir / f"{stem}.log", workdir / f"{stem}.json"
    if path.is_file() and meta_path.is_file():
        meta: dict[str, Any] = json.loads(meta_path.read_text())
        return path, dbc, meta
    db = cantools.database.load_file(str(dbc), strict=False)
    assert isinstance(db, Database)
    partial = workdir / f".{stem}.log.partial"
    known = {m.frame_id for m in db.messages}
    in_dbc = same_as_last = 0
    last: dict[int, bytes] = {}
    last_t = 0.0
    with can.CanutilsLogWriter(str(partial)) as writer:
        for n, msg in enumerate(real_frames(db, seed)):
            if n >= frames:
                break
            writer.on_message_received(msg)
            data = bytes(msg.data)
            in_dbc += msg.arbitration_id in known
            same_as_last += last.get(msg.arbitration_id) == data
            last[msg.arbitration_id] = data
            last_t = msg.timestamp
    os.replace(partial, path)
    meta = {"frames": frames, "seed": seed, "dbc": dbc.name, "ids": len(last),
            "seconds_of_driving": last_t - T0, "share_of_frames_in_dbc": in_dbc / frames,
            "repeat_previous_payload_of_id": same_as_last / frames,
            "bytes": path.stat().st_size}
    meta_path.write_text(json.dumps(meta, indent=1))
    return path, dbc, meta


# --------------------------------------------------------------------------------------------
# The references: bare reading and the naive converter (with or without the scene)


#: What the ratios compare (``--clock``): "wall", the elapsed time a user waits; or "cpu", user +
#: system CPU time of the contender (its process and children, or this process for the
#: in-process references), which a loaded shared machine disturbs far less than elapsed time.
CLOCK = "wall"


@dataclass
class Run:
    frames: int
    wall: float
    rss_mb: float | None = None
    errors: int = 0
    unknown: int = 0
    cpu: float = 0.0

    @property
    def seconds(self) -> float:
        """The time on :data:`CLOCK`."""
        return self.cpu if CLOCK == "cpu" else self.wall

    @property
    def rate(self) -> float:
        return self.frames / self.seconds if self.seconds else 0.0


def bare_read(path: Path) -> Run:
    """(a) python-can's reader alone."""
    started, cpu = time.perf_counter(), time.process_time()
    n = 0
    for _ in can.LogReader(str(path)):
        n += 1
    return Run(n, time.perf_counter() - started, cpu=time.process_time() - cpu)


#: Scene updates per second of log time, as ``tankviz convert`` makes them by default.
SCENE_RATE = 20.0
#: The ecocar categories the naive converter draws (tankviz's topics ``/scene/<category>``).
NAIVE_SCENE_CATEGORIES = ("ego", "lanes", "radar", "camera", "tracks", "lead")


def naive_scene(latest: dict[str, dict[str, Any]], t_ns: int) -> list[tuple[str, Any]]:
    """The ecocar's scene drawn the straightforward way: one ``foxglove.SceneUpdate`` per category.

    ``latest`` holds the newest decoded signals of each DBC message. Ego: a box; lanes: each
    valid camera lane (``Source == 1 and Quality > 0``) as a 100-point line of its cubic, 100 m
    ahead (the camera counts y to the right); radar objects (``Valid == 1 and ProbExist > 70``),
    camera obstacles (``Valid == 1``), fusion tracks (``Status != 0``) and the lead vehicle
    (``Valid == 1``) as boxes with a text label. Fixed reference code: it never changes with
    tankviz."""
    from foxglove_schemas_protobuf.Color_pb2 import Color
    from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
    from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
    from foxglove_schemas_protobuf.Point3_pb2 import Point3
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
    from google.protobuf.timestamp_pb2 import Timestamp

    stamp = Timestamp(seconds=t_ns // 1_000_000_000, nanos=t_ns % 1_000_000_000)

    def entity(ident: str) -> Any:
        return SceneEntity(timestamp=stamp, frame_id="vehicle", id=ident, frame_locked=True)

    def box(x: float, y: float, length: float, width: float, height: float,
            rgba: tuple[float, float, float, float]) -> Any:
        return CubePrimitive(pose=Pose(position=Vector3(x=x, y=y, z=height / 2)),
                             size=Vector3(x=max(length, 0.3), y=max(width, 0.3), z=height),
                             color=Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]))

    def label(x: float, y: float, text: str) -> Any:
        return TextPrimitive(pose=Pose(position=Vector3(x=x, y=y, z=2.0)), billboard=True,
                             font_size=12, scale_invariant=True,
                             color=Color(r=1, g=1, b=1, a=1), text=text)

    def get(name: str) -> dict[str, Any]:
        return latest.get(name, {})

    out: list[tuple[str, Any]] = []
    ego = entity("ego")
    ego.cubes.append(box(0.0, 0.0, 2.5, 1.5, 1.0, (0.2, 0.5, 1.0, 0.8)))
    out.append(("ego", SceneUpdate(entities=[ego])))

    lanes = SceneUpdate()
    for name in ("CamLaneLeft", "CamLaneRight", "CamLaneNextLeft", "CamLaneNextRight"):
        s = get(name)
        if not (s.get("Source") == 1 and s.get("Quality", 0) > 0):
            continue
        c0, c1 = s["C0_Offset"], s["C1_Heading"]
        c2, c3 = s["C2_Curvature"], s["C3_CurvatureDerivative"]
        line = LinePrimitive(type=LinePrimitive.LINE_STRIP, thickness=0.15,
                             color=Color(r=1, g=1, b=1, a=0.9))
        for k in range(100):
            x = k * 100.0 / 99
            line.points.append(Point3(x=x, y=-(c0 + c1 * x + c2 * x * x + c3 * x * x * x),
                                      z=0.0))
        e = entity(f"lane-{name}")
        e.lines.append(line)
        lanes.entities.append(e)
    out.append(("lanes", lanes))

    radar = SceneUpdate()
    for i in range(32):
        a, b = get(f"RadarObj{i}_A"), get(f"RadarObj{i}_B")
        if not (a.get("Valid") == 1 and a.get("ProbExist", 0) > 70):
            continue
        x, y = a["LongDist"], a["LatDist"]
        e = entity(f"radar-{i}")
        e.cubes.append(box(x, y, b.get("Length", 0.5), b.get("Width", 0.5), 1.5,
                           (1.0, 0.3, 0.3, 0.6)))
        e.texts.append(label(x, y, f"radar {i} {a['LongSpeed']:+.1f} m/s"))
        radar.entities.append(e)
    out.append(("radar", radar))

    camera = SceneUpdate()
    for i in range(10):
        a, b = get(f"CamObstacle{i}_A"), get(f"CamObstacle{i}_B")
        if a.get("Valid") != 1:
            continue
        x, y = a["PosX"], -a["PosY"]
        e = entity(f"camera-{a['ObstacleID']}")
        e.cubes.append(box(x, y, b.get("Length", 1.0), b.get("Width", 1.0), 1.5,
                           (0.3, 1.0, 0.3, 0.6)))
        e.texts.append(label(x, y, f"camera {a['ObstacleID']}"))
        camera.entities.append(e)
    out.append(("camera", camera))

    tracks = SceneUpdate()
    for i in range(20):
        s = get(f"FusionTrack{i}")
        if s.get("Status", 0) == 0:
            continue
        x, y = s["PosX"], s["PosY"]
        e = entity(f"track-{s['TrackID']}")
        e.cubes.append(box(x, y, 4.5, 1.8, 1.5, (1.0, 0.8, 0.2, 0.6)))
        e.texts.append(label(x, y, f"track {s['TrackID']} {s['RelVelX']:+.1f} m/s"))
        tracks.entities.append(e)
    out.append(("tracks", tracks))

    lead = SceneUpdate()
    s = get("LeadVehicle")
    if s.get("Valid") == 1:
        x, y = s["PosX"], s["PosY"]
        e = entity("lead")
        e.cubes.append(box(x, y, 4.5, 1.8, 1.6, (1.0, 0.0, 1.0, 0.7)))
        e.texts.append(label(x, y, f"lead {x:.1f} m, gap {s['TimeGap']:.1f} s"))
        lead.entities.append(e)
    out.append(("lead", lead))
    return out


def _bus_name(channel: Any) -> str:
    """tankviz's bus name of a python-can channel (docs/commands.md: ``can<N>`` for numbered
    channels)."""
    if isinstance(channel, int):
        return f"can{channel}"
    return str(channel).strip() or "can"


def naive_convert(path: Path, output: Path, dbc: Path = ECOCAR_DBC, *,
                  scene: bool = False) -> Run:
    """(b) The straightforward converter: LogReader → cantools → mcap_protobuf Writer (zstd).

    With ``scene``, also :func:`naive_scene` at :data:`SCENE_RATE` of log time (the ecocar's
    categories), from the newest decoded values of each message."""
    from google.protobuf import descriptor_pool
    from mcap_protobuf.writer import Writer

    from bridge.decode.proto_schema import MessageSchema
    from bridge.pb.can_frame_pb2 import CanFrame

    started, cpu = time.perf_counter(), time.process_time()
    db = cantools.database.load_file(str(dbc), strict=False)
    assert isinstance(db, Database)
    pool = descriptor_pool.DescriptorPool()
    schemas = {m.frame_id: (m.name, MessageSchema(m, dbc.stem, pool)) for m in db.messages}
    # Every field the recorder writes: the schema (schemas/can_frame.proto) is the contract.
    with_time = "timestamp_ns" in CanFrame.DESCRIPTOR.fields_by_name
    frames = errors = unknown = 0
    latest: dict[str, dict[str, Any]] = {}
    period = round(1e9 / SCENE_RATE)
    next_tick: int | None = None
    with output.open("wb") as stream, Writer(stream) as writer:
        for msg in can.LogReader(str(path)):
            frames += 1
            bus = _bus_name(msg.channel)
            t = round(msg.timestamp * 1_000_000) * 1000
            if scene:
                if next_tick is None:
                    next_tick = t - t % period
                while t >= next_tick:
                    for category, update in naive_scene(latest, next_tick):
                        writer.write_message(f"/scene/{category}", update, log_time=next_tick,
                                             publish_time=next_tick)
                    next_tick += period
            data = bytes(msg.data)
            raw = CanFrame(
                bus=bus, id=msg.arbitration_id, extended=msg.is_extended_id, fd=msg.is_fd,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
                error=msg.is_error_frame, remote=msg.is_remote_frame, dlc=msg.dlc, data=data)
            if with_time:
                raw.timestamp_ns = t
            writer.write_message(f"/can/{bus}/frames", raw, log_time=t, publish_time=t)
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            entry = schemas.get(msg.arbitration_id)
            if entry is None:
                unknown += 1
                continue
            name, schema = entry
            try:
                signals = cast(dict[str, Any], db.decode_message(
                    msg.arbitration_id, data, decode_choices=False))
            except Exception:
                errors += 1
                continue
            if scene:
                latest[name] = signals
            if schema.renamed:
                signals = {schema.renamed.get(k, k): v for k, v in signals.items()}
            writer.write_message(f"/can/{bus}/{name}", schema.message_class(**signals),
                                 log_time=t, publish_time=t)
    return Run(frames, time.perf_counter() - started, errors=errors, unknown=unknown,
               cpu=time.process_time() - cpu)


# --------------------------------------------------------------------------------------------
# tankviz


def tankviz_command(path: Path, output: Path, *, dbc: Path | None = ECOCAR_DBC,
                    profile: str | None = None) -> list[str]:
    """``tankviz convert`` of ``path``: raw only (no ``dbc``/``profile``), decoded, or the scene."""
    command = [sys.executable, "-m", "bridge", "convert", str(path), "-o", str(output),
               "--quiet", "--force"]
    if dbc is not None:
        command += ["--dbc", str(dbc)]
    if profile is not None:
        command += ["--profile", profile]
    return command


def timed_process(command: list[str], frames: int = 0) -> Run:
    """Run ``command``: wall time from outside (start-up included), that process's peak RSS."""
    with tempfile.TemporaryFile() as said:
        started = time.perf_counter()
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=said)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - started
        code = os.waitstatus_to_exitcode(status)
        if code != 0:
            said.seek(0)
            raise SystemExit(f"failed with status {code}: {' '.join(command)}\n"
                             + said.read().decode(errors="replace"))
    return Run(frames, seconds, rss_mb=usage.ru_maxrss / 1024,  # ru_maxrss: KiB on Linux
               cpu=usage.ru_utime + usage.ru_stime)


def tankviz_convert(path: Path, output: Path, frames: int, *, dbc: Path | None = ECOCAR_DBC,
                    profile: str | None = None) -> Run:
    """(c) ``tankviz convert`` in its own process: wall time and that process's peak RSS."""
    return timed_process(tankviz_command(path, output, dbc=dbc, profile=profile), frames)


def startup_seconds() -> float:
    """Interpreter start-up plus importing what ``convert`` imports, part of (c)'s time."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import bridge.cli, bridge.apps.convert"], check=True)
    return time.perf_counter() - started


def topic_counts(path: Path) -> dict[str, int]:
    """Messages per topic, but frames on the raw-frame topics (tankviz writes them in blocks;
    a tankviz from before blocks, measured by ``bench_report.py --before``, one a message)."""
    from mcap.reader import make_reader

    from bridge.topics import frames_topic

    try:
        from bridge.io.drives import raw_frame_counts
        blocks = True
    except ImportError:  # before blocks: a message per frame
        blocks = False
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, f"{path}: no summary"
        counts = {summary.channels[cid].topic: n
                  for cid, n in summary.statistics.channel_message_counts.items()}
        if blocks:
            counts.update({frames_topic(bus): n for bus, n in raw_frame_counts(reader).items()})
    return counts


def index_bytes(path: Path) -> int:
    """Bytes of an MCAP's MessageIndex records (the chunk indexes' ``message_index_length``):
    16 bytes per message (log time, offset), never compressed. ``@mcap/core``'s indexed reader
    (Foxglove's) refuses a chunk of messages without them, so they are the archive's floor."""
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None, f"{path}: no summary"
    return sum(c.message_index_length for c in summary.chunk_indexes)


def compare_outputs(naive: Path, ours: Path) -> list[str]:
    """Topics the naive converter wrote whose message counts (frames, on the raw-frame topics)
    differ in tankviz's MCAP (tankviz's
    extra topics - perception, health, /tf, /ego - are not compared; a scene category may
    differ by one tick at the end of the log)."""
    a, b = topic_counts(naive), topic_counts(ours)
    problems = []
    for topic in sorted(a):
        slack = 1 if topic.startswith("/scene/") else 0
        if abs(a[topic] - b.get(topic, 0)) > slack:
            problems.append(f"{topic}: naive {a[topic]}, tankviz {b.get(topic, 0)}")
    return problems


# --------------------------------------------------------------------------------------------
# The measurements


def _warm(path: Path) -> None:
    """Read the file once so every contender starts from the page cache."""
    with path.open("rb") as f:
        while f.read(1 << 22):
            pass


@dataclass
class Contender:
    """One way to read or convert a log, run ``runs`` times interleaved with the others."""

    key: str
    label: str
    go: Callable[[], Run]
    runs: list[Run] = field(default_factory=list)
    log: str = ""  # which log, for the progress lines

    @property
    def best(self) -> Run:
        return min(self.runs, key=lambda r: r.seconds)

    def best_rate(self, clock: str) -> float:
        """Frames per second of the best run on ``clock`` ("cpu" or "wall")."""
        return max(r.frames / (r.cpu if clock == "cpu" else r.wall) for r in self.runs)


def interleaved(contenders: list[Contender], runs: int, loads: list[float]) -> None:
    """Round-robin: every contender once per round, ``runs`` rounds (best of them counts)."""
    for k in range(runs):
        for c in contenders:
            loads.append(os.getloadavg()[0])
            c.runs.append(c.go())
            print(f"  round {k + 1} of {runs}: {c.label} ({c.log}) {c.runs[-1].seconds:.2f} s",
                  file=sys.stderr, flush=True)


def _best_of(runs: int, command: list[str]) -> float:
    """The best time on :data:`CLOCK` of ``runs`` runs of ``command``."""
    return min(timed_process(command).seconds for _ in range(runs))


@dataclass
class Row:
    """One line of issue #15's table: the measure, the figure now, the goal, met or not."""

    measure: str
    now: str
    goal: str
    ok: bool | None = None
    value: float | None = None


def _ratio_row(rows: list[Row], measure: str, value: float, goal: float, *,
               at_most: bool = False, unit: str = "x", aside: str = "") -> None:
    ok = value <= goal if at_most else value >= goal
    rows.append(Row(measure, f"{value:.2f}{unit}{aside}",
                    f"{'≤' if at_most else '≥'} {goal:g}{unit}", ok, value))


def _speed_row(rows: list[Row], measure: str, ours: Contender, reference: Contender,
               goal: float) -> None:
    """tankviz's speed over the reference's on :data:`CLOCK`, the other clock's aside."""
    other = "cpu" if CLOCK == "wall" else "wall"
    aside = ours.best_rate(other) / reference.best_rate(other)
    _ratio_row(rows, measure, ours.best_rate(CLOCK) / reference.best_rate(CLOCK), goal,
               aside=f" ({aside:.2f}x {other})")


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every measurement of one run; returns the table rows and the details (for --json)."""
    workdir: Path = args.workdir
    loads: list[float] = []
    details: list[str] = []

    def say(line: str) -> None:
        """A detail: printed after the table (and to stderr now, as progress)."""
        details.append(line)
        if line:
            print(line, file=sys.stderr, flush=True)

    # tankviz as pip installs it: its bytecode compiled (see the module's description)
    import bridge

    compileall.compile_dir(str(Path(bridge.__file__).parent), quiet=1)

    # -- the simulated drive, BLF and ASC: five contenders each, interleaved, best of --runs
    blf, meta = synthetic_log(workdir, args.frames, args.seed)
    asc = asc_copy(blf)
    say(f"simulated drive {blf.name}: {meta['frames']:,} frames, "
        f"{meta['seconds_of_driving']:.0f} s of driving, BLF {blf.stat().st_size / MB:.1f} MB, "
        f"ASC {asc.stat().st_size / MB:.1f} MB; per bus {meta['frames_per_bus']}; payload = "
        f"previous one of its id {meta['repeat_previous_payload_of_id']:.1%}, one of the last 16 "
        f"{meta['repeat_one_of_last_16_payloads_of_id']:.1%}")
    out = workdir / "out"
    out.mkdir(exist_ok=True)
    contenders: dict[tuple[str, str], Contender] = {}
    order: list[Contender] = []
    for fmt, log in (("BLF", blf), ("ASC", asc)):
        _warm(log)
        n = meta["frames"]
        for key, label, go in (
            ("bare", "bare can.LogReader iteration", lambda log=log: bare_read(log)),
            ("naive", "naive raw + decoded", lambda log=log, fmt=fmt: naive_convert(
                log, out / f"naive-{fmt}.mcap")),
            ("naive_scene", "naive with scene", lambda log=log, fmt=fmt: naive_convert(
                log, out / f"naive-scene-{fmt}.mcap", scene=True)),
            ("tankviz", "tankviz raw + decoded", lambda log=log, fmt=fmt, n=n: tankviz_convert(
                log, out / f"tankviz-{fmt}.mcap", n)),
            ("tankviz_scene", "tankviz with scene", lambda log=log, fmt=fmt, n=n: tankviz_convert(
                log, out / f"tankviz-scene-{fmt}.mcap", n, profile="ecocar")),
        ):
            c = Contender(key, label, go, log=fmt)
            contenders[(fmt, key)] = c
            order.append(c)
    interleaved(order, args.runs, loads)
    for fmt in ("BLF", "ASC"):
        for naive, ours in (("naive", "tankviz"), ("naive-scene", "tankviz-scene")):
            problems = compare_outputs(out / f"{naive}-{fmt}.mcap", out / f"{ours}-{fmt}.mcap")
            if problems:
                say(f"WARNING: {naive} and {ours} ({fmt}) wrote different message counts: "
                    + "; ".join(problems[:10]))
            else:
                say(f"{naive} and {ours} ({fmt}) wrote the same messages per topic of the naive "
                    "converter")

    # -- sizes (BLF): raw only (one more run), raw + decoded, with the scene
    raw_only = tankviz_convert(blf, out / "tankviz-raw-BLF.mcap", meta["frames"], dbc=None)
    blf_bytes = blf.stat().st_size
    sizes = {"raw only": (out / "tankviz-raw-BLF.mcap").stat().st_size,
             "raw + decoded": (out / "tankviz-BLF.mcap").stat().st_size,
             "with scene": (out / "tankviz-scene-BLF.mcap").stat().st_size,
             "naive raw + decoded": (out / "naive-BLF.mcap").stat().st_size,
             "naive with scene": (out / "naive-scene-BLF.mcap").stat().st_size}
    indexes = {k: index_bytes(out / f"tankviz{tag}-BLF.mcap") for k, tag in
               (("raw only", "-raw"), ("raw + decoded", ""), ("with scene", "-scene"))}
    say(f"tankviz raw only (one run, BLF): {raw_only.seconds:.2f} s {CLOCK}")

    # -- the public real-format log: raw + decoded, tankviz vs naive
    real: dict[str, Any] | None = None
    try:
        rlog, rdbc, rmeta = real_log(workdir, args.real_frames, args.seed, args.real_dbc)
    except FileNotFoundError as e:
        say(f"real-format log skipped: {e}")
    else:
        _warm(rlog)
        say(f"real-format log {rlog.name} (candump, {rmeta['dbc']}): {rmeta['frames']:,} frames, "
            f"{rmeta['ids']} ids, {rmeta['share_of_frames_in_dbc']:.1%} of frames in the DBC, "
            f"{rmeta['seconds_of_driving']:.0f} s, payload = previous one of its id "
            f"{rmeta['repeat_previous_payload_of_id']:.1%}")
        rc = [Contender("bare", "bare can.LogReader iteration", lambda: bare_read(rlog)),
              Contender("naive", "naive raw + decoded", lambda: naive_convert(
                  rlog, out / "naive-real.mcap", rdbc)),
              Contender("tankviz", "tankviz raw + decoded", lambda: tankviz_convert(
                  rlog, out / "tankviz-real.mcap", rmeta["frames"], dbc=rdbc))]
        for c in rc:
            c.log = "candump"
        interleaved(rc, args.runs, loads)
        problems = compare_outputs(out / "naive-real.mcap", out / "tankviz-real.mcap")
        if problems:
            say("WARNING: naive and tankviz (real log) wrote different message counts: "
                + "; ".join(problems[:10]))
        real = {c.key: c for c in rc} | {"meta": rmeta}

    # -- start-up: tankviz --help, a 1 s log converted with the scene, the import share
    one_s, _ = synthetic_log(workdir, ONE_SECOND_FRAMES, args.seed)
    interpreter = _best_of(args.runs, [sys.executable, "-c", "pass"])
    imports = _best_of(args.runs, [sys.executable, "-c", "import bridge.cli, bridge.apps.convert"])
    help_s = _best_of(args.runs, [sys.executable, "-m", "bridge", "--help"])
    short = _best_of(args.runs, tankviz_command(one_s, out / "one-second.mcap", profile="ecocar"))
    import_share = max(0.0, imports - interpreter) / short

    # -- memory: the longer drive with the scene, one run
    long_blf, long_meta = synthetic_log(workdir, args.frames2, args.seed)
    _warm(long_blf)
    long_run = tankviz_convert(long_blf, out / "tankviz-scene-long.mcap", long_meta["frames"],
                               profile="ecocar")
    short_rss = max(r.rss_mb or 0.0 for r in contenders[("BLF", "tankviz_scene")].runs)
    long_rss = long_run.rss_mb or 0.0

    # -- the table
    rows: list[Row] = []

    def contender(fmt: str, key: str) -> Contender:
        return contenders[(fmt, key)]

    for fmt in ("BLF", "ASC"):
        _speed_row(rows, f"convert with the scene, tankviz / naive ({fmt}, simulated)",
                   contender(fmt, "tankviz_scene"), contender(fmt, "naive_scene"), 3.0)
    for fmt in ("BLF", "ASC"):
        _speed_row(rows, f"convert raw + decoded, tankviz / naive ({fmt}, simulated)",
                   contender(fmt, "tankviz"), contender(fmt, "naive"), 3.0)
    if real is not None:
        _speed_row(rows, "convert raw + decoded, tankviz / naive (candump, real-format log)",
                   real["tankviz"], real["naive"], 3.0)
    else:
        rows.append(Row("convert raw + decoded, tankviz / naive (candump, real-format log)",
                        "skipped (no ../shared/data/dbc)", "≥ 3x"))
    for fmt in ("BLF", "ASC"):
        _speed_row(rows, f"convert raw + decoded, tankviz / bare LogReader ({fmt})",
                   contender(fmt, "tankviz"), contender(fmt, "bare"), 0.5)
    # issue #26's goals (raw frames archived in blocks); raw + decoded keeps #15's
    for label, goal in (("raw only", 1.0), ("raw + decoded", 3.0), ("with scene", 4.0)):
        _ratio_row(rows, f"archive size / BLF size, {label}", sizes[label] / blf_bytes, goal,
                   at_most=True)
    _ratio_row(rows, "share of a 1 s log's convert (with scene) spent importing", import_share,
               0.1, at_most=True, unit="")
    growth = long_rss - short_rss
    rows.append(Row(f"peak RSS, with scene: {args.frames:,} → {args.frames2:,} frames",
                    f"{short_rss:.0f} → {long_rss:.0f} MB ({growth:+.0f} MB)",
                    "flat (≤ +5 %)", growth <= max(2.0, 0.05 * short_rss), growth))
    per_hour = long_run.seconds / long_meta["seconds_of_driving"] * 3600
    rows.append(Row(f"1 hour of the 3-bus drive with the scene, one convert ({CLOCK} time, "
                    "extrapolated)",
                    f"{per_hour / 60:.1f} min", "≤ 2 min", per_hour <= 120, per_hour))

    # -- details
    sim_seconds = meta["seconds_of_driving"]
    say("")
    say(f"{'best of ' + str(args.runs) + ', interleaved (' + CLOCK + ')':<44}{'frames':>11}"
        f"{'CPU s':>9}{'wall s':>9}{'frames/s':>11}{'peak RSS':>10}")
    groups: list[tuple[str, list[Contender]]] = [
        (f"simulated {fmt}", [contenders[(fmt, k)] for k in
                              ("bare", "naive", "naive_scene", "tankviz", "tankviz_scene")])
        for fmt in ("BLF", "ASC")]
    if real is not None:
        groups.append(("real-format candump", [real["bare"], real["naive"], real["tankviz"]]))
    for title, cs in groups:
        say(title)
        for c in cs:
            r = c.best
            rss = f"{r.rss_mb:,.0f} MB" if r.rss_mb is not None else ""
            say(f"  {c.label:<42}{r.frames:>11,}{r.cpu:>9.2f}{r.wall:>9.2f}{r.rate:>11,.0f}"
                f"{rss:>10}")
    say(f"archive sizes (simulated drive, {sim_seconds:.0f} s; BLF {blf_bytes / MB:.2f} MB): "
        + ", ".join(f"{k} {v / MB:.2f} MB ({v / blf_bytes:.2f}x)" for k, v in sizes.items()))
    say("  of which message indexes (16 bytes per message, uncompressed; Foxglove's reader needs "
        "them): " + ", ".join(f"{k} {v / MB:.2f} MB ({v / blf_bytes:.2f}x the BLF)"
                              for k, v in indexes.items()))
    say(f"start-up, best of {args.runs}, {CLOCK} time: python -c pass {interpreter:.2f} s; "
        f"import bridge.cli + convert {imports:.2f} s; tankviz --help {help_s:.2f} s; "
        f"1 s log ({ONE_SECOND_FRAMES:,} frames) converted with the scene {short:.2f} s, "
        f"of which importing {import_share:.0%} and the interpreter {interpreter / short:.0%}")
    say(f"longer drive {long_blf.name}: {long_meta['frames']:,} frames, "
        f"{long_meta['seconds_of_driving']:.0f} s of driving, with scene "
        f"{long_run.seconds:.2f} s {CLOCK} (peak RSS {long_rss:.0f} MB)")
    cores = os.cpu_count() or 1
    say(f"1-min load average during the runs: {min(loads):.2f}..{max(loads):.2f} ({cores} cores; "
        "this benchmark adds about 1)")
    if max(loads) > cores:
        say("NOTE: other processes competed for the CPU during the run: the figures are noisy "
            "(the ratios less so: every reference ran interleaved with tankviz)")
    return {"rows": [vars(r) for r in rows], "details": details, "clock": CLOCK,
            "load": [min(loads), max(loads)], "runs": args.runs,
            "frames": [args.frames, args.frames2, args.real_frames]}


#: About one second of the simulated drive (2,400 frames/s on its three buses).
ONE_SECOND_FRAMES = 2_400


def print_table(rows: list[dict[str, Any]]) -> None:
    """The ratios of issue #15's table, measure | now | goal | ok."""
    width = max(len(r["measure"]) for r in rows)
    now_w = max(len(r["now"]) for r in rows)
    print(f"{'measure (same run, ratios)':<{width}}  {'now':<{now_w}}  goal")
    for r in rows:
        ok = "" if r["ok"] is None else "  ok" if r["ok"] else "  MISSED"
        print(f"{r['measure']:<{width}}  {r['now']:<{now_w}}  {r['goal']}{ok}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--frames", type=int, default=1_440_000,
                        help="frames of the simulated drive (1,440,000: about 600 s)")
    parser.add_argument("--frames2", type=int, default=2_880_000,
                        help="frames of the longer drive, for memory (2,880,000)")
    parser.add_argument("--real-frames", type=int, default=135_000,
                        help="frames of the real-format candump log (135,000)")
    parser.add_argument("--real-dbc", type=Path, metavar="DBC",
                        help=f"the public DBC of the real-format log ({REAL_DBC} in "
                        "../shared/data/dbc)")
    parser.add_argument("--runs", type=int, default=3, help="interleaved rounds, best of (3)")
    parser.add_argument("--quick", action="store_true",
                        help="200k / 400k simulated and 50k real frames, to iterate")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workdir", type=Path,
                        default=Path(tempfile.gettempdir()) / "tankviz-bench",
                        help="where logs are cached and outputs written")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="wall",
                        help="compare elapsed time (default: what a user waits) or CPU time "
                        "(steadier on a shared machine; counts the second core's work)")
    parser.add_argument("--json", type=Path, metavar="FILE",
                        help="also write the table and the details as JSON (for bench_report)")
    args = parser.parse_args(argv)
    global CLOCK
    CLOCK = args.clock
    if args.quick:
        args.frames, args.frames2, args.real_frames = 200_000, 400_000, 50_000
    args.workdir.mkdir(parents=True, exist_ok=True)
    print(f"tankviz convert benchmark: {args.frames:,} / {args.frames2:,} simulated frames, "
          f"{args.real_frames:,} real-format frames, best of {args.runs} interleaved runs, "
          f"{CLOCK} time (progress on stderr; the table first, then the details)", flush=True)
    result = measure(args)
    print()
    print_table(result["rows"])
    missed = [r for r in result["rows"] if r["ok"] is False]
    for r in missed:
        print(f"TARGET MISSED: {r['measure']}: {r['now']} (goal {r['goal']})")
    print("\n".join(result["details"]))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
