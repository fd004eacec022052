"""The highway car: a production car at highway range (``tankviz simulate --car highway``).

Each test reads like an example of what the simulated car gives: the frames decoded with the
bundled databases against the scenario's ground truth (:mod:`bridge.sim.highway`), and what
``tankviz simulate --car highway`` makes of them.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any, NamedTuple, cast

import cantools
import pytest
from mcap.reader import make_reader

from bridge.cli import main
from bridge.frame import NS, Frame
from bridge.io.can_logs import LogSource
from bridge.pb import perception_pb2
from bridge.pipeline.drive import load_stages
from bridge.sim.highway import (
    CAR_BUS,
    HIGHWAY,
    RADAR_BUS,
    SPEEDOMETER_GAIN,
    ego_at,
    highway_database,
    lead_at,
    objects_at,
    simulate_highway,
    slots_at,
    twins_at,
)
from bridge.sim.highway_body import UNKNOWN_IDS
from bridge.sim.highway_world import RADAR_X_M, STEERING_RATIO, WHEELBASE_M
from bridge.sim.scenario import DEFAULT_START_NS
from bridge.topics import LEAD_TOPIC, objects_topic

MS = 1_000_000
#: The cut-in car's centre crosses into the ego lane half way through its lane change.
CROSSING_S = (HIGHWAY.cut_in_begin_s + HIGHWAY.cut_in_end_s) / 2


class Slot(NamedTuple):
    """One slot of one radar cycle, decoded: radar frame (x ahead, y LEFT, from -LAT_DIST)."""

    valid: bool
    new: bool
    x: float
    y: float
    v: float
    score: int
    lat_dist: float


class Cycle(NamedTuple):
    t: float  # the measurement time: k * 50 ms after the start
    first_ns: int
    counter: int
    slots: tuple[Slot, ...]


@pytest.fixture(scope="module")
def frames() -> list[Frame]:
    return list(simulate_highway())  # the whole 60 s drive: under a second


@pytest.fixture(scope="module")
def cycles(frames: list[Frame]) -> list[Cycle]:
    """Every radar cycle: the 32 frames of one cycle come within 16 ms of its measurement
    (the radar bus's id no database defines left out)."""
    radar = highway_database("radar")
    by_cycle: dict[int, list[Frame]] = defaultdict(list)
    for f in frames:
        if f.bus == RADAR_BUS and f.arbitration_id not in UNKNOWN_IDS:
            by_cycle[(f.timestamp_ns - DEFAULT_START_NS) // (50 * MS)].append(f)
    out = []
    for k, group in sorted(by_cycle.items()):
        assert [f.arbitration_id for f in group] == [*range(0x210, 0x230)]
        decoded = [signals(radar, f) for f in group]
        counters = {d["COUNTER"] for d in decoded}
        assert len(counters) == 1
        slots = tuple(Slot(a["VALID"] == 1, a["NEW_TRACK"] == 1, a["LONG_DIST"], -a["LAT_DIST"],
                           a["REL_SPEED"], b["SCORE"], a["LAT_DIST"])
                      for a, b in zip(decoded[:16], decoded[16:], strict=True))
        out.append(Cycle(k * 0.05, group[0].timestamp_ns, counters.pop(), slots))
    return out


@pytest.fixture(scope="module")
def car(frames: list[Frame]) -> dict[str, list[tuple[float, dict[str, Any]]]]:
    """The car bus decoded: message name -> (seconds since the start, signals); the ids no
    database defines left out."""
    db = highway_database("car")
    out: dict[str, list[tuple[float, dict[str, Any]]]] = defaultdict(list)
    for f in frames:
        if f.bus == CAR_BUS and f.arbitration_id not in UNKNOWN_IDS:
            message = db.get_message_by_frame_id(f.arbitration_id)
            out[message.name].append(((f.timestamp_ns - DEFAULT_START_NS) / NS,
                                      signals(db, f)))
    return out


def signals(db: cantools.database.can.Database, frame: Frame) -> dict[str, Any]:
    return cast(dict[str, Any], db.decode_message(frame.arbitration_id, frame.data))


def name_at(t: float, slot: int) -> str | None:
    """Which car the slot holds at ``t``, by the ground truth."""
    held = slots_at(t)[slot]
    return held.name if held is not None else None


def between(cycles: list[Cycle], begin: float, end: float) -> list[Cycle]:
    return [c for c in cycles if begin <= c.t < end]


# ---------------------------------------------------------------------------------------------
# The frames
# ---------------------------------------------------------------------------------------------


def test_the_same_seed_gives_the_same_frames_and_another_seed_only_other_noise() -> None:
    first = list(simulate_highway(duration_s=3.0, seed=7))
    assert first == list(simulate_highway(duration_s=3.0, seed=7))
    other = list(simulate_highway(duration_s=3.0, seed=8))
    assert other != first
    # the scenario is the same: which slot is valid or new, in every radar cycle
    radar = highway_database("radar")

    def flags(run: list[Frame]) -> list[tuple[int, int, int]]:
        return [(f.arbitration_id, d["VALID"], d["NEW_TRACK"])
                for f in run if f.arbitration_id in range(0x210, 0x220)
                for d in [signals(radar, f)]]

    assert flags(first) == flags(other)


def test_frames_come_in_time_order_on_two_buses_within_the_run() -> None:
    start = 5 * NS
    run = list(simulate_highway(duration_s=2.0, start_ns=start))
    stamps = [f.timestamp_ns for f in run]
    assert stamps == sorted(stamps) and start <= stamps[0] and stamps[-1] < start + 2 * NS
    assert all(t % 1000 == 0 for t in stamps)  # whole microseconds
    assert {f.bus for f in run} == {RADAR_BUS, CAR_BUS} == {"can1", "can0"}
    assert not any(f.is_fd or f.is_extended or f.is_error or f.is_remote for f in run)


@pytest.mark.slow
def test_every_frame_decodes_with_the_bundled_database_of_its_bus(frames: list[Frame]) -> None:
    """... but those of the ids the databases do not define (:mod:`bridge.sim.highway_body`)."""
    databases = {RADAR_BUS: highway_database("radar"), CAR_BUS: highway_database("car")}
    for f in frames:
        if f.arbitration_id in UNKNOWN_IDS:
            continue
        message = databases[f.bus].get_message_by_frame_id(f.arbitration_id)
        assert len(f.data) == f.dlc == message.length
        message.decode(f.data)
        if "CHECKSUM" in message.signal_tree:  # Toyota's rule: id bytes, length and the data
            fid = f.arbitration_id
            assert f.data[-1] == ((fid & 0xFF) + (fid >> 8) + len(f.data) + sum(f.data[:-1])) & 0xFF


def test_every_message_comes_at_its_dbc_cycle_time(frames: list[Frame]) -> None:
    databases = {RADAR_BUS: highway_database("radar"), CAR_BUS: highway_database("car")}
    times: dict[tuple[str, int], list[int]] = defaultdict(list)
    for f in frames:
        if f.arbitration_id not in UNKNOWN_IDS:  # no cycle time in a database
            times[(f.bus, f.arbitration_id)].append(f.timestamp_ns)
    assert len(times) == 32 + 4
    for (bus, fid), stamps in times.items():
        cycle_ms = databases[bus].get_message_by_frame_id(fid).cycle_time
        assert cycle_ms in (10, 12, 20, 50)
        gaps = [(b - a) / MS for a, b in itertools.pairwise(stamps)]
        assert abs(statistics.mean(gaps) - cycle_ms) < 0.01
        assert max(abs(g - cycle_ms) for g in gaps) < 1.0  # a little jitter, never a lost cycle


def test_every_radar_cycle_sends_all_16_slots_with_one_counter(cycles: list[Cycle]) -> None:
    assert len(cycles) == 1200  # 60 s at 20 Hz, A slots then B slots (checked by the fixture)
    for before, now in itertools.pairwise(cycles):
        assert now.counter == (before.counter + 1) % 256
        assert 2 * MS <= now.first_ns - DEFAULT_START_NS - round(now.t * NS) < 7 * MS
    # empty slots are sent too, as VALID = 0 with nothing in them
    for c in cycles:
        for s in c.slots:
            if not s.valid:
                assert (s.new, s.x, s.y, s.v, s.score) == (False, 0.0, 0.0, 0.0, 0)


# ---------------------------------------------------------------------------------------------
# What the radar reports, against the ground truth
# ---------------------------------------------------------------------------------------------


def test_the_slots_hold_what_the_ground_truth_says(cycles: list[Cycle]) -> None:
    for c in cycles:
        truth = slots_at(c.t)
        objects = {o.name: o for o in objects_at(c.t)}
        for slot, (got, want) in enumerate(zip(c.slots, truth, strict=True)):
            assert got.valid == (want is not None and want.valid), (c.t, slot)
            if want is None or not want.valid:
                continue
            assert got.new == want.new, (c.t, slot)
            o = objects[want.name]
            assert math.hypot(got.x - (o.x - RADAR_X_M), got.y - o.y) < 1.5, (c.t, slot)
            assert abs(got.v - o.vx) < 0.4
            assert got.score >= 38


def test_an_object_keeps_its_slot_the_lead_slot_2_and_the_cut_in_car_slot_0(
        cycles: list[Cycle]) -> None:
    assert [s.name if s else None for s in slots_at(0.0)][:8] == [
        "cut_in", "left_near", "lead", "right_80", "left_120", "left_far", "right_190", None]
    for c in cycles:
        truth = slots_at(c.t)
        lead, cut_in = truth[HIGHWAY.lead_slot], truth[HIGHWAY.cut_in_slot]
        assert lead is not None and (lead.name, lead.twin) == ("lead", False)
        assert cut_in is not None and (cut_in.name, cut_in.twin) == ("cut_in", False)
    # NEW_TRACK only on a slot's first cycle with a new object: never twice in a row
    for before, now in itertools.pairwise(cycles):
        for a, b in zip(before.slots, now.slots, strict=True):
            assert not (a.new and b.new and a.valid)


def test_a_car_leaves_the_radar_range_and_its_slot_is_sent_empty(cycles: list[Cycle]) -> None:
    assert name_at(0.0, 5) == "left_far"
    last = max(c.t for c in cycles if c.slots[5].valid and name_at(c.t, 5) == "left_far")
    assert HIGHWAY.left_far_leaves_s - 0.2 < last < HIGHWAY.left_far_leaves_s + 0.2
    assert not any(c.slots[5].valid for c in between(cycles, last + 0.01, last + 2.0))
    assert max(c.slots[5].x for c in cycles if c.slots[5].valid and c.t <= last) > 199.0


def test_objects_from_10_to_200_m_and_always_one_beyond_150_m(cycles: list[Cycle]) -> None:
    xs = [s.x for c in cycles for s in c.slots if s.valid]
    assert min(xs) < 10.5 and max(xs) > 199.0
    assert all(any(s.valid and math.hypot(s.x, s.y) > 150.0 for s in c.slots) for c in cycles)
    near = [c for c in cycles if any(s.valid and s.x < 25.0 for s in c.slots)]
    assert len(near) > 0.99 * len(cycles)  # a car within 25 m (left_near, cut_in) but dropouts


def test_lat_dist_is_positive_to_the_right(cycles: list[Cycle]) -> None:
    straight = between(cycles, 1.0, 19.0)
    left_near = [c.slots[1].lat_dist for c in straight if c.slots[1].valid]
    right_lane = [c.slots[HIGHWAY.cut_in_slot].lat_dist for c in straight
                  if c.slots[HIGHWAY.cut_in_slot].valid]
    assert 3.0 < -statistics.mean(left_near) < 4.2  # the car in the LEFT lane: negative
    assert 3.0 < statistics.mean(right_lane) < 4.2  # the car in the right lane: positive
    # in the left-hand curve the lead ahead drifts to the left: negative LAT_DIST
    curve = [c.slots[HIGHWAY.lead_slot].lat_dist for c in between(cycles, 26.0, 36.0)
             if c.slots[HIGHWAY.lead_slot].valid]
    assert statistics.mean(curve) < -1.0


def test_twins_are_one_object_in_two_slots_at_the_documented_times(cycles: list[Cycle]) -> None:
    distances, speeds = [], []
    for c in cycles:
        pairs = twins_at(c.t)
        valid = [i for i, s in enumerate(c.slots) if s.valid]
        for a, b in itertools.combinations(valid, 2):
            sa, sb = c.slots[a], c.slots[b]
            apart = math.hypot(sa.x - sb.x, sa.y - sb.y)
            if frozenset((a, b)) in pairs:
                distances.append(apart)
                speeds.append(abs(sa.v - sb.v))
            else:  # two different cars: never as close as twins
                assert apart > 3.0, (c.t, a, b)
    assert max(distances) < 1.5 and statistics.quantiles(distances, n=100)[-1] < 1.0
    assert 0.2 < statistics.median(distances) < 1.0
    assert max(speeds) <= 0.3
    # most of the time most of the cars are reported twice
    assert sum(len(twins_at(c.t)) >= 2 for c in cycles) > 0.7 * len(cycles)
    twinned = Counter(name_at(c.t, i) for c in cycles for pair in twins_at(c.t) for i in pair)
    for name in HIGHWAY.twinned:
        assert 0.3 * 2 * len(cycles) < twinned[name] < 0.75 * 2 * len(cycles), name
    assert "left_far" not in twinned


def test_the_lead_s_twin_comes_and_goes_while_it_is_the_lead() -> None:
    def lead_twinned(t: float) -> bool:
        return any(HIGHWAY.lead_slot in pair for pair in twins_at(t))

    states = [lead_twinned(k * 0.05) for k in range(round(CROSSING_S / 0.05))]
    comes = sum(1 for a, b in itertools.pairwise(states) if b and not a)
    goes = sum(1 for a, b in itertools.pairwise(states) if a and not b)
    assert comes >= 5 and goes >= 4
    runs = [len(list(g)) * 0.05 for twinned, g in itertools.groupby(states) if twinned]
    assert all(r <= 6.05 for r in runs)  # a twin slot lives 1 to 6 s (a dropout may cut one)


def test_dropouts_send_a_slot_invalid_for_a_few_cycles_and_keep_it(cycles: list[Cycle]) -> None:
    lead = [c.slots[HIGHWAY.lead_slot].valid for c in cycles]
    gaps = [len(list(g)) for valid, g in itertools.groupby(lead) if not valid]
    assert 4 <= len(gaps) <= 8 and max(gaps) <= 3
    # after a dropout the lead comes back in its slot, not as a new track
    assert not any(c.slots[HIGHWAY.lead_slot].new for c in cycles[1:])


@pytest.mark.slow
def test_the_cut_in_car_enters_the_ego_lane_in_the_documented_window(
        cycles: list[Cycle], car: dict[str, list[tuple[float, dict[str, Any]]]]) -> None:
    """As the view sees it: its lane from the steering angle (bicycle model) against the
    cut-in car's slot in the vehicle frame."""
    steering = car["STEER_ANGLE_SENSOR"]

    def lane_offset(c: Cycle) -> float:
        _, sig = min(steering, key=lambda row: abs(row[0] - c.t))
        angle = math.radians(sig["STEER_ANGLE"] + sig["STEER_FRACTION"])
        curvature = math.tan(angle / STEERING_RATIO) / WHEELBASE_M
        s = c.slots[HIGHWAY.cut_in_slot]
        x = s.x + RADAR_X_M
        return s.y - curvature * x * x / 2

    offsets = [(c.t, lane_offset(c)) for c in cycles if c.slots[HIGHWAY.cut_in_slot].valid]
    before = [o for t, o in offsets if HIGHWAY.cut_in_begin_s - 10 <= t < HIGHWAY.cut_in_begin_s]
    after = [o for t, o in offsets if HIGHWAY.cut_in_end_s <= t]
    assert all(-4.6 < o < -2.6 for o in before)  # in the right lane
    assert all(abs(o) < 1.0 for o in after)  # in the ego lane
    crossed = min(t for t, o in offsets if o > -1.8)
    assert HIGHWAY.cut_in_begin_s < crossed < HIGHWAY.cut_in_end_s
    assert abs(crossed - CROSSING_S) < 0.5
    # ... and it is clearly nearer than the old lead, which stays in the ego lane
    for c in between(cycles, HIGHWAY.cut_in_end_s, 60.0):
        lead, cut_in = c.slots[HIGHWAY.lead_slot], c.slots[HIGHWAY.cut_in_slot]
        if lead.valid and cut_in.valid:
            assert lead.x - cut_in.x > 15.0
            assert HIGHWAY.cut_in_gap_m[0] - 1 < cut_in.x < HIGHWAY.cut_in_gap_m[1] + 1


def test_the_ground_truth_names_the_lead() -> None:
    assert all(lead_at(k * 0.5) == "lead" for k in range(round(CROSSING_S * 2)))
    assert all(lead_at(k * 0.5) == "cut_in" for k in range(round(CROSSING_S * 2) + 1, 120))
    for t in (0.0, 10.0, 30.0, 37.0):
        lead = next(o for o in objects_at(t) if o.name == "lead")
        assert HIGHWAY.lead_gap_m[0] - 0.1 < lead.x - RADAR_X_M < HIGHWAY.lead_gap_m[1] + 0.5
        assert abs(lead.d) < 0.2 and lead.in_view


# ---------------------------------------------------------------------------------------------
# The car bus
# ---------------------------------------------------------------------------------------------


def test_speed_yaw_rate_and_steering_follow_the_curve(
        car: dict[str, list[tuple[float, dict[str, Any]]]]) -> None:
    wheels = [(t, sum(s[f"WHEEL_SPEED_{w}"] for w in ("FL", "FR", "RL", "RR")) / 4 / 3.6)
              for t, s in car["WHEEL_SPEEDS"]]
    assert all(abs(v - ego_at(t).speed) < 0.1 for t, v in wheels)
    assert 29.5 < statistics.mean(v for _, v in wheels) < 30.5
    speedometer = statistics.mean(s["SPEED"] for _, s in car["SPEED"]) / 3.6
    assert speedometer / statistics.mean(v for _, v in wheels) == pytest.approx(
        SPEEDOMETER_GAIN, abs=0.002)  # reads a little high
    steer = [(t, s["STEER_ANGLE"] + s["STEER_FRACTION"]) for t, s in car["STEER_ANGLE_SENSOR"]]
    yaw = [(t, s["YAW_RATE"]) for t, s in car["KINEMATICS"]]
    in_curve = [a for t, a in steer if 23.0 <= t < 37.0]
    expected = math.degrees(STEERING_RATIO * math.atan(WHEELBASE_M / HIGHWAY.curve_radius_m))
    assert statistics.mean(in_curve) == pytest.approx(expected, abs=0.15)  # about 2.9 deg left
    assert all(abs(a) < 0.5 for t, a in steer if t < 19.0 or t >= 41.0)  # straight
    yaw_curve = statistics.mean(r for t, r in yaw if 23.0 <= t < 37.0)
    assert yaw_curve == pytest.approx(math.degrees(30.0 / HIGHWAY.curve_radius_m), abs=0.1)
    # the two agree through the bicycle model, sample by sample
    for (t, a), (_, r) in zip(steer[::50], yaw[::50], strict=True):
        v = ego_at(t).speed
        bicycle = math.degrees(STEERING_RATIO * math.atan(WHEELBASE_M * math.radians(r) / v))
        assert abs(a - bicycle) < 0.4, t


# ---------------------------------------------------------------------------------------------
# The profile, and `tankviz simulate --car highway`
# ---------------------------------------------------------------------------------------------


def test_the_bundled_profile_loads_by_name_with_a_database_per_bus() -> None:
    decoder, profile = load_stages([], "highway")
    assert profile is not None and profile.name == "highway"
    assert {bus: [p.name for p in paths] for bus, paths in profile.databases.items()} == {
        "can0": ["highway_car.dbc"], "can1": ["highway_radar.dbc"]}
    assert decoder.warnings() == []
    assert {name: g.role for name, g in profile.groups.items()} == {
        "radar": "detections", "tracks": "tracks"}
    assert profile.lead is not None and profile.lead.source == "tracks"
    assert profile.lanes is not None and profile.lanes.lines == {}  # steering lanes only
    assert profile.sensors["radar"].lateral == "right"


def perception(path: Path) -> tuple[dict[int, list[Any]], dict[int, Any]]:
    """/perception/tracks and /perception/lead of a drive, by log time."""
    tracks: dict[int, list[Any]] = {}
    leads: dict[int, Any] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(
                topics=[objects_topic("tracks"), LEAD_TOPIC]):
            if channel.topic == LEAD_TOPIC:
                leads[message.log_time] = perception_pb2.LeadVehicle.FromString(message.data)
            else:
                tracks[message.log_time] = list(
                    perception_pb2.PerceivedObjects.FromString(message.data).objects)
    return tracks, leads


@pytest.mark.slow
def test_simulate_car_highway_mcap_has_the_tracks_and_the_lead_from_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "highway.mcap"
    assert main(["simulate", "--car", "highway", "-o", str(path), "--duration", "45"]) == 0
    assert "of the simulated highway drive" in capsys.readouterr().out
    tracks, leads = perception(path)
    assert len(tracks) == len(leads) > 800  # 20 Hz scenes
    for t_ns, objects in tracks.items():
        t = (t_ns - DEFAULT_START_NS) / NS
        assert {o.id for o in objects} <= set(range(16))
        # the tracks are where the cars are (vehicle frame: origin on the rear axle, y left)
        truth = objects_at(t)  # those in view, and one that left it a moment ago
        for o in objects:
            assert min(math.hypot(o.x - c.x, o.y - c.y) for c in truth) < 2.5, (t, o.id)
    for t_ns, lead in leads.items():
        t = (t_ns - DEFAULT_START_NS) / NS
        if t < 0.5 or abs(t - CROSSING_S) < 1.5:
            continue  # the first scenes, and the cut-in while it happens
        assert lead.present, t
        car = next(o for o in objects_at(t) if o.name == lead_at(t))
        assert abs(lead.object.x - car.x) < 2.0 and abs(lead.object.y - car.y) < 1.0, t
        # its own slot, or its twin's: one that held it within a track's lifetime (0.3 s)
        held = {i for k in range(7) for i, s in enumerate(slots_at(t - k * 0.05))
                if s is not None and s.name == lead_at(t)}
        assert lead.object.id in held, t


def test_simulate_car_highway_as_blf_reads_back_the_same_frames_on_the_same_buses(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "highway.blf"
    assert main(["simulate", "--car", "highway", "-o", str(path), "--duration", "2",
                 "--seed", "4"]) == 0
    assert "wrote" in capsys.readouterr().out
    source = LogSource(path)
    back = list(source)
    assert source.issues == []
    assert back == list(simulate_highway(duration_s=2.0, seed=4))
    assert Counter(f.bus for f in back).keys() == {"can0", "can1"}


def test_simulate_car_highway_warns_where_a_log_has_no_bus_and_keeps_both_in_trc(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv = tmp_path / "highway.csv"
    assert main(["simulate", "--car", "highway", "-o", str(csv), "--duration", "0.5"]) == 0
    err = capsys.readouterr().err
    assert "CSV has no column for the bus" in err and "can0, can1" in err
    assert {f.bus for f in LogSource(csv)} == {"can0"}
    # TRC numbers its buses from 1 as BLF and ASC do (#33 item 9): both buses read back
    trc = tmp_path / "highway.trc"
    assert main(["simulate", "--car", "highway", "-o", str(trc), "--duration", "0.5"]) == 0
    assert Counter(f.bus for f in LogSource(trc)) == Counter(
        f.bus for f in simulate_highway(duration_s=0.5))


def test_a_database_file_is_a_cantools_can_database() -> None:
    for name in ("radar", "car"):
        db = highway_database(name)
        assert isinstance(db, cantools.database.can.Database)
    radar = highway_database("radar")
    comments = " ".join(str(s.comment) for m in radar.messages for s in m.signals)
    assert "right" not in comments.lower() and "left" not in comments.lower()  # the sign: unsaid
