"""Values a car really sends that no arithmetic likes: IEEE float signals of +inf, -inf or NaN,
and validity rules that cannot be evaluated (a division by zero).

A non-finite value is counted per message and signal (the summary, the drive's statistics,
/health and /log), its raw frame and decoded message are recorded as they came, and the world
never takes it: the scene and the semantic topics never carry a non-finite number. A validity
rule that cannot be evaluated leaves the object out; the failures are counted per group and
reported in the summary, the statistics, /health and /log.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
from google.protobuf.message import Message
from harness import Viewer, assert_survived, recorded, start, steady, with_fault
from mcap.reader import make_reader

from bridge.cli import main
from bridge.frame import NS, Frame
from bridge.io.drives import ArchiveSource
from bridge.resources import data_dir
from bridge.sim.ecocar import simulate

INF, NAN = float("inf"), float("nan")
STEERING = 257  # ecocar's Steering message

# --- ecocar with a float steering angle ------------------------------------------------------
# ecocar's SteeringWheelAngle is a 16-bit integer; some cars send it as an IEEE float. This
# copy of ecocar.dbc makes it one (bytes 0-3, little endian, in degrees) and moves the rate out
# of its way.


def ecocar_float_dbc(folder: Path) -> Path:
    text = (data_dir() / "ecocar.dbc").read_text()
    text = text.replace(
        ' SG_ SteeringWheelAngle : 7|16@0- (0.1,0) [-780|780] "deg"',
        ' SG_ SteeringWheelAngle : 0|32@1- (1,0) [-780|780] "deg"')
    text = text.replace(' SG_ SteeringWheelRate : 23|16@0- (0.1,0)',
                        ' SG_ SteeringWheelRate : 32|8@1- (10,0)')
    text = text.replace(' SG_ DriverTorque : 39|12@0- (0.01,0)',
                        ' SG_ DriverTorque : 44|3@1- (1,0)')
    text = text.replace("SIG_VALTYPE_ 272 Latitude : 1;",
                        "SIG_VALTYPE_ 257 SteeringWheelAngle : 1;\nSIG_VALTYPE_ 272 Latitude : 1;")
    path = folder / "ecocar_float.dbc"
    path.write_text(text)
    assert cantools.database.load_file(path).get_message_by_name(
        "Steering").get_signal_by_name("SteeringWheelAngle").is_float
    return path


def _original() -> Any:
    return cantools.database.load_file(data_dir() / "ecocar.dbc").get_message_by_frame_id(
        STEERING)


def with_float_steering(frames: Iterator[tuple[float, Frame]], folder: Path,
                        fault: tuple[float, float], values: tuple[float, ...]
                        ) -> Iterator[tuple[float, Frame]]:
    """The drive with every Steering frame in the float layout; inside ``fault`` (seconds after
    the start) its angle is each of ``values`` in turn. No camera lanes: the lanes come from the
    steering angle."""
    original = _original()
    floating = cantools.database.load_file(ecocar_float_dbc(folder)).get_message_by_frame_id(
        STEERING)
    lanes = {m.frame_id for m in cantools.database.load_file(
        data_dir() / "ecocar.dbc").messages if m.name.startswith("CamLane")}
    n = 0
    for at, frame in frames:
        if frame.arbitration_id in lanes:
            continue
        if frame.arbitration_id == STEERING:
            signals = original.decode(frame.data, decode_choices=False)
            signals["DriverTorque"] = 0
            signals["SteeringWheelRate"] = 0
            if fault[0] <= at < fault[1]:
                signals["SteeringWheelAngle"] = values[n % len(values)]
                n += 1
            frame = frame._replace(data=floating.encode(signals, strict=False))
        yield at, frame


def non_finite_numbers(message: Message, path: str = "") -> list[str]:
    """Every float field of a protobuf message (recursively) that is not finite."""
    bad = []
    for field, value in message.ListFields():
        values = value if field.label == field.LABEL_REPEATED else [value]
        for item in values:
            where = f"{path}.{field.name}"
            if isinstance(item, Message):
                bad += non_finite_numbers(item, where)
            elif isinstance(item, float) and not math.isfinite(item):
                bad.append(f"{where}={item}")
    return bad


def metadata(path: Path) -> dict[str, Any]:
    import json

    with path.open("rb") as f:
        for record in make_reader(f).iter_metadata():
            if record.name == "tankviz":
                return {k: json.loads(v) if v[:1] in "[{" else v
                        for k, v in record.metadata.items()}
    raise AssertionError("no tankviz metadata")


def write_candump(path: Path, frames: Iterator[Frame]) -> int:
    n = 0
    with can.Logger(str(path)) as log:
        for f in frames:
            log(can.Message(timestamp=f.timestamp_ns / NS, arbitration_id=f.arbitration_id,
                            data=f.data, is_extended_id=f.is_extended, is_fd=f.is_fd,
                            bitrate_switch=f.bitrate_switch, channel=f.bus))
            n += 1
    return n


def assert_scene_finite(recording: dict[str, list[Any]]) -> None:
    checked = 0
    for topic, messages in recording.items():
        if topic.startswith("/can/"):
            continue  # the bus as it was, NaN and all
        for message in messages:
            assert non_finite_numbers(message) == [], topic
            checked += 1
    assert checked


@pytest.mark.slow
def test_inf_and_nan_in_a_float_steering_angle_are_counted_and_kept_out_of_the_scene(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    simulated = list(simulate(duration_s=3.0, seed=1))
    t0 = simulated[0].timestamp_ns
    frames = [f for _, f in with_float_steering(
        (((f.timestamp_ns - t0) / NS, f) for f in simulated), tmp_path, (1.0, 1.5),
        (INF, -INF, NAN))]
    log = tmp_path / "drive.log"
    sent = write_candump(log, iter(frames))
    out = tmp_path / "drive.mcap"

    code = main(["convert", str(log), "-o", str(out), "--dbc", str(tmp_path / "ecocar_float.dbc"),
                 "--profile", "ecocar"])

    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "non-finite values" in printed.out
    assert re.search(r"can0/Steering\.SteeringWheelAngle \(\d+\)", printed.out), printed.out
    recording = recorded_file(out)
    assert len(list(ArchiveSource(out))) == sent
    angles = [m.SteeringWheelAngle for m in recording["/can/can0/Steering"]]
    assert any(a == INF for a in angles) and any(a == -INF for a in angles)
    assert any(math.isnan(a) for a in angles)  # decoded and recorded as they came
    assert_scene_finite(recording)
    from bridge.apps.inspect import format_summary, summarize_file

    inspected = format_summary(str(out), summarize_file(out))  # tankviz inspect says so
    assert re.search(r"non-finite values \(kept out of the scene\): [\d,]+ — "
                     r"can0/Steering\.SteeringWheelAngle", inspected), inspected
    assert all(math.isfinite(e.steering_wheel_angle) and math.isfinite(e.curvature)
               for e in recording["/ego"])
    statistics = metadata(out)["statistics"]
    bad = sum(1 for a in angles if not math.isfinite(a))
    assert statistics["non_finite"] == {"can0/Steering.SteeringWheelAngle": bad}
    health = recording["/health"][-1]
    assert sum(b.non_finite_total for b in health.buses) == bad
    assert any("SteeringWheelAngle" in m.message for m in recording["/log"])


def recorded_file(path: Path) -> dict[str, list[Any]]:
    folder = path.parent / "one"
    folder.mkdir(exist_ok=True)
    (folder / path.name).write_bytes(path.read_bytes())
    return recorded(folder)


# --- a car that is not ecocar: a shuttle with float signals everywhere ------------------------

SHUTTLE_DBC = """\
VERSION ""

