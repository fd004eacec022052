#!/usr/bin/env python3
"""Benchmark ``tankviz convert`` on a synthetic multi-bus drive (a report, not a test).

In one run, for two log lengths (default 1,000,000 and 2,000,000 frames), it times

(a) bare ``can.LogReader`` iteration over the log (the floor: python-can's reading alone),
(b) a naive reference converter in this process: LogReader → cantools ``decode_message`` →
    ``mcap_protobuf.writer.Writer`` (zstd), writing the same raw (``/can/<bus>/frames``,
    :class:`bridge.pb.can_frame_pb2.CanFrame`) and decoded (``/can/<bus>/<Message>``, the very
    protobuf types tankviz generates, from
    :class:`bridge.decode.proto_schema.MessageSchema`) topics,
(c) ``tankviz convert`` in a subprocess, timed from outside (interpreter start-up included), with
    the peak RSS of that process alone (``os.wait4``),

and prints frames/s of each, the ratios c/b and c/a, and the RSS of (c) at both lengths. Targets:
c/b ≥ 2.0 (stretch c/a ≥ 0.5), RSS < 300 MB and not growing with the log length; a missed target
prints a ``TARGET MISSED: …`` line. The exit status is 0 regardless: this is a report.
It also checks that (b) and (c) wrote the same number of messages per topic.

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

Generated logs are cached in ``--workdir`` (default: ``$TMPDIR/tankviz-bench``), keyed by frame
count, seed and generator version, so re-runs do not regenerate them.

    python tools/bench_convert.py --quick      # 200k / 400k frames, to iterate
    python tools/bench_convert.py              # 1M / 2M frames
"""

from __future__ import annotations

import argparse
import heapq
import json
import math
import os
import random
import resource
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

TARGET_C_OVER_B = 2.0
STRETCH_C_OVER_A = 0.5
TARGET_RSS_MB = 300.0


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


# --------------------------------------------------------------------------------------------
# (a), (b), (c)


@dataclass
class Run:
    frames: int
    seconds: float
    rss_mb: float | None = None
    errors: int = 0
    unknown: int = 0

    @property
    def rate(self) -> float:
        return self.frames / self.seconds if self.seconds else 0.0


def bare_read(path: Path) -> Run:
    """(a) python-can's reader alone."""
    started = time.perf_counter()
    n = 0
    for _ in can.LogReader(str(path)):
        n += 1
    return Run(n, time.perf_counter() - started)


def naive_convert(path: Path, output: Path) -> Run:
    """(b) The straightforward converter: LogReader → cantools → mcap_protobuf Writer (zstd)."""
    from google.protobuf import descriptor_pool
    from mcap_protobuf.writer import Writer

    from bridge.decode.proto_schema import MessageSchema
    from bridge.pb.can_frame_pb2 import CanFrame

    started = time.perf_counter()
    db = cantools.database.load_file(str(ECOCAR_DBC), strict=False)
    assert isinstance(db, Database)
    pool = descriptor_pool.DescriptorPool()
    schemas = {m.frame_id: (m.name, MessageSchema(m, "ecocar", pool)) for m in db.messages}
    # Every field the recorder writes: the schema (schemas/can_frame.proto) is the contract.
    with_time = "timestamp_ns" in CanFrame.DESCRIPTOR.fields_by_name
    frames = errors = unknown = 0
    with output.open("wb") as stream, Writer(stream) as writer:
        for msg in can.LogReader(str(path)):
            frames += 1
            bus = f"can{msg.channel}"
            t = round(msg.timestamp * 1_000_000) * 1000
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
            if schema.renamed:
                signals = {schema.renamed.get(k, k): v for k, v in signals.items()}
            writer.write_message(f"/can/{bus}/{name}", schema.message_class(**signals),
                                 log_time=t, publish_time=t)
    return Run(frames, time.perf_counter() - started, errors=errors, unknown=unknown)


def tankviz_convert(path: Path, output: Path, frames: int) -> Run:
    """(c) ``tankviz convert`` in its own process: wall time and that process's peak RSS."""
    command = [sys.executable, "-m", "bridge", "convert", str(path), "-o", str(output),
               "--dbc", str(ECOCAR_DBC), "--quiet", "--force"]
    started = time.perf_counter()
    proc = subprocess.Popen(command)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - started
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"tankviz convert failed with status {proc.returncode}: "
                         f"{' '.join(command)}")
    return Run(frames, seconds, rss_mb=usage.ru_maxrss / 1024)  # ru_maxrss: KiB on Linux


