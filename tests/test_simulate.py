"""The simulator: realistic, deterministic ecocar traffic, and the scripted scenario it tells.

Scenario facts are checked the way a consumer sees them: by decoding the frames with the DBC.
"""

from __future__ import annotations

import functools
import importlib
import itertools
import math
import sys
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any, NamedTuple

import cantools
import pytest
from cantools.database.namedsignalvalue import NamedSignalValue

from bridge.frame import Frame
from bridge.io.can_logs import LogSource
from bridge.sim.ecocar import simulate
from bridge.sim.ego import STEERING_RATIO, WHEELBASE_M
from bridge.sim.frames import load_ecocar
from bridge.sim.scenario import (
    BABBLE_PERIOD_US,
    DEFAULT_START_NS,
    FAULT_ONSET_S,
    FAULT_RECOVERY_S,
    MISALIGNMENT_DEG,
    RADAR_SLOW_EVERY,
    SCENARIOS,
    TIMELINE,
    Episode,
)

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_LOG = ROOT / "bridge" / "data" / "ecocar_sample.blf"
DURATION_S = 10.0

RADAR_IDS = {0x300, 0x301, *range(0x310, 0x350)}
LANE_MESSAGES = ("CamLaneLeft", "CamLaneRight", "CamLaneNextLeft", "CamLaneNextRight")


class Decoded(NamedTuple):
    t: float  # seconds since the start of the run
    timestamp_ns: int
    name: str
    signals: dict[str, Any]


def decode(message: Any, data: bytes) -> dict[str, Any]:
    """Signal values by name; value-table entries as their names (``"pedestrian"``)."""
    return {name: value.name if isinstance(value, NamedSignalValue) else value
            for name, value in message.decode(data).items()}


@pytest.fixture(scope="module")
def db() -> cantools.database.can.Database:
    return load_ecocar()


@pytest.fixture(scope="module")
def frames() -> list[Frame]:
    return list(simulate(duration_s=DURATION_S))


@pytest.fixture(scope="module")
def drive(frames: list[Frame], db: cantools.database.can.Database) -> list[Decoded]:
    """The 10 s drive, decoded with the DBC (value tables as names)."""
    out = []
    for f in frames:
        message = db.get_message_by_frame_id(f.arbitration_id)
        out.append(Decoded((f.timestamp_ns - DEFAULT_START_NS) / 1e9, f.timestamp_ns,
                           message.name, decode(message, f.data)))
    return out


def named(drive: list[Decoded], name: str) -> list[Decoded]:
    return [d for d in drive if d.name == name]


def window(episode: Episode, duration_s: float = DURATION_S) -> tuple[float, float]:
    return episode.window_s(duration_s)


def radar_objects(drive: list[Decoded]) -> list[dict[str, Any]]:
    """Every radar object report: part A and part B of one slot in one cycle, merged."""
    part_a: dict[int, dict[str, Any]] = {}
    objects = []
    for d in drive:
        if d.name.startswith("RadarObj"):
            slot_text, part = d.name.removeprefix("RadarObj").split("_")
            slot = int(slot_text)
            if part == "A":
                part_a[slot] = d.signals
            else:
                objects.append({**part_a.pop(slot), **d.signals, "slot": slot, "t": d.t})
    return objects


# --- frames on the bus ------------------------------------------------------------------------


def test_every_frame_decodes_with_the_ecocar_dbc(frames: list[Frame],
                                                  db: cantools.database.can.Database) -> None:
    assert len(frames) > 20_000
    for f in frames:
        message = db.get_message_by_frame_id(f.arbitration_id)
        message.decode(f.data)
        assert len(f.data) == message.length == f.dlc
        assert f.is_fd == message.is_fd
        assert f.bus == "can0" and not f.is_extended and not f.is_error and not f.is_remote
    assert {f.arbitration_id for f in frames if f.is_fd} == {db.get_message_by_name(
        "RadarHeader").frame_id}


def test_the_same_seed_gives_the_same_frames_and_another_seed_other_frames() -> None:
    first = list(simulate(duration_s=3.0, seed=7))
    assert first == list(simulate(duration_s=3.0, seed=7))
    other = list(simulate(duration_s=3.0, seed=8))
    assert [f.data for f in other] != [f.data for f in first]
    assert [f.timestamp_ns for f in other] != [f.timestamp_ns for f in first]


@pytest.mark.slow
def test_passing_the_database_explicitly_changes_nothing() -> None:
    assert list(simulate(duration_s=1.0, database=load_ecocar())) == list(
        simulate(duration_s=1.0))


