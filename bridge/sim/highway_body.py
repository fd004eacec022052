"""The highway car's unknown ids: frames its databases do not define, as a real car sends them.

:func:`body_families` adds four such ids to :func:`bridge.sim.highway.simulate_highway`, each a
family with its own randomness (``run.rng``), so the defined ids' frames are the same with them
as without. Their ground truth is here (:data:`BRAKE_PRESSES`, :func:`brake_at`). Bit i is bit
``i % 8`` of byte ``i // 8``; a big-endian field's start bit is its most significant (``@0``), a
little-endian one's its least (``@1``), as in a DBC. Cycle k measures at ``k * cycle`` and is sent
at start + phase (up to half a cycle) + ``k * cycle`` + up to 200 us, in whole microseconds; none at
or after the end of the run. The seed changes noise, jitter, phases and counter starts, never the
brake presses.

=======  =====  =====  ===  =============================================================
id       bus    cycle  len  payload
=======  =====  =====  ===  =============================================================
0x2C4    can0   20 ms  8    byte 0: 0xA5; byte 1: bits 0-3 a rolling counter (0..15, +1 a
                            frame, its start drawn per seed), bits 4-7 0; bytes 2-3: the
                            speedometer (the ego's speed * ``SPEEDOMETER_GAIN`` + 0.0035 m/s
                            of noise, m/s), unsigned big-endian, ``23|16@0+ (0.001,-20)``;
                            byte 4: bit 32 the brake switch (1 while pressed), bits 33-39
                            0; bytes 5-6: the yaw rate (deg/s, left, + 0.03 deg/s of noise),
                            signed little-endian, ``40|16@1- (0.01,0)``; byte 7: checksum
                            ``(id & 0xFF) + (id >> 8) + 8 + bytes 0..6``, & 0xFF
0x3B7    can0   100 ms 4    bytes 0-2: 0x01 0x00 0x7F; byte 3: a rolling counter (0..255)
0x4C8    can0   500 ms 2    0x00 0x10
0x2E0    can1   100 ms 8    byte 0: a rolling counter (0..255); bytes 1-7: 0x00 0x00 0x40
                            0x00 0x00 0x00 0x12
=======  =====  =====  ===  =============================================================
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from typing import NamedTuple, Protocol

from bridge.frame import NS, Frame
from bridge.sim.highway_world import Highway, ego_at

__all__ = ["BRAKE_BIT", "BRAKE_ID", "BRAKE_PRESSES", "CAR_IDS", "CONSTANT_ID", "HEARTBEAT_ID",
           "RADAR_IDS", "RADAR_STATUS_ID", "SPEED_FIELD", "UNKNOWN_IDS", "YAW_FIELD", "BodyRun",
           "Field", "body_families", "brake_at"]

#: The ids (all 11-bit): on the car bus the brake/speed/yaw message, a heartbeat with a
#: counter, a constant one; on the radar bus a status with a counter.
BRAKE_ID = 0x2C4
HEARTBEAT_ID = 0x3B7
CONSTANT_ID = 0x4C8
RADAR_STATUS_ID = 0x2E0
#: The unknown ids of the car bus (``can0``), of the radar bus (``can1``), and all of them.
CAR_IDS = (BRAKE_ID, HEARTBEAT_ID, CONSTANT_ID)
RADAR_IDS = (RADAR_STATUS_ID,)
UNKNOWN_IDS = CAR_IDS + RADAR_IDS

#: The brake is pressed from the first to the second time (seconds after the start).
BRAKE_PRESSES: tuple[tuple[float, float], ...] = ((14.0, 17.0), (45.0, 48.0))
#: The brake switch: bit 0 of byte 4 of :data:`BRAKE_ID`.
BRAKE_BIT = 32


class Field(NamedTuple):
    """A field as a DBC says it: ``start|length@(0 big-endian, 1 little-endian)(+/-)
    (scale,offset)``; physical value = raw * scale + offset."""

    start: int
    length: int
    big_endian: bool
    signed: bool
    scale: float
    offset: float


#: The speedometer in :data:`BRAKE_ID`, m/s: ``23|16@0+ (0.001,-20)``.
SPEED_FIELD = Field(start=23, length=16, big_endian=True, signed=False, scale=0.001,
                    offset=-20.0)
#: The yaw rate in :data:`BRAKE_ID`, deg/s (left): ``40|16@1- (0.01,0)``.
YAW_FIELD = Field(start=40, length=16, big_endian=False, signed=True, scale=0.01, offset=0.0)

_SPEED_NOISE_MPS = 0.0035  # cut at 2.5 sigma: the field is within 0.01 m/s of the truth
_YAW_NOISE_DEG_S = 0.03


def brake_at(t_s: float) -> bool:
    """Whether the brake is pressed ``t_s`` seconds after the start (:data:`BRAKE_PRESSES`:
    from each press's start, inclusive, to its end, exclusive)."""
    return any(begin <= t_s < end for begin, end in BRAKE_PRESSES)


class BodyRun(Protocol):
    """What the families need of the run: its road, end, randomness and timing."""

    @property
    def highway(self) -> Highway: ...

    @property
    def end_ns(self) -> int: ...

    def rng(self, family: str) -> random.Random: ...

    def ticks(self, rng: random.Random, cycle_ms: int, phase_us: tuple[int, int],
              jitter_us: int = 200) -> Iterator[tuple[int, int]]: ...


def _frame(ts: int, bus: str, frame_id: int, data: bytes) -> Frame:
    return Frame(ts, bus, frame_id, data, False, False, False, False, False, False, len(data))


def _cut(rng: random.Random, sigma: float) -> float:
    return max(-2.5 * sigma, min(2.5 * sigma, rng.gauss(0.0, sigma)))


def _brake_speed_yaw(run: BodyRun, bus: str, speedometer_gain: float) -> Iterator[Frame]:
    rng = run.rng(f"unknown-{BRAKE_ID:03X}")
    counter = rng.randrange(16)
    for tick, ts in run.ticks(rng, 20, (0, 10_000)):
        if ts >= run.end_ns:
            return
        t = tick / NS
        ego = ego_at(t, run.highway)
        speed = ego.speed * speedometer_gain + _cut(rng, _SPEED_NOISE_MPS)
        yaw = math.degrees(ego.yaw_rate) + rng.gauss(0.0, _YAW_NOISE_DEG_S)
        raw_speed = min(max(round((speed - SPEED_FIELD.offset) / SPEED_FIELD.scale), 0), 0xFFFF)
        raw_yaw = min(max(round(yaw / YAW_FIELD.scale), -0x8000), 0x7FFF)
        head = (bytes((0xA5, counter)) + raw_speed.to_bytes(2, "big")
                + bytes((int(brake_at(t)),)) + raw_yaw.to_bytes(2, "little", signed=True))
        total = (BRAKE_ID & 0xFF) + (BRAKE_ID >> 8) + 8 + sum(head)
        yield _frame(ts, bus, BRAKE_ID, head + bytes((total & 0xFF,)))
        counter = (counter + 1) % 16


def _counted(run: BodyRun, bus: str, frame_id: int, cycle_ms: int, before: bytes,
             after: bytes) -> Iterator[Frame]:
    """A message of constant bytes around an 8-bit rolling counter."""
    rng = run.rng(f"unknown-{frame_id:03X}")
    counter = rng.randrange(256)
    for _, ts in run.ticks(rng, cycle_ms, (0, cycle_ms * 1000 // 2)):
        if ts >= run.end_ns:
            return
        yield _frame(ts, bus, frame_id, before + bytes((counter,)) + after)
        counter = (counter + 1) % 256


def _constant(run: BodyRun, bus: str, frame_id: int, cycle_ms: int,
              data: bytes) -> Iterator[Frame]:
    rng = run.rng(f"unknown-{frame_id:03X}")
    for _, ts in run.ticks(rng, cycle_ms, (0, cycle_ms * 1000 // 2)):
        if ts >= run.end_ns:
            return
        yield _frame(ts, bus, frame_id, data)


def body_families(run: BodyRun, *, car_bus: str, radar_bus: str,
                  speedometer_gain: float) -> list[Iterator[Frame]]:
    """The unknown ids' families, each in timestamp order (the module docstring's table);
    ``speedometer_gain``: what the speedometer reads high, as the car's own SPEED."""
    return [
        _brake_speed_yaw(run, car_bus, speedometer_gain),
        _counted(run, car_bus, HEARTBEAT_ID, 100, b"\x01\x00\x7f", b""),
        _constant(run, car_bus, CONSTANT_ID, 500, b"\x00\x10"),
        _counted(run, radar_bus, RADAR_STATUS_ID, 100, b"", b"\x00\x00\x40\x00\x00\x00\x12"),
    ]
