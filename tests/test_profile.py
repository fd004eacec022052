"""Vehicle profiles (bridge/profile.py): what the bundled ecocar profile maps, and every error a
profile can cause, each with its exact one-line message (file, key, bad name, closest names).

Most error tests take the bundled ``ecocar.toml`` and change one thing in it; the profile is
written as ``car.toml`` in the current directory, so that messages read as the CLI prints them:
``car.toml: objects.radar.x: no signal 'LongDst' in RadarObj0_A, RadarObj0_B; closest: LongDist``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from pathlib import Path

import cantools
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from bridge.errors import BridgeError
from bridge.pipeline.drive import load_stages
from bridge.profile.loader import load_profile, read_profile_databases
from bridge.profile.model import (
    FamilyMember,
    LaneLine,
    Mount,
    ObjectClass,
    Profile,
    ProfileError,
    Sensor,
    SensorKind,
    SignalRef,
    Vehicle,
    expand,
)
from bridge.resources import data_dir
from bridge.world.observe import LaneObservation, ObjectObservation, Observer

Database = cantools.database.can.Database

ECOCAR = (data_dir() / "ecocar.toml").read_text()


def edit(*changes: tuple[str, str], text: str = ECOCAR) -> str:
    """``text`` (the ecocar profile) with each ``(old, new)`` replaced; ``old`` must occur once."""
    for old, new in changes:
        assert text.count(old) == 1, f"{old!r} occurs {text.count(old)} times"
        text = text.replace(old, new)
    return text


def section(header: str, body: str, text: str = ECOCAR) -> str:
    """``text`` with the section ``header`` (up to the next blank line) replaced by ``body``."""
    lines = text.splitlines(keepends=True)
    start = lines.index(header + "\n")
    end = next(i for i in range(start, len(lines)) if not lines[i].strip())
    return "".join(lines[:start]) + body + "".join(lines[end:])


def without(header: str, text: str = ECOCAR) -> str:
    """``text`` without the section ``header``."""
    return section(header, "", text)


@pytest.fixture
def car(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Where the profile under test goes: ``car.toml``, relative to the current directory."""
    monkeypatch.chdir(tmp_path)
    return Path("car.toml")


@pytest.fixture
def load(car: Path, ecocar: Database) -> Callable[[str], Profile]:
    """Write a profile's text to car.toml and load it against ecocar.dbc."""

    def load(text: str) -> Profile:
        car.write_text(text)
        return load_profile(car, [ecocar])

    return load


@pytest.fixture
def error(load: Callable[[str], Profile]) -> Callable[[str], str]:
    """The message of the ProfileError that loading a profile's text raises."""

    def error(text: str) -> str:
        with pytest.raises(ProfileError) as info:
            load(text)
        return one_line(info.value)

    return error


def one_line(exc: ProfileError) -> str:
    """A profile error's message, after checking that it is one line and a BridgeError."""
    message = str(exc)
    assert isinstance(exc, BridgeError)
    assert "\n" not in message and "\r" not in message
    assert message == (f"{exc.path}: {exc.key}: {exc.reason}" if exc.key
                       else f"{exc.path}: {exc.reason}")
    return message


# --- the bundled profile --------------------------------------------------------------------------


def test_the_bundled_ecocar_profile_maps_objects_lanes_lead_and_ego(ecocar: Database) -> None:
    profile = load_profile("ecocar", [ecocar])  # a bundled name, or a path
    assert profile.name == "ecocar"
    assert profile.path == data_dir() / "ecocar.toml"
    assert profile.databases == {"*": (data_dir() / "ecocar.dbc",)}
    assert profile.vehicle == Vehicle(wheelbase_m=2.8, steering_ratio=15.0, length_m=2.5,
                                      width_m=1.5, height_m=1.0)

    # sensors: where they are and which way their lateral axis points
    assert profile.sensors == {
        "radar": Sensor("radar", SensorKind.RADAR, Mount(z=0.5), lateral="left",
                        fov_range=160.0, fov_azimuth_deg=45.0),
        "camera": Sensor("camera", SensorKind.CAMERA, Mount(z=1.3), lateral="right",
                         fov_range=120.0, fov_azimuth_deg=26.0),
        "fusion": Sensor("fusion", SensorKind.FUSION),
    }
    assert profile.sensors["camera"].lateral_sign == -1.0
    assert profile.sensors["radar"].lateral_sign == 1.0

    # object groups: 32 radar objects in two messages each, 10 camera obstacles, 20 tracks
    assert {name: (g.sensor.name, g.templates, len(g.members), g.lifetime_s, g.is_tracks)
            for name, g in profile.groups.items()} == {
        "radar": ("radar", ("RadarObj{i}_A", "RadarObj{i}_B"), 64, 0.1, False),
        "camera": ("camera", ("CamObstacle{i}_A", "CamObstacle{i}_B"), 20, 0.1, False),
        "tracks": ("fusion", ("FusionTrack{i}",), 20, 0.3, True),
    }
    radar, camera, tracks = (profile.groups[n] for n in ("radar", "camera", "tracks"))
    assert radar.members["RadarObj0_A"] == FamilyMember("RadarObj{i}_A", 0)
    assert radar.members["RadarObj31_B"] == FamilyMember("RadarObj{i}_B", 31)
    assert "RadarObj32_A" not in radar.members
    # signals are stored with the template that carries them, for every instance of the family
    assert (radar.x, radar.y) == (SignalRef("RadarObj{i}_A", "LongDist"),
                                  SignalRef("RadarObj{i}_A", "LatDist"))
    assert (radar.vx, radar.vy) == (SignalRef("RadarObj{i}_A", "LongSpeed"),
                                    SignalRef("RadarObj{i}_B", "LatSpeed"))
    assert radar.probability == SignalRef("RadarObj{i}_A", "ProbExist")
    assert radar.class_signal == SignalRef("RadarObj{i}_B", "Class")
    assert radar.classes == {0: ObjectClass.UNKNOWN, 1: ObjectClass.CAR,
                             2: ObjectClass.TWO_WHEELER, 3: ObjectClass.PEDESTRIAN,
                             4: ObjectClass.STATIONARY}
    assert radar.id is None  # the index is the id
    assert (radar.range, radar.azimuth) == (None, None)
    # one validity rule per object
    assert sorted(radar.valid) == list(range(32))
    assert radar.valid[31].names == {"Valid", "ProbExist"}
    assert radar.valid[31].test({"Valid": 1, "ProbExist": 71})
    assert not radar.valid[31].test({"Valid": 1, "ProbExist": 70})
    # ObstacleID is in both camera messages: the profile says which with Message.Signal
    assert camera.id == SignalRef("CamObstacle{i}_A", "ObstacleID")
    assert camera.classes[0] is camera.classes[1] is ObjectClass.CAR
    assert camera.classes[4] is ObjectClass.TWO_WHEELER
    assert tracks.id == SignalRef("FusionTrack{i}", "TrackID")
    assert tracks.valid[0].text == "Status != 0"

    # the lead vehicle from its own message
    lead = profile.lead
    assert lead is not None and lead.source == "message" and lead.lifetime_s == 0.3
    assert lead.group is not None
    assert lead.group.members == {"LeadVehicle": FamilyMember("LeadVehicle", None)}
    assert lead.group.sensor is profile.sensors["fusion"]
    assert (lead.group.id, lead.group.x, lead.group.y) == (
        SignalRef("LeadVehicle", "TrackID"), SignalRef("LeadVehicle", "PosX"),
        SignalRef("LeadVehicle", "PosY"))
    assert list(lead.group.valid) == [None]  # not indexed: one object at a time
    assert lead.group.valid[None].text == "Valid == 1"

    # four lane lines from the camera, in the camera's frame
    lanes = profile.lanes
    assert lanes is not None and lanes.sensor is profile.sensors["camera"]
    assert list(lanes.lines) == ["left", "right", "next_left", "next_right"]
    assert [line.message for line in lanes.lines.values()] == [
        "CamLaneLeft", "CamLaneRight", "CamLaneNextLeft", "CamLaneNextRight"]
    left = lanes.lines["left"]
    assert left == LaneLine("left", "CamLaneLeft", SignalRef("CamLaneLeft", "C0_Offset"),
                            SignalRef("CamLaneLeft", "C1_Heading"),
                            SignalRef("CamLaneLeft", "C2_Curvature"),
                            SignalRef("CamLaneLeft", "C3_CurvatureDerivative"), left.valid)
    assert left.valid is not None and left.valid.text == "Source == 1 and Quality > 0"
    assert (lanes.stale_after_s, lanes.length_m) == (0.5, 100.0)
    assert (lanes.fallback_left_m, lanes.fallback_right_m) == (1.8, -1.8)

    # ego signals with their unit conversions
    assert profile.ego.speed == SignalRef("EgoMotion", "VehicleSpeed", scale=0.2777778)
    assert profile.ego.yaw_rate == SignalRef("EgoMotion", "YawRate", scale=0.01745329)
    assert profile.ego.steering_wheel_angle == SignalRef("Steering", "SteeringWheelAngle",
                                                         scale=0.01745329)
    assert profile.ego.speed.read({"VehicleSpeed": 36.0}) == pytest.approx(10.0)
    assert profile.ego.speed.read({"YawRate": 1.0}) is None

    # every message the profile reads: 64 + 20 + 20 objects, the lead, 4 lanes, 2 ego messages
    names = profile.message_names()
    assert len(names) == 111
    assert {"LeadVehicle", "CamLaneNextRight", "EgoMotion", "Steering"} <= names
    assert not {"RadarStatus", "SensorDiag"} & names