def test_a_database_without_the_ecocar_messages_is_refused_at_once() -> None:
    with pytest.raises(ValueError, match="EgoMotion"):
        simulate(duration_s=1.0, database=cantools.database.can.Database())


def test_timestamps_start_at_start_ns_and_never_go_back() -> None:
    start = 1_000_000_000_000
    stamps = [f.timestamp_ns for f in simulate(duration_s=2.0, start_ns=start, bus="vehicle")]
    assert stamps[0] == start
    assert all(a <= b for a, b in itertools.pairwise(stamps))
    assert stamps[-1] < start + 2 * 10**9
    assert all(t % 1000 == 0 for t in stamps)  # whole microseconds: exact through any log


def test_the_bus_name_is_the_one_asked_for() -> None:
    assert {f.bus for f in simulate(duration_s=0.5, bus="vehicle")} == {"vehicle"}


def test_a_duration_must_be_positive() -> None:
    with pytest.raises(ValueError, match="duration_s"):
        simulate(duration_s=0)


def test_every_message_comes_at_its_dbc_cycle_time(frames: list[Frame],
                                                   db: cantools.database.can.Database) -> None:
    counts = Counter(f.arbitration_id for f in frames)
    begin, end = window(TIMELINE.radar_dropout)
    for message in db.messages:
        assert message.cycle_time, message.name
        expected = DURATION_S * 1000 / message.cycle_time
        if message.frame_id in RADAR_IDS:
            expected *= 1 - (end - begin) / DURATION_S
        assert counts[message.frame_id] == pytest.approx(expected, rel=0.03, abs=1), message.name


def test_frames_of_one_cycle_are_spread_over_the_bus_with_jitter(drive: list[Decoded]) -> None:
    headers = [d.timestamp_ns for d in named(drive, "RadarHeader")]
    periods = {b - a for a, b in itertools.pairwise(headers) if b - a < 60_000_000}
    assert len(periods) > 10  # not a perfect clock
    assert all(49_000_000 < p < 51_000_000 for p in periods)
    first_cycle = [d.timestamp_ns for d in drive if d.name.startswith("RadarObj")][:64]
    assert len(set(first_cycle)) == 64


def test_counters_roll_and_checksums_follow_the_dbc_rule(frames: list[Frame],
                                                         drive: list[Decoded]) -> None:
    for name in ("EgoMotion", "Steering", "RadarObj5_A", "LeadVehicle"):
        counters = [d.signals["Counter"] for d in named(drive, name)]
        assert all(b == (a + 1) % 16 for a, b in itertools.pairwise(counters)), name
        assert set(counters) == set(range(16))
    lanes = [d.signals["Counter"] for d in named(drive, "CamLaneLeft")]
    assert all(b == (a + 1) % 4 for a, b in itertools.pairwise(lanes))
    for f, d in zip(frames, drive, strict=True):
        if d.name in ("EgoMotion", "Steering"):
            # Checksum = (byte0 + ... + byte6) & 0xFF, carried in byte 7
            assert d.signals["Checksum"] == sum(f.data[:7]) & 0xFF == f.data[7]


def test_payloads_repeat_only_partly_like_real_traffic(frames: list[Frame]) -> None:
    ego = [f.data for f in frames if f.arbitration_id == 0x100]
    assert len(set(ego)) > 0.9 * len(ego)


# --- the ego vehicle --------------------------------------------------------------------------


def test_ego_drives_about_25_mps_and_yaw_rate_and_steering_follow_the_curvature(
        drive: list[Decoded]) -> None:
    ego = named(drive, "EgoMotion")
    steering = named(drive, "Steering")
    speeds = [d.signals["VehicleSpeed"] for d in ego]  # km/h
    assert speeds[0] == pytest.approx(90, abs=1)
    assert min(speeds) < 70  # the ego (ACC) brakes behind the braking lead vehicle
    yaw_rates = [d.signals["YawRate"] for d in ego]
    assert max(yaw_rates) > 1.0 and min(yaw_rates) < -1.0  # an S-curve: left, then right
    for e, s in zip(ego, steering, strict=True):
        v = e.signals["VehicleSpeed"] / 3.6
        curvature = math.radians(e.signals["YawRate"]) / v
        angle = STEERING_RATIO * math.degrees(math.atan(WHEELBASE_M * curvature))
        assert s.signals["SteeringWheelAngle"] == pytest.approx(angle, abs=1.0)
        assert e.signals["LatAccel"] == pytest.approx(v * v * curvature, abs=0.3)


