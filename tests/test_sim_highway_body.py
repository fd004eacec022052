"""The highway car's unknown ids (:mod:`bridge.sim.highway_body`): frames its databases do not
define, as a real car sends them, for bring-up to find the signals in.

Each test reads like an example: the payloads taken apart by the layouts the module states (the
speed and yaw rate fields decoded by cantools from a DBC line made of them) and held against the
ground truth (:func:`ego_at`, :func:`brake_at`); the frames of the ids the databases define are
the same with the unknown ids as without them.
"""

from __future__ import annotations

import functools
import itertools
import math
import statistics
from collections import defaultdict
from typing import Any, cast

import cantools
import pytest

from bridge.frame import NS, Frame
from bridge.sim.highway import (
    CAR_BUS,
    RADAR_BUS,
    ROADS,
    SPEEDOMETER_GAIN,
    _simulate,
    ego_at,
    highway_database,
    simulate_highway,
)
from bridge.sim.highway_body import (
    BRAKE_BIT,
    BRAKE_ID,
    BRAKE_PRESSES,
    CAR_IDS,
    CONSTANT_ID,
    HEARTBEAT_ID,
    RADAR_IDS,
    RADAR_STATUS_ID,
    SPEED_FIELD,
    UNKNOWN_IDS,
    YAW_FIELD,
    Field,
    brake_at,
)
from bridge.sim.scenario import DEFAULT_START_NS

MS = 1_000_000
#: id -> (bus, cycle in ms, payload length)
LAYOUT = {BRAKE_ID: (CAR_BUS, 20, 8), HEARTBEAT_ID: (CAR_BUS, 100, 4),
          CONSTANT_ID: (CAR_BUS, 500, 2), RADAR_STATUS_ID: (RADAR_BUS, 100, 8)}
#: The bits of the 8-bit rolling counters that stay the same for 16 frames or more (1.6 s at
#: 100 ms): bits 4 to 7 of 0x3B7's byte 3 and of 0x2E0's byte 0.
SLOW_COUNTER_BITS = {(HEARTBEAT_ID, bit) for bit in range(28, 32)} | {
    (RADAR_STATUS_ID, bit) for bit in range(4, 8)}


@functools.cache
def drive(road: str = "curve") -> tuple[Frame, ...]:
    return tuple(simulate_highway(road=road))  # the whole 60 s drive, seed 0