def test_a_profile_names_its_databases_without_loading_them(car: Path) -> None:
    assert read_profile_databases(data_dir() / "ecocar.toml") == {
        "*": (data_dir() / "ecocar.dbc",)}
    # beside the profile first, then bundled; a string is a list of one; a table is per bus
    Path("mine.dbc").write_text((data_dir() / "ecocar.dbc").read_text())
    car.write_text('[profile]\ndatabases = { radar = "mine.dbc", "*" = ["ecocar.dbc"] }\n')
    assert read_profile_databases(car) == {"radar": (Path("mine.dbc"),),
                                           "*": (data_dir() / "ecocar.dbc",)}


def test_databases_given_elsewhere_set_the_profiles_own_aside(car: Path) -> None:
    # a profile copied from another machine names a database that is not here; --dbc gives it
    Path("radar.dbc").write_text((data_dir() / "ecocar.dbc").read_text())
    car.write_text('[profile]\nname = "moved"\ndatabases = ["/nowhere/radar.dbc"]\n')
    with pytest.raises(BridgeError, match=r"car.toml: profile.databases: no database file"):
        load_stages([], car)
    decoder, profile = load_stages(["radar.dbc"], car)
    assert profile is not None and profile.name == "moved" and profile.databases == {}
    assert [f.path for f in decoder.files] == [Path("radar.dbc")]


def test_everything_but_the_names_is_optional(load: Callable[[str], Profile]) -> None:
    profile = load('[sensors.fusion]\nkind = "fusion"\n\n'
                   '[objects.tracks]\nsensor = "fusion"\nmessages = "FusionTrack{i}"\n'
                   'index = [0, 19]\nx = "PosX"\ny = "PosY"\n')
    assert profile.name == "car"  # the file name
    assert profile.vehicle == Vehicle()
    assert profile.sensors["fusion"].mount == Mount()
    assert profile.groups["tracks"].lifetime_s == 0.1
    assert profile.groups["tracks"].valid == {}  # every object is valid
    assert (profile.lead, profile.lanes) == (None, None)
    assert profile.databases == {}  # the --dbc files are needed
    assert load("").groups == {}


def test_signals_with_unit_conversions_and_message_prefixes(
        load: Callable[[str], Profile]) -> None:
    profile = load(edit(
        ('x = "LongDist"', 'x = { signal = "LongDist", scale = 0.01, offset = -1 }'),
        ('vy = "LatSpeed"', 'vy = "RadarObj{i}_B.LatSpeed"'),
        ('index = [0, 19]', 'index = [5, 19]'),
        ('id = "TrackID"\nx = "PosX"\ny = "PosY"\nvx = "RelVelX"\nvy',
         'id = "FusionTrack{i}.TrackID"\nx = "PosX"\ny = "PosY"\nvx = "RelVelX"\nvy'),
    ))
    radar, tracks = profile.groups["radar"], profile.groups["tracks"]
    assert radar.x == SignalRef("RadarObj{i}_A", "LongDist", scale=0.01, offset=-1.0)
    assert radar.x.read({"LongDist": 12345}) == pytest.approx(122.45)
    assert radar.vy == SignalRef("RadarObj{i}_B", "LatSpeed")
    # with index [5, 19], "FusionTrack{i}.TrackID" names the family's first instance
    assert tracks.id == SignalRef("FusionTrack{i}", "TrackID")
    assert min(m.index or 0 for m in tracks.members.values()) == 5
    assert len(tracks.members) == 15


#: Per-object signals, as in GM's object fusion: object i is Tracks_i with signals TrkiRng, ...
#: Object 3 names its signals otherwise.
TRACKS_DBC = """VERSION ""

BS_:

BU_: FUSION

BO_ 1281 Tracks_1: 8 FUSION
 SG_ Trk1Rng : 0|16@1+ (0.1,0) [0|6553.5] "m" Vector__XXX
 SG_ Trk1Azi : 16|16@1- (0.01,0) [-327.68|327.67] "deg" Vector__XXX
 SG_ Trk1Valid : 32|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 1282 Tracks_2: 8 FUSION
 SG_ Trk2Rng : 0|16@1+ (0.1,0) [0|6553.5] "m" Vector__XXX
 SG_ Trk2Azi : 16|16@1- (0.01,0) [-327.68|327.67] "deg" Vector__XXX
 SG_ Trk2Valid : 32|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 1283 Tracks_3: 8 FUSION
 SG_ Trk3Rng : 0|16@1+ (0.1,0) [0|6553.5] "m" Vector__XXX
 SG_ Trk3Az : 16|16@1- (0.01,0) [-327.68|327.67] "deg" Vector__XXX
 SG_ Trk3Vld : 32|1@1+ (1,0) [0|1] "" Vector__XXX
"""

TRACKS = """\
[sensors.front]
kind = "fusion"
coordinates = "polar"

[objects.tracks]
sensor = "front"
messages = "Tracks_{i}"
index = [1, 2]
range = "Trk{i}Rng"
azimuth = { signal = "Trk{i}Azi", scale = 0.5 }
valid = "Trk{i}Valid == 1"
"""


def load_tracks(car: Path, text: str) -> Profile:
    car.write_text(text)
    return load_profile(car, [cantools.database.load_string(TRACKS_DBC, "dbc")])


def test_signals_and_rules_may_carry_the_object_index(car: Path) -> None:
    tracks = load_tracks(car, TRACKS).groups["tracks"]
    assert tracks.members == {"Tracks_1": FamilyMember("Tracks_{i}", 1),
                              "Tracks_2": FamilyMember("Tracks_{i}", 2)}
    assert tracks.range == SignalRef("Tracks_{i}", "Trk{i}Rng")
    assert tracks.azimuth == SignalRef("Tracks_{i}", "Trk{i}Azi", scale=0.5)
    assert {i: rule.text for i, rule in tracks.valid.items()} == {1: "Trk1Valid == 1",
                                                                   2: "Trk2Valid == 1"}


@pytest.mark.parametrize(("changes", "expected"), [
    pytest.param([("index = [1, 2]", "index = [1, 3]")],
                 "objects.tracks.valid: rule 'Trk3Valid == 1' reads 'Trk3Valid', which is not a "
                 "signal of Tracks_3; closest: Trk3Vld", id="rule"),
    pytest.param([("index = [1, 2]", "index = [1, 3]"), ('valid = "Trk{i}Valid == 1"\n', "")],
                 "objects.tracks.azimuth.signal: no signal 'Trk3Azi' in Tracks_3; closest: "
                 "Trk3Az", id="signal"),
    pytest.param([('range = "Trk{i}Rng"', 'range = "Trk1Rng"')],
                 "objects.tracks.range: no signal 'Trk1Rng' in Tracks_2; closest: Trk2Rng",
                 id="signal-without-i"),
])
def test_every_object_of_the_family_is_checked(car: Path, changes: list[tuple[str, str]],
                                               expected: str) -> None:
    with pytest.raises(ProfileError) as info:
        load_tracks(car, edit(*changes, text=TRACKS))
    assert one_line(info.value) == f"car.toml: {expected}"


def test_a_polar_sensor_reports_range_and_azimuth(load: Callable[[str], Profile]) -> None:
    profile = load(edit(
        ('coordinates = "cartesian"\nfov = { range = 160.0',
         'coordinates = "polar"\nangle_unit = "rad"\ndistance_scale = 0.01\n'
         'fov = { range = 160.0'),
        ('x = "LongDist"\ny = "LatDist"', 'range = "LongDist"\nazimuth = "LatDist"'),
    ))
    radar = profile.groups["radar"]
    assert (radar.x, radar.y) == (None, None)
    assert radar.range == SignalRef("RadarObj{i}_A", "LongDist")
    assert radar.azimuth == SignalRef("RadarObj{i}_A", "LatDist")
    assert (radar.sensor.coordinates, radar.sensor.angle_unit) == ("polar", "rad")
    assert radar.sensor.distance_scale == 0.01


def test_the_lead_vehicle_can_be_chosen_from_the_tracks(load: Callable[[str], Profile]) -> None:
    profile = load(section("[lead]", '[lead]\nsource = "tracks"\nlifetime = 0.5\n'))
    assert profile.lead is not None
    assert (profile.lead.source, profile.lead.group, profile.lead.lifetime_s) == (
        "tracks", None, 0.5)
    assert "LeadVehicle" not in profile.message_names()


def test_index_templates_may_pad_with_zeros() -> None:
    assert expand("RadarObj{i}_A", 7) == "RadarObj7_A"
    assert expand("Obj{i:02d}", 7) == "Obj07"
    assert expand("Obj{i:03d}.Range", 12) == "Obj012.Range"
    assert expand("Obj{i:12d}", 7) == "Obj000000000007"  # at most 2 digits of width