# --- lanes ------------------------------------------------------------------------------------


def test_camera_lanes_bound_the_ego_lane_in_the_camera_sign_convention(
        drive: list[Decoded]) -> None:
    begin, end = window(TIMELINE.lane_dropout)
    expected = {"CamLaneLeft": -1.8, "CamLaneRight": 1.8,  # y positive RIGHT
                "CamLaneNextLeft": -5.4, "CamLaneNextRight": 5.4}
    for name, offset in expected.items():
        for d in named(drive, name):
            if not begin <= d.t < end:
                assert d.signals["Source"] == "camera" and d.signals["Quality"] == "high"
                assert d.signals["C0_Offset"] == pytest.approx(offset, abs=0.3)


def test_lane_curvature_matches_the_ego_yaw_rate(drive: list[Decoded]) -> None:
    ego = named(drive, "EgoMotion")
    for lane in named(drive, "CamLaneLeft")[::10]:
        if lane.signals["Source"] != "camera":
            continue
        e = min(ego, key=lambda d: abs(d.t - lane.t))
        curvature = math.radians(e.signals["YawRate"]) / (e.signals["VehicleSpeed"] / 3.6)
        # C2 is about half the curvature, positive = curving right
        assert -2 * lane.signals["C2_Curvature"] == pytest.approx(curvature, abs=6e-4)


def test_during_the_lane_dropout_the_camera_reports_no_lanes(drive: list[Decoded]) -> None:
    begin, end = window(TIMELINE.lane_dropout)
    inside = [d for d in drive if d.name in LANE_MESSAGES and begin <= d.t < end]
    assert len(inside) >= 4 * 14  # a second of camera cycles, all four lines
    for d in inside:
        assert d.signals["Source"] == "none" and d.signals["Quality"] == "none"
    after = [d for d in drive if d.name == "CamLaneLeft" and d.t >= end]
    assert after[0].signals["Source"] == "camera"  # the lanes come back


# --- lead vehicle and cut-in ------------------------------------------------------------------


def test_the_lead_vehicle_brakes_and_the_gap_shrinks(drive: list[Decoded]) -> None:
    begin, end = window(TIMELINE.lead_braking)
    lead = [d for d in named(drive, "LeadVehicle") if d.t < window(TIMELINE.cut_in)[0]]
    assert all(d.signals["Valid"] == "lead" for d in lead)
    assert len({d.signals["TrackID"] for d in lead}) == 1  # one stable track
    before = [d.signals["PosX"] for d in lead if d.t < begin]
    assert before == pytest.approx([40.0] * len(before), abs=1.0)
    at_end = [d for d in lead if end - 0.2 <= d.t < end]
    assert at_end and all(d.signals["PosX"] < 30 for d in at_end)
    closing = [d for d in lead if begin <= d.t < end]
    assert min(d.signals["RelVelX"] for d in closing) < -5
    assert min(d.signals["TTC"] for d in closing) < 10
    assert all(d.signals["TimeGap"] == pytest.approx(
        d.signals["PosX"] / 25, abs=0.6) for d in lead if d.t < begin)


def test_the_cut_in_car_becomes_the_lead_vehicle_inside_the_ego_lane(
        drive: list[Decoded]) -> None:
    begin, end = window(TIMELINE.cut_in)
    leads = named(drive, "LeadVehicle")
    first = next(d for d in leads if d.t >= begin - 0.5).signals
    last = [d.signals for d in leads if d.t >= end]
    cut_in_id = last[0]["TrackID"]
    assert cut_in_id != first["TrackID"]
    assert all(d["TrackID"] == cut_in_id and d["PosX"] < first["PosX"] for d in last)
    tracks = [d for d in drive if d.name.startswith("FusionTrack")
              and d.signals["TrackID"] == cut_in_id and d.signals["Status"] != "invalid"]
    lateral_before = [d.signals["PosY"] for d in tracks if d.t < begin + 0.3]
    lateral_after = [d.signals["PosY"] for d in tracks if d.t >= end]
    assert lateral_before and all(y < -2.5 for y in lateral_before)  # right neighbour lane
    assert lateral_after and all(abs(y) < 1.8 for y in lateral_after)  # ego lane
    flagged = [d for d in drive if d.name.startswith("CamObstacle") and d.name.endswith("_A")
               and d.signals["CutInOut"] == "cut_in"]
    assert flagged and all(d.signals["Blinker"] == "left" for d in flagged)


