"""Steering-only lanes: a car without a lane camera declares ``[lanes]`` with no camera lines.

Such a car (a radar, speed and steering on the car bus, nothing else) gets the lanes extrapolated
from the steering angle on every tick, drawn magenta, and never ``lanes.lost``: there is no camera
to lose. A car that declares camera lines and never gets them still raises ``lanes.lost``.
The car here is made up (a small DBC and profile written in tmp_path), not ecocar.
"""

from __future__ import annotations

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
from bridge.profile.model import Profile, ProfileError
from bridge.scene.entities import STEERING_LANE_COLOR
from bridge.topics import HEALTH_TOPIC, LANES_TOPIC, scene_topic

DBC = """\
VERSION ""

NS_ :

BS_:

BU_: CAR RADAR CAM

BO_ 256 CarState: 8 CAR
 SG_ Speed : 0|16@1+ (0.01,0) [0|655.35] "m/s" Vector__XXX
 SG_ SteerAngle : 16|16@1- (0.1,0) [-3276.8|3276.7] "deg" Vector__XXX

BO_ 512 RadarTrack: 8 RADAR
 SG_ Slot : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ Dist : 8|16@1+ (0.01,0) [0|655.35] "m" Vector__XXX
 SG_ Lat : 24|16@1- (0.01,0) [-327.68|327.67] "m" Vector__XXX
 SG_ Valid : 40|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 768 LaneLeft: 8 CAM
 SG_ Offset : 0|16@1- (0.01,0) [-327.68|327.67] "m" Vector__XXX
 SG_ Ok : 16|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 769 LaneRight: 8 CAM
 SG_ Offset : 0|16@1- (0.01,0) [-327.68|327.67] "m" Vector__XXX
 SG_ Ok : 16|1@1+ (1,0) [0|1] "" Vector__XXX
"""

#: A car with a radar and speed and steering on the car bus, and no lane camera.
NO_CAMERA = """\
[profile]
name = "no_camera"

[vehicle]
wheelbase = 2.7
steering_ratio = 16.0

[sensors.radar]
kind = "radar"
mount = { x = 3.8, y = 0.0, z = 0.5 }

[objects.radar]
sensor = "radar"
messages = ["RadarTrack"]
id = "Slot"
x = "Dist"
y = "Lat"
valid = "Valid == 1"

[lanes]                             # no camera lines: lanes from the steering angle, always
fallback = { left = 1.75, right = -1.75 }

[ego]
speed = "CarState.Speed"
steering_wheel_angle = { signal = "CarState.SteerAngle", scale = 0.01745329 }
"""

#: The same car with a lane camera declared, whose lines never come.
WITH_CAMERA = NO_CAMERA.replace("""\
[lanes]                             # no camera lines: lanes from the steering angle, always
fallback = { left = 1.75, right = -1.75 }
""", """\
[sensors.camera]
kind = "camera"
mount = { x = 1.9, y = 0.0, z = 1.3 }

[lanes]
sensor = "camera"

[lanes.left]
message = "LaneLeft"
c0 = "Offset"
valid = "Ok == 1"

[lanes.right]
message = "LaneRight"
c0 = "Offset"
valid = "Ok == 1"
""")


def car(tmp_path: Path, profile: str) -> tuple[Path, Path, cantools.database.can.Database]:
    dbc = tmp_path / "car.dbc"
    dbc.write_text(DBC)
    path = tmp_path / "car.toml"
    path.write_text(profile)
    return dbc, path, cantools.database.load_file(dbc)


def drive(db: cantools.database.can.Database, seconds: float = 4.0) -> Iterator[can.Message]:
    """Healthy traffic at 20 Hz: a car at 15 m/s turning slightly left behind a car 30 m ahead."""
    for i in range(round(seconds * 20)):
        t = T0 + i * 0.05
        yield message(db, "CarState", t, Speed=15.0, SteerAngle=30.0)
        yield message(db, "RadarTrack", t + 0.01, Slot=1, Dist=30.0, Lat=0.5, Valid=1)


def load(dbc: Path, path: Path) -> Profile:
    _, profile = load_stages([str(dbc)], path)
    assert profile is not None
    return profile


def topic(path: Path, name: str) -> list[Any]:
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [m for _, _, _, m in reader.iter_decoded_messages(topics=[name])]