def test_an_index_wider_than_two_digits_is_refused(load: Callable[[str], Profile]) -> None:
    # {i:999999999d} once built a string of a billion zeros per message name
    with pytest.raises(ProfileError) as info:
        load(edit(('messages = ["RadarObj{i}_A", "RadarObj{i}_B"]',
                   'messages = ["RadarObj{i:999999999d}_A", "RadarObj{i}_B"]')))
    one_line(info.value)
    assert info.value.key == "objects.radar.messages"


def test_an_index_wider_than_two_digits_says_so(error: Callable[[str], str]) -> None:
    assert error(edit(('messages = ["RadarObj{i}_A", "RadarObj{i}_B"]',
                       'messages = ["RadarObj{i:100d}_A", "RadarObj{i}_B"]'))) == (
        "car.toml: objects.radar.messages: 'RadarObj{i:100d}_A': the width of {i:0Nd} is at "
        "most 2 digits, got 100")


# --- finding the profile --------------------------------------------------------------------------


def test_a_missing_file_or_an_unknown_bundled_name(car: Path, ecocar: Database) -> None:
    with pytest.raises(ProfileError) as info:
        load_profile("car.toml", [ecocar])
    assert one_line(info.value) == ("car.toml: no such profile file, and no bundled profile of "
                                    "that name (bundled: ecocar, highway)")
    with pytest.raises(ProfileError) as info:
        load_profile("ecocr", [ecocar])
    assert one_line(info.value) == ("ecocr: no such profile file, and no bundled profile of "
                                    "that name (bundled: ecocar, highway)")


def test_an_unreadable_file(car: Path, ecocar: Database, monkeypatch: pytest.MonkeyPatch) -> None:
    car.write_text(ECOCAR)

    def refuse(*args: object, **kwargs: object) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(Path, "open", refuse)
    with pytest.raises(ProfileError) as info:
        load_profile(car, [ecocar])
    assert one_line(info.value) == "car.toml: cannot read: Permission denied"


def test_invalid_toml_names_the_line_and_column(error: Callable[[str], str]) -> None:
    assert error(edit(("[vehicle]", "[vehicle"))) == (
        "car.toml: not valid TOML: Expected ']' at the end of a table declaration "
        "(at line 9, column 9)")
    assert error(edit(("wheelbase = 2.8", "wheelbase = 2.8.1"))) == (
        "car.toml: not valid TOML: Expected newline or end of document after a statement "
        "(at line 10, column 16)")


def test_a_profile_that_is_not_utf8(car: Path, ecocar: Database) -> None:
    car.write_bytes(edit(("# Vehicle profile", "# Vehicle profile \xb0")).encode("latin-1"))
    with pytest.raises(ProfileError) as info:
        load_profile(car, [ecocar])
    assert one_line(info.value) == (
        "car.toml: not valid TOML: not UTF-8 text (byte 0xb0 at position 18)")


@pytest.mark.parametrize(("databases", "expected"), [
    ('["ecocar2.dbc"]',
     "profile.databases: no database file 'ecocar2.dbc' beside the profile or bundled"),
    ('{ radar = ["radar.dbc"] }',
     "profile.databases.radar: no database file 'radar.dbc' beside the profile or bundled"),
    ("5", "profile.databases: expected a list of database files, got a number (5)"),
    ('["ecocar.dbc", 5]', "profile.databases: expected a list of database files, got a list"),
    ('{ radar = true }',
     "profile.databases.radar: expected a list of database files, got a boolean (true)"),
    pytest.param("0", "profile.databases: expected a list of database files, got a number (0)",
                 id="zero"),
    pytest.param("false",
                 "profile.databases: expected a list of database files, got a boolean (false)",
                 id="false"),
])
def test_databases_must_exist(error: Callable[[str], str], car: Path, databases: str,
                              expected: str) -> None:
    text = edit(('databases = ["ecocar.dbc"]', f"databases = {databases}"))
    assert error(text) == f"car.toml: {expected}"
    with pytest.raises(ProfileError) as info:
        read_profile_databases(car)
    assert one_line(info.value) == f"car.toml: {expected}"


# --- keys and types -------------------------------------------------------------------------------


@pytest.mark.parametrize(("old", "new", "expected"), [
    pytest.param(
        "[vehicle]", "[vehicel]",
        "vehicel: unknown key; closest: vehicle "
        "(allowed: buses, ego, lanes, lead, marks, objects, profile, sensors, vehicle)",
        id="top-level"),
    pytest.param(
        'name = "ecocar"', 'nam = "ecocar"',
        "profile.nam: unknown key; closest: name (allowed: databases, description, name)",
        id="profile"),
    pytest.param(
        "wheelbase = 2.8", "wheel_base = 2.8",
        "vehicle.wheel_base: unknown key; closest: wheelbase "
        "(allowed: height, length, origin, rear_overhang, steering_ratio, wheelbase, width)",
        id="vehicle"),
    pytest.param(
        '[sensors.fusion]\nkind = "fusion"', '[sensors.fusion]\nkind = "fusion"\ncolour = "red"',
        "sensors.fusion.colour: unknown key (allowed: angle_unit, coordinates, distance_scale, "
        "fov, kind, lateral, mount)",
        id="sensor-without-a-close-name"),
    pytest.param(
        "mount = { x = 0.0, y = 0.0, z = 0.5, yaw = 0.0 }",
        "mount = { x = 0.0, y = 0.0, z = 0.5, yaw_deg = 0.0 }",
        "sensors.radar.mount.yaw_deg: unknown key (allowed: x, y, yaw, z)",
        id="mount"),
    pytest.param(
        "fov = { range = 160.0, azimuth = 45.0 }", "fov = { range = 160.0, opening = 45.0 }",
        "sensors.radar.fov.opening: unknown key (allowed: azimuth, range)",
        id="fov"),
    pytest.param(
        'probability = "ProbExist"', 'probabilty = "ProbExist"',
        "objects.radar.probabilty: unknown key; closest: probability (allowed: azimuth, class, "
        "classes, id, index, lifetime, messages, probability, range, role, sensor, valid, vx, "
        "vy, x, y)",
        id="object-group"),
    pytest.param(
        'id = "TrackID"\nx = "PosX"\ny = "PosY"\nvx = "RelVelX"\nvalid',
        'id = "TrackID"\nx = "PosX"\ny = "PosY"\nvx = "RelVelX"\nspeed = "RelVelX"\nvalid',
        "lead.speed: unknown key (allowed: azimuth, class, classes, id, index, lifetime, "
        "messages, probability, range, sensor, valid, vx, vy, x, y)",
        id="lead"),
    pytest.param(
        "stale_after = 0.5", "stale = 0.5",
        "lanes.stale: unknown key (allowed: fallback, left, length, next_left, next_right, "
        "right, sensor, stale_after)",
        id="lanes"),
    pytest.param(
        "[lanes.next_left]", "[lanes.next_lft]",
        "lanes.next_lft: unknown key; closest: next_left (allowed: fallback, left, length, "
        "next_left, next_right, right, sensor, stale_after)",
        id="lane-name"),
    pytest.param(
        'message = "CamLaneLeft"', 'msg = "CamLaneLeft"',
        "lanes.left.msg: unknown key (allowed: c0, c1, c2, c3, message, valid)",
        id="lane-line"),
    pytest.param(
        "fallback = { left = 1.8, right = -1.8 }", "fallback = { left = 1.8, rigth = -1.8 }",
        "lanes.fallback.rigth: unknown key; closest: right (allowed: left, right)",
        id="fallback"),
    pytest.param(
        "yaw_rate = {", "yawrate = {",
        "ego.yawrate: unknown key; closest: yaw_rate (allowed: speed, steering_wheel_angle, "
        "yaw_rate)",
        id="ego"),
    pytest.param(
        '"EgoMotion.VehicleSpeed", scale', '"EgoMotion.VehicleSpeed", factor',
        "ego.speed.factor: unknown key (allowed: offset, scale, signal)",
        id="signal-table"),
])
def test_unknown_keys_name_the_allowed_and_the_closest_keys(error: Callable[[str], str], old: str,
                                                   new: str, expected: str) -> None:
    assert error(edit((old, new))) == f"car.toml: {expected}"


