"""The layout that ``tankviz live``, ``demo`` and ``replay`` tell the user to import, and the
line that says how to stop them.

With the bundled ecocar profile (and its bundled database) the bundled ``layouts/tank-viz.json``
is the one. With another profile, ``live`` recording into a drives folder writes the layouts made
for that profile and its buses into ``DRIVES/layouts/<profile>/`` (never overwriting a file,
never failing the drive) and points at them; otherwise the exact ``tankviz layouts`` command
that writes them is printed. ``replay`` of a recorded drive points at the layouts beside the
drive when they are the ones made for its profile, else prints the command with what the drive
was recorded with. ``--no-record`` does not speak of a recording.

The commands run in this process, as a user runs them (``bridge.cli.main``); live reads a
virtual bus and stops by itself (``--for``).
"""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import cantools
import pytest
from conftest import T0, WriteLog, message

from bridge.cli import main
from bridge.pipeline.convert import convert
from bridge.resources import layouts_dir

PROFILE = Path(__file__).resolve().parent / "profiles" / "mazda_radar.toml"
BUNDLED = layouts_dir() / "tank-viz.json"
BUNDLED_LINE = f"layout:   import {BUNDLED} (Layouts menu)"
LAYOUT_FILES = ("bring-up.json", "can-debug.json", "engineer.json", "tank-viz.json")


pytestmark = pytest.mark.usefixtures("restore_stop_signals")


@pytest.fixture
def mazda_dbc(shared_dbc: Path) -> Path:
    return shared_dbc / "mazda_radar.dbc"


_runs = iter(range(1_000_000))


def live(*argv: str, seconds: float = 0.3) -> None:
    """``tankviz live`` on a fresh virtual bus (unless one is given) for ``seconds``."""
    bus = [] if "--bus" in argv else ["--bus", f"can0=virtual:hint-{os.getpid()}-{next(_runs)}"]
    assert main(["live", *bus, "--port", "0", "--for", str(seconds), *argv]) == 0


def command_line(*argv: str | Path) -> str:
    return shlex.join(["tankviz", "layouts", *map(str, argv)])


def run_printed(command: str) -> None:
    """Run a printed ``tankviz ...`` command as the user would paste it."""
    words = shlex.split(command)
    assert words[0] == "tankviz"
    assert main(words[1:]) == 0


# --- live and demo -------------------------------------------------------------------------------