def test_fusion_track_ids_are_stable_while_tracked(drive: list[Decoded]) -> None:
    slots: dict[str, set[int]] = defaultdict(set)
    for d in drive:
        if d.name.startswith("FusionTrack") and d.signals["Status"] != "invalid":
            slots[d.name].add(d.signals["TrackID"])
    assert slots  # a slot sees a handful of objects over the drive, not a new id every cycle
    assert all(len(ids) < 10 for ids in slots.values())


# --- camera -----------------------------------------------------------------------------------


def test_the_camera_reports_lateral_positions_positive_right(drive: list[Decoded]) -> None:
    begin, _ = window(TIMELINE.lead_braking)
    lead = next(d for d in named(drive, "LeadVehicle") if d.t >= begin).signals
    camera = [d.signals for d in drive if d.name.endswith("_A") and d.name.startswith(
        "CamObstacle") and begin <= d.t < begin + 0.07 and d.signals["Valid"] == "valid"]
    match = min(camera, key=lambda c: abs(c["PosX"] - lead["PosX"]))
    assert match["PosX"] == pytest.approx(lead["PosX"], abs=2.0)
    assert match["PosY"] == pytest.approx(-lead["PosY"], abs=0.5)
    assert abs(lead["PosY"]) > 0.5  # on the curve the lead is well off the x axis


def test_the_camera_sees_the_pedestrian_and_the_cyclist(drive: list[Decoded]) -> None:
    types = {d.signals["Type"] for d in drive
             if d.name.startswith("CamObstacle") and d.name.endswith("_A")
             and d.signals["Valid"] == "valid"}
    assert {"vehicle", "truck", "pedestrian", "bicycle"} <= types


# --- radar ------------------------------------------------------------------------------------


def test_radar_sees_real_objects_with_classes_and_high_existence(drive: list[Decoded]) -> None:
    objects = radar_objects(drive)
    valid = [o for o in objects if o["Valid"] == "valid"]
    real = [o for o in valid if o["Class"] != "unknown"]
    assert {"four_wheel", "two_wheel", "pedestrian", "stationary"} <= {o["Class"] for o in real}
    assert all(o["ProbExist"] >= 80 for o in real)
    pedestrians = [o for o in real if o["Class"] == "pedestrian"]
    near = [o for o in pedestrians if o["LongDist"] < 40]  # far away, the road curve shifts y
    assert near and all(o["LatDist"] < -3 for o in near)  # on the right-hand roadside
    unused = [o for o in objects if o["Valid"] == "invalid"]
    assert unused and all(o["ProbExist"] == 0 for o in unused)


def test_radar_reports_flickering_low_probability_detections(drive: list[Decoded]) -> None:
    ghosts = [o for o in radar_objects(drive) if o["Valid"] == "valid" and o["ProbExist"] <= 30]
    assert len(ghosts) >= 5
    assert all(o["Class"] == "unknown" for o in ghosts)


def test_radar_slots_keep_their_object_while_it_is_visible(drive: list[Decoded]) -> None:
    lead_slots = {o["slot"] for o in radar_objects(drive)
                  if o["Valid"] == "valid" and o["t"] < 1.0 and 38 < o["LongDist"] < 42
                  and o["Class"] == "four_wheel"}
    assert len(lead_slots) == 1


def test_during_the_radar_dropout_the_radar_is_silent(frames: list[Frame]) -> None:
    begin, end = TIMELINE.radar_dropout.window_ns(DURATION_S)
    radar = [f.timestamp_ns for f in frames if f.arbitration_id in RADAR_IDS]
    assert not [t for t in radar if begin <= t < end]
    assert any(t < begin for t in radar) and any(t >= end for t in radar)
    non_radar = [f for f in frames if begin <= f.timestamp_ns < end]
    assert non_radar  # the rest of the car carries on


def test_during_the_misalignment_the_radar_reports_it_and_its_objects_rotate(
        drive: list[Decoded]) -> None:
    begin, end = window(TIMELINE.radar_misalignment)
    for d in named(drive, "RadarStatus"):
        expected = MISALIGNMENT_DEG if begin <= d.t < end else 0.0
        assert d.signals["HorizontMisalignment"] == pytest.approx(expected, abs=0.1)
    # The lead vehicle (cut-in car) seen by radar: about 3 degrees further right than fused.
    leads = named(drive, "LeadVehicle")
    offsets = []
    for o in radar_objects(drive):
        if o["Valid"] == "valid" and begin + 0.1 <= o["t"] < end and o["Class"] == "four_wheel":
            lead = min(leads, key=lambda d: abs(d.t - o["t"])).signals
            if abs(o["LongDist"] - lead["PosX"]) < 1.5:
                offsets.append(math.degrees(math.atan2(o["LatDist"], o["LongDist"])
                                            - math.atan2(lead["PosY"], lead["PosX"])))
    assert offsets
    assert sum(offsets) / len(offsets) == pytest.approx(-MISALIGNMENT_DEG, abs=1.0)