def alarms_raised(path: Path) -> set[str]:
    return {alarm.id for health in topic(path, HEALTH_TOPIC) for alarm in health.alarms
            if alarm.raised_count > 0}


def test_lanes_without_camera_lines_load_as_steering_only_lanes(tmp_path: Path) -> None:
    dbc, path, _ = car(tmp_path, NO_CAMERA)

    profile = load(dbc, path)

    assert profile.lanes is not None
    assert profile.lanes.lines == {}
    assert profile.lanes.sensor is None
    assert (profile.lanes.fallback_left_m, profile.lanes.fallback_right_m) == (1.75, -1.75)


def test_a_car_without_camera_gets_magenta_steering_lanes_on_every_tick_and_no_alarm(
        tmp_path: Path, write_log: WriteLog) -> None:
    dbc, path, db = car(tmp_path, NO_CAMERA)
    log = write_log("drive.blf", drive(db))

    convert([log], tmp_path / "drive.mcap", [str(dbc)], profile=path)

    lanes = topic(tmp_path / "drive.mcap", LANES_TOPIC)
    assert len(lanes) > 50
    assert {m.source for m in lanes[1:]} == {"steering"}  # the first tick may precede the angle
    assert all([line.name for line in m.lines] == ["left", "right"] for m in lanes[1:])
    left = lanes[-1].lines[0]
    assert left.c0 == pytest.approx(1.75) and left.c2 > 0  # turning left
    scenes = topic(tmp_path / "drive.mcap", scene_topic("lanes"))
    drawn = [e for scene in scenes[1:] for e in scene.entities]
    assert len(drawn) == 2 * (len(scenes) - 1)
    assert {(e.lines[0].color.r, e.lines[0].color.g, e.lines[0].color.b, e.lines[0].color.a)
            for e in drawn} == {STEERING_LANE_COLOR}
    assert alarms_raised(tmp_path / "drive.mcap") == set()


def test_camera_lines_that_never_come_still_raise_lanes_lost(
        tmp_path: Path, write_log: WriteLog) -> None:
    dbc, path, db = car(tmp_path, WITH_CAMERA)
    log = write_log("drive.blf", drive(db))

    convert([log], tmp_path / "drive.mcap", [str(dbc)], profile=path)

    assert "lanes.lost" in alarms_raised(tmp_path / "drive.mcap")


@pytest.mark.parametrize(("lanes", "error"), [
    ('[lanes]\nsensor = "radar"\n[lanes.left]\nmessage = "LaneLeft"\nc0 = "Offset"\n',
     "car.toml: lanes: [lanes.left] needs [lanes.right] too; or no camera lines at all for "
     "lanes from the steering angle only"),
    ('[lanes]\n[lanes.left]\nmessage = "LaneLeft"\nc0 = "Offset"\n'
     '[lanes.right]\nmessage = "LaneRight"\nc0 = "Offset"\n',
     "car.toml: lanes: missing required key 'sensor'"),
    ('[lanes]\nsensor = "radar"\n',
     "car.toml: lanes.sensor: 'radar' but there are no camera lines ([lanes.left], "
     "[lanes.right]): lanes from the steering angle need no sensor"),
])
def test_half_declared_camera_lines_are_refused_in_one_line(
        tmp_path: Path, lanes: str, error: str) -> None:
    text = NO_CAMERA.replace("""\
[lanes]                             # no camera lines: lanes from the steering angle, always
fallback = { left = 1.75, right = -1.75 }
""", lanes)
    dbc, path, _ = car(tmp_path, text)

    with pytest.raises(ProfileError) as raised:
        load(dbc, path)

    assert str(raised.value).endswith(error) and "\n" not in str(raised.value)


def test_steering_only_lanes_need_a_steering_wheel_angle(tmp_path: Path) -> None:
    text = NO_CAMERA.replace(
        'steering_wheel_angle = { signal = "CarState.SteerAngle", scale = 0.01745329 }\n', "")
    dbc, path, _ = car(tmp_path, text)

    with pytest.raises(ProfileError) as raised:
        load(dbc, path)

    assert str(raised.value).endswith(
        "car.toml: lanes: no camera lines and no ego.steering_wheel_angle: nothing to draw "
        "the lanes from")
