"""``tankviz profile new`` and ``tankviz profile check``: a profile started from the databases of
another car, and checked against them and a log.

The public DBCs of ../shared/data/dbc (conftest's ``shared_dbc``; skipped where absent) are cars
unlike ecocar: a Bosch radar with companion messages, Mazda track slots 361..366, GM object
fusion with numbered signal names, a Ford radar and powertrain bus, and a Delphi ESR. A small
DBC written here gives a family whose lateral position cannot be found.
"""

from __future__ import annotations

import re
import shutil
import sys
from pathlib import Path

import can
import cantools
import pytest
from conftest import T0, WriteLog, message
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.cli import main
from bridge.profile.loader import load_profile
from bridge.profile.model import ProfileError
from bridge.topics import objects_topic

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

PROFILES = Path(__file__).resolve().parent / "profiles"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def draft(capsys: pytest.CaptureFixture[str], tmp_path: Path, *dbcs: Path
          ) -> tuple[Path, dict[str, object], str]:
    """``tankviz profile new`` into tmp_path: the file, its TOML and what the command said."""
    output = tmp_path / "car.toml"
    args = ["profile", "new", "-o", str(output)]
    for dbc in dbcs:
        args += ["--dbc", str(dbc)]
    code, out, err = run(capsys, *args)
    assert code == 0, err
    assert f"wrote {output}" in out
    return output, tomllib.loads(output.read_text()), out


def mapped_lines(text: str) -> list[str]:
    """The key lines of the object groups and [ego] (what the draft guessed)."""
    section, out = "", []
    for line in text.splitlines():
        if line.startswith("["):
            section = line
        elif "=" in line and not line.startswith("#") and (
                section.startswith("[objects.") or section == "[ego]"):
            out.append(line)
    return out


def loads_or_names_todo(path: Path, dbcs: list[Path]) -> str:
    """Loads the draft: "loads", or the error, which must name a '# TODO:' line of it."""
    databases = [cantools.database.load_file(p) for p in dbcs]
    try:
        load_profile(path, databases)
    except ProfileError as exc:
        match = re.search(r": line (\d+): (TODO: .*)", str(exc))
        assert match, f"not a TODO line: {exc}"
        line = path.read_text().splitlines()[int(match.group(1)) - 1]
        assert line.startswith("# TODO:") and match.group(2).startswith(line[2:].strip())
        return str(exc)
    return "loads"


ALL_CARS = [
    ("tesla_radar_bosch.dbc",),
    ("mazda_radar.dbc",),
    ("gm_global_a_object.dbc",),
    ("ford_fusion_2018_adas.dbc", "ford_fusion_2018_pt.dbc"),
    ("ESR.dbc",),
]


@pytest.mark.parametrize("names", ALL_CARS, ids=lambda n: "+".join(n))
def test_every_draft_is_toml_with_each_guess_commented_and_loads_or_names_its_todo(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path,
        names: tuple[str, ...]) -> None:
    dbcs = [shared_dbc / n for n in names]
    path, doc, _ = draft(capsys, tmp_path, *dbcs)
    assert doc["objects"], "every one of these cars has object families"
    for line in mapped_lines(path.read_text()):
        key = line.split("=")[0].strip()
        if key in ("sensor", "messages", "index", "lifetime"):
            continue
        assert "#" in line, f"a guess without its reason: {line}"
    assert loads_or_names_todo(path, dbcs) == "loads"