# --- the timeline scales with the duration ----------------------------------------------------


@pytest.mark.slow
def test_a_long_drive_has_every_episode_too(db: cantools.database.can.Database) -> None:
    duration = 60.0
    status = db.get_message_by_name("RadarStatus")
    lane = db.get_message_by_name("CamLaneLeft")
    radar_times, misalignments, lane_sources = [], [], []
    for f in simulate(duration_s=duration, seed=3):
        t = (f.timestamp_ns - DEFAULT_START_NS) / 1e9
        if f.arbitration_id in RADAR_IDS:
            radar_times.append(t)
        if f.arbitration_id == status.frame_id:
            misalignments.append((t, decode(status, f.data)["HorizontMisalignment"]))
        if f.arbitration_id == lane.frame_id:
            lane_sources.append((t, decode(lane, f.data)["Source"]))
    begin, end = window(TIMELINE.radar_dropout, duration)
    assert end - begin == pytest.approx(3.0)
    assert not [t for t in radar_times if begin <= t < end]
    begin, end = window(TIMELINE.radar_misalignment, duration)
    assert all((m > 2.5) == (begin <= t < end) for t, m in misalignments)
    begin, end = window(TIMELINE.lane_dropout, duration)
    assert all((s == "none") == (begin <= t < end) for t, s in lane_sources)


def test_episodes_are_ordered_fractions_of_the_drive() -> None:
    for episode in TIMELINE.episodes():
        assert 0 < episode.start < episode.end < 1
        begin, end = episode.window_ns(10.0, start_ns=0)
        assert episode.contains(begin, 10.0, start_ns=0)
        assert not episode.contains(end, 10.0, start_ns=0)


# --- the bundled sample log -------------------------------------------------------------------


def test_the_bundled_sample_log_is_the_simulated_drive(frames: list[Frame]) -> None:
    assert SAMPLE_LOG.stat().st_size < 1_000_000
    assert list(LogSource(SAMPLE_LOG)) == frames


def test_the_sample_log_tool_writes_a_readable_log(tmp_path: Path) -> None:
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        make_sample_log = importlib.import_module("make_sample_log")
    finally:
        sys.path.remove(str(ROOT / "tools"))
    path = tmp_path / "drive.blf"
    count = make_sample_log.write_blf(path, simulate(duration_s=1.0, seed=5))
    assert list(LogSource(path)) == list(simulate(duration_s=1.0, seed=5))
    assert count > 2000


# --- fault scenarios (for the health monitor) -------------------------------------------------

SCENARIO_S = FAULT_RECOVERY_S + 1.0  # the fault and a second after it


@functools.cache
def scenario(name: str) -> list[Decoded]:
    """A fault scenario, decoded (a second past the recovery)."""
    db = load_ecocar()
    out = []
    for f in simulate(duration_s=SCENARIO_S, scenario=name):
        message = db.get_message_by_frame_id(f.arbitration_id)
        out.append(Decoded((f.timestamp_ns - DEFAULT_START_NS) / 1e9, f.timestamp_ns,
                           message.name, decode(message, f.data)))
    return out


def fault(d: Decoded) -> bool:
    return FAULT_ONSET_S <= d.t < FAULT_RECOVERY_S


def test_every_fault_scenario_has_its_fault_at_the_documented_times() -> None:
    for name, s in SCENARIOS.items():
        if name in ("drive", "clean"):
            assert s.window_ns() is None
        else:
            assert s.window_ns(0) == (FAULT_ONSET_S * 1e9, FAULT_RECOVERY_S * 1e9)
            assert s.duration_s > FAULT_RECOVERY_S + 3  # room to see the alarm clear
    with pytest.raises(ValueError, match="radar_dropout"):
        simulate(duration_s=1.0, scenario="no_such_scenario")


@pytest.mark.slow
def test_the_clean_scenario_has_no_fault_at_all() -> None:
    clean = scenario("clean")
    assert all(d.signals["Source"] == "camera" for d in clean if d.name in LANE_MESSAGES)
    assert all(abs(d.signals["HorizontMisalignment"]) < 0.1 for d in named(clean, "RadarStatus"))
    headers = [d.t for d in named(clean, "RadarHeader")]
    assert len(headers) == pytest.approx(SCENARIO_S * 20, abs=1)  # every radar cycle
    assert max(b - a for a, b in itertools.pairwise(headers)) < 0.06