NS_ :
    SIG_VALTYPE_

BS_:

BU_: Shuttle Lidar Cam

BO_ 256 Motion: 8 Shuttle
 SG_ Speed : 0|32@1- (1,0) [0|0] "m/s" Lidar
 SG_ WheelAngle : 32|32@1- (1,0) [0|0] "rad" Lidar

BO_ 512 Obstacle: 8 Lidar
 SG_ Ahead : 0|32@1- (1,0) [0|0] "m" Shuttle
 SG_ Side : 32|8@1- (0.1,0) [-12.8|12.7] "m" Shuttle
 SG_ Track : 40|8@1+ (1,0) [0|255] "" Shuttle
 SG_ Quality : 48|8@1+ (1,0) [0|255] "" Shuttle
 SG_ Gain : 56|8@1+ (1,0) [0|255] "" Shuttle

BO_ 768 LeftLine: 8 Cam
 SG_ Offset : 0|32@1- (1,0) [0|0] "m" Shuttle
 SG_ Bend : 32|32@1- (1,0) [0|0] "1/m" Shuttle

BO_ 769 RightLine: 8 Cam
 SG_ Offset : 0|32@1- (1,0) [0|0] "m" Shuttle
 SG_ Bend : 32|32@1- (1,0) [0|0] "1/m" Shuttle

