"""Values computed from several signals: a mapped field of a profile written as an expression.

A car sends its steering wheel angle as a coarse ``STEER_ANGLE`` plus a fine ``STEER_FRACTION``,
its speed as four wheel speeds, and a radar distance whose zero means "no object". The profile
says so in the language of the validity rules (bridge/profile/expr.py): a string that is more
than one name is an expression, and ``{ value = "...", scale = .., offset = .. }`` is one with a
unit conversion. The car here is made up (a small DBC and profile written in tmp_path), not
ecocar.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cantools
import pytest

import bridge.profile.expr
import bridge.profile.loader
from bridge.pipeline.perception import Perception
from bridge.profile.loader import load_profile
from bridge.profile.model import Computed, Profile, ProfileError, SignalRef
from bridge.topics import objects_topic, scene_topic
from bridge.world.observe import EgoObservation, LaneObservation, ObjectObservation, Observer

DEG = 0.01745329
NS = 1_000_000_000


def _family() -> str:
    out = []
    for i in range(4):
        out.append(f"""
BO_ {512 + i} Obj{i}_Pos: 8 RADAR
 SG_ Dist : 0|16@1+ (0.05,0) [0|3276.75] "m" Vector__XXX
 SG_ Lat : 16|16@1- (0.05,0) [-1638.4|1638.35] "m" Vector__XXX
 SG_ Quality : 32|2@1+ (1,0) [0|3] "" Vector__XXX

BO_ {528 + i} Obj{i}_Vel: 8 RADAR
 SG_ VLong : 0|16@1- (0.01,0) [-327.68|327.67] "m/s" Vector__XXX
 SG_ VLat : 16|16@1- (0.01,0) [-327.68|327.67] "m/s" Vector__XXX
""")
    return "".join(out)


DBC = """\
VERSION ""

NS_ :

BS_:

BU_: CAR RADAR CAM

BO_ 100 Steering: 8 CAR
 SG_ STEER_ANGLE : 0|16@1- (1.5,0) [-1500|1500] "deg" Vector__XXX
 SG_ STEER_FRACTION : 16|8@1- (0.1,0) [-12.8|12.7] "deg" Vector__XXX

BO_ 101 WheelSpeeds: 8 CAR
 SG_ WHEEL_SPEED_FL : 0|16@1+ (0.01,0) [0|655.35] "km/h" Vector__XXX
 SG_ WHEEL_SPEED_FR : 16|16@1+ (0.01,0) [0|655.35] "km/h" Vector__XXX
 SG_ WHEEL_SPEED_RL : 32|16@1+ (0.01,0) [0|655.35] "km/h" Vector__XXX
 SG_ WHEEL_SPEED_RR : 48|16@1+ (0.01,0) [0|655.35] "km/h" Vector__XXX

BO_ 102 Imu: 8 CAR
 SG_ YawRate : 0|16@1- (0.01,0) [-327.68|327.67] "deg/s" Vector__XXX

BO_ 103 ImuCalibration: 8 CAR
 SG_ YawBias : 0|16@1- (0.01,0) [-327.68|327.67] "deg/s" Vector__XXX

BO_ 768 LaneLeft: 8 CAM
 SG_ OffsetCoarse : 0|8@1- (0.5,0) [-64|63.5] "m" Vector__XXX
 SG_ OffsetFine : 8|8@1- (0.01,0) [-1.28|1.27] "m" Vector__XXX
 SG_ Ok : 16|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 769 LaneRight: 8 CAM
 SG_ OffsetCoarse : 0|8@1- (0.5,0) [-64|63.5] "m" Vector__XXX
 SG_ OffsetFine : 8|8@1- (0.01,0) [-1.28|1.27] "m" Vector__XXX
 SG_ Ok : 16|1@1+ (1,0) [0|1] "" Vector__XXX
""" + _family()

PROFILE = """\
[profile]
name = "kart"

[sensors.radar]
kind = "radar"
mount = { x = 3.0, y = 0.0, z = 0.4 }

[sensors.camera]
kind = "camera"
mount = { x = 1.5, y = 0.0, z = 1.2 }