@pytest.mark.parametrize(("old", "new", "expected"), [
    # a string where a number belongs
    pytest.param("wheelbase = 2.8", 'wheelbase = "2.8"',
                 "vehicle.wheelbase: expected a number, got a string ('2.8')", id="str-number"),
    pytest.param("z = 0.5", "z = [0.5]",
                 "sensors.radar.mount.z: expected a number, got a list", id="list-number"),
    pytest.param("lifetime = 0.3\n\n# Lane", "lifetime = true\n\n# Lane",
                 "lead.lifetime: expected a number, got a boolean (true)", id="bool-number"),
    pytest.param("scale = 0.2777778", 'scale = "1/3.6"',
                 "ego.speed.scale: expected a number, got a string ('1/3.6')",
                 id="scale-is-a-number"),
    # a number where a string belongs
    pytest.param('name = "ecocar"', "name = 1",
                 "profile.name: expected a string, got a number (1)", id="number-string"),
    pytest.param('kind = "radar"', "kind = 1",
                 "sensors.radar.kind: expected a string, got a number (1)", id="kind"),
    pytest.param('sensor = "radar"', "sensor = 0",
                 "objects.radar.sensor: expected a string, got a number (0)", id="sensor"),
    pytest.param('message = "CamLaneLeft"', 'message = ["CamLaneLeft"]',
                 "lanes.left.message: expected a string, got a list", id="list-string"),
    pytest.param('x = "LongDist"', "x = 3",
                 "objects.radar.x: expected a signal name, got a number (3)", id="signal"),
    pytest.param('x = "LongDist"', 'x = ""',
                 "objects.radar.x: expected a signal name, got a string ('')", id="empty-signal"),
    pytest.param('c0 = "C0_Offset"\nc1 = "C1_Heading"\nc2 = "C2_Curvature"\n'
                 'c3 = "C3_CurvatureDerivative"\nvalid = "Source == 1 and Quality > 0"\n\n'
                 "[lanes.right]",
                 'c0 = 0.0\nc1 = "C1_Heading"\nc2 = "C2_Curvature"\n'
                 'c3 = "C3_CurvatureDerivative"\nvalid = "Source == 1 and Quality > 0"\n\n'
                 "[lanes.right]",
                 "lanes.left.c0: expected a signal name, got a number (0.0)", id="lane-signal"),
    pytest.param('valid = "Valid == 1 and ProbExist > 70"', "valid = 1",
                 "objects.radar.valid: expected a rule (string), got a number (1)", id="rule"),
    pytest.param('messages = ["FusionTrack{i}"]', "messages = []",
                 "objects.tracks.messages: expected a non-empty list of message names "
                 "(templates with {i} for an indexed family)", id="no-messages"),
    pytest.param('messages = ["FusionTrack{i}"]', 'messages = { first = "FusionTrack{i}" }',
                 "objects.tracks.messages: expected a non-empty list of message names "
                 "(templates with {i} for an indexed family)", id="table-messages"),
    pytest.param('messages = ["FusionTrack{i}"]', 'messages = ["FusionTrack{i}", ""]',
                 "objects.tracks.messages: expected a non-empty list of message names "
                 "(templates with {i} for an indexed family)", id="empty-message-name"),
    # a list where a table belongs
    pytest.param("fallback = { left = 1.8, right = -1.8 }", "fallback = [1.8, -1.8]",
                 "lanes.fallback: expected a table, got a list", id="list-table"),
    pytest.param("mount = { x = 0.0, y = 0.0, z = 0.5, yaw = 0.0 }", "mount = [0, 0, 0.5]",
                 "sensors.radar.mount: expected a table, got a list", id="mount"),
    pytest.param('classes = { 0 = "unknown", 1 = "car", 2 = "two_wheeler", 3 = "pedestrian", '
                 '4 = "stationary" }\nvalid = "Valid == 1 and',
                 'classes = ["unknown", "car"]\nvalid = "Valid == 1 and',
                 "objects.radar.classes: expected a table, got a list", id="classes"),
    pytest.param('speed = { signal = "EgoMotion.VehicleSpeed", scale = 0.2777778 }',
                 'speed = { signal = "EgoMotion.VehicleSpeed", scale = 0.2777778, offset = [] }',
                 "ego.speed.offset: expected a number, got a list", id="offset"),
    pytest.param('x = "LongDist"', 'x = { scale = 0.01 }',
                 "objects.radar.x: missing required key 'signal'", id="signal-table"),
])
def test_wrong_types(error: Callable[[str], str], old: str, new: str, expected: str) -> None:
    assert error(edit((old, new))) == f"car.toml: {expected}"


@pytest.mark.parametrize(("text", "expected"), [
    ("vehicle = 5\n", "vehicle: expected a table, got a number (5)"),
    ('lead = "tracks"\n', "lead: expected a table, got a string ('tracks')"),
    ('[sensors]\nradar = "radar"\n', "sensors.radar: expected a table, got a string ('radar')"),
    ("[objects]\nradar = 1.5\n", "objects.radar: expected a table, got a number (1.5)"),
    ('[sensors.camera]\nkind = "camera"\n\n[lanes]\nsensor = "camera"\nleft = true\n',
     "lanes.left: expected a table, got a boolean (true)"),
    ("[ego]\nspeed = 5\n", "ego.speed: expected Message.Signal, got a number (5)"),
    ('[ego]\nspeed = { signal = 5 }\n',
     "ego.speed.signal: expected Message.Signal, got a number (5)"),
])
def test_sections_must_be_tables(error: Callable[[str], str], text: str, expected: str) -> None:
    assert error(text) == f"car.toml: {expected}"


@pytest.mark.parametrize(("text", "expected"), [
    ("sensors = 5\n", "sensors: expected a table, got a number (5)"),
    ("objects = true\n", "objects: expected a table, got a boolean (true)"),
    ('[[sensors]]\nkind = "radar"\n', "sensors: expected a table, got a list"),
    ('[[objects]]\nsensor = "radar"\n', "objects: expected a table, got a list"),
])
def test_sensors_and_objects_must_be_tables(error: Callable[[str], str], text: str,
                                            expected: str) -> None:
    assert error(text) == f"car.toml: {expected}"


def test_the_description_is_a_string(error: Callable[[str], str]) -> None:
    text = re.sub(r'description = ".*"', "description = 5", ECOCAR)
    assert error(text) == "car.toml: profile.description: expected a string, got a number (5)"


# --- impossible values ----------------------------------------------------------------------------


@pytest.mark.parametrize(("old", "new", "expected"), [
    # not finite
    pytest.param("wheelbase = 2.8", "wheelbase = nan",
                 "vehicle.wheelbase: must be finite, got nan", id="nan"),
    pytest.param("yaw = 0.0 }\nlateral = \"left\"  ", "yaw = -inf }\nlateral = \"left\"  ",
                 "sensors.radar.mount.yaw: must be finite, got -inf", id="-inf"),
    pytest.param("scale = 0.01745329 }              #", "scale = inf }              #",
                 "ego.yaw_rate.scale: must be finite, got inf", id="inf"),
    pytest.param("wheelbase = 2.8", "wheelbase = 1e400",
                 "vehicle.wheelbase: must be finite, got inf", id="too-large"),
    # zero or negative where only positive makes sense
    pytest.param("wheelbase = 2.8", "wheelbase = 0",
                 "vehicle.wheelbase: must be greater than 0, got 0", id="zero-wheelbase"),
    pytest.param("steering_ratio = 15.0", "steering_ratio = -15.0",
                 "vehicle.steering_ratio: must be greater than 0, got -15.0", id="ratio"),
    pytest.param("height = 1.0", "height = 0.0",
                 "vehicle.height: must be greater than 0, got 0.0", id="height"),
    pytest.param('[sensors.fusion]\nkind = "fusion"',
                 '[sensors.fusion]\nkind = "fusion"\ndistance_scale = -0.01',
                 "sensors.fusion.distance_scale: must be greater than 0, got -0.01",
                 id="distance-scale"),
    pytest.param("fov = { range = 160.0", "fov = { range = 0",
                 "sensors.radar.fov.range: must be greater than 0, got 0", id="fov-range"),
    pytest.param("azimuth = 26.0", "azimuth = -26.0",
                 "sensors.camera.fov.azimuth: must be greater than 0, got -26.0",
                 id="fov-azimuth"),
    pytest.param("stale_after = 0.5", "stale_after = 0",
                 "lanes.stale_after: must be greater than 0, got 0", id="stale-after"),
    pytest.param("length = 100.0", "length = -100.0",
                 "lanes.length: must be greater than 0, got -100.0", id="lane-length"),
    # negative lifetimes (0 is fine: an object lasts until the next frame)
    pytest.param('valid = "Status != 0"\nlifetime = 0.3', 'valid = "Status != 0"\nlifetime = -0.3',
                 "objects.tracks.lifetime: must not be negative, got -0.3", id="lifetime"),
    pytest.param('valid = "Valid == 1"\nlifetime = 0.3', 'valid = "Valid == 1"\nlifetime = -1',
                 "lead.lifetime: must not be negative, got -1", id="lead-lifetime"),
    # a half opening angle of more than 180 degrees
    pytest.param("azimuth = 45.0", "azimuth = 181",
                 "sensors.radar.fov.azimuth: is a half angle: at most 180, got 181.0",
                 id="fov-over-180"),
    # one of a few words
    pytest.param('kind = "radar"', 'kind = "lidar"',
                 "sensors.radar.kind: must be one of radar, camera, fusion, got 'lidar'",
                 id="kind"),
    pytest.param('lateral = "right"', 'lateral = "Right"',
                 "sensors.camera.lateral: must be one of left, right, got 'Right'", id="lateral"),
    pytest.param('coordinates = "cartesian"\nfov = { range = 160.0',
                 'coordinates = "spherical"\nfov = { range = 160.0',
                 "sensors.radar.coordinates: must be one of cartesian, polar, got 'spherical'",
                 id="coordinates"),
    pytest.param('[sensors.fusion]\nkind = "fusion"',
                 '[sensors.fusion]\nkind = "fusion"\nangle_unit = "degrees"',
                 "sensors.fusion.angle_unit: must be one of deg, rad, got 'degrees'",
                 id="angle-unit"),
])
def test_impossible_values(error: Callable[[str], str], old: str, new: str,
                           expected: str) -> None:
    assert error(edit((old, new))) == f"car.toml: {expected}"


def test_a_zero_lifetime_is_fine(load: Callable[[str], Profile]) -> None:
    profile = load(edit(('valid = "Status != 0"\nlifetime = 0.3',
                         'valid = "Status != 0"\nlifetime = 0')))
    assert profile.groups["tracks"].lifetime_s == 0.0