SIG_VALTYPE_ 256 Speed : 1;
SIG_VALTYPE_ 256 WheelAngle : 1;
SIG_VALTYPE_ 512 Ahead : 1;
SIG_VALTYPE_ 768 Offset : 1;
SIG_VALTYPE_ 768 Bend : 1;
SIG_VALTYPE_ 769 Offset : 1;
SIG_VALTYPE_ 769 Bend : 1;
"""

SHUTTLE_PROFILE = """\
[profile]
name = "shuttle"
description = "a people mover: one lidar obstacle, camera lines, all in IEEE floats"

[vehicle]
wheelbase = 3.0
steering_ratio = 1.0

[sensors.lidar]
kind = "radar"
mount = {{ x = 2.0, y = 0.0, z = 1.0, yaw = 0.0 }}
lateral = "left"
coordinates = "cartesian"

[sensors.cam]
kind = "camera"
mount = {{ x = 1.0, y = 0.0, z = 2.0, yaw = 0.0 }}
lateral = "left"

[objects.obstacles]
sensor = "lidar"
messages = ["Obstacle"]
id = "Track"
x = "Ahead"
y = "Side"
valid = "{rule}"
lifetime = 0.5

[lanes]
sensor = "cam"
stale_after = 0.3

[lanes.left]
message = "LeftLine"
c0 = "Offset"
c2 = "Bend"

[lanes.right]
message = "RightLine"
c0 = "Offset"
c2 = "Bend"