[objects.radar]
sensor = "radar"
messages = ["Obj{i}_Pos", "Obj{i}_Vel"]
index = [0, 3]
x = "if(Dist == 0, none, Dist)"           # a distance of zero: no object in this slot
y = "Lat"
vx = { value = "VLong + 0", scale = 2.0, offset = -1.0 }
vy = "Obj{i}_Vel.VLat"
probability = "Quality * 100 / 3"

[lanes]
sensor = "camera"

[lanes.left]
message = "LaneLeft"
c0 = "OffsetCoarse + OffsetFine"
valid = "Ok == 1"

[lanes.right]
message = "LaneRight"
c0 = "OffsetCoarse + OffsetFine"
valid = "Ok == 1"

[ego]
speed = { value = "(WheelSpeeds.WHEEL_SPEED_FL + WheelSpeeds.WHEEL_SPEED_FR + WheelSpeeds.WHEEL_SPEED_RL + WheelSpeeds.WHEEL_SPEED_RR) / 4", scale = 0.2777778 }
yaw_rate = "(Imu.YawRate - ImuCalibration.YawBias) * 0.01745329"
steering_wheel_angle = "(Steering.STEER_ANGLE + Steering.STEER_FRACTION) * 0.01745329"
"""  # noqa: E501


def kart(tmp_path: Path, profile: str = PROFILE) -> tuple[Profile, cantools.database.can.Database]:
    dbc = tmp_path / "kart.dbc"
    dbc.write_text(DBC)
    path = tmp_path / "car.toml"
    path.write_text(profile)
    db = cantools.database.load_file(dbc)
    return load_profile(path, [db]), db


def signals(db: cantools.database.can.Database, name: str, **values: float) -> dict[str, Any]:
    """``values`` (others at 0) as the bridge sees them: encoded, then decoded with the DBC."""
    m = db.get_message_by_name(name)
    data = m.encode({s.name: values.get(s.name, 0) for s in m.signals})
    decoded: dict[str, Any] = m.decode(data, decode_choices=False)  # type: ignore[assignment]
    return decoded


def load_error(tmp_path: Path, old: str, new: str) -> str:
    assert old in PROFILE
    with pytest.raises(ProfileError) as caught:
        kart(tmp_path, PROFILE.replace(old, new))
    return str(caught.value).replace(str(tmp_path / "car.toml"), "car.toml")


# --- the ego signals ------------------------------------------------------------------------------

def test_a_steering_angle_sent_as_coarse_plus_fine_part_is_their_sum(tmp_path: Path) -> None:
    profile, db = kart(tmp_path)
    observer = Observer(profile)

    (ego,) = observer.observe("Steering", signals(db, "Steering", STEER_ANGLE=-91.5,
                                                  STEER_FRACTION=0.7), 0)

    assert isinstance(ego, EgoObservation)
    assert ego.steering_wheel_angle == pytest.approx(-90.8 * DEG)  # right: negative
    assert ego.speed is None and ego.yaw_rate is None  # not in this message


def test_the_vehicle_speed_is_the_mean_of_four_wheel_speeds(tmp_path: Path) -> None:
    profile, db = kart(tmp_path)

    (ego,) = Observer(profile).observe("WheelSpeeds", signals(
        db, "WheelSpeeds", WHEEL_SPEED_FL=70.0, WHEEL_SPEED_FR=74.0, WHEEL_SPEED_RL=71.0,
        WHEEL_SPEED_RR=73.0), 0)

    assert isinstance(ego, EgoObservation)
    assert ego.speed == pytest.approx(20.0, abs=1e-5)  # 72 km/h


def test_an_ego_value_from_two_messages_waits_for_both_then_follows_each(tmp_path: Path) -> None:
    profile, db = kart(tmp_path)
    observer = Observer(profile)

    (first,) = observer.observe("Imu", signals(db, "Imu", YawRate=10.5), 0)
    (second,) = observer.observe("ImuCalibration", signals(db, "ImuCalibration", YawBias=0.5),
                                 NS // 100)
    (third,) = observer.observe("Imu", signals(db, "Imu", YawRate=-9.5), NS // 50)

    assert isinstance(first, EgoObservation) and first.yaw_rate is None  # no bias yet
    assert isinstance(second, EgoObservation)
    assert second.yaw_rate == pytest.approx(10.0 * DEG)
    assert isinstance(third, EgoObservation)
    assert third.yaw_rate == pytest.approx(-10.0 * DEG)


# --- objects and lanes ----------------------------------------------------------------------------

def test_objects_fields_computed_from_their_messages(tmp_path: Path) -> None:
    profile, db = kart(tmp_path)
    observer = Observer(profile)

    observer.observe("Obj2_Vel", signals(db, "Obj2_Vel", VLong=-3.0, VLat=0.5), 0)
    (obj,) = observer.observe("Obj2_Pos", signals(db, "Obj2_Pos", Dist=25.0, Lat=-1.5,
                                                  Quality=2), NS // 100)

    assert isinstance(obj, ObjectObservation)
    assert (obj.object_id, obj.x, obj.y) == (2, pytest.approx(28.0), pytest.approx(-1.5))
    assert obj.vx == pytest.approx(-3.0 * 2.0 - 1.0)  # the expression, then scale and offset
    assert obj.vy == pytest.approx(0.5)
    assert obj.probability == pytest.approx(200 / 3)


def test_a_distance_of_zero_is_no_object_and_no_error(tmp_path: Path) -> None:
    profile, db = kart(tmp_path)
    perception = Perception(profile)
    frames = [("Obj0_Pos", signals(db, "Obj0_Pos", Dist=40.0, Lat=2.0, Quality=3)),
              ("Obj1_Pos", signals(db, "Obj1_Pos", Dist=0.0, Lat=0.0)),  # an empty slot
              ("Obj2_Pos", signals(db, "Obj2_Pos", Dist=0.0, Lat=1.0, Quality=1))]

    assert [len(Observer(profile).observe(name, values, 0)) for name, values in frames] == [1, 0, 0]
    for name, values in frames:
        perception.advance(NS)
        perception.feed(name, values, NS)
    outputs = {out.topic: out.message for out in perception.tick(NS)}

    assert [o.id for o in outputs[objects_topic("radar")].objects] == [0]
    drawn = [e for e in outputs[scene_topic("radar")].entities if e.spheres]
    assert [(e.spheres[0].pose.position.x, e.spheres[0].pose.position.y) for e in drawn] == [
        pytest.approx((43.0, 2.0))]
    assert not perception.world.rule_errors  # nothing counted: an empty slot is no error


def test_lane_coefficients_computed_from_the_lines_message(tmp_path: Path) -> None:
    profile, db = kart(tmp_path)

    (line,) = Observer(profile).observe("LaneLeft", signals(db, "LaneLeft", OffsetCoarse=1.5,
                                                            OffsetFine=0.27, Ok=1), 0)

    assert isinstance(line, LaneObservation)
    assert line.coefficients == pytest.approx((1.77, 0.0, 0.0, 0.0))


# --- the forms, and what loading makes of them ----------------------------------------------------

def test_one_signal_forms_stay_signal_references(tmp_path: Path) -> None:
    profile, _ = kart(tmp_path)
    radar = profile.groups["radar"]

    assert radar.y == SignalRef("Obj{i}_Pos", "Lat")
    assert radar.vy == SignalRef("Obj{i}_Vel", "VLat")
    assert isinstance(radar.x, Computed) and isinstance(radar.vx, Computed)
    assert isinstance(profile.ego.steering_wheel_angle, Computed)
    assert profile.ego.steering_wheel_angle.messages == ("Steering",)
    assert profile.ego.yaw_rate is not None
    assert profile.ego.yaw_rate.messages == ("Imu", "ImuCalibration")
    assert profile.ego.yaw_rate.signals == (("Imu", "YawRate"), ("ImuCalibration", "YawBias"))
    assert {"Imu", "ImuCalibration", "WheelSpeeds", "Steering"} <= profile.message_names()


def test_expressions_are_compiled_once_when_the_profile_loads(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    profile, db = kart(tmp_path)

    def no_parsing(text: str) -> None:
        raise AssertionError(f"parsed {text!r} again")

    monkeypatch.setattr(bridge.profile.expr, "parse", no_parsing)
    monkeypatch.setattr(bridge.profile.loader, "parse", no_parsing)
    observer = Observer(profile)
    for i in range(3):
        (ego,) = observer.observe("Steering", signals(db, "Steering", STEER_ANGLE=3.0 * i), i)
        assert isinstance(ego, EgoObservation)
        assert ego.steering_wheel_angle == pytest.approx(3.0 * i * DEG)


# --- errors: one line, the file, the key, the column, the bad name and the closest ones ----------

@pytest.mark.parametrize(("old", "new", "error"), [
    ("(WheelSpeeds.WHEEL_SPEED_FL +", "(WheelSpeeds.WheelSpeedFL +",
     "car.toml: ego.speed.value: rule '(WheelSpeeds.WheelSpeedFL + WheelSpeeds.WHEEL_SPEED_FR + "
     "WheelSpeeds.WHEEL_SPEED_RL + WheelSpeeds.WHEEL_SPEED_RR) / 4': column 2: no signal "
     "'WheelSpeedFL' in WheelSpeeds; closest: WHEEL_SPEED_FL, WHEEL_SPEED_RL, WHEEL_SPEED_FR"),
    ('"(Steering.STEER_ANGLE + Steering.STEER_FRACTION)',
     '"(STEER_ANGLE + Steering.STEER_FRACTION)',
     "car.toml: ego.steering_wheel_angle: rule '(STEER_ANGLE + Steering.STEER_FRACTION) * "
     "0.01745329': column 2: write Message.Signal for 'STEER_ANGLE': ego values may come from "
     "any message"),
    ('"(Imu.YawRate', '"(Imu2.YawRate',
     "car.toml: ego.yaw_rate: rule '(Imu2.YawRate - ImuCalibration.YawBias) * 0.01745329': "
     "column 2: no message 'Imu2' in the databases; closest: Imu"),
    ('x = "if(Dist == 0, none, Dist)"', 'x = "if(Dist == 0, none, Dsit)"',
     "car.toml: objects.radar.x: rule 'if(Dist == 0, none, Dsit)': column 21: no signal 'Dsit' "
     "in Obj0_Pos, Obj0_Vel; closest: Dist"),
    ('vy = "Obj{i}_Vel.VLat"', 'vy = "Obj{i}_Acc.VLat * 2"',
     "car.toml: objects.radar.vy: rule 'Obj0_Acc.VLat * 2': column 1: message 'Obj0_Acc' is not "
     "one of Obj0_Pos, Obj0_Vel"),
    ('x = "if(Dist == 0, none, Dist)"', 'x = "if(Dist == 0, none, Dist"',
     "car.toml: objects.radar.x: rule 'if(Dist == 0, none, Dist': column 25: expected ',' or ')' "
     "to close the '(' at column 3, found end of rule"),
    ('c0 = "OffsetCoarse + OffsetFine"\nvalid = "Ok == 1"\n\n[lanes.right]',
     'c0 = "LaneRight.OffsetCoarse + OffsetFine"\nvalid = "Ok == 1"\n\n[lanes.right]',
     "car.toml: lanes.left.c0: rule 'LaneRight.OffsetCoarse + OffsetFine': column 1: message "
     "'LaneRight' is not one of LaneLeft"),
    ('vx = { value = "VLong + 0",', 'vx = { value = "VLong + 0", signal = "VLong",',
     "car.toml: objects.radar.vx: give either signal or value, not both"),
    ('vx = { value = "VLong + 0",', 'vx = { value = 3,',
     "car.toml: objects.radar.vx.value: expected an expression (string), got a number (3)"),
])
def test_a_wrong_name_in_an_expression_is_one_line_naming_it(
        tmp_path: Path, old: str, new: str, error: str) -> None:
    assert load_error(tmp_path, old, new) == error