def test_a_lead_chosen_from_tracks_takes_only_source_and_lifetime(
        error: Callable[[str], str]) -> None:
    assert error(section("[lead]", '[lead]\nsource = "tracks"\nlifetime = -0.3\n')) == (
        "car.toml: lead.lifetime: must not be negative, got -0.3")
    assert error(section("[lead]", '[lead]\nsource = "tracks"\nsensor = "fusion"\n')) == (
        "car.toml: lead.sensor: unknown key (allowed: lifetime, source)")


def test_the_lead_source_is_checked(error: Callable[[str], str]) -> None:
    assert error(edit(("[lead]\n", '[lead]\nsource = "trcks"\n'))) == (
        "car.toml: lead.source: must be one of message, tracks, got 'trcks'")
    assert error(edit(("[lead]\n", "[lead]\nsource = 5\n"))) == (
        "car.toml: lead.source: expected a string, got a number (5)")


def test_the_lead_source_may_say_message(load: Callable[[str], Profile]) -> None:
    lead = load(edit(("[lead]\n", '[lead]\nsource = "message"\n'))).lead
    assert lead is not None and lead.source == "message" and lead.group is not None
    assert list(lead.group.members) == ["LeadVehicle"]


@pytest.mark.parametrize("big", ["9" * 400, "-" + "9" * 400])
def test_an_integer_too_large_for_a_float_is_a_profile_error(
        load: Callable[[str], Profile], big: str) -> None:
    with pytest.raises(ProfileError) as info:
        load(edit(("wheelbase = 2.8", f"wheelbase = {big}")))
    one_line(info.value)
    assert info.value.key == "vehicle.wheelbase"
    assert info.value.reason.startswith("must be finite, got ")
    assert len(info.value.reason) < 60  # not the 400 digits


def test_an_integer_too_large_for_a_float(error: Callable[[str], str]) -> None:
    big = "9" * 400
    assert error(edit(("wheelbase = 2.8", f"wheelbase = {big}"))) == (
        f"car.toml: vehicle.wheelbase: must be finite, got {big[:20]}… (400 digits)")


# --- object families ------------------------------------------------------------------------------




@pytest.mark.parametrize(("old", "new", "expected"), [
    pytest.param("index = [0, 31]", "index = [31, 0]",
                 "objects.radar.index: empty family: [31, 0]", id="empty-range"),
    pytest.param("index = [0, 31]", "index = [0]",
                 "objects.radar.index: expected [first, last] object indices, e.g. [0, 31]",
                 id="one-number"),
    pytest.param("index = [0, 31]", "index = [0, 15, 31]",
                 "objects.radar.index: expected [first, last] object indices, e.g. [0, 31]",
                 id="three-numbers"),
    pytest.param("index = [0, 31]", "index = [0.0, 31.0]",
                 "objects.radar.index: expected [first, last] object indices, e.g. [0, 31]",
                 id="floats"),
    pytest.param("index = [0, 31]", "index = [false, true]",
                 "objects.radar.index: expected [first, last] object indices, e.g. [0, 31]",
                 id="booleans"),
    pytest.param("index = [0, 31]", 'index = "0-31"',
                 "objects.radar.index: expected [first, last] object indices, e.g. [0, 31]",
                 id="string"),
    pytest.param("index = [0, 31]", "index = [0, 32]",
                 "objects.radar.messages: no message 'RadarObj32_A' in the databases; closest: "
                 "RadarObj3_A, RadarObj2_A, RadarObj31_A", id="beyond-the-family"),
    pytest.param('messages = ["RadarObj{i}_A", "RadarObj{i}_B"]',
                 'messages = ["RadarObj{i}_A", "RadarObj0_B"]',
                 "objects.radar.messages: 'RadarObj0_B' has no {i} for the index",
                 id="template-without-i"),
    pytest.param('messages = ["FusionTrack{i}"]\nindex = [0, 19]', 'messages = ["FusionTrack{i}"]',
                 "objects.tracks.messages: 'FusionTrack{i}' has {i} but there is no 'index' range",
                 id="i-without-index"),
    pytest.param('messages = ["LeadVehicle"]\nid = "TrackID"', 'messages = ["LeadVehicle"]',
                 "lead: without 'index' each frame carries one object: name the signal that says "
                 "which with 'id'", id="no-index-no-id"),
    pytest.param('messages = ["LeadVehicle"]', 'messages = ["LeadVehicle", "FusionTrack0"]',
                 "lead.messages: without 'index' the family is one message carrying one object "
                 "per frame", id="no-index-two-messages"),
    pytest.param('messages = ["CamObstacle{i}_A", "CamObstacle{i}_B"]',
                 'messages = ["CamObstacle{i}_A", "CamObstacle{i}_C"]',
                 "objects.camera.messages: no message 'CamObstacle0_C' in the databases; "
                 "closest: CamObstacle0_B, CamObstacle0_A, CamObstacle9_B",
                 id="unknown-message"),
    pytest.param('messages = ["LeadVehicle"]', 'messages = ["LeadVehicles"]',
                 "lead.messages: no message 'LeadVehicles' in the databases; closest: "
                 "LeadVehicle", id="unknown-lead-message"),
    pytest.param('messages = ["LeadVehicle"]', 'messages = ["Target"]',
                 "lead.messages: no message 'Target' in the databases", id="nothing-close"),
    pytest.param('sensor = "radar"', 'sensor = "radar_front"',
                 "objects.radar.sensor: no sensor 'radar_front' in [sensors]; there are: camera, "
                 "fusion, radar",
                 id="unknown-sensor"),
    pytest.param('[lanes]\nsensor = "camera"', '[lanes]\nsensor = "front_camera"',
                 "lanes.sensor: no sensor 'front_camera' in [sensors]; there are: camera, fusion, "
                 "radar",
                 id="unknown-lane-sensor"),
    pytest.param('[lanes]\nsensor = "camera"', '[lanes]\nsensor = "camra"',
                 "lanes.sensor: no sensor 'camra' in [sensors]; closest: camera",
                 id="misspelt-sensor"),
    pytest.param('[objects.tracks]\nsensor = "fusion"', '[objects.tracks]',
                 "objects.tracks: missing required key 'sensor'", id="no-sensor"),
    pytest.param('[sensors.fusion]\nkind = "fusion"\n', '[sensors.fusion]\n',
                 "sensors.fusion: missing required key 'kind'", id="no-kind"),
])
def test_object_families(error: Callable[[str], str], old: str, new: str,
                         expected: str) -> None:
    assert error(edit((old, new))) == f"car.toml: {expected}"


def test_a_negative_index(error: Callable[[str], str]) -> None:
    assert error(edit(("index = [0, 31]", "index = [-1, 31]"))) == (
        "car.toml: objects.radar.index: indices cannot be negative, got [-1, 31]")
    assert error(edit(("index = [0, 31]", "index = [-5, -1]"))) == (
        "car.toml: objects.radar.index: indices cannot be negative, got [-5, -1]")


def test_a_message_named_twice(error: Callable[[str], str]) -> None:
    assert error(edit(('messages = ["FusionTrack{i}"]',
                       'messages = ["FusionTrack{i}", "FusionTrack{i}"]'))) == (
        "car.toml: objects.tracks.messages: 'FusionTrack{i}' is named twice")


@pytest.mark.parametrize("name", ["ego", "health", "lanes", "lead", "marks", "mio"])
def test_group_names_that_are_taken(error: Callable[[str], str], name: str) -> None:
    # each would overwrite its /scene/<name> topic
    assert error(edit(("[objects.tracks]", f"[objects.{name}]"))) == (
        f"car.toml: objects.{name}: '{name}' is taken by /scene/{name}; not one of ego, health, "
        "lanes, lead, marks, mio")


@pytest.mark.parametrize("name", ['""', '"../x"', '"a b"', '"radar/near"'])
def test_group_names_must_be_one_topic_segment(error: Callable[[str], str], name: str) -> None:
    """#33 item 12: "" gave the topic /scene/ and "../x" /scene/../x."""
    assert error(edit(("[objects.tracks]", f"[objects.{name}]"))) == (
        f"car.toml: objects.{name.strip(chr(34))}: {name.strip(chr(34))!r} is not a name for "
        "its topics (/scene/<name>, /perception/<name>): letters, digits and _ only")


def test_a_sensor_named_like_the_vehicle_frame(error: Callable[[str], str]) -> None:
    assert error('[sensors.vehicle]\nkind = "fusion"\n') == (
        "car.toml: sensors.vehicle: 'vehicle' is the vehicle frame; name the sensor otherwise")


# --- positions: cartesian or polar ----------------------------------------------------------------


POLAR_RADAR = ('coordinates = "cartesian"\nfov = { range = 160.0',
               'coordinates = "polar"\nfov = { range = 160.0')