def of(frames: tuple[Frame, ...], frame_id: int) -> list[tuple[int, bytes]]:
    """``(tick k, payload)`` of every frame of one id: cycle k is sent within its first half."""
    bus, cycle_ms, _ = LAYOUT[frame_id]
    return [((f.timestamp_ns - DEFAULT_START_NS) // (cycle_ms * MS), f.data)
            for f in frames if f.arbitration_id == frame_id and f.bus == bus]


def dbc_line(name: str, field: Field) -> str:
    return (f" SG_ {name} : {field.start}|{field.length}@{0 if field.big_endian else 1}"
            f"{'-' if field.signed else '+'} ({field.scale:g},{field.offset:g}) [0|0] \"\" X\n")


@functools.cache
def fields_db() -> cantools.database.can.Database:
    """The speed and yaw rate fields as a DBC would state them: cantools decodes them."""
    text = ('VERSION ""\n\nBU_: X\n\n'
            f"BO_ {BRAKE_ID} UNKNOWN_2C4: 8 X\n"
            + dbc_line("SPEED", SPEED_FIELD) + dbc_line("YAW", YAW_FIELD) + "\n")
    database = cantools.database.load_string(text, "dbc")
    assert isinstance(database, cantools.database.can.Database)
    return database


def bit(data: bytes, i: int) -> int:
    return (data[i // 8] >> (i % 8)) & 1


# ---------------------------------------------------------------------------------------------
# The ids and their frames
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_unknown_ids_are_in_no_highway_database_and_on_their_buses() -> None:
    defined = {m.frame_id for name in ("car", "radar") for m in highway_database(name).messages}
    assert not defined & set(UNKNOWN_IDS)
    assert (set(CAR_IDS), set(RADAR_IDS)) == ({0x2C4, 0x3B7, 0x4C8}, {0x2E0})
    seen = {(f.bus, f.arbitration_id) for f in drive() if f.arbitration_id not in defined}
    assert seen == {(CAR_BUS, i) for i in CAR_IDS} | {(RADAR_BUS, i) for i in RADAR_IDS}
    assert (CAR_BUS, RADAR_BUS) == ("can0", "can1")


@pytest.mark.slow
@pytest.mark.parametrize("frame_id", sorted(LAYOUT))
def test_every_unknown_id_comes_every_cycle_at_its_length(frame_id: int) -> None:
    _, cycle_ms, length = LAYOUT[frame_id]
    frames = [f for f in drive() if f.arbitration_id == frame_id]
    assert len(frames) == 60_000 // cycle_ms  # every cycle of the 60 s, none at or after the end
    ticks = [k for k, _ in of(drive(), frame_id)]
    assert ticks == list(range(len(frames)))
    assert all(len(f.data) == f.dlc == length for f in frames)
    assert not any(f.is_fd or f.is_extended or f.is_error or f.is_remote for f in frames)
    assert all(f.timestamp_ns % 1000 == 0 for f in frames)  # whole microseconds
    gaps = [(b.timestamp_ns - a.timestamp_ns) / MS for a, b in itertools.pairwise(frames)]
    assert max(abs(g - cycle_ms) for g in gaps) < 0.2  # a little jitter


@pytest.mark.slow
def test_0x2c4_carries_the_speedometer_the_brake_switch_and_the_yaw_rate() -> None:
    for road in ROADS:
        frames = of(drive(road), BRAKE_ID)
        yaw_errors = []
        for k, data in frames:
            t = k * 20 * MS / NS
            ego = ego_at(t, ROADS[road])
            assert data[0] == 0xA5 and data[1] >> 4 == 0
            signals = cast(dict[str, Any], fields_db().decode_message(BRAKE_ID, data))
            # big-endian 16 bits, byte 2 the high one: raw = (m/s + 20) / 0.001
            raw = int.from_bytes(data[2:4], "big")
            assert signals["SPEED"] == pytest.approx(raw * 0.001 - 20.0)
            assert abs(signals["SPEED"] - ego.speed * SPEEDOMETER_GAIN) < 0.01, (road, t)
            assert bit(data, BRAKE_BIT) == brake_at(t) and data[4] >> 1 == 0, (road, t)
            # little-endian signed 16 bits: raw = deg/s / 0.01
            yaw = int.from_bytes(data[5:7], "little", signed=True) * 0.01
            assert signals["YAW"] == pytest.approx(yaw)
            yaw_errors.append(yaw - math.degrees(ego.yaw_rate))
            fid = BRAKE_ID
            assert data[7] == ((fid & 0xFF) + (fid >> 8) + 8 + sum(data[:7])) & 0xFF
        assert abs(statistics.mean(yaw_errors)) < 0.005
        assert 0.025 < statistics.stdev(yaw_errors) < 0.035  # 0.03 deg/s of noise
        assert max(map(abs, yaw_errors)) < 0.2
        counters = [data[1] & 0x0F for _, data in frames]
        assert all(b == (a + 1) % 16 for a, b in itertools.pairwise(counters))


@pytest.mark.slow
def test_the_speed_fields_changing_bits_span_more_than_a_byte_on_every_road() -> None:
    """30 m/s +-0.25 m/s read 1.5 % high: raw about 50190 to 50710 (0xC40E to 0xC616)."""
    for road in ROADS:
        raws = [int.from_bytes(data[2:4], "big") for _, data in of(drive(road), BRAKE_ID)]
        changing = functools.reduce(lambda acc, r: acc | (r ^ raws[0]), raws, 0)
        assert changing.bit_length() > 8 and changing >> 8, (road, min(raws), max(raws))
        assert min(raws) > 50_100 and max(raws) < 50_800


def test_the_brake_is_pressed_at_the_stated_times() -> None:
    assert BRAKE_PRESSES == ((14.0, 17.0), (45.0, 48.0))
    assert [brake_at(t) for t in (0.0, 13.99, 14.0, 16.99, 17.0, 44.99, 45.0, 47.99, 48.0)] == [
        False, False, True, True, False, False, True, True, False]
    pressed = [k for k, data in of(drive(), BRAKE_ID) if bit(data, BRAKE_BIT)]
    assert pressed == [*range(700, 850), *range(2250, 2400)]  # 20 ms ticks


def test_the_counted_and_constant_ids() -> None:
    heartbeat = [data for _, data in of(drive(), HEARTBEAT_ID)]
    assert {data[:3] for data in heartbeat} == {b"\x01\x00\x7f"}
    assert all(b[3] == (a[3] + 1) % 256 for a, b in itertools.pairwise(heartbeat))
    radar = [data for _, data in of(drive(), RADAR_STATUS_ID)]
    assert {data[1:] for data in radar} == {b"\x00\x00\x40\x00\x00\x00\x12"}
    assert all(b[0] == (a[0] + 1) % 256 for a, b in itertools.pairwise(radar))
    assert {data for _, data in of(drive(), CONSTANT_ID)} == {b"\x00\x10"}


@pytest.mark.slow
def test_the_seed_changes_counter_starts_and_noise_never_the_brake() -> None:
    one = of(tuple(simulate_highway(duration_s=20.0, seed=1)), BRAKE_ID)
    two = of(tuple(simulate_highway(duration_s=20.0, seed=2)), BRAKE_ID)
    assert [bit(d, BRAKE_BIT) for _, d in one] == [bit(d, BRAKE_BIT) for _, d in two]
    assert [d for _, d in one] != [d for _, d in two]


# ---------------------------------------------------------------------------------------------
# The defined ids are not changed by them
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("road", list(ROADS))
def test_the_defined_ids_frames_are_the_same_as_without_the_unknown_ids(road: str) -> None:
    """The unknown ids' families draw from randomness of their own, and merge in between."""
    defined = [f for f in drive(road) if f.arbitration_id not in UNKNOWN_IDS]
    assert defined == list(_simulate(60.0, 0, DEFAULT_START_NS, road, unknown=False))
    assert len(defined) == 58_400 and len(drive(road)) == 58_400 + 3000 + 600 + 120 + 600
    short = list(simulate_highway(duration_s=7.3, seed=5, road=road, start_ns=NS))
    assert [f for f in short if f.arbitration_id not in UNKNOWN_IDS] == list(
        _simulate(7.3, 5, NS, road, unknown=False))


# ---------------------------------------------------------------------------------------------
# Around the brake: only the brake switch switches
# ---------------------------------------------------------------------------------------------


def switches(frames: tuple[Frame, ...], edge: float) -> set[tuple[int, int]]:
    """(id, bit) of every bit of the unknown ids that is the same in every frame of the 1.4 s
    before ``edge`` (to 0.1 s before it) and the other value in every frame of the 1.4 s after
    (from 0.1 s after it)."""
    payloads: dict[int, list[tuple[float, bytes]]] = defaultdict(list)
    for f in frames:
        if f.arbitration_id in UNKNOWN_IDS:
            payloads[f.arbitration_id].append(((f.timestamp_ns - DEFAULT_START_NS) / NS, f.data))
    found = set()
    for frame_id, sent in payloads.items():
        before = [d for t, d in sent if edge - 1.5 <= t < edge - 0.1]
        after = [d for t, d in sent if edge + 0.1 < t <= edge + 1.5]
        assert before and after
        for i in range(8 * len(sent[0][1])):
            was, now = {bit(d, i) for d in before}, {bit(d, i) for d in after}
            if len(was) == len(now) == 1 and was != now:
                found.add((frame_id, i))
    return found


EDGES = sorted(t for press in BRAKE_PRESSES for t in press)


@pytest.mark.slow
@pytest.mark.parametrize("road", list(ROADS))
def test_only_the_brake_switch_switches_at_every_brake_edge(road: str) -> None:
    at = [switches(drive(road), edge) for edge in EDGES]
    assert set.intersection(*at) == {(BRAKE_ID, BRAKE_BIT)}


@pytest.mark.slow
@pytest.mark.parametrize("road", list(ROADS))
def test_at_one_brake_edge_nothing_but_the_brake_switch_and_slow_counter_bits_switch(
        road: str) -> None:
    """A bit of an 8-bit counter sent every 100 ms from bit 4 up stays the same for 1.6 s or
    more: steady through a 1.4 s window, it seems to switch when it flips between the two; no
    field (speed, yaw rate), constant or checksum bit does (seed 0: 0x3B7's bits 28 and 29 at
    17 s, 0x2E0's bit 4 at 45 s). The speed field's bit 16 (raw 0xC4xx below 30.432 m/s, 0xC5xx
    above) nearly does at 14 s, where the speed crosses 29.98 m/s 0.16 s before the press:
    two frames of the 1.4 s before it keep it from switching."""
    for edge in EDGES:
        found = switches(drive(road), edge)
        assert (BRAKE_ID, BRAKE_BIT) in found
        assert found - {(BRAKE_ID, BRAKE_BIT)} <= SLOW_COUNTER_BITS, (road, edge)
