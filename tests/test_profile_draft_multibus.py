"""``tankviz profile new`` for a production car with a database per bus (issue #24): a 2017 RAV4,
its radar on one bus (opendbc's toyota_adas.dbc: 16 slots, each ``TRACK_A_{i}`` with the position
and ``TRACK_B_{i}`` with the score) and the car's own on another (toyota_2017_pt.dbc: four wheel
speeds, the speedometer, yaw rate, a steering angle in two parts). Id 0x228 is a different message
in each file, so they must be on separate buses.

The drafts are compared with goldens (tests/golden/drafts/*.toml). After a deliberate change of the
draft, regenerate them with
    TANKVIZ_REGENERATE_GOLDENS=1 python -m pytest tests/test_profile_draft_multibus.py
and review the diff before committing it. The finished RAV4 profile, tests/profiles/rav4.toml, is
the draft with its edits, counted here on the loaded profiles.

The DBCs are read where they are, in ../shared/data/dbc (conftest's ``shared_dbc``: the tests are
skipped where that folder is absent).
"""

from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Mapping
from enum import Enum
from pathlib import Path
from typing import Any

import pytest
from cantools.database.can.database import Database
from conftest import GOLDEN, T0, WriteLog, check_golden, message

from bridge.cli import main
from bridge.decode.database import load_database
from bridge.errors import DatabaseError
from bridge.pipeline.drive import load_stages
from bridge.profile.draft import draft_profile, find_families, group_families
from bridge.profile.model import Computed, Profile, Rule, Sensor

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

TESTS = Path(__file__).resolve().parent
FINISHED = TESTS / "profiles" / "rav4.toml"
RADAR, CAR = "toyota_adas.dbc", "toyota_2017_pt.dbc"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def new(capsys: pytest.CaptureFixture[str], output: Path, *dbcs: str) -> str:
    """``tankviz profile new --dbc …`` into ``output``; what it said."""
    code, out, err = run(capsys, "profile", "new", "-o", str(output),
                         *(word for dbc in dbcs for word in ("--dbc", dbc)))
    assert code == 0, err
    return out


def check_draft(name: str, text: str) -> None:
    check_golden(GOLDEN / "drafts" / name, text, "the draft")


def database(shared_dbc: Path, name: str) -> Database:
    return load_database(shared_dbc / name).db


# --- a database per bus -------------------------------------------------------------------------


