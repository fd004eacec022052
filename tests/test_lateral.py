"""The lateral sign, checked from the data (:mod:`bridge.world.lateral`).

A made-up car, nothing like ecocar: a front radar with eight track slots ``TRK_0 .. TRK_7``
whose lateral distance is positive to the RIGHT, and a vehicle message with speed (km/h), yaw
rate (deg/s) and steering wheel angle (deg). The DBC and profile are written to tmp_path; the
drives are made here, frame by frame, encoded with cantools: the ego drives a left curve (or a
straight road, or stands) past posts standing beside the road, and a car drives ahead of it.

With the right sign (``lateral = "right"``) the posts sweep against the turn: "ok". With the
sign flipped in the profile (``lateral = "left"``) the scene is mirrored and the posts sweep with
the turn: "flipped", said once on ``/log`` and printed by ``tankviz inspect``. A straight road and
a standstill never give a verdict, whichever the sign, and the message says what was missing,
with the figures. (The vehicles ahead leaning into highway curves: test_lateral_highway.py.)
"""

from __future__ import annotations

import json
import math
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any, cast

import can
import cantools
import pytest
from conftest import T0, WriteLog, message
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.apps.inspect import format_summary, summarize_file
from bridge.pipeline.convert import convert
from bridge.pipeline.drive import load_stages
from bridge.pipeline.perception import Perception
from bridge.profile.model import Profile
from bridge.sinks.mcap import METADATA_NAME
from bridge.topics import LOG_TOPIC
from bridge.world.lateral import LateralSettings, LateralSignCheck, LateralVerdict

DBC = """VERSION ""

BU_: RDR VEH

BO_ 1568 TRK_0: 8 RDR
 SG_ TRK_ID : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ TRK_LONG : 8|16@1+ (0.01,0) [0|655] "m" Vector__XXX
 SG_ TRK_LAT : 24|16@1- (0.01,0) [-327|327] "m" Vector__XXX
 SG_ TRK_VX : 40|12@1- (0.05,0) [-102|102] "m/s" Vector__XXX
 SG_ TRK_STATE : 52|2@1+ (1,0) [0|3] "" Vector__XXX
{more}
BO_ 1792 VEH_DYN: 8 VEH
 SG_ SPEED : 0|16@1+ (0.01,0) [0|655] "km/h" Vector__XXX
 SG_ YAW : 16|16@1- (0.01,0) [-327|327] "deg/s" Vector__XXX
 SG_ STEER : 32|16@1- (0.1,0) [-3276|3276] "deg" Vector__XXX
"""

SLOTS = 8
TURN_SPEED = 15.0  # m/s
RADIUS = 75.0  # m: a left curve at 0.2 rad/s (11.5 deg/s)
MOUNT_X = 3.5
WHEELBASE, RATIO = 2.9, 16.0


def dbc_text() -> str:
    more = "".join(
        DBC[DBC.index("BO_ 1568"):DBC.index("{more}")].replace("1568 TRK_0", f"{1568 + i} TRK_{i}")
        for i in range(1, SLOTS))
    return DBC.replace("{more}", more)


def profile_text(lateral: str, *, vx: bool = True, yaw: bool = True) -> str:
    ego = ('yaw_rate = { signal = "VEH_DYN.YAW", scale = 0.01745329 }' if yaw else
           'steering_wheel_angle = { signal = "VEH_DYN.STEER", scale = 0.01745329 }')
    return f"""
[profile]
name = "trk_radar"

[vehicle]
wheelbase = {WHEELBASE}
steering_ratio = {RATIO}
origin = "rear_axle"

[sensors.front_radar]
kind = "radar"
mount = {{ x = {MOUNT_X} }}
lateral = "{lateral}"
fov = {{ range = 80.0, azimuth = 50.0 }}

[objects.trk]
sensor = "front_radar"
role = "tracks"
messages = ["TRK_{{i}}"]
index = [0, {SLOTS - 1}]
id = "TRK_ID"
x = "TRK_LONG"
y = "TRK_LAT"
{'vx = "TRK_VX"' if vx else ''}
valid = "TRK_STATE == 1"
lifetime = 0.3

[ego]
speed = {{ signal = "VEH_DYN.SPEED", scale = 0.2777778 }}
{ego}
"""


def write_car(tmp_path: Path, lateral: str, **kwargs: bool) -> tuple[Path, Path]:
    dbc = tmp_path / "trk_radar.dbc"
    dbc.write_text(dbc_text())
    profile = tmp_path / f"trk_radar_{lateral}.toml"
    profile.write_text(profile_text(lateral, **kwargs))
    return dbc, profile