[ego]
speed = "Motion.Speed"
steering_wheel_angle = "Motion.WheelAngle"
"""


def shuttle(folder: Path, rule: str = "Quality > 50") -> tuple[Path, Path]:
    dbc, profile = folder / "shuttle.dbc", folder / "shuttle.toml"
    dbc.write_text(SHUTTLE_DBC)
    profile.write_text(SHUTTLE_PROFILE.format(rule=rule))
    return dbc, profile


def shuttle_drive(seconds: float, *, bad: float | None = None, gain: int = 2,
                  camera: bool = True) -> Iterator[Frame]:
    """The shuttle at 10 Hz: driving, an obstacle ahead, camera lines; from 1 s to 2 s every
    float it sends is ``bad`` (when given)."""
    t0 = 1_700_000_000 * NS
    for i in range(int(seconds * 10)):
        t = t0 + i * NS // 10
        at = i / 10
        v = bad if bad is not None and 1.0 <= at < 2.0 else None

        def f(x: float, v: float | None = v) -> bytes:
            return struct.pack("<f", x if v is None else v)

        yield Frame(t, "can0", 256, f(8.0) + f(0.02))
        yield Frame(t + 1_000_000, "can0", 512,
                    f(30.0) + struct.pack("<bBBB", 5, 7, 90, gain))
        if camera:
            yield Frame(t + 2_000_000, "can0", 768, f(1.7) + f(0.001))
            yield Frame(t + 3_000_000, "can0", 769, f(-1.7) + f(0.001))


@pytest.mark.parametrize("bad", [INF, -INF, NAN], ids=["inf", "-inf", "nan"])
@pytest.mark.parametrize("camera", [True, False], ids=["camera lanes", "steering lanes"])
def test_a_non_finite_float_of_another_car_is_counted_per_signal_and_never_drawn(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], bad: float, camera: bool) -> None:
    dbc, profile = shuttle(tmp_path)
    log = tmp_path / "shuttle.log"
    sent = write_candump(log, shuttle_drive(3.0, bad=bad, camera=camera))
    out = tmp_path / "shuttle.mcap"

    code = main(["convert", str(log), "-o", str(out), "--dbc", str(dbc),
                 "--profile", str(profile)])

    printed = capsys.readouterr()
    assert code == 0, printed.err
    recording = recorded_file(out)
    assert len(list(ArchiveSource(out))) == sent
    assert_scene_finite(recording)
    statistics = metadata(out)["statistics"]
    expected = {"can0/Motion.Speed": 10, "can0/Motion.WheelAngle": 10,
                "can0/Obstacle.Ahead": 10}
    if camera:
        expected |= {f"can0/{m}.{s}": 10 for m in ("LeftLine", "RightLine")
                     for s in ("Offset", "Bend")}
    assert statistics["non_finite"] == expected
    assert "can0/Motion.WheelAngle (10)" in printed.out
    # the obstacle stays where it was last seen finite (until its lifetime ends)
    objects = recording["/perception/obstacles"]
    assert all(o.x == pytest.approx(32.0) for m in objects for o in m.objects)
    assert any(m.count for m in objects)


def test_a_validity_rule_that_divides_by_zero_is_counted_per_group_and_reported(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dbc, profile = shuttle(tmp_path, rule="Quality / Gain > 30")
    log = tmp_path / "shuttle.log"
    write_candump(log, shuttle_drive(3.0, gain=0))
    out = tmp_path / "shuttle.mcap"

    code = main(["convert", str(log), "-o", str(out), "--dbc", str(dbc),
                 "--profile", str(profile)])

    printed = capsys.readouterr()
    assert code == 0, printed.err
    recording = recorded_file(out)
    # the rule cannot say the object is valid: it is left out, and counted
    assert all(m.count == 0 for m in recording["/perception/obstacles"])
    errors = metadata(out)["statistics"]["rule_errors"]
    assert set(errors) == {"obstacles"} and errors["obstacles"] > 0
    assert re.search(r"rule errors \(objects left out\): obstacles \(\d+\)",
                     printed.out), printed.out
    assert "ZeroDivisionError" in printed.out
    family = next(f for f in recording["/health"][-1].families if f.name == "obstacles")
    assert 0 < family.rule_errors_total <= errors["obstacles"]  # /health comes once a second
    assert "ZeroDivisionError" in family.last_rule_error
    assert any("obstacles" in m.message and "rule" in m.message for m in recording["/log"])


def test_a_rule_that_holds_counts_no_error(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    dbc, profile = shuttle(tmp_path, rule="Quality / Gain > 30")
    log = tmp_path / "shuttle.log"
    write_candump(log, shuttle_drive(2.0, gain=2))
    out = tmp_path / "shuttle.mcap"

    assert main(["convert", str(log), "-o", str(out), "--dbc", str(dbc),
                 "--profile", str(profile), "--quiet"]) == 0

    recording = recorded_file(out)
    assert any(m.count == 1 for m in recording["/perception/obstacles"])
    assert metadata(out)["statistics"]["rule_errors"] == {}


# --- live -------------------------------------------------------------------------------------

FAULT = (1.5, 2.5)


def inf_steering() -> Iterator[tuple[float, Any]]:
    folder = Path(__file__).resolve().parent
    drive = with_float_steering(steady(4.0), _tmp(folder), FAULT, (INF,))
    for at, frame, _ in with_fault(drive, FAULT):
        yield at, frame


def _tmp(folder: Path) -> Path:
    import os
    import tempfile

    path = Path(os.environ.get("VALUES_TMP") or tempfile.mkdtemp())
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.mark.slow
def test_live_goes_on_through_an_infinite_steering_angle(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VALUES_TMP", str(tmp_path))
    dbc = ecocar_float_dbc(tmp_path)
    car = start(tmp_path, f"{__file__}:inf_steering", "--dbc", str(dbc), "--profile", "ecocar")
    viewer = Viewer(car.url)
    ended = car.when("car: fault ends")

    recording = assert_survived(car, viewer, fault_ended=ended, on_log="SteeringWheelAngle")

    assert_scene_finite(recording)
    angles = [m.SteeringWheelAngle for m in recording["/can/can0/Steering"]]
    assert INF in angles


def test_a_rule_tells_an_error_from_a_rule_that_does_not_hold() -> None:
    from bridge.profile.expr import parse

    rule = parse("Quality / Gain > 30")
    assert rule.judge({"Quality": 90, "Gain": 2}) == (True, "")
    assert rule.judge({"Quality": 90, "Gain": 9}) == (False, "")
    assert rule.judge({"Quality": 90}) == (False, "")  # Gain has not come yet: not an error
    assert rule.judge({"Quality": 90, "Gain": 0}) == (
        False, "ZeroDivisionError: division by zero")
    assert rule.test({"Quality": 90, "Gain": 0}) is False