@pytest.mark.parametrize(("changes", "expected"), [
    pytest.param([POLAR_RADAR],
                 "objects.radar: sensor 'radar' is polar: use range and azimuth, not x and y",
                 id="polar-with-x-y"),
    pytest.param([POLAR_RADAR, ('x = "LongDist"\ny = "LatDist"', 'range = "LongDist"')],
                 "objects.radar: sensor 'radar' is polar: name 'range' and 'azimuth'",
                 id="polar-without-azimuth"),
    pytest.param([('y = "LatDist"', 'y = "LatDist"\nrange = "LongDist"')],
                 "objects.radar: sensor 'radar' is cartesian: use x and y (or set coordinates = "
                 "\"polar\" on the sensor)", id="cartesian-with-range"),
    pytest.param([('y = "LatDist"\n', "")],
                 "objects.radar: sensor 'radar' is cartesian: name 'x' and 'y'",
                 id="cartesian-without-y"),
    pytest.param([('x = "PosX"\ny = "PosY"\nvx = "RelVelX"\nvalid', 'vx = "RelVelX"\nvalid')],
                 "lead: sensor 'fusion' is cartesian: name 'x' and 'y'", id="lead-without-x-y"),
])
def test_positions(error: Callable[[str], str], changes: list[tuple[str, str]],
                   expected: str) -> None:
    assert error(edit(*changes)) == f"car.toml: {expected}"


# --- signal names ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("old", "new", "expected"), [
    pytest.param('x = "LongDist"', 'x = "LongDst"',
                 "objects.radar.x: no signal 'LongDst' in RadarObj0_A, RadarObj0_B; closest: "
                 "LongDist", id="unknown-signal"),
    pytest.param('x = "LongDist"', 'x = { signal = "LongDst", scale = 0.01 }',
                 "objects.radar.x.signal: no signal 'LongDst' in RadarObj0_A, RadarObj0_B; "
                 "closest: LongDist", id="unknown-signal-in-a-table"),
    pytest.param('probability = "ProbExist"', 'probability = "Probability"',
                 "objects.radar.probability: no signal 'Probability' in RadarObj0_A, RadarObj0_B",
                 id="no-guesses"),
    pytest.param('vx = "RelVelX"\nvy', 'vx = "Speed"\nvy',
                 "objects.tracks.vx: no signal 'Speed' in FusionTrack0", id="nothing-close"),
    pytest.param('id = "CamObstacle{i}_A.ObstacleID"', 'id = "ObstacleID"',
                 "objects.camera.id: signal 'ObstacleID' is in CamObstacle0_A and "
                 "CamObstacle0_B: write Message.Signal", id="in-two-messages"),
    pytest.param('vy = "LatSpeed"', 'vy = "RadarObj{i}_A.LatSpeed"',
                 "objects.radar.vy: no signal 'LatSpeed' in RadarObj0_A",
                 id="not-in-the-message-named"),
    pytest.param('vy = "LatSpeed"', 'vy = "RadarObj{i}_C.LatSpeed"',
                 "objects.radar.vy: message 'RadarObj0_C' is not one of RadarObj0_A, "
                 "RadarObj0_B; closest: RadarObj0_B, RadarObj0_A", id="outside-the-family"),
    pytest.param('vy = "LatSpeed"', 'vy = "EgoMotion.YawRate"',
                 "objects.radar.vy: message 'EgoMotion' is not one of RadarObj0_A, RadarObj0_B",
                 id="another-message-of-the-dbc"),
    pytest.param('vy = "LatSpeed"', 'vy = "RadarObj5_B.LatSpeed"',
                 "objects.radar.vy: message 'RadarObj5_B' is not one of RadarObj0_A, "
                 "RadarObj0_B; closest: RadarObj0_B, RadarObj0_A", id="another-instance"),
    pytest.param('message = "CamLaneLeft"', 'message = "CamLaneLft"',
                 "lanes.left.message: no message 'CamLaneLft' in the databases; closest: "
                 "CamLaneLeft, CamLaneNextLeft", id="lane-message"),
    pytest.param('message = "CamLaneLeft"\nc0 = "C0_Offset"',
                 'message = "CamLaneLeft"\nc0 = "C0_Offst"',
                 "lanes.left.c0: no signal 'C0_Offst' in CamLaneLeft; closest: C0_Offset",
                 id="lane-signal"),
    pytest.param('message = "CamLaneLeft"\nc0 = "C0_Offset"',
                 'message = "CamLaneLeft"\nc0 = "CamLaneRight.C0_Offset"',
                 "lanes.left.c0: message 'CamLaneRight' is not one of CamLaneLeft",
                 id="lane-signal-of-another-line"),
    pytest.param('message = "CamLaneLeft"\nc0 = "C0_Offset"', 'message = "CamLaneLeft"',
                 "lanes.left: missing required key 'c0'", id="lane-without-c0"),
    pytest.param('"EgoMotion.VehicleSpeed"', '"VehicleSpeed"',
                 "ego.speed.signal: write Message.Signal, got 'VehicleSpeed'",
                 id="ego-without-message"),
    pytest.param('"EgoMotion.VehicleSpeed"', '".VehicleSpeed"',
                 "ego.speed.signal: write Message.Signal, got '.VehicleSpeed'",
                 id="ego-empty-message"),
    pytest.param('"EgoMotion.VehicleSpeed"', '"EgoMotion."',
                 "ego.speed.signal: write Message.Signal, got 'EgoMotion.'",
                 id="ego-empty-signal"),
    pytest.param('steering_wheel_angle = { signal = "Steering.SteeringWheelAngle", '
                 'scale = 0.01745329 }', 'steering_wheel_angle = "SteeringWheelAngle"',
                 "ego.steering_wheel_angle: write Message.Signal, got 'SteeringWheelAngle'",
                 id="ego-string-without-message"),
    pytest.param('steering_wheel_angle = { signal = "Steering.SteeringWheelAngle", '
                 'scale = 0.01745329 }', 'steering_wheel_angle = "Steerin.SteeringWheelAngle"',
                 "ego.steering_wheel_angle: no message 'Steerin' in the databases; closest: "
                 "Steering", id="ego-string-unknown-message"),
    pytest.param('"EgoMotion.VehicleSpeed"', '"EgoMotion.VehicleSped"',
                 "ego.speed.signal: no signal 'VehicleSped' in EgoMotion; closest: VehicleSpeed",
                 id="ego-signal"),
])
def test_signal_names(error: Callable[[str], str], old: str, new: str, expected: str) -> None:
    assert error(edit((old, new))) == f"car.toml: {expected}"


def test_the_readme_example(error: Callable[[str], str]) -> None:
    assert error(edit(('x = "LongDist"', 'x = "LongDst"'))) == (
        "car.toml: objects.radar.x: no signal 'LongDst' in RadarObj0_A, RadarObj0_B; "
        "closest: LongDist")


def test_an_unknown_ego_message_names_the_closest_not_every_message(
        error: Callable[[str], str]) -> None:
    assert error(edit(('"EgoMotion.VehicleSpeed"', '"EgoMotio.VehicleSpeed"'))) == (
        "car.toml: ego.speed.signal: no message 'EgoMotio' in the databases; closest: EgoMotion")
    assert error(edit(('"EgoMotion.VehicleSpeed"', '"Speedometer.VehicleSpeed"'))) == (
        "car.toml: ego.speed.signal: no message 'Speedometer' in the databases")


def test_an_ego_signal_table_without_signal(error: Callable[[str], str]) -> None:
    assert error(edit(('speed = { signal = "EgoMotion.VehicleSpeed", scale = 0.2777778 }',
                       "speed = { scale = 0.2777778 }"))) == (
        "car.toml: ego.speed: missing required key 'signal'")


def test_names_are_checked_against_the_loaded_databases(car: Path) -> None:
    car.write_text(ECOCAR)
    with pytest.raises(ProfileError) as info:
        load_profile(car, [])
    assert one_line(info.value) == (
        "car.toml: objects.radar.messages: no message 'RadarObj0_A' in the databases")


# --- classes --------------------------------------------------------------------------------------


RADAR_CLASSES = ('classes = { 0 = "unknown", 1 = "car", 2 = "two_wheeler", 3 = "pedestrian", '
                 '4 = "stationary" }\nvalid = "Valid == 1 and')


def radar_classes(classes: str) -> tuple[str, str]:
    return RADAR_CLASSES, f'classes = {classes}\nvalid = "Valid == 1 and'


@pytest.mark.parametrize(("changes", "expected"), [
    pytest.param([('"ProbExist"\nclass = "Class"\n', '"ProbExist"\n')],
                 "objects.radar.classes: given without a 'class' signal", id="without-class"),
    pytest.param([radar_classes('{ car = "car" }')],
                 "objects.radar.classes.car: keys are the signal's raw values (integers)",
                 id="key-not-an-integer"),
    pytest.param([radar_classes('{ "1.5" = "car" }')],
                 "objects.radar.classes.1.5: keys are the signal's raw values (integers)",
                 id="key-a-float"),
    pytest.param([radar_classes('{ 1 = "truck" }')],
                 "objects.radar.classes.1: unknown class 'truck'; one of unknown, car, "
                 "two_wheeler, pedestrian, stationary", id="unknown-class"),
    pytest.param([radar_classes('{ 1 = "Car" }')],
                 "objects.radar.classes.1: unknown class 'Car'; one of unknown, car, "
                 "two_wheeler, pedestrian, stationary", id="class-names-are-lower-case"),
    pytest.param([('"ProbExist"\nclass = "Class"', '"ProbExist"\nclass = "Klass"')],
                 "objects.radar.class: no signal 'Klass' in RadarObj0_A, RadarObj0_B; closest: "
                 "Class", id="unknown-class-signal"),
])
def test_classes(error: Callable[[str], str], changes: list[tuple[str, str]],
                 expected: str) -> None:
    assert error(edit(*changes)) == f"car.toml: {expected}"