def posts(road: str) -> list[tuple[float, float]]:
    """Posts standing 5 m beside the road, both sides, every 6 m (world frame, start at 0, 0)."""
    if road == "curve":  # the road's centre circles (0, RADIUS), to the left
        return [(r * math.sin(a), RADIUS - r * math.cos(a))
                for r in (RADIUS - 5.0, RADIUS + 5.0) for a in
                (k * 6.0 / RADIUS for k in range(1, 40))]
    return [(6.0 * k, side) for k in range(1, 60) for side in (-5.0, 5.0)]


def drive(db: cantools.database.can.Database, road: str, *,
          seconds: float = 10.0) -> Iterator[can.Message]:
    """Radar tracks and vehicle dynamics at 20 Hz: a left curve, a straight road or a
    standstill; the posts are tracks 1.., the car 25 m ahead (in the lane) is track 200. Each
    position has 0.15 m of noise, as a radar's has (the same on every run)."""
    noise = random.Random(14)
    speed = 0.0 if road == "standstill" else TURN_SPEED
    omega = speed / RADIUS if road == "curve" else 0.0
    steer = math.degrees(math.atan(WHEELBASE / RADIUS) * RATIO) if road == "curve" else 0.0
    world = posts("curve" if road == "curve" else "straight")
    for k in range(round(seconds * 20)):
        t = k * 0.05
        heading = omega * t
        if road == "curve":
            ex, ey = RADIUS * math.sin(heading), RADIUS - RADIUS * math.cos(heading)
        else:
            ex, ey = speed * t, 0.0
        c, s = math.cos(heading), math.sin(heading)
        seen = []
        for number, (px, py) in enumerate(world, start=1):
            dx, dy = px - ex, py - ey
            x, y = c * dx + s * dy, -s * dx + c * dy  # vehicle frame, y left
            xs = x - MOUNT_X
            if 1.0 < xs < 80.0 and abs(math.degrees(math.atan2(y, xs))) < 50.0:
                seen.append((xs, y, -speed + omega * y, number))
        seen.sort()
        tracks = [(25.0 - MOUNT_X, 0.0, 0.0, 200), *seen[:SLOTS - 1]]
        yield message(db, "VEH_DYN", T0 + t, SPEED=speed * 3.6, YAW=math.degrees(omega),
                      STEER=steer)
        for slot in range(SLOTS):
            if slot < len(tracks):
                xs, y, vx, number = tracks[slot]
                # the radar's lateral distance is positive to the right
                yield message(db, f"TRK_{slot}", T0 + t + 0.001 * (slot + 1), TRK_ID=number,
                              TRK_LONG=xs + noise.gauss(0, 0.15),
                              TRK_LAT=-y + noise.gauss(0, 0.15), TRK_VX=vx, TRK_STATE=1)
            else:
                yield message(db, f"TRK_{slot}", T0 + t + 0.001 * (slot + 1), TRK_STATE=0)


def load(dbc: Path, profile_path: Path) -> tuple[cantools.database.can.Database, Profile]:
    decoder, profile = load_stages([str(dbc)], profile_path)
    assert profile is not None
    (database,) = decoder.files
    return database.db, profile


def check_drive(tmp_path: Path, lateral: str, road: str, **kwargs: bool) -> LateralVerdict:
    """Run the drive through perception as the pipeline does, the check fed at every tick."""
    db, profile = load(*write_car(tmp_path, lateral, **kwargs))
    perception = Perception(profile)
    check = LateralSignCheck(profile)
    for frame in drive(db, road):
        t_ns = round(frame.timestamp * 1e9)
        for tick in perception.due_ticks(t_ns):
            perception.tick(tick)
            check.update(tick, perception.world)
        definition = db.get_message_by_frame_id(frame.arbitration_id)
        perception.feed(definition.name, cast("dict[str, Any]", definition.decode(
            bytes(frame.data), decode_choices=False)), t_ns)
    (verdict,) = check.verdicts()
    return verdict


@pytest.mark.parametrize("rule", ["vx", "motion"])
def test_posts_sweeping_against_a_left_turn_say_the_sign_is_right(
        tmp_path: Path, rule: str) -> None:
    verdict = check_drive(tmp_path, "right", "curve", vx=rule == "vx")

    assert verdict.verdict == "ok", verdict.message
    assert verdict.sensor == "front_radar"
    assert verdict.samples >= LateralSettings().min_samples and verdict.with_turn == 0
    assert verdict.message.startswith(
        f"front_radar: stationary objects sweep against the turn in {verdict.against} of "
        f"{verdict.samples} samples")