def startup_seconds() -> float:
    """Interpreter start-up plus importing what ``convert`` imports, part of (c)'s time."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import bridge.cli, bridge.apps.convert"], check=True)
    return time.perf_counter() - started


def topic_counts(path: Path) -> dict[str, int]:
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None, f"{path}: no summary"
    return {summary.channels[cid].topic: n
            for cid, n in summary.statistics.channel_message_counts.items()}


def compare_outputs(naive: Path, ours: Path) -> list[str]:
    a, b = topic_counts(naive), topic_counts(ours)
    problems = []
    for topic in sorted(set(a) | set(b)):
        if a.get(topic, 0) != b.get(topic, 0):
            problems.append(f"{topic}: naive {a.get(topic, 0)}, tankviz {b.get(topic, 0)}")
    return problems


# --------------------------------------------------------------------------------------------


def _warm(path: Path) -> None:
    """Read the file once so (a), (b) and (c) all start from the page cache."""
    with path.open("rb") as f:
        while f.read(1 << 22):
            pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--frames", type=int, default=1_000_000, help="first log length")
    parser.add_argument("--frames2", type=int, default=2_000_000, help="second log length")
    parser.add_argument("--quick", action="store_true", help="200k and 400k frames")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workdir", type=Path,
                        default=Path(tempfile.gettempdir()) / "tankviz-bench",
                        help="where logs are cached and outputs written")
    args = parser.parse_args(argv)
    lengths = [200_000, 400_000] if args.quick else [args.frames, args.frames2]
    args.workdir.mkdir(parents=True, exist_ok=True)

    results: list[tuple[int, dict[str, Any], Run, Run, Run]] = []
    loads: list[float] = []  # 1-minute load average around the timed steps
    for n in lengths:
        path, meta = synthetic_log(args.workdir, n, args.seed)
        how = "cached" if meta["cached"] else f"generated in {meta['generation_seconds']:.1f} s"
        print(f"log {path.name}: {meta['frames']:,} frames, "
              f"{meta['seconds_of_driving']:.0f} s of driving, {meta['bytes'] / MB:.1f} MB "
              f"({how}); per bus {meta['frames_per_bus']}; payload = previous one of its id "
              f"{meta['repeat_previous_payload_of_id']:.1%}, one of the last 16 of its id "
              f"{meta['repeat_one_of_last_16_payloads_of_id']:.1%}", flush=True)
        _warm(path)
        loads.append(os.getloadavg()[0])
        a = bare_read(path)
        naive_out = args.workdir / f"naive-{n}.mcap"
        ours_out = args.workdir / f"tankviz-{n}.mcap"
        b = naive_convert(path, naive_out)
        loads.append(os.getloadavg()[0])
        c = tankviz_convert(path, ours_out, a.frames)
        loads.append(os.getloadavg()[0])
        problems = compare_outputs(naive_out, ours_out)
        if problems:
            print(f"WARNING: (b) and (c) wrote different message counts at {n:,} frames:")
            for p in problems[:20]:
                print(f"  {p}")
        else:
            print(f"  (b) and (c) wrote the same messages per topic ({n:,} frames; "
                  f"{b.unknown:,} frames of an unknown id, {b.errors:,} decode errors); "
                  f"MCAP sizes: naive {naive_out.stat().st_size / MB:.1f} MB, "
                  f"tankviz {ours_out.stat().st_size / MB:.1f} MB", flush=True)
        naive_out.unlink()
        ours_out.unlink()
        results.append((n, meta, a, b, c))

    startup = startup_seconds()
    print()
    print(f"{'':36}{'frames':>12}{'seconds':>10}{'frames/s':>12}{'peak RSS':>12}")
    for n, _meta, a, b, c in results:
        print(f"{n:,} frames")
        for label, r in (("(a) can.LogReader iteration", a),
                         ("(b) naive: LogReader+cantools+mcap", b),
                         ("(c) tankviz convert (subprocess)", c)):
            rss = f"{r.rss_mb:,.0f} MB" if r.rss_mb is not None else ""
            print(f"  {label:<34}{r.frames:>12,}{r.seconds:>10.2f}{r.rate:>12,.0f}{rss:>12}")
        print(f"  ratios: c/b = {c.rate / b.rate:.2f} (target ≥ {TARGET_C_OVER_B}), "
              f"c/a = {c.rate / a.rate:.2f} (stretch ≥ {STRETCH_C_OVER_A})")
    print(f"(c) includes {startup:.2f} s of interpreter start-up and imports; "
          f"peak RSS of this benchmark process: "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")

    cores = os.cpu_count() or 1
    print(f"1-min load average around the timed steps: {min(loads):.2f}..{max(loads):.2f} "
          f"({cores} cores; this benchmark adds about 1)")
    if max(loads) > cores:
        print("NOTE: other processes competed for the CPU during the run: the figures are noisy")
    missed = []
    for n, _meta, a, b, c in results:
        if c.rate / b.rate < TARGET_C_OVER_B:
            missed.append(f"c/b = {c.rate / b.rate:.2f} < {TARGET_C_OVER_B} at {n:,} frames")
        if c.rate / a.rate < STRETCH_C_OVER_A:
            missed.append(f"(stretch) c/a = {c.rate / a.rate:.2f} < {STRETCH_C_OVER_A} "
                          f"at {n:,} frames")
        assert c.rss_mb is not None
        if c.rss_mb >= TARGET_RSS_MB:
            missed.append(f"RSS of (c) {c.rss_mb:.0f} MB ≥ {TARGET_RSS_MB:.0f} MB at {n:,} frames")
    if len(results) >= 2:
        (n1, _, _, _, c1), (n2, _, _, _, c2) = results[0], results[-1]
        assert c1.rss_mb is not None and c2.rss_mb is not None
        growth = c2.rss_mb - c1.rss_mb
        print(f"RSS of (c): {c1.rss_mb:.0f} MB at {n1:,} frames, {c2.rss_mb:.0f} MB at "
              f"{n2:,} frames ({growth:+.0f} MB)")
        if growth > max(10.0, 0.1 * c1.rss_mb):
            missed.append(f"RSS of (c) grows with the log: {c1.rss_mb:.0f} MB at {n1:,} "
                          f"frames, {c2.rss_mb:.0f} MB at {n2:,} frames")
    for m in missed:
        print(f"TARGET MISSED: {m}")
    if not missed:
        print("all targets met")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