def test_negative_raw_class_values(load: Callable[[str], Profile]) -> None:
    profile = load(edit(radar_classes('{ -1 = "unknown", 1 = "car" }')))
    assert profile.groups["radar"].classes == {-1: ObjectClass.UNKNOWN, 1: ObjectClass.CAR}


@pytest.mark.parametrize(("classes", "expected"), [
    pytest.param("5", "objects.radar.classes: expected a table, got a number (5)", id="number"),
    pytest.param("[[1]]", "objects.radar.classes: expected a table, got a list",
                 id="list-of-lists"),
    pytest.param('{ 1 = ["car"] }', "objects.radar.classes.1: expected a class name (string), got "
                 "a list", id="label-a-list"),
    pytest.param('{ 1 = 1 }', "objects.radar.classes.1: expected a class name (string), got "
                 "a number (1)", id="label-a-number"),
])
def test_classes_of_the_wrong_type(error: Callable[[str], str], classes: str,
                                   expected: str) -> None:
    assert error(edit(radar_classes(classes))) == f"car.toml: {expected}"


# --- validity rules -------------------------------------------------------------------------------


CAMERA_RULE = 'valid = "Valid == 1"\nlifetime = 0.1'
LEFT_RULE = 'valid = "Source == 1 and Quality > 0"\n\n[lanes.right]'


@pytest.mark.parametrize(("old", "new", "expected"), [
    pytest.param('valid = "Valid == 1 and ProbExist > 70"', 'valid = "Valid = 1"',
                 "objects.radar.valid: rule 'Valid = 1': column 7: use '==' to compare, not '='",
                 id="syntax"),
    pytest.param('valid = "Valid == 1 and ProbExist > 70"', 'valid = "Valid == 1 and"',
                 "objects.radar.valid: rule 'Valid == 1 and': column 15: expected a value, found "
                 "end of rule", id="incomplete"),
    pytest.param('valid = "Valid == 1 and ProbExist > 70"', 'valid = "Valid == 1 && ProbExist"',
                 "objects.radar.valid: rule 'Valid == 1 && ProbExist': column 12: use 'and' "
                 "instead of '&&'", id="another-language"),
    pytest.param('valid = "Valid == 1 and ProbExist > 70"',
                 'valid = "Valid == 1 and ProbExst > 70"',
                 "objects.radar.valid: rule 'Valid == 1 and ProbExst > 70' reads 'ProbExst', "
                 "which is not a signal of RadarObj0_A, RadarObj0_B; closest: ProbExist",
                 id="unknown-signal"),
    pytest.param('valid = "Status != 0"', 'valid = "Status != 0 and ProbExist > 70"',
                 "objects.tracks.valid: rule 'Status != 0 and ProbExist > 70' reads 'ProbExist', "
                 "which is not a signal of FusionTrack0", id="signal-of-another-family"),
    pytest.param('valid = "Valid == 1"\nlifetime = 0.3', 'valid = "Vaild == 1"\nlifetime = 0.3',
                 "lead.valid: rule 'Vaild == 1' reads 'Vaild', which is not a signal of "
                 "LeadVehicle; closest: Valid", id="lead"),
    pytest.param('c3 = "C3_CurvatureDerivative"\nvalid = "Source == 1 and Quality > 0"\n\n'
                 "[lanes.right]",
                 'c3 = "C3_CurvatureDerivative"\nvalid = "Source == 1 and Quality >"\n\n'
                 "[lanes.right]",
                 "lanes.left.valid: rule 'Source == 1 and Quality >': column 26: expected a "
                 "value, found end of rule", id="lane-syntax"),
    pytest.param('c3 = "C3_CurvatureDerivative"\nvalid = "Source == 1 and Quality > 0"\n\n'
                 "[lanes.right]",
                 'c3 = "C3_CurvatureDerivative"\nvalid = "Source == 1 and Qualty > 0"\n\n'
                 "[lanes.right]",
                 "lanes.left.valid: rule 'Source == 1 and Qualty > 0' reads 'Qualty', which is "
                 "not a signal of CamLaneLeft; closest: Quality", id="lane-signal"),
    # a plain name must be in exactly one message of the object
    pytest.param(CAMERA_RULE, 'valid = "Counter >= 0"',
                 "objects.camera.valid: rule 'Counter >= 0' reads 'Counter', which is in "
                 "CamObstacle0_A and CamObstacle0_B: write Message.Signal", id="in-two-messages"),
    # Message.Signal: the message must be one of the object's own
    pytest.param(CAMERA_RULE, 'valid = "CamObstacle{i}_C.Valid == 1"',
                 "objects.camera.valid: rule 'CamObstacle0_C.Valid == 1' reads "
                 "'CamObstacle0_C.Valid', but 'CamObstacle0_C' is not one of CamObstacle0_A, "
                 "CamObstacle0_B", id="message-outside-the-family"),
    pytest.param(CAMERA_RULE, 'valid = "CamObstacle5_A.Valid == 1"',
                 "objects.camera.valid: rule 'CamObstacle5_A.Valid == 1' reads "
                 "'CamObstacle5_A.Valid', but 'CamObstacle5_A' is not one of CamObstacle0_A, "
                 "CamObstacle0_B", id="message-of-another-object"),
    pytest.param(CAMERA_RULE, 'valid = "EgoMotion.YawRate < 10"',
                 "objects.camera.valid: rule 'EgoMotion.YawRate < 10' reads 'EgoMotion.YawRate', "
                 "but 'EgoMotion' is not one of CamObstacle0_A, CamObstacle0_B",
                 id="another-message-of-the-dbc"),
    pytest.param(LEFT_RULE, 'valid = "CamLaneRight.Source == 1"\n\n[lanes.right]',
                 "lanes.left.valid: rule 'CamLaneRight.Source == 1' reads 'CamLaneRight.Source', "
                 "but 'CamLaneRight' is not one of CamLaneLeft", id="lane-message-of-another-line"),
    pytest.param(LEFT_RULE, 'valid = "CamLaneLeft.Sorce == 1"\n\n[lanes.right]',
                 "lanes.left.valid: rule 'CamLaneLeft.Sorce == 1' reads 'CamLaneLeft.Sorce', which "
                 "is not a signal of CamLaneLeft; closest: Source", id="lane-message-signal"),
    # the signal must be in the message named
    pytest.param(CAMERA_RULE, 'valid = "CamObstacle{i}_B.Valid == 1"',
                 "objects.camera.valid: rule 'CamObstacle0_B.Valid == 1' reads "
                 "'CamObstacle0_B.Valid', which is not a signal of CamObstacle0_B",
                 id="not-in-the-message-named"),
    pytest.param(CAMERA_RULE, 'valid = "CamObstacle{i}_A.Vaild == 1"',
                 "objects.camera.valid: rule 'CamObstacle0_A.Vaild == 1' reads "
                 "'CamObstacle0_A.Vaild', which is not a signal of CamObstacle0_A; closest: Valid",
                 id="message-signal-misspelt"),
])
def test_validity_rules(error: Callable[[str], str], old: str, new: str, expected: str) -> None:
    assert error(edit((old, new))) == f"car.toml: {expected}"


def test_a_rule_is_shown_on_one_line(error: Callable[[str], str]) -> None:
    # TOML multi-line strings may hold a rule; the message stays on one line
    text = edit(('valid = "Valid == 1 and ProbExist > 70"',
                 'valid = """Valid == 1\nand ProbExist >"""'))
    assert error(text) == ("car.toml: objects.radar.valid: rule 'Valid == 1 and ProbExist >': "
                           "column 27: expected a value, found end of rule")


#: Rules naming Message.Signal: a camera obstacle is valid while its two messages carry the same
#: counter (Counter is in both: a plain name would be ambiguous); likewise for a lane and the lead.
QUALIFIED_RULES = (
    (CAMERA_RULE, 'valid = "Valid == 1 and CamObstacle{i}_B.Counter == CamObstacle{i}_A.Counter"'),
    (LEFT_RULE, 'valid = "CamLaneLeft.Source == 1 and Quality > 0"\n\n[lanes.right]'),
    ('valid = "Valid == 1"\nlifetime = 0.3', 'valid = "LeadVehicle.Valid == 1"\nlifetime = 0.3'),
)