@pytest.mark.slow
def test_radar_dropout_silences_the_radar_only_during_the_fault() -> None:
    frames = scenario("radar_dropout")
    radar = [d for d in frames if d.name.startswith("Radar")]
    assert not [d for d in radar if fault(d)]
    assert [d for d in radar if d.t < FAULT_ONSET_S] and [d for d in radar if d.t >= 11.0]
    assert [d for d in frames if fault(d) and d.name.startswith("Cam")]


@pytest.mark.slow
def test_the_yawed_radar_sees_everything_turned_right_and_does_not_know() -> None:
    frames = scenario("radar_yaw")
    assert all(abs(d.signals["HorizontMisalignment"]) < 0.1 for d in named(frames, "RadarStatus"))
    leads = named(frames, "LeadVehicle")
    inside, outside = [], []
    for o in radar_objects(frames):
        if o["Valid"] != "valid" or o["Class"] != "four_wheel" or o["LongDist"] < 10:
            continue
        lead = min(leads, key=lambda d: abs(d.t - o["t"])).signals
        if lead["Valid"] == "lead" and abs(o["LongDist"] - lead["PosX"]) < 1.5:
            offset = math.degrees(math.atan2(o["LatDist"], o["LongDist"])
                                  - math.atan2(lead["PosY"], lead["PosX"]))
            (inside if FAULT_ONSET_S + 0.1 <= o["t"] < FAULT_RECOVERY_S else outside).append(
                offset)
    assert sum(inside) / len(inside) == pytest.approx(-MISALIGNMENT_DEG, abs=1.0)
    assert abs(sum(outside) / len(outside)) < 1.0


@pytest.mark.slow
def test_the_blind_radar_sends_every_frame_but_no_valid_object() -> None:
    frames = scenario("radar_blind")
    objects = [o for o in radar_objects(frames) if FAULT_ONSET_S <= o["t"] < FAULT_RECOVERY_S]
    assert len(objects) == pytest.approx(32 * 20 * (FAULT_RECOVERY_S - FAULT_ONSET_S), rel=0.02)
    assert all(o["Valid"] == "invalid" for o in objects)
    assert any(o["Valid"] == "valid" for o in radar_objects(frames) if o["t"] >= 11.1)


@pytest.mark.slow
def test_the_slow_radar_sends_one_cycle_in_three() -> None:
    headers = [d for d in named(scenario("radar_slow"), "RadarHeader")]
    inside = [d for d in headers if fault(d)]
    expected = (FAULT_RECOVERY_S - FAULT_ONSET_S) * 20 / RADAR_SLOW_EVERY
    assert len(inside) == pytest.approx(expected, abs=1)
    assert len([d for d in headers if d.t < FAULT_ONSET_S]) == pytest.approx(
        FAULT_ONSET_S * 20, abs=1)


@pytest.mark.slow
def test_lane_loss_reports_no_lanes_during_the_fault() -> None:
    lanes = [d for d in scenario("lane_loss") if d.name in LANE_MESSAGES]
    assert all((d.signals["Source"] == "none") == fault(d) for d in lanes)


@pytest.mark.slow
def test_a_silent_bus_carries_no_frame_at_all_during_the_fault() -> None:
    frames = scenario("bus_silent")
    assert not [d for d in frames if fault(d)]
    assert frames[-1].t >= SCENARIO_S - 0.1  # and it comes back


@pytest.mark.slow
def test_a_babbling_gateway_floods_the_bus_with_one_frame() -> None:
    frames = scenario("babbling")
    diag = named(frames, "SensorDiag")
    inside = [d for d in diag if fault(d)]
    period_s = BABBLE_PERIOD_US / 1e6
    babble = (FAULT_RECOVERY_S - FAULT_ONSET_S) / period_s
    assert babble <= len(inside) <= babble + 6  # and its own once a second
    payloads = Counter(tuple(sorted(d.signals.items())) for d in inside)
    assert payloads.most_common(1)[0][1] == babble  # one stuck payload
    assert len([d for d in diag if not fault(d)]) <= SCENARIO_S - 4  # 1 Hz outside
    clean = scenario("clean")
    assert len(frames) - len(inside) == pytest.approx(len(clean), rel=0.001)