@pytest.mark.parametrize("rule", ["vx", "motion"])
def test_a_flipped_sign_makes_the_posts_sweep_with_the_turn(tmp_path: Path, rule: str) -> None:
    verdict = check_drive(tmp_path, "left", "curve", vx=rule == "vx")

    assert verdict.verdict == "flipped", verdict.message
    assert verdict.samples >= LateralSettings().min_samples and verdict.against == 0
    assert verdict.message == (
        f"front_radar: stationary objects sweep WITH the turn in {verdict.with_turn} of "
        f'{verdict.samples} samples: lateral = "left" looks wrong, try lateral = "right"')


def test_without_a_yaw_rate_the_steering_angle_and_speed_tell_the_turn(tmp_path: Path) -> None:
    right, flipped = tmp_path / "right", tmp_path / "flipped"
    right.mkdir()
    flipped.mkdir()

    assert check_drive(right, "right", "curve", yaw=False).verdict == "ok"
    assert check_drive(flipped, "left", "curve", yaw=False).verdict == "flipped"


@pytest.mark.parametrize("lateral", ["left", "right"])
@pytest.mark.parametrize("road", ["straight", "standstill"])
def test_a_straight_road_or_a_standstill_gives_no_verdict(
        tmp_path: Path, road: str, lateral: str) -> None:
    verdict = check_drive(tmp_path, lateral, road)

    assert verdict.verdict == "unknown"
    assert verdict.samples == 0
    assert "lateral sign not judged: 0 samples" in verdict.message


def converted(tmp_path: Path, write_log: WriteLog, lateral: str, road: str) -> Path:
    dbc, profile = write_car(tmp_path, lateral)
    db, _ = load(dbc, profile)
    log = write_log(f"{road}-{lateral}.blf", drive(db, road))
    out = tmp_path / f"{road}-{lateral}.mcap"
    convert([log], out, [str(dbc)], profile=profile)
    return out


def lateral_logs(path: Path) -> list[str]:
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [m.message for *_, m in reader.iter_decoded_messages(topics=[LOG_TOPIC])
                if "lateral sign" in m.message]


def metadata_verdicts(path: Path) -> list[dict[str, Any]]:
    found = summarize_file(path).metadata[METADATA_NAME]["lateral_sign"]
    return cast("list[dict[str, Any]]", json.loads(found))


def test_a_flipped_sign_is_warned_on_log_once_and_shown_by_inspect(
        tmp_path: Path, write_log: WriteLog) -> None:
    drive_path = converted(tmp_path, write_log, "left", "curve")

    (warning,) = lateral_logs(drive_path)
    assert warning.startswith("lateral sign of front_radar: stationary objects sweep WITH the "
                              "turn in ")
    assert warning.endswith('lateral = "left" looks wrong, try lateral = "right"')
    (verdict,) = metadata_verdicts(drive_path)
    assert verdict["verdict"] == "flipped" and verdict["sensor"] == "front_radar"
    report = format_summary(str(drive_path), summarize_file(drive_path)).splitlines()
    heading = report.index("lateral sign (stationary objects against the turn, vehicles ahead into "
                           "the curves):")
    assert report[heading + 1] == f"  flipped  {verdict['message']}"


@pytest.mark.parametrize(("lateral", "road", "expected"), [
    ("right", "curve", "ok"),
    ("left", "straight", "unknown"),
    ("right", "standstill", "unknown"),
])
def test_no_warning_for_a_right_sign_a_straight_road_or_a_standstill(
        tmp_path: Path, write_log: WriteLog, lateral: str, road: str, expected: str) -> None:
    drive_path = converted(tmp_path, write_log, lateral, road)

    assert lateral_logs(drive_path) == []
    (verdict,) = metadata_verdicts(drive_path)
    assert verdict["verdict"] == expected
    report = format_summary(str(drive_path), summarize_file(drive_path))
    assert f"  {expected:<7}  {verdict['message']}" in report.splitlines()


@pytest.mark.parametrize(("road", "why"), [
    ("straight", "turned at most 0.0°/s (2.9°/s needed) over 10 s; 0 samples of vehicles ahead "
                 "in curves (20 needed): no vehicle ahead in a curve (a turn of 0.6°/s or more "
                 "held for 2 s)"),
    ("standstill", "never drove at 3 m/s or more; 0 samples of vehicles ahead in curves (20 "
                   "needed): no vehicle driving ahead within 100 m at 10 m/s or more"),
])
def test_no_verdict_says_what_was_missing_with_the_figures(
        tmp_path: Path, road: str, why: str) -> None:
    verdict = check_drive(tmp_path, "right", road)

    assert verdict.message == ("front_radar: lateral sign not judged: 0 samples of stationary "
                               f"objects while turning (50 needed): {why}")
