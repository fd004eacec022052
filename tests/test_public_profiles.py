"""The profile format on cars other than ours: one profile per public DBC (tests/profiles/).

- bosch_radar.toml: opendbc's tesla_radar_bosch.dbc, a Bosch MRR-style radar (cartesian);
- gm_object.toml: gm_global_a_object.dbc, GM's long-range radar tracks (polar) and camera lanes;
- delphi_esr.toml: ESR.dbc, a Delphi ESR (polar, angle clockwise).

Frames are encoded with cantools, decoded as the bridge decodes them and fed through the
perception stage; the tests check where each object lands in the vehicle frame (x forward,
y left: the sensor's lateral convention applied, its mount added), or convert a whole drive.
The DBCs are read where they are, in ../shared/data/dbc (conftest's ``shared_dbc``: the tests
are skipped where that folder is absent).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import can
import cantools
import pytest
from conftest import T0, WriteLog, message
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.pb.perception_pb2 import ObjectClass
from bridge.pipeline.convert import convert
from bridge.pipeline.drive import load_stages
from bridge.pipeline.perception import Perception
from bridge.profile.model import Profile
from bridge.topics import EGO_TOPIC, LANES_TOPIC, LEAD_TOPIC, objects_topic, scene_topic

PROFILES = Path(__file__).resolve().parent / "profiles"
Database = cantools.database.can.Database


@dataclass(frozen=True)
class Car:
    """A public DBC and the profile that says what its signals mean."""

    dbc: Path
    profile_path: Path
    db: Database
    profile: Profile

    def perceive(self, frames: Iterable[can.Message]) -> dict[str, Any]:
        """Feed the frames to perception as the converter does; what one tick after them says."""
        perception = Perception(self.profile)
        t_ns = 0
        for frame in frames:
            t_ns = round(frame.timestamp * 1e9)
            perception.advance(t_ns)
            definition = self.db.get_message_by_frame_id(frame.arbitration_id)
            signals = cast("dict[str, Any]",
                           definition.decode(bytes(frame.data), decode_choices=False))
            perception.feed(definition.name, signals, t_ns)
        return {out.topic: out.message for out in perception.tick(t_ns)}


def load(dbc: Path, profile_path: Path) -> Car:
    decoder, profile = load_stages([str(dbc)], profile_path)  # checks every name in the profile
    assert profile is not None
    (database,) = decoder.files
    return Car(dbc, profile_path, database.db, profile)


@pytest.fixture
def bosch(shared_dbc: Path) -> Car:
    return load(shared_dbc / "tesla_radar_bosch.dbc", PROFILES / "bosch_radar.toml")


@pytest.fixture
def gm(shared_dbc: Path) -> Car:
    return load(shared_dbc / "gm_global_a_object.dbc", PROFILES / "gm_object.toml")


@pytest.fixture
def esr(shared_dbc: Path) -> Car:
    return load(shared_dbc / "ESR.dbc", PROFILES / "delphi_esr.toml")


def objects(outputs: dict[str, Any], group: str) -> dict[int, Any]:
    """The objects of ``/perception/<group>`` by id."""
    return {o.id: o for o in outputs[objects_topic(group)].objects}


def lane(outputs: dict[str, Any], name: str) -> Any:
    return next(line for line in outputs[LANES_TOPIC].lines if line.name == name)


def lateral(line: Any, x: float) -> float:
    return float(line.c0 + line.c1 * x + line.c2 * x**2 + line.c3 * x**3)


def test_each_profile_loads_against_its_dbc_and_maps_what_the_dbc_has(
        bosch: Car, gm: Car, esr: Car) -> None:
    assert set(bosch.profile.groups) == {"radar"}
    assert len(bosch.profile.groups["radar"].members) == 2 * 32  # RadarPoint0_A .. 31_B
    assert bosch.profile.lanes is None and bosch.profile.lead is None

    assert set(gm.profile.groups) == {"tracks", "camera"}
    assert sorted(gm.profile.groups["tracks"].members)[::19] == ["LRRObject01", "LRRObject20"]
    assert gm.profile.lanes is not None
    assert set(gm.profile.lanes.lines) == {"left", "right", "next_left", "next_right"}
    assert gm.profile.lead is not None and gm.profile.lead.source == "tracks"

    assert set(esr.profile.groups) == {"radar"}
    assert len(esr.profile.groups["radar"].members) == 64  # Target1 .. Target64
    assert esr.profile.lanes is None and esr.profile.lead is None


# --- Bosch MRR-style radar: cartesian, LatDist positive to the left, mounted at x = 3.6 m -------

def test_a_bosch_radar_point_lands_where_the_radar_saw_it_with_its_class(bosch: Car) -> None:
    frames = []
    for cycle in range(2):  # B follows A: the class comes from the previous cycle's B frame
        t = T0 + cycle * 0.05
        frames += [
            message(bosch.db, "RadarPoint5_A", t, LongDist=30.0, LatDist=2.0, ProbExist=90,
                    Valid=1),
            message(bosch.db, "RadarPoint5_B", t + 0.001, Class=3),  # pedestrian
            message(bosch.db, "RadarPoint6_A", t + 0.002, LongDist=60.0, LatDist=-4.5,
                    ProbExist=90, Valid=1),
            message(bosch.db, "RadarPoint6_B", t + 0.003, Class=1),  # four-wheel vehicle
        ]

    found = objects(bosch.perceive(frames), "radar")

    assert set(found) == {5, 6}
    pedestrian, car = found[5], found[6]
    assert (pedestrian.x, pedestrian.y) == pytest.approx((3.6 + 30.0, 2.0))  # left of the car
    assert pedestrian.object_class == ObjectClass.OBJECT_CLASS_PEDESTRIAN
    assert pedestrian.probability == pytest.approx(90.625)  # ProbExist comes in 3.125 % steps
    assert (car.x, car.y) == pytest.approx((3.6 + 60.0, -4.5))  # right of the car
    assert car.object_class == ObjectClass.OBJECT_CLASS_CAR


def test_bosch_radar_points_it_flags_invalid_or_doubts_are_not_shown(bosch: Car) -> None:
    frames = [
        message(bosch.db, "RadarPoint0_A", T0, LongDist=20.0, ProbExist=90, Valid=0),
        message(bosch.db, "RadarPoint1_A", T0 + 0.001, LongDist=25.0, ProbExist=50, Valid=1),
        message(bosch.db, "RadarPoint2_A", T0 + 0.002, LongDist=30.0, ProbExist=75, Valid=1),
    ]

    assert set(objects(bosch.perceive(frames), "radar")) == {2}


def test_the_radar_wheel_speed_input_is_the_ego_speed(bosch: Car) -> None:
    frames = [message(bosch.db, "Msg169_ESP_wheelSpeeds", T0, ESP_wheelSpeedReL_HS=72.0)]

    assert bosch.perceive(frames)[EGO_TOPIC].speed == pytest.approx(20.0)  # 72 km/h


# --- GM object bus: radar tracks in range and azimuth (left positive), camera lanes ------------

def test_a_gm_radar_track_lands_where_range_and_azimuth_point(gm: Car) -> None:
    frames = [
        message(gm.db, "LRRObject03", T0, TrkRange=50.0, TrkAzimuth=10.0, TrkObjectID=7),
        message(gm.db, "LRRObject04", T0 + 0.001, TrkRange=0.0, TrkObjectID=8),  # empty slot
    ]

    found = objects(gm.perceive(frames), "tracks")

    assert set(found) == {7}  # the track id, not the slot
    azimuth = math.radians(10.0)
    assert (found[7].x, found[7].y) == pytest.approx(
        (3.6 + 50.0 * math.cos(azimuth), 50.0 * math.sin(azimuth)))  # positive: to the left


def lane_frames(db: Database, t: float, *, left_valid: bool = True) -> list[can.Message]:
    """Ego lane 1.7 m to the left and 1.9 m to the right, outer lines at 5.4 m and -5.6 m."""
    return [
        message(db, "F_Vision_Environment", t, LnSenseDistToLLnEdge=1.7,
                LnSnsDistToRLnEdge=1.9, LaneSnsLLnPosValid=0 if left_valid else 1,
                LnSnsRLnPosValid=0),  # 0 = "Valid" in the DBC's value table
        message(db, "F_Vision_Environment_5", t + 0.001, LnMrkg3LnSnsLnDst=5.4,
                LnMrkg3LnSnsLnHdngTngt=0.02, LnMrkg3LnSnsLnCrvt=0.001, LnMrkg3LnQltyConfLvl=80),
        message(db, "F_Vision_Environment_6", t + 0.002, LnMrkg4LnSnsLnDst=-5.6,
                LnMrkg4LnQltyConfLvl=80),
    ]


def test_gm_camera_lanes_from_unsigned_distances_and_curvature(gm: Car) -> None:
    outputs = gm.perceive(lane_frames(gm.db, T0))

    assert outputs[LANES_TOPIC].source == "camera"
    assert lateral(lane(outputs, "left"), 30.0) == pytest.approx(1.7)  # straight: c0 only
    assert lateral(lane(outputs, "right"), 30.0) == pytest.approx(-1.9)  # negated: to the right
    assert lateral(lane(outputs, "next_right"), 30.0) == pytest.approx(-5.6)
    outer = lane(outputs, "next_left")
    assert outer.c2 == pytest.approx(0.0005, abs=5e-7)  # half the curvature, within one step
    camera_x = 1.9  # its mount in gm_object.toml
    # 20 m ahead of the camera: 5.4 + 0.02 * 20 + 0.001 / 2 * 20**2 = 6.0 m
    assert lateral(outer, camera_x + 20.0) == pytest.approx(6.0, abs=1e-3)


def test_gm_lanes_the_camera_marks_invalid_are_not_drawn(gm: Car) -> None:
    outputs = gm.perceive(lane_frames(gm.db, T0, left_valid=False))

    assert outputs[LANES_TOPIC].source == "none"  # no ego lane, no steering fallback


def test_the_gm_lead_is_the_closest_radar_track_inside_the_camera_lane(gm: Car) -> None:
    frames = [
        *lane_frames(gm.db, T0),
        message(gm.db, "LRRObject01", T0 + 0.01, TrkRange=40.0, TrkAzimuth=0.0, TrkObjectID=3),
        message(gm.db, "LRRObject02", T0 + 0.011, TrkRange=25.0, TrkAzimuth=20.0,
                TrkObjectID=4),  # closer, but 8.6 m to the left: next lane
        message(gm.db, "LRRObject03", T0 + 0.012, TrkRange=60.0, TrkAzimuth=-1.0,
                TrkObjectID=5),  # in the lane, farther
    ]

    lead = gm.perceive(frames)[LEAD_TOPIC]

    assert lead.present and lead.mio_ok
    assert lead.object.id == 3
    assert (lead.object.x, lead.object.y) == pytest.approx((43.6, 0.0))


def test_gm_camera_objects_name_their_signals_with_their_own_number(gm: Car) -> None:
    """Each GM vision slot numbers its signals (FwdVsnRngTrk1Rev, ...): {i} in signal names."""
    camera = gm
    frames = [
        message(gm.db, "F_Vision_Obj_Track_1", T0, FwdVsnRngTrk1Rev=30.0),
        message(gm.db, "F_Vision_Obj_Track_2", T0 + 0.001, FwdVsnRngTrk2Rev=45.0),
    ]

    assert set(objects(camera.perceive(frames), "camera")) == {1, 2}


# --- Delphi ESR: range and angle, the angle positive clockwise (to the right) -----------------

def test_an_esr_track_lands_where_range_and_clockwise_angle_point(esr: Car) -> None:
    frames = [
        message(esr.db, "Target12", T0, CAN_TX_TRACK_RANGE=50.0, CAN_TX_TRACK_ANGLE=10.0,
                CAN_TX_TRACK_STATUS=3),
        message(esr.db, "Target13", T0 + 0.001, CAN_TX_TRACK_RANGE=80.0,
                CAN_TX_TRACK_ANGLE=-5.0, CAN_TX_TRACK_STATUS=3),
    ]

    found = objects(esr.perceive(frames), "radar")

    assert set(found) == {12, 13}  # the slot is the track
    right, left = math.radians(10.0), math.radians(-5.0)
    assert (found[12].x, found[12].y) == pytest.approx(
        (3.6 + 50.0 * math.cos(right), -50.0 * math.sin(right)), abs=0.01)  # clockwise: right
    assert (found[13].x, found[13].y) == pytest.approx(
        (3.6 + 80.0 * math.cos(left), -80.0 * math.sin(left)), abs=0.01)  # counter-clockwise


@pytest.mark.parametrize(("status", "shown"), [
    (0, False),  # no target
    (1, True),  # new
    (2, True),  # new updated
    (3, True),  # updated
    (4, True),  # coasted
    (5, False),  # merged into another track
    (6, False),  # invalid coasted
    (7, False),  # new coasted
])
def test_the_esr_track_status_decides_what_is_shown(esr: Car, status: int, shown: bool) -> None:
    frames = [message(esr.db, "Target1", T0, CAN_TX_TRACK_RANGE=30.0,
                      CAN_TX_TRACK_STATUS=status)]

    assert (1 in objects(esr.perceive(frames), "radar")) is shown


# --- whole drives: log file -> tankviz convert -> MCAP ------------------------------------------

Cycle = Callable[[Database, float], list[can.Message]]


def bosch_cycle(db: Database, t: float) -> list[can.Message]:
    return [message(db, "RadarPoint5_A", t, LongDist=30.0, LatDist=2.0, ProbExist=90, Valid=1),
            message(db, "RadarPoint5_B", t + 0.001, Class=3)]


def gm_cycle(db: Database, t: float) -> list[can.Message]:
    return [*lane_frames(db, t),
            message(db, "LRRObject01", t + 0.01, TrkRange=40.0, TrkObjectID=3)]


def esr_cycle(db: Database, t: float) -> list[can.Message]:
    return [message(db, "Target12", t, CAN_TX_TRACK_RANGE=50.0, CAN_TX_TRACK_STATUS=3)]


@pytest.mark.parametrize(("dbc", "profile", "cycle", "scenes", "group", "where"), [
    ("tesla_radar_bosch.dbc", "bosch_radar.toml", bosch_cycle, {"radar"}, "radar",
     (33.6, 2.0)),
    ("gm_global_a_object.dbc", "gm_object.toml", gm_cycle, {"tracks", "lanes", "lead"},
     "tracks", (43.6, 0.0)),
    ("ESR.dbc", "delphi_esr.toml", esr_cycle, {"radar"}, "radar", (53.6, 0.0)),
], ids=["bosch", "gm", "esr"])
def test_a_drive_converts_with_the_profile_end_to_end(
        shared_dbc: Path, write_log: WriteLog, tmp_path: Path, dbc: str, profile: str,
        cycle: Cycle, scenes: set[str], group: str, where: tuple[float, float]) -> None:
    car = load(shared_dbc / dbc, PROFILES / profile)
    log = write_log("drive.blf", [m for i in range(20) for m in cycle(car.db, T0 + i * 0.05)])

    convert([log], tmp_path / "drive.mcap", [str(car.dbc)], profile=car.profile_path)

    with (tmp_path / "drive.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        counts = {summary.channels[i].topic: n
                  for i, n in summary.statistics.channel_message_counts.items()}
        assert all(counts.get(scene_topic(scene), 0) > 0 for scene in scenes), sorted(counts)
        *_, (_, _, _, last) = reader.iter_decoded_messages(topics=[objects_topic(group)])
    (seen,) = last.objects
    assert (seen.x, seen.y) == pytest.approx(where)