def test_live_with_ecocar_points_at_the_bundled_layout(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    drives = tmp_path / "drives"
    live("--profile", "ecocar", "--drives", str(drives))
    lines = capsys.readouterr().out.splitlines()
    assert BUNDLED_LINE in lines
    assert f"recording into {drives}/" in lines
    assert "Ctrl+C stops and finishes the recording." in lines
    assert not (drives / "layouts").exists()  # nothing written: the bundled ones are right


def test_live_with_another_profile_writes_its_layouts_into_the_drives_folder(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    drives = tmp_path / "drives"
    live("--profile", str(PROFILE), "--dbc", str(mazda_dbc), "--drives", str(drives))
    out = capsys.readouterr().out
    folder = drives / "layouts" / "mazda_radar"
    assert (f"layout:   import {folder / 'tank-viz.json'} (Layouts menu), made for profile "
            f"mazda_radar") in out.splitlines()
    assert str(BUNDLED) not in out and "ecocar" not in out
    assert "Ctrl+C stops and finishes the recording." in out.splitlines()
    assert sorted(p.name for p in folder.iterdir()) == list(LAYOUT_FILES)
    # exactly what `tankviz layouts` writes for this profile and database
    run_printed(command_line("--profile", PROFILE, "--dbc", mazda_dbc, "--export", "made"))
    for name in LAYOUT_FILES:
        assert (folder / name).read_text() == (tmp_path / "made" / name).read_text(), name


def test_live_keeps_a_layout_file_it_did_not_make_and_says_so(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drives = tmp_path / "drives"
    folder = drives / "layouts" / "mazda_radar"
    folder.mkdir(parents=True)
    (folder / "tank-viz.json").write_text("{}\n")  # the user's own
    live("--profile", str(PROFILE), "--dbc", str(mazda_dbc), "--drives", str(drives))
    captured = capsys.readouterr()
    assert (folder / "tank-viz.json").read_text() == "{}\n"
    assert (folder / "engineer.json").is_file() and (folder / "can-debug.json").is_file()
    (warning,) = [line for line in captured.err.splitlines() if "tank-viz.json" in line]
    force = command_line("--profile", PROFILE, "--dbc", mazda_dbc, "--export", folder, "--force")
    assert warning == (f"warning: kept {folder / 'tank-viz.json'}: it differs from the layout "
                       f"made for profile mazda_radar now; {force} replaces it")
    kept_line = f"layout:   import {folder / 'tank-viz.json'} (Layouts menu)"
    assert kept_line in captured.out.splitlines()  # the user's, not claimed to be made for it


@pytest.mark.slow
def test_live_that_cannot_write_the_layouts_warns_once_and_records_anyway(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drives = tmp_path / "drives"
    drives.mkdir()
    (drives / "layouts").write_text("not a folder")
    # the demo's car sends frames (ecocar's: recorded raw) while live runs with this profile
    assert main(["demo", "--port", "0", "--for", "3", "--profile", str(PROFILE),
                 "--dbc", str(mazda_dbc), "--drives", str(drives)]) == 0
    captured = capsys.readouterr()
    warnings = [line for line in captured.err.splitlines() if "layouts" in line]
    assert len(warnings) == 1 and warnings[0].startswith(
        f"warning: cannot write the layouts into {drives / 'layouts' / 'mazda_radar'}: "), warnings
    folder = drives / "layouts" / "mazda_radar"
    command = command_line("--profile", PROFILE, "--dbc", mazda_dbc, "--export", folder)
    assert f"layout:   made for profile mazda_radar by: {command}" in captured.out.splitlines()
    (recorded,) = drives.glob("*.mcap")  # the drive went on
    assert f"recorded {recorded}" in captured.out.splitlines()


def test_live_without_recording_prints_the_command_and_no_recording(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    live("--profile", str(PROFILE), "--dbc", str(mazda_dbc), "--no-record")
    out = capsys.readouterr().out
    lines = out.splitlines()
    command = command_line("--profile", PROFILE, "--dbc", mazda_dbc,
                           "--export", "mazda_radar-layouts")
    assert f"layout:   made for profile mazda_radar by: {command}" in lines
    assert "          then import mazda_radar-layouts/tank-viz.json (Layouts menu)" in lines
    assert str(BUNDLED) not in out and "ecocar" not in out
    assert "Ctrl+C stops." in lines
    assert "recording" not in out
    assert not (tmp_path / "drives").exists()
    run_printed(command)  # it works as printed
    assert sorted(p.name for p in (tmp_path / "mazda_radar-layouts").iterdir()) == list(
        LAYOUT_FILES)


@pytest.mark.slow
def test_live_command_names_the_buses_live_reads(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A database for every bus on a bus that is not can0: the command says which bus, and the
    layouts written for the recording are the ones it makes."""
    monkeypatch.chdir(tmp_path)
    bus = f"radar=virtual:hint-radar-{os.getpid()}"
    live("--bus", bus, "--profile", str(PROFILE), "--dbc", str(mazda_dbc), "--no-record")
    command = command_line("--profile", PROFILE, "--dbc", f"radar={mazda_dbc}",
                           "--export", "mazda_radar-layouts")
    assert f"layout:   made for profile mazda_radar by: {command}" in capsys.readouterr().out
    run_printed(command)
    live("--bus", bus, "--profile", str(PROFILE), "--dbc", str(mazda_dbc),
         "--drives", str(tmp_path / "drives"))
    written = tmp_path / "drives" / "layouts" / "mazda_radar"
    for name in LAYOUT_FILES:
        assert (written / name).read_text() == (
            tmp_path / "mazda_radar-layouts" / name).read_text(), name
    assert "/can/radar/frames" in (written / "can-debug.json").read_text()


def test_live_with_databases_and_no_profile_says_how_to_make_one(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str]) -> None:
    live("--dbc", str(mazda_dbc), "--no-record")
    lines = capsys.readouterr().out.splitlines()
    draft = shlex.join(["tankviz", "profile", "new", "--dbc", str(mazda_dbc), "-o", "car.toml"])
    assert f"layout:   none without a profile: draft one with: {draft}" in lines
    command = command_line("--profile", "car.toml", "--dbc", mazda_dbc, "--export", "car-layouts")
    assert f"          then: {command}" in lines
    assert BUNDLED_LINE not in lines


@pytest.mark.slow
def test_the_draft_command_keeps_the_bus_of_each_database(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``--dbc BUS=PATH``: ``profile new`` takes it as given and drafts the databases per bus."""
    monkeypatch.chdir(tmp_path)
    live("--bus", f"can1=virtual:hint-can1-{os.getpid()}", "--dbc", f"can1={mazda_dbc}",
         "--no-record")
    lines = capsys.readouterr().out.splitlines()
    draft = shlex.join(["tankviz", "profile", "new", "--dbc", f"can1={mazda_dbc}",
                        "-o", "car.toml"])
    assert f"layout:   none without a profile: draft one with: {draft}" in lines
    run_printed(draft)
    text = (tmp_path / "car.toml").read_text()
    written = re.search(r'^databases = \{ can1 = \["([^"]+)"\] \}', text, re.MULTILINE)
    assert written and (tmp_path / written[1]).resolve() == mazda_dbc.resolve()


@pytest.mark.slow
def test_demo_without_recording_points_at_the_bundled_layout(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--port", "0", "--for", "0.5", "--no-record",
                 "--drives", str(tmp_path / "drives")]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert BUNDLED_LINE in lines
    assert "Ctrl+C stops." in lines
    assert "recording" not in out and not (tmp_path / "drives").exists()


# --- replay --------------------------------------------------------------------------------------


def replay(*argv: str) -> None:
    assert main(["replay", *argv, "--port", "0", "--for", "0.3"]) == 0


@pytest.fixture
def mazda_drive(mazda_dbc: Path, write_log: WriteLog, tmp_path: Path) -> Path:
    """A Mazda drive (converted with the profile) in a drives folder."""
    db = cantools.database.load_file(mazda_dbc)
    log = write_log("mazda.blf", [message(db, f"RADAR_TRACK_{slot}", T0 + i * 0.1,
                                          DIST_OBJ=640, ANG_OBJ=0)
                                  for i in range(30) for slot in range(361, 367)])
    out = tmp_path / "drives" / "mazda.mcap"
    out.parent.mkdir()
    convert([log], out, [str(mazda_dbc)], profile=PROFILE)
    return out


@pytest.mark.slow
def test_replay_of_an_ecocar_drive_points_at_the_bundled_layout(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drive = tmp_path / "eco.mcap"
    assert main(["simulate", "-o", str(drive), "--duration", "1"]) == 0
    capsys.readouterr()
    replay(str(drive))
    assert BUNDLED_LINE in capsys.readouterr().out.splitlines()


def test_replay_of_another_drive_prints_the_command_for_it(
        mazda_drive: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str]) -> None:
    replay(str(mazda_drive))
    out = capsys.readouterr().out
    lines = out.splitlines()
    folder = mazda_drive.parent / "layouts" / "mazda_radar"
    command = command_line("--profile", "mazda_radar.toml", "--dbc", mazda_dbc,
                           "--export", folder)
    assert f"layout:   made for profile mazda_radar by: {command}" in lines
    assert (f"          (mazda_radar.toml: the profile {mazda_drive} was recorded with, "
            "attached to it)") in lines
    assert f"          then import {folder / 'tank-viz.json'} (Layouts menu)" in lines
    assert str(BUNDLED) not in out and "ecocar" not in out


@pytest.mark.slow
def test_replay_of_a_drive_points_at_the_layouts_made_for_it_beside_it(
        mazda_drive: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = mazda_drive.parent / "layouts" / "mazda_radar"
    run_printed(command_line("--profile", PROFILE, "--dbc", mazda_dbc, "--export", folder))
    capsys.readouterr()
    replay(str(mazda_drive))
    assert (f"layout:   import {folder / 'tank-viz.json'} (Layouts menu), made for profile "
            "mazda_radar") in capsys.readouterr().out.splitlines()
    replay(str(mazda_drive), "--rederive")  # re-derived with what it holds: the same
    assert (f"layout:   import {folder / 'tank-viz.json'} (Layouts menu), made for profile "
            "mazda_radar") in capsys.readouterr().out.splitlines()


def test_replay_of_a_drive_with_a_profile_given_names_that_profile(
        mazda_drive: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str]) -> None:
    replay(str(mazda_drive), "--profile", str(PROFILE))
    folder = mazda_drive.parent / "layouts" / "mazda_radar"
    command = command_line("--profile", PROFILE, "--dbc", mazda_dbc, "--export", folder)
    lines = capsys.readouterr().out.splitlines()
    assert f"layout:   made for profile mazda_radar by: {command}" in lines
    assert not any("attached to it" in line for line in lines)


def test_replay_of_a_log_with_another_profile_prints_the_command(
        mazda_drive: Path, mazda_dbc: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    replay(str(tmp_path / "mazda.blf"), "--profile", str(PROFILE), "--dbc", str(mazda_dbc))
    out = capsys.readouterr().out
    command = command_line("--profile", PROFILE, "--dbc", mazda_dbc,
                           "--export", "mazda_radar-layouts")
    assert f"layout:   made for profile mazda_radar by: {command}" in out.splitlines()
    assert str(BUNDLED) not in out


@pytest.mark.slow
def test_replay_of_a_drive_live_recorded_points_at_the_layouts_live_wrote(
        tmp_path: Path, mazda_dbc: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drives = tmp_path / "drives"
    assert main(["demo", "--port", "0", "--for", "3", "--profile", str(PROFILE),
                 "--dbc", str(mazda_dbc), "--drives", str(drives)]) == 0
    (recorded,) = drives.glob("*.mcap")
    capsys.readouterr()
    replay(str(recorded))
    folder = drives / "layouts" / "mazda_radar"
    assert (f"layout:   import {folder / 'tank-viz.json'} (Layouts menu), made for profile "
            "mazda_radar") in capsys.readouterr().out.splitlines()


def test_the_connection_line_says_who_can_open_it() -> None:
    """The default server is this machine's only; a newcomer learns what serves a laptop."""
    from bridge.apps.hints import connection_lines

    assert connection_lines("127.0.0.1", ["ws://localhost:8765"]) == [
        "Foxglove: open connection ws://localhost:8765 (Foxglove WebSocket)",
        "          this machine only: --host 0.0.0.0 serves other laptops too"]
    assert connection_lines("0.0.0.0", ["ws://10.0.0.2:8765", "ws://192.168.1.4:8765"]) == [
        "Foxglove: open connection ws://10.0.0.2:8765 or ws://192.168.1.4:8765 "
        "(Foxglove WebSocket)"]