def test_bosch_draft_finds_radar_points_with_their_companions_and_signals(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    path, doc, out = draft(capsys, tmp_path, shared_dbc / "tesla_radar_bosch.dbc")
    groups = doc["objects"]
    assert isinstance(groups, dict)
    radar = groups["radar_point"]
    assert radar["messages"] == ["RadarPoint{i}_A", "RadarPoint{i}_B"]
    assert radar["index"] == [0, 31]
    assert (radar["x"], radar["y"]) == ("LongDist", "LatDist")
    assert (radar["vx"], radar["vy"]) == ("LongSpeed", "LatSpeed")
    assert radar["probability"] == "ProbExist" and radar["class"] == "Class"
    assert radar["classes"]["2"] == "two_wheeler" and radar["classes"]["4"] == "stationary"
    assert radar["valid"] == "Valid == 1"
    assert doc["sensors"]["radar_point"]["kind"] == "radar"  # type: ignore[index]
    assert 'y = "LatDist"  # guessed from the name LatDist and unit meters' in path.read_text()
    assert "it loads as written" in out
    # km/h of the wheel speeds -> m/s
    assert doc["ego"]["speed"]["scale"] == pytest.approx(1 / 3.6)  # type: ignore[index]


def test_mazda_draft_finds_the_track_slots_361_to_366_and_says_what_is_unclear(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    path, doc, _ = draft(capsys, tmp_path, shared_dbc / "mazda_radar.dbc")
    tracks = doc["objects"]["radar_track"]  # type: ignore[index]
    assert tracks["messages"] == ["RADAR_TRACK_{i}"] and tracks["index"] == [361, 366]
    assert (tracks["range"], tracks["azimuth"]) == ("DIST_OBJ", "ANG_OBJ")
    text = path.read_text()
    assert "# TODO (optional): the DBC gives no unit for DIST_OBJ" in text
    assert "no unit for ANG_OBJ: deg or rad?" in text
    assert "# TODO (optional): no vehicle speed found" in text


def test_ford_draft_finds_64_objects_and_the_ego_on_the_powertrain_bus(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    path, doc, _ = draft(capsys, tmp_path, shared_dbc / "ford_fusion_2018_adas.dbc",
                         shared_dbc / "ford_fusion_2018_pt.dbc")
    objects = doc["objects"]["object"]  # type: ignore[index]
    assert objects["messages"] == ["Object_{i:02d}"] and objects["index"] == [0, 63]
    assert (objects["range"], objects["azimuth"]) == ("X_Rel", "Angle")  # no lateral: polar
    ego = doc["ego"]
    assert isinstance(ego, dict)
    assert ego["speed"]["signal"].startswith("WheelSpeed_CG1.")  # rad/s times a radius
    assert ego["yaw_rate"] == "Yaw_Data.VehYaw_W_Actl"  # already rad/s
    assert ego["steering_wheel_angle"] == {
        "signal": "Steering_Wheel_Data_CG1.SteWhlRelInit_An_Sns", "scale": pytest.approx(
            0.01745329)}  # deg -> rad
    assert doc["lanes"] == {"length": 100.0}  # steering-only: no camera lines
    assert "rolling radius" in path.read_text()


def test_gm_draft_finds_zero_padded_slots_and_signals_numbered_like_their_message(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    path, doc, _ = draft(capsys, tmp_path, shared_dbc / "gm_global_a_object.dbc")
    groups = doc["objects"]
    assert isinstance(groups, dict)
    lrr = groups["lrr_object"]
    assert lrr["messages"] == ["LRRObject{i:02d}"] and lrr["index"] == [1, 20]
    assert (lrr["range"], lrr["azimuth"], lrr["id"]) == ("TrkRange", "TrkAzimuth", "TrkObjectID")
    assert lrr["role"] == "tracks"
    vision = groups["f_vision_obj_track"]
    assert vision["messages"] == ["F_Vision_Obj_Track_{i}", "F_Vision_Obj_Track_{i}_B"]
    assert vision["range"] == "FwdVsnRngTrk{i}Rev"
    assert doc["sensors"]["f_vision_obj_track"]["kind"] == "camera"  # type: ignore[index]
    assert "# TODO (optional): lane signals found in F_Vision_Environment" in path.read_text()


def test_esr_draft_finds_64_targets_in_range_and_angle(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    path, doc, _ = draft(capsys, tmp_path, shared_dbc / "ESR.dbc")
    target = doc["objects"]["target"]  # type: ignore[index]
    assert target["messages"] == ["Target{i}"] and target["index"] == [1, 64]
    assert (target["range"], target["azimuth"]) == ("CAN_TX_TRACK_RANGE", "CAN_TX_TRACK_ANGLE")
    text = path.read_text()
    assert "CAN_TX_TRACK_STATUS may say which slots hold an object" in text
    assert "CAN_RX_STEERING_ANGLE cannot be negative in the DBC: its sign may be in " \
           "CAN_RX_STEERING_ANGLE_SIGN" in text


SMALL_DBC = """VERSION ""
BU_: R
{messages}
"""


def test_a_family_without_lateral_position_fails_naming_its_todo_line(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    messages = "\n".join(
        f'BO_ {0x200 + i} Obj{i}_A: 8 R\n'
        f' SG_ ObjDistLong : 0|12@1+ (0.1,0) [0|409.5] "m" R\n'
        f' SG_ ObjWidth : 16|8@1+ (0.1,0) [0|25.5] "m" R\n'
        for i in range(1, 5))
    dbc = tmp_path / "car_radar.dbc"
    dbc.write_text(SMALL_DBC.format(messages=messages))
    path, doc, out = draft(capsys, tmp_path, dbc)
    assert doc["objects"]["obj"]["x"] == "ObjDistLong"  # type: ignore[index]
    assert doc["objects"]["obj"]["index"] == [1, 4]  # type: ignore[index]
    lines = path.read_text().splitlines()
    todo = next(n for n, line in enumerate(lines, 1) if line.startswith("# TODO:"))
    expected = (f"{path}: line {todo}: TODO: no lateral position found for objects.obj "
                "(signals: ObjDistLong, ObjWidth)")
    assert f"it does not load yet: {expected}" in out
    assert loads_or_names_todo(path, [dbc]) == expected
    code, _, err = run(capsys, "profile", "check", str(path))
    assert (code, err) == (1, f"error: {expected}\n")


def bosch_frames(db: cantools.database.can.Database) -> list[object]:
    """One second of two radar points at 10 Hz: point 3 from x 20 to 29 m at y -2.5 m (right),
    point 7 at x 40 m, y 4 m (left); point 5 flagged invalid (also at 1 s: the scene ticks
    after the last observation); nothing else valid."""
    frames = []
    for k in range(10):
        t = T0 + k * 0.1
        frames.append(message(db, "RadarPoint3_A", t, LongDist=20 + k, LatDist=-2.5, Valid=1,
                              ProbExist=90))
        frames.append(message(db, "RadarPoint7_A", t + 0.001, LongDist=40, LatDist=4, Valid=1,
                              ProbExist=90))
        frames.append(message(db, "RadarPoint5_A", t + 0.002, LongDist=60, LatDist=1, Valid=0,
                              ProbExist=90))
    frames.append(message(db, "RadarPoint5_A", T0 + 1.0, LongDist=60, Valid=0))
    return frames


def test_the_bosch_draft_converts_a_log_with_objects_where_they_are(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path,
        write_log: WriteLog) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    path, _, _ = draft(capsys, tmp_path, dbc)
    log = write_log("drive.blf", bosch_frames(cantools.database.load_file(dbc)))
    output = tmp_path / "drive.mcap"
    # without --dbc: the draft names its database, relative to itself
    code, _, err = run(capsys, "convert", str(log), "-o", str(output), "--profile", str(path))
    assert code == 0, err
    seen: dict[int, set[tuple[float, float]]] = {}
    with output.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, decoded in reader.iter_decoded_messages(
                topics=[objects_topic("radar_point")]):
            for o in decoded.objects:
                seen.setdefault(o.id, set()).add((round(o.x, 3), round(o.y, 3)))
    assert set(seen) == {3, 7}
    # the draft mounts a forward radar at the front of a typical car: x 3.5 m
    assert {(23.5 + k, -2.5) for k in range(10)} == seen[3]
    assert seen[7] == {(43.5, 4.0)}


def test_check_prints_what_a_profile_maps(capsys: pytest.CaptureFixture[str],
                                          shared_dbc: Path) -> None:
    profile = PROFILES / "bosch_radar.toml"
    code, out, err = run(capsys, "profile", "check", str(profile), "--dbc",
                         str(shared_dbc / "tesla_radar_bosch.dbc"))
    assert code == 0, err
    assert f"profile {profile} (name 'bosch_radar'): loads against" in out
    assert "  radar: radar, cartesian, lateral left, mount x 3.6 y 0 z 0.5 yaw 0 deg" in out
    assert ("  radar: sensor radar (radar), role detections, RadarPoint{i}_A + RadarPoint{i}_B "
            "[0..31] (32 objects)") in out
    assert "x LongDist, y LatDist, vx LongSpeed, vy LatSpeed, probability ProbExist" in out
    assert "valid: Valid == 1 and ProbExist > 70; lifetime 0.1 s" in out
    assert "ego: speed Msg169_ESP_wheelSpeeds.ESP_wheelSpeedReL_HS (*0.277778); yaw rate -" in out
    assert "lanes: none" in out and "lead: none" in out


def test_check_of_a_profile_with_a_bad_signal_is_one_line_with_closest_names(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text((PROFILES / "bosch_radar.toml").read_text().replace(
        'y = "LatDist"', 'y = "LatDst"'))
    code, out, err = run(capsys, "profile", "check", str(bad), "--dbc",
                         str(shared_dbc / "tesla_radar_bosch.dbc"))
    assert (code, out) == (1, "")
    assert err == (f"error: {bad}: objects.radar.y: no signal 'LatDst' in RadarPoint0_A, "
                   "RadarPoint0_B; closest: LatDist\n")


def test_check_with_a_log_counts_valid_objects_and_their_ranges(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, shared_dbc: Path,
        write_log: WriteLog) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    log = write_log("drive.blf", bosch_frames(cantools.database.load_file(dbc)))
    profile = tmp_path / "bosch_radar.toml"
    shutil.copy(PROFILES / "bosch_radar.toml", profile)
    code, out, err = run(capsys, "profile", "check", str(profile), str(log), "--dbc", str(dbc))
    assert code == 0, err
    assert "log: 31 frames; valid objects per group (vehicle frame, m):" in out
    # mounted at x 3.6: point 3 from 23.6 to 32.6 m, point 7 at 43.6 m; 10 observations each
    assert "  radar: 2 objects (ids/slots), 20 observations; x 23.6..43.6, y -2.5..4.0" in out
    assert "lateral sign:\n  radar: lateral sign not judged: 0 samples" in out


def test_check_says_a_group_that_saw_nothing(capsys: pytest.CaptureFixture[str],
                                             tmp_path: Path, shared_dbc: Path,
                                             write_log: WriteLog) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    db = cantools.database.load_file(dbc)
    log = write_log("drive.blf", [message(db, "RadarPoint1_A", T0 + k * 0.1, LongDist=10,
                                          Valid=0) for k in range(5)])
    code, out, err = run(capsys, "profile", "check", str(PROFILES / "bosch_radar.toml"),
                         str(log), "--dbc", str(dbc))
    assert code == 0, err
    # which rule never held, and with what values (#33 item 3)
    assert ("  radar: no valid object: rule 'Valid == 1 and ProbExist > 70' held in 0 of 1 "
            "judgements; ProbExist was 0..0; Valid was 0..0") in out.splitlines()


def test_check_says_when_no_frame_of_the_log_decoded(
        capsys: pytest.CaptureFixture[str], shared_dbc: Path, write_log: WriteLog) -> None:
    # #33 item 12: a log none of whose ids the databases know said only "no valid object"
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    log = write_log("drive.blf", [can.Message(timestamp=T0 + k * 0.1, arbitration_id=0x7F0,
                                              data=bytes(8), is_extended_id=False)
                                  for k in range(5)])
    code, out, err = run(capsys, "profile", "check", str(PROFILES / "bosch_radar.toml"),
                         str(log), "--dbc", str(dbc))
    assert code == 0, err
    assert ("log: 5 frames, 0 decoded: none of their ids is in the databases (the wrong log, "
            "or the wrong bus?); valid objects per group (vehicle frame, m):") in out
    assert ("  radar: no valid object: none of its messages (RadarPoint{i}_A + RadarPoint{i}_B) "
            "decoded") in out.splitlines()


@pytest.mark.parametrize("dbc,written", [
    ("ecocar", 'databases = ["ecocar.dbc"]'),
    ("ecocar.dbc", 'databases = ["ecocar.dbc"]'),
    ("radar=highway_radar", 'databases = { radar = ["highway_radar.dbc"] }'),
])
def test_new_names_a_bundled_database_by_its_bundled_name(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        dbc: str, written: str) -> None:
    # #33 item 12: a bundled name was written as a path into the venv's site-packages, which
    # breaks when the venv moves or tankviz is upgraded
    monkeypatch.chdir(tmp_path)
    output = tmp_path / "profiles" / "car.toml"
    output.parent.mkdir()
    code, _, err = run(capsys, "profile", "new", "--dbc", dbc, "-o", str(output))
    assert code == 0, err
    lines = output.read_text().splitlines()
    assert any(line.startswith(f"{written}  # ") for line in lines), lines
    assert "site-packages" not in output.read_text() and "bridge/data" not in output.read_text()
    # the profile finds it from anywhere (or stops at a TODO line of the draft, not before)
    code, _, err = run(capsys, "profile", "check", str(output))
    assert code == 0 or ": TODO: " in err, err