def test_profile_new_takes_a_database_per_bus_and_names_them_per_bus(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    output = tmp_path / "rav4.toml"
    out = new(capsys, output, f"can1={shared_dbc / RADAR}", f"can0={shared_dbc / CAR}")
    assert out.splitlines()[1].startswith("it loads as written: object groups radar, track;")
    doc = tomllib.loads(output.read_text())
    relative = os.path.relpath(shared_dbc, tmp_path)
    assert doc["profile"]["databases"] == {"can0": [f"{relative}/{CAR}"],
                                           "can1": [f"{relative}/{RADAR}"]}
    assert doc["buses"] == {"can0": {"bitrate": 500000}, "can1": {"bitrate": 500000}}
    # the profile's own databases, each on its bus: 0x228 is TRACK_B_8 on can1 only
    stages = load_stages([], output)
    assert stages.profile is not None and set(stages.profile.groups) == {"radar", "track"}


def test_files_that_conflict_without_buses_are_told_both_ways_to_give_buses(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    code, out, err = run(capsys, "profile", "new", "-o", str(tmp_path / "car.toml"),
                         "--dbc", str(shared_dbc / RADAR), "--dbc", str(shared_dbc / CAR))
    assert (code, out) == (1, "")
    assert err == (f"error: {shared_dbc / CAR}: id 0x228 is VSC1S29 here but TRACK_B_8 (defined "
                   f"differently) in {shared_dbc / RADAR}; give each file its own bus: --dbc "
                   f"BUS=PATH, or in a profile [profile] databases = {{ BUS = [\"{RADAR}\"], "
                   f"OTHER_BUS = [\"{CAR}\"] }}\n")
    # a profile's flat list of both: the same advice
    flat = tmp_path / "flat.toml"
    flat.write_text(f'[profile]\ndatabases = ["{shared_dbc / RADAR}", "{shared_dbc / CAR}"]\n')
    with pytest.raises(DatabaseError, match=r"or in a profile \[profile\] databases = \{ BUS = "):
        load_stages([], flat)


# --- the drafts ---------------------------------------------------------------------------------


def test_the_rav4_draft_matches_its_golden(shared_dbc: Path) -> None:
    text = draft_profile([(RADAR, database(shared_dbc, RADAR)), (CAR, database(shared_dbc, CAR))],
                         name="rav4", buses={"can1": [RADAR], "can0": [CAR]})
    check_draft("rav4.toml", text)


def test_the_radar_alone_draft_matches_its_golden(shared_dbc: Path) -> None:
    text = draft_profile([(RADAR, database(shared_dbc, RADAR))], name="toyota_adas")
    check_draft("toyota_adas.toml", text)


def test_the_radar_alone_draft_loads_as_written_with_one_radar_and_its_slots_twice(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    output = tmp_path / "radar.toml"
    out = new(capsys, output, str(shared_dbc / RADAR))
    assert "it loads as written" in out
    text = output.read_text()
    assert not [line for line in text.splitlines() if line.startswith("# TODO:")]
    doc = tomllib.loads(text)
    assert list(doc["sensors"]) == ["radar"]
    assert doc["sensors"]["radar"]["mount"]["x"] == 3.5  # the typical car's front: 4.5 - 1.0 m
    detections, tracks = doc["objects"]["radar"], doc["objects"]["track"]
    for group in (detections, tracks):
        assert group["messages"] == ["TRACK_A_{i}", "TRACK_B_{i}"] and group["index"] == [0, 15]
        assert (group["x"], group["y"], group["vx"]) == ("LONG_DIST", "LAT_DIST", "REL_SPEED")
        assert (group["probability"], group["valid"]) == ("SCORE", "VALID == 1")
    assert (detections["role"], tracks["role"]) == ("detections", "tracks")
    assert doc["lead"] == {"source": "tracks"}
    # the lateral sign is not guessed: the draft says it is unknown and how to find out
    assert ("# TODO (optional): lateral is UNKNOWN: the DBC does not say which way positive "
            "LAT_DIST\n") in text
    assert f"`tankviz profile check {output.stem}.toml DRIVE`" in text


def test_the_car_bus_gives_the_mean_wheel_speed_and_the_whole_steering_angle(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    output = tmp_path / "rav4.toml"
    new(capsys, output, f"can1={shared_dbc / RADAR}", f"can0={shared_dbc / CAR}")
    text = output.read_text()
    ego = tomllib.loads(text)["ego"]
    assert ego["speed"] == {
        "value": "(WHEEL_SPEEDS.WHEEL_SPEED_FL + WHEEL_SPEEDS.WHEEL_SPEED_FR + "
                 "WHEEL_SPEEDS.WHEEL_SPEED_RL + WHEEL_SPEEDS.WHEEL_SPEED_RR) / 4",
        "scale": pytest.approx(1 / 3.6)}
    assert "the alternative is SPEED.SPEED (km/h)" in text  # the speedometer
    assert ego["steering_wheel_angle"] == {
        "value": "STEER_ANGLE_SENSOR.STEER_ANGLE + STEER_ANGLE_SENSOR.STEER_FRACTION",
        "scale": pytest.approx(0.01745329)}
    vehicle = tomllib.loads(text)["vehicle"]
    assert set(vehicle) == {"length", "width", "height", "origin", "rear_overhang", "wheelbase",
                            "steering_ratio"}
    for key in vehicle:  # each a typical number saying why it matters
        line = next(line for line in text.splitlines() if line.startswith(f"{key} = "))
        assert "# TODO (optional): " in line, line


SMALL_DBC = 'VERSION ""\nBU_: R\n{messages}\n'


def test_companions_that_differ_by_a_letter_before_or_after_the_index_are_one_family_group(
        tmp_path: Path) -> None:
    messages = []
    for i in range(4):
        for n, name in enumerate((f"X_A_{i}", f"X_B_{i}", f"Obj{i}_A", f"Obj{i}_B")):
            messages.append(f"BO_ {0x100 + 16 * n + i} {name}: 8 R\n"
                            f" SG_ Sig{n} : 0|8@1+ (1,0) [0|255] \"\" R\n")
    dbc = tmp_path / "letters.dbc"
    dbc.write_text(SMALL_DBC.format(messages="\n".join(messages)))
    db = load_database(dbc).db
    groups = group_families(find_families((dbc.name, m) for m in db.messages))
    assert sorted(sorted(f.template for f in g) for g in groups) == [
        ["Obj{i}_A", "Obj{i}_B"], ["X_A_{i}", "X_B_{i}"]]


# --- how far the draft is from the finished profile ----------------------------------------------


def flatten(value: Any, key: str = "") -> dict[str, Any]:
    """A loaded profile as (dotted key -> plain value): what two profiles can differ in."""
    if isinstance(value, Sensor) and key.count(".") > 1:  # a group's sensor: by its name
        return {key: value.name}
    if isinstance(value, Computed):
        return {key: (value.text, value.scale, value.offset)}
    if isinstance(value, Rule):
        return {key: value.expression.text}
    if isinstance(value, Path):
        return {key: str(value.resolve())}
    if isinstance(value, Enum):
        return {key: value.value}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(value):
            out.update(flatten(getattr(value, f.name), f"{key}.{f.name}" if key else f.name))
        return out
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            out.update(flatten(v, f"{key}.{k}"))
        return out or {key: {}}
    if isinstance(value, tuple | list):
        return {key: tuple(flatten(v, "").get("", v) for v in value)}
    return {key: value}


#: What the issue allows the RAV4's draft to differ in, as edits: the lateral sign, and the car's
#: dimensions and origin (the radar's place at the car's front moves with them).
EDITS = {
    "lateral": {"sensors.radar.lateral"},
    "dimensions": {"vehicle.length_m", "vehicle.width_m", "vehicle.height_m",
                   "vehicle.wheelbase_m", "vehicle.steering_ratio", "vehicle.rear_overhang_m",
                   "sensors.radar.mount.x"},
    "origin": {"vehicle.origin"},
}


def front_of_the_car(profile: Profile) -> float:
    vehicle = profile.vehicle
    return vehicle.box_centre_x + vehicle.length_m / 2


def test_the_rav4_draft_is_the_finished_profile_but_for_lateral_and_the_cars_dimensions(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    output = tmp_path / "rav4.toml"
    new(capsys, output, f"can1={shared_dbc / RADAR}", f"can0={shared_dbc / CAR}")
    drafted = load_stages([], output).profile
    finished = load_stages([], FINISHED).profile
    assert drafted is not None and finished is not None
    a, b = flatten(drafted), flatten(finished)
    differ = {k for k in a.keys() | b.keys() if a.get(k) != b.get(k)} - {"name", "path"}
    allowed = set().union(*EDITS.values())
    assert differ <= allowed, f"edits beyond lateral and the car: {sorted(differ - allowed)}"
    edits = [name for name, keys in EDITS.items() if keys & differ]
    assert edits == ["lateral", "dimensions"]  # the origin on the rear axle, as drafted
    # the radar's x is not an edit of its own: in both, the front of the car
    for profile in (drafted, finished):
        assert profile.sensors["radar"].mount.x == pytest.approx(front_of_the_car(profile))
    assert (drafted.sensors["radar"].lateral, finished.sensors["radar"].lateral) == (
        "left", "right")


#: Every shared database, alone and in its car's set, with and without buses.
SETS = [
    (f"radar={RADAR}",), (f"can1={RADAR}", f"can0={CAR}"), (CAR,),
    ("radar=ford_fusion_2018_adas.dbc", "car=ford_fusion_2018_pt.dbc"),
    ("ford_fusion_2018_adas.dbc", "ford_fusion_2018_pt.dbc"), ("ford_fusion_2018_adas.dbc",),
    ("ford_fusion_2018_pt.dbc",), ("radar=mazda_radar.dbc",), ("mazda_radar.dbc",),
    ("tesla_radar_bosch.dbc",), ("gm_global_a_object.dbc",), ("ESR.dbc",),
]


@pytest.mark.parametrize("dbcs", SETS, ids=lambda dbcs: "+".join(dbcs))
def test_every_shared_database_set_drafts_a_profile_that_loads_as_written(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path,
        dbcs: tuple[str, ...]) -> None:
    options = [f"{bus}={shared_dbc / path}" if path else str(shared_dbc / bus)
               for bus, _, path in (dbc.partition("=") for dbc in dbcs)]
    output = tmp_path / "car.toml"
    out = new(capsys, output, *options)
    assert "it loads as written" in out, out
    assert load_stages([], output).profile is not None  # with its own databases, on their buses


def test_those_sets_hold_every_shared_database(shared_dbc: Path) -> None:
    named = {dbc.rpartition("=")[2] for dbcs in SETS for dbc in dbcs}
    assert {p.name for p in shared_dbc.glob("*.dbc")} <= named


# --- profile check says everything --------------------------------------------------------------


def test_check_repeats_the_warnings_of_the_databases(
        capsys: pytest.CaptureFixture[str], shared_dbc: Path) -> None:
    code, out, err = run(capsys, "profile", "check", str(FINISHED))  # its own databases
    assert code == 0, err
    car = FINISHED.parent / "../../../shared/data/dbc" / CAR  # as the profile names it
    assert car.resolve() == (shared_dbc / CAR).resolve()
    assert (f"warning: {car}: the signals PCS_TEMP and SET_ME_X10 are "
            "overlapping in message PCS_HUD (0x411); cantools cannot decode any frame of it"
            ) in out.splitlines()


def test_a_lateral_sign_the_dbc_states_is_taken_and_an_unstated_one_is_not_guessed(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    def draft(name: str, comment: str) -> str:
        messages = "\n".join(f'BO_ {0x300 + i} Obj{i}: 8 R\n'
                             f' SG_ LongDist : 0|12@1+ (0.1,0) [0|409.5] "m" R\n'
                             f' SG_ LatDist : 16|12@1- (0.1,0) [-204.8|204.7] "m" R\n'
                             for i in range(3))
        comments = "".join(f'CM_ SG_ {0x300 + i} LatDist "{comment}";\n' for i in range(3))
        dbc = tmp_path / f"{name}.dbc"
        dbc.write_text(SMALL_DBC.format(messages=messages) + comments)
        output = tmp_path / f"{name}.toml"
        assert "it loads as written" in new(capsys, output, str(dbc))
        return output.read_text()

    stated = draft("stated", "Lateral distance, positive to the right.")
    assert ('lateral = "right"  # the DBC\'s comment on LatDist: Lateral distance, positive to the '
            'right.') in stated.splitlines()
    unstated = draft("unstated", "Lateral distance from the boresight.")
    assert "# TODO (optional): lateral is UNKNOWN" in unstated
    assert 'lateral = "left"' in unstated.splitlines()  # the default, below what says so


def test_check_runs_a_drive_of_both_buses_through_the_finished_profile(
        capsys: pytest.CaptureFixture[str], shared_dbc: Path, write_log: WriteLog) -> None:
    """Half a second: slot 3 from 20 to 29 m ahead of the radar and 1 m to its right (LAT_DIST
    positive), its score in TRACK_B_3 (id 0x223 on can1; on can0 0x223 is nothing, and 0x228 is
    VSC1S29, not TRACK_B_8), the car at 72 km/h on can0."""
    radar, car = database(shared_dbc, RADAR), database(shared_dbc, CAR)
    frames = []
    for k in range(10):
        t = T0 + k * 0.05
        frames.append(message(radar, "TRACK_A_3", t, "can1", LONG_DIST=20 + k, LAT_DIST=1.0,
                              REL_SPEED=-2.0, VALID=1))
        frames.append(message(radar, "TRACK_B_3", t + 0.001, "can1", SCORE=90))
        frames.append(message(car, "WHEEL_SPEEDS", t + 0.002, "can0", WHEEL_SPEED_FL=72,
                              WHEEL_SPEED_FR=72, WHEEL_SPEED_RL=72, WHEEL_SPEED_RR=72))
    log = write_log("drive.log", frames)
    code, out, err = run(capsys, "profile", "check", str(FINISHED), str(log))
    assert code == 0, err
    # at the front of the car, 3.6 m ahead of the rear axle; y negative: to the right
    assert "  radar: 1 objects (ids/slots), 10 observations; x 23.6..32.6, y -1.0..-1.0" in out
    assert "  track: 1 objects (ids/slots), 10 observations; x 23.6..32.6, y -1.0..-1.0" in out