def test_a_rule_may_name_message_signal(load: Callable[[str], Profile]) -> None:
    profile = load(edit(*QUALIFIED_RULES))
    assert profile.lead is not None and profile.lead.group is not None
    lead_rule = profile.lead.group.valid[None]
    assert (lead_rule.text, lead_rule.names) == ("LeadVehicle.Valid == 1", {"LeadVehicle.Valid"})
    assert lead_rule.test({}, {"LeadVehicle": {"Valid": 1}})
    assert not lead_rule.test({}, {"LeadVehicle": {"Valid": 0}})
    assert not lead_rule.test({}, {})  # a message not seen yet: not satisfied
    # each object's rule names that object's messages
    camera = profile.groups["camera"]
    rule = camera.valid[3]
    assert rule.expression.text == rule.text == (
        "Valid == 1 and CamObstacle3_B.Counter == CamObstacle3_A.Counter")
    assert rule.names == {"Valid", "CamObstacle3_A.Counter", "CamObstacle3_B.Counter"}
    in_sync = {"CamObstacle3_A": {"Valid": 1, "Counter": 5}, "CamObstacle3_B": {"Counter": 5}}
    assert rule.test({"Valid": 1}, in_sync)
    assert not rule.test({"Valid": 0}, in_sync)
    assert not rule.test({"Valid": 1}, {**in_sync, "CamObstacle3_B": {"Counter": 6}})
    assert not rule.test({"Valid": 1})  # Message.Signal names need the values by message
    assert camera.valid[0].names == {"Valid", "CamObstacle0_A.Counter", "CamObstacle0_B.Counter"}
    assert profile.lanes is not None
    left, right = profile.lanes.lines["left"].valid, profile.lanes.lines["right"].valid
    assert left is not None and left.names == {"CamLaneLeft.Source", "Quality"}
    assert right is not None and right.text == "Source == 1 and Quality > 0"  # plain names


def test_message_signal_rules_decide_validity_in_the_observer(
        load: Callable[[str], Profile]) -> None:
    observer = Observer(load(edit(*QUALIFIED_RULES)))

    def camera(message: str, t_ns: int, **values: float) -> list[bool]:
        found = observer.observe(message, values, t_ns)
        assert all(isinstance(o, ObjectObservation) and o.group == "camera" for o in found)
        return [o.valid for o in found if isinstance(o, ObjectObservation)]

    a3 = {"ObstacleID": 7, "PosX": 20.0, "PosY": 1.0, "RelVelX": 0.0, "Type": 1, "Valid": 1}
    # object 3's first message: its companion (CamObstacle3_B.Counter) is not seen yet
    assert camera("CamObstacle3_A", 1, **a3, Counter=5) == [False]
    # object 0's companion says nothing about object 3
    assert camera("CamObstacle0_B", 2, ObstacleID=1, Counter=5) == []
    assert camera("CamObstacle3_B", 3, ObstacleID=7, Counter=5) == [True]
    assert camera("CamObstacle3_B", 4, ObstacleID=7, Counter=6) == [False]
    assert camera("CamObstacle3_A", 5, **a3, Counter=6) == [True]
    assert camera("CamObstacle0_B", 6, ObstacleID=1, Counter=9) == []
    assert camera("CamObstacle3_A", 7, **{**a3, "Valid": 0}, Counter=6) == [False]

    def lane(**values: float) -> bool:
        found = observer.observe("CamLaneLeft", {"C0_Offset": 1.5, "C1_Heading": 0.0,
                                                 "C2_Curvature": 0.0,
                                                 "C3_CurvatureDerivative": 0.0, **values}, 10)
        assert len(found) == 1 and isinstance(found[0], LaneObservation)
        assert found[0].name == "left" and found[0].coefficients == (1.5, 0.0, 0.0, 0.0)
        return found[0].valid

    assert lane(Source=1, Quality=2)
    assert not lane(Source=2, Quality=2)
    assert not lane(Source=1, Quality=0)
    assert not lane(Quality=2)  # without the signal the rule is not satisfied

    def lead(valid: int) -> bool:
        found = observer.observe("LeadVehicle", {"Valid": valid, "TrackID": 4, "PosX": 30.0,
                                                 "PosY": 0.0, "RelVelX": -1.0}, 20)
        assert len(found) == 1 and isinstance(found[0], ObjectObservation)
        assert (found[0].group, found[0].object_id) == ("lead", 4)
        return found[0].valid

    assert lead(1)
    assert not lead(0)


# --- lanes ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(("header", "other"), [("[lanes.left]", "[lanes.right]"),
                                               ("[lanes.right]", "[lanes.left]")])
def test_lanes_need_a_left_and_a_right_line(error: Callable[[str], str], header: str,
                                            other: str) -> None:
    assert error(without(header)) == (f"car.toml: lanes: {other} needs {header} too; or no "
                                      "camera lines at all for lanes from the steering angle only")


def test_neighbour_lines_are_optional(load: Callable[[str], Profile]) -> None:
    profile = load(without("[lanes.next_right]", without("[lanes.next_left]")))
    assert profile.lanes is not None and list(profile.lanes.lines) == ["left", "right"]


def test_lanes_need_a_sensor(error: Callable[[str], str]) -> None:
    assert error(edit(('[lanes]\nsensor = "camera"\n', "[lanes]\n"))) == (
        "car.toml: lanes: missing required key 'sensor'")


# --- random edits ---------------------------------------------------------------------------------


LINES = ECOCAR.splitlines()
_KEY = re.compile(r"(?:^|(?<=[{,]))\s*[A-Za-z0-9_]+\s*=\s*")
_VALUE = re.compile(r'"[^"]*"|\[[^\]]*\]|\{[^}]*\}|[^\s,}\]#]+')


def _value_sites() -> list[tuple[int, int, int]]:
    """(line, start, end) of every value in ecocar.toml, also the values inside inline tables."""
    sites = []
    for n, line in enumerate(LINES):
        if line.lstrip().startswith(("#", "[")):
            continue
        for key in _KEY.finditer(line):
            value = _VALUE.match(line, key.end())
            if value:
                sites.append((n, value.start(), value.end()))
    return sites


SITES = _value_sites()

#: Strings that mean something in a profile, besides random text.
WORDS = ["LongDist", "RadarObj{i}_A", "RadarObj{i}_B.Class", "FusionTrack{i}", "LeadVehicle",
         "EgoMotion.VehicleSpeed", "CamLaneLeft", "car", "radar", "camera", "fusion", "polar",
         "rad", "right", "tracks", "ecocar.dbc", "{i}", "{i:02d}", ".", "", "Valid == 1",
         "Valid ==", "1 +"]
TABLE_KEYS = ["signal", "scale", "offset", "x", "y", "z", "yaw", "range", "azimuth", "left",
              "right", "0", "1", "-1", "car", "radar", "sensor"]


def toml_float(x: float) -> str:
    if math.isnan(x):
        return "nan"
    return repr(x) if math.isfinite(x) else ("inf" if x > 0 else "-inf")


scalars = st.one_of(
    st.integers(-(2**63), 2**63 - 1).map(str),  # TOML's integers are 64-bit
    st.floats().map(toml_float),
    st.booleans().map(lambda b: "true" if b else "false"),
    st.sampled_from(WORDS).map(json.dumps),
    st.text(max_size=8).map(json.dumps),  # lone surrogates make invalid TOML: fine too
)
toml_values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=3).map(lambda items: "[" + ", ".join(items) + "]"),
    st.dictionaries(st.sampled_from(TABLE_KEYS), inner, max_size=3).map(
        lambda table: "{ " + ", ".join(f"{k} = {v}" for k, v in table.items()) + " }"),
), max_leaves=6)


def deleted(n: int) -> str:
    return "\n".join(LINES[:n] + LINES[n + 1:]) + "\n"


def replaced(site: tuple[int, int, int], value: str) -> str:
    n, start, end = site
    line = LINES[n]
    return "\n".join([*LINES[:n], line[:start] + value + line[end:], *LINES[n + 1:]]) + "\n"


random_edits = st.one_of(
    st.integers(0, len(LINES) - 1).map(deleted),
    st.builds(replaced, st.sampled_from(SITES), toml_values),
)

def loads_or_fails_cleanly(text: str, path: Path, databases: list[Database]) -> None:
    path.write_text(text, errors="surrogateescape")
    try:
        load_profile(path, databases)
    except ProfileError as exc:
        assert str(exc).startswith(f"{path}: ")
        assert "\n" not in str(exc)


def test_the_random_edits_reach_every_kind_of_value() -> None:
    assert len(SITES) > 100
    texts = {LINES[n][start:end] for n, start, end in SITES}
    assert {"2.8", '"radar"', "[0, 31]", '"unknown"', '"EgoMotion.VehicleSpeed"',
            "0.2777778", "{ range = 160.0, azimuth = 45.0 }"} <= texts


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=random_edits)
# values that crashed the loader once (TypeError, KeyError, OverflowError, UnicodeDecodeError)
@pytest.mark.slow
@example(text=edit(radar_classes("5")))
@example(text=edit(radar_classes('{ 1 = ["car"] }')))
@example(text=edit(('speed = { signal = "EgoMotion.VehicleSpeed", scale = 0.2777778 }',
                    "speed = {}")))
@example(text=edit(('speed = { signal = "EgoMotion.VehicleSpeed", scale = 0.2777778 }',
                    "speed = 5")))
@example(text=edit(("wheelbase = 2.8", "wheelbase = " + "9" * 400)))
@example(text=edit(("[sensors.radar]", "[[sensors]]")))
@example(text=edit(("# Vehicle profile", "# Vehicle profile \udcb0")))  # the byte 0xb0
@example(text=edit(('messages = ["RadarObj{i}_A", "RadarObj{i}_B"]',
                    'messages = ["RadarObj{i:999999999d}_A", "RadarObj{i}_B"]')))
def test_random_edits_raise_nothing_but_profile_errors(
        text: str, ecocar: Database, tmp_path_factory: pytest.TempPathFactory) -> None:
    loads_or_fails_cleanly(text, tmp_path_factory.getbasetemp() / "random.toml", [ecocar])
