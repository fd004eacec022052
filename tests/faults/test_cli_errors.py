"""Nonsense on the command line or in the environment gets one line, ``error: …``, and exit
status 1: never a traceback (issue #13, item 14)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest


def tankviz(*argv: str, cwd: Path, env: dict[str, str] | None = None,
            ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bridge", *argv], capture_output=True, text=True,
                          cwd=cwd, timeout=120, env={**os.environ, **(env or {})})


def one_error_line(result: subprocess.CompletedProcess[str]) -> str:
    """The only line of stderr, checked to be an ``error:`` line with exit status 1."""
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith("error: ")
    return line


@pytest.mark.slow
@pytest.mark.parametrize("duration", ["0", "-5", "nan", "inf"])
def test_simulate_wants_a_duration_of_some_seconds(tmp_path: Path, duration: str) -> None:
    line = one_error_line(tankviz("simulate", "-o", "drive.blf", f"--duration={duration}",
                                  cwd=tmp_path))
    assert line == f"error: --duration {duration}: expected a number of seconds > 0"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [["--help"], ["live", "--help"], ["demo", "--for", "1"]])
def test_a_bad_port_in_the_environment_is_named(tmp_path: Path, argv: list[str]) -> None:
    line = one_error_line(tankviz(*argv, cwd=tmp_path, env={"TANKVIZ_PORT": "abc"}))
    assert line == "error: TANKVIZ_PORT='abc': expected a port number (0 to 65535)"


def test_a_bad_run_time_in_the_environment_is_named(tmp_path: Path) -> None:
    line = one_error_line(tankviz("--help", cwd=tmp_path, env={"TANKVIZ_RUN_FOR": "soon"}))
    assert line == "error: TANKVIZ_RUN_FOR='soon': expected a number of seconds > 0"


@pytest.mark.slow
def test_good_settings_in_the_environment_are_the_defaults(tmp_path: Path) -> None:
    result = tankviz("live", "--help", cwd=tmp_path,
                     env={"TANKVIZ_PORT": "9001", "TANKVIZ_RUN_FOR": "2.5"})
    assert result.returncode == 0, result.stderr


@pytest.mark.slow
def test_inspect_a_folder_says_it_is_one(tmp_path: Path) -> None:
    (tmp_path / "drives").mkdir()
    line = one_error_line(tankviz("inspect", "drives", cwd=tmp_path))
    assert line.startswith("error: drives: is a folder")
    assert "drives/*.mcap" in line


@pytest.mark.slow
@pytest.mark.parametrize("rate", ["0", "-1", "100"])
@pytest.mark.parametrize("command", ["convert", "batch"])
def test_a_scene_rate_of_zero_is_refused_as_any_other_out_of_range(
        tmp_path: Path, rate: str, command: str) -> None:
    """``--scene-rate 0`` was quietly the default, while 100 was refused."""
    argv = (["convert", "--sample", "-o", "x.mcap"] if command == "convert"
            else ["batch", "convert", "nothing/*.blf", "--out", "out"])
    line = one_error_line(tankviz(*argv, f"--scene-rate={rate}", cwd=tmp_path))
    assert line == f"error: --scene-rate {rate}: must be above 0 and at most 50 Hz"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_simulate_and_replay_say_what_their_file_is(tmp_path: Path) -> None:
    simulate = tankviz("simulate", "--help", cwd=tmp_path).stdout
    assert "-o OUTPUT, --output OUTPUT\n" in simulate  # its help follows on the next line
    assert ".blf" in simulate.split("--output OUTPUT", 1)[1].split("--car", 1)[0]
    replay = tankviz("replay", "--help", cwd=tmp_path).stdout
    assert "FILE" in replay and ".mcap" in replay


def test_simulate_shows_its_progress_on_a_terminal() -> None:
    """22 s for a 300 s drive, without a word: now a bar as convert's (only on a terminal)."""
    from bridge.apps.simulate import with_progress
    from bridge.sim.ecocar import simulate

    seen: list[tuple[int, float | None]] = []
    frames = list(with_progress(simulate(duration_s=2.0), 2.0,
                                lambda n, f: seen.append((n, f)), every=500))
    fractions = [f for _, f in seen]
    assert seen[-1] == (len(frames), 1.0)
    assert len(seen) > 3 and fractions == sorted(fractions)  # type: ignore[type-var]
    assert all(0.0 <= f <= 1.0 for f in fractions if f is not None)


@pytest.mark.slow
def test_the_highway_car_drives_the_road_asked_for(tmp_path: Path) -> None:
    """``--road winding`` is the drive the lateral-sign check judges on gentle curves."""
    done = tankviz("simulate", "--car", "highway", "--road", "winding", "--duration", "2",
                   "-o", "w.mcap", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    from bridge.io.drives import read_drive

    assert read_drive(tmp_path / "w.mcap").metadata["simulated"]["road"] == "winding"
    line = one_error_line(tankviz("simulate", "--road", "winding", "-o", "e.blf", cwd=tmp_path))
    assert line == "error: --road winding: only the highway car has other roads (--car highway)"


@pytest.mark.slow
@pytest.mark.parametrize("command", [["live", "--bus", "can0=virtual:tankviz-for-check"],
                                     ["demo"], ["replay", "drive.blf"]])
@pytest.mark.parametrize("seconds", ["0", "-1", "nan", "inf", "soon"])
def test_for_wants_a_number_of_seconds_above_zero(tmp_path: Path, command: list[str],
                                                 seconds: str) -> None:
    """#33 item 12: `--for -1` or `--for nan` failed with "did not open before the run was
    stopped", and `--for 0` ran with no limit. Each is one line before anything starts."""
    line = one_error_line(tankviz(*command, f"--for={seconds}", "--port", "0", cwd=tmp_path))
    assert line == f"error: --for {seconds}: expected a number of seconds > 0"
