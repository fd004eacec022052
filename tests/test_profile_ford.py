"""A Ford Fusion 2018 from its public DBCs (tests/profiles/ford_fusion.toml): values computed
from several signals, on a real car's databases.

ford_fusion_2018_adas.dbc gives each of 64 radar slots a longitudinal distance ``X_Rel`` (0: an
empty slot) and a bearing ``Angle`` with a negative scale; the profile computes y from both.
ford_fusion_2018_pt.dbc has no vehicle speed but four wheel speeds in rad/s (the speed is their
mean times the rolling radius), and the steering wheel angle in two parts that add up. There is
no lane camera: the lanes come from the steering angle. Frames are encoded with cantools from the
DBCs and converted as ``tankviz convert`` converts them; the tests check the drawn scene, the ego
state, the lanes and /health. The DBCs are read where they are, in ../shared/data/dbc
(conftest's ``shared_dbc``: the tests are skipped where that folder is absent).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
from conftest import T0, WriteLog, message
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.pipeline.convert import convert
from bridge.pipeline.drive import load_stages
from bridge.profile.model import Computed
from bridge.topics import EGO_TOPIC, HEALTH_TOPIC, LANES_TOPIC, objects_topic, scene_topic

PROFILE = Path(__file__).resolve().parent / "profiles" / "ford_fusion.toml"
Database = cantools.database.can.Database

RADAR_X = 3.75  # the radar's mount in ford_fusion.toml
RADIUS = 0.33  # the rolling radius in ford_fusion.toml
#: slot -> (m ahead of the radar, m to the left): one car 20 m ahead 3 m to the left, one 40 m
#: ahead 2 m to the right.
OBJECTS = {3: (20.0, 3.0), 17: (40.0, -2.0)}
WHEELS = {"WhlFl_W_Meas": 60.0, "WhlFr_W_Meas": 61.2, "WhlRl_W_Meas": 60.4, "WhlRr_W_Meas": 60.8}
STEER_INIT, STEER_CALIB = 12.0, -2.5  # deg: the wheel is 9.5 deg to the left of straight ahead
YAW_RATE = 0.0786  # rad/s, turning left as the steering says at 20 m/s


@pytest.fixture
def dbcs(shared_dbc: Path) -> tuple[Path, Path]:
    return (shared_dbc / "ford_fusion_2018_adas.dbc", shared_dbc / "ford_fusion_2018_pt.dbc")


def drive(adas: Database, pt: Database, seconds: float = 3.0) -> Iterator[can.Message]:
    """Healthy traffic at 20 Hz: every radar slot each cycle (all but two empty), the wheel
    speeds, yaw rate and steering wheel angle; two cars driving along with the Fusion."""
    for cycle in range(round(seconds * 20)):
        t = T0 + cycle * 0.05
        for slot in range(64):
            ahead, left = OBJECTS.get(slot, (0.0, 0.0))
            angle = math.degrees(math.atan2(left, ahead)) if ahead else 0.0
            yield message(adas, f"Object_{slot:02d}", t + slot * 0.0002, X_Rel=ahead,
                          Angle=angle, V_Rel=0.0)
        yield message(pt, "WheelSpeed_CG1", t + 0.02, **WHEELS)
        yield message(pt, "Yaw_Data", t + 0.021, VehYaw_W_Actl=YAW_RATE)
        yield message(pt, "Steering_Wheel_Data_CG1", t + 0.022, SteWhlRelInit_An_Sns=STEER_INIT,
                      SteWhlRelCalib_An_Sns=STEER_CALIB)


def topic(path: Path, name: str) -> list[Any]:
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [m for _, _, _, m in reader.iter_decoded_messages(topics=[name])]


@pytest.fixture
def converted(tmp_path: Path, dbcs: tuple[Path, Path], write_log: WriteLog) -> Path:
    adas, pt = (cantools.database.load_file(p) for p in dbcs)
    log = write_log("fusion.blf", drive(adas, pt))
    out = tmp_path / "fusion.mcap"
    convert([log], out, [str(p) for p in dbcs], profile=PROFILE)
    return out


def test_the_profile_loads_and_computes_what_the_dbcs_split(dbcs: tuple[Path, Path]) -> None:
    _, profile = load_stages([str(p) for p in dbcs], PROFILE)
    assert profile is not None

    radar = profile.groups["radar"]
    assert len(radar.members) == 64 and "Object_63" in radar.members
    assert isinstance(radar.x, Computed) and isinstance(radar.y, Computed)
    assert radar.y.at(42).signals == (("Object_42", "X_Rel"), ("Object_42", "Angle"))
    assert profile.ego.speed is not None and len(profile.ego.speed.signals) == 4
    assert profile.lanes is not None and profile.lanes.lines == {}  # steering lanes only


def test_radar_objects_are_drawn_where_they_are_and_empty_slots_not_at_all(
        converted: Path) -> None:
    scenes = topic(converted, scene_topic("radar"))

    assert len(scenes) > 40
    expected = sorted((RADAR_X + ahead, left) for ahead, left in OBJECTS.values())
    for scene in scenes[2:]:  # every tick once the first cycle is in
        spheres = sorted((e.spheres[0].pose.position.x, e.spheres[0].pose.position.y)
                         for e in scene.entities if e.spheres)
        # X_Rel in 0.1 m, Angle in 0.1 deg: 40 m * tan(0.05 deg) is 3.5 cm
        assert spheres == [pytest.approx(p, abs=0.05) for p in expected]
    objects = topic(converted, objects_topic("radar"))[-1].objects
    assert sorted(o.id for o in objects) == sorted(OBJECTS)  # the slots


def test_ego_speed_is_the_mean_wheel_speed_and_the_steering_angle_the_sum_of_its_parts(
        converted: Path) -> None:
    ego = topic(converted, EGO_TOPIC)[-1]

    mean = sum(WHEELS.values()) / 4
    assert ego.speed == pytest.approx(mean * RADIUS, abs=0.01)  # 20 m/s
    assert ego.steering_wheel_angle == pytest.approx(math.radians(STEER_INIT + STEER_CALIB),
                                                     abs=1e-3)
    assert ego.yaw_rate == pytest.approx(YAW_RATE, abs=2e-4)


@pytest.mark.slow
def test_lanes_come_from_the_steering_and_the_healthy_drive_raises_no_alarm(
        converted: Path) -> None:
    lanes = topic(converted, LANES_TOPIC)

    assert len(lanes) > 40
    assert {m.source for m in lanes[1:]} == {"steering"}
    assert all([line.name for line in m.lines] == ["left", "right"] for m in lanes[1:])
    assert lanes[-1].lines[0].c2 > 0  # bending left, as the wheel is turned
    raised = {alarm.id for health in topic(converted, HEALTH_TOPIC) for alarm in health.alarms
              if alarm.raised_count > 0}
    assert raised == set()
