"""The command line: what a user sees, including every error as one line naming the culprit."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from conftest import ECOCAR_DBC, T0, WriteLog, message

from bridge.apps.progress import ProgressBar
from bridge.cli import main


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def log(write_log: WriteLog, ecocar: cantools.database.can.Database) -> Path:
    return write_log("drive.blf", [message(ecocar, "EgoMotion", T0 + i * 0.01, VehicleSpeed=i)
                                   for i in range(100)])


def test_convert_then_inspect(capsys: pytest.CaptureFixture[str], log: Path,
                              tmp_path: Path) -> None:
    out_path = tmp_path / "drive.mcap"
    code, out, err = run(capsys, "convert", str(log), "-o", str(out_path), "--dbc", "ecocar")
    assert code == 0, err
    # 100 decoded, 1 s of raw frames in 20 ms blocks (50 or 51), and /health
    assert re.search(rf"wrote {re.escape(str(out_path))}: 100 frames, 15\d messages", out), out
    assert "decoded 100, unknown ids 0, decode errors 0" in out

    code, out, _ = run(capsys, "inspect", str(out_path))
    assert code == 0
    assert "/can/can0/EgoMotion" in out and "100" in out


def test_quiet_prints_nothing(capsys: pytest.CaptureFixture[str], log: Path,
                              tmp_path: Path) -> None:
    code, out, err = run(capsys, "convert", str(log), "-o", str(tmp_path / "d.mcap"),
                         "--dbc", str(ECOCAR_DBC), "--quiet")
    assert (code, out, err) == (0, "", "")


@pytest.mark.parametrize(("argv", "message"), [
    (["convert", "{tmp}/missing.blf", "-o", "{tmp}/o.mcap", "--dbc", "ecocar"],
     "error: {tmp}/missing.blf: no such file"),
    (["convert", "{tmp}/drive.xyz", "-o", "{tmp}/o.mcap", "--dbc", "ecocar"],
     "error: {tmp}/drive.xyz: unknown log format '.xyz'; python-can reads .asc, .blf"),
    (["convert", "{log}", "-o", "{tmp}/o.mcap", "--dbc", "{tmp}/broken.dbc"],
     "error: {tmp}/broken.dbc: cantools cannot load it: "),
    (["convert", "{log}", "-o", "{log}", "--dbc", "ecocar"],
     "error: {log}: is the same file as the input {log}: tankviz never writes over its inputs"),
    (["convert", "{log}", "-o", "{tmp}/o.asc", "--dbc", "ecocar"],
     "error: {tmp}/o.asc: convert writes an MCAP drive archive: the output's name must end in "
     ".mcap"),
    (["convert", "{log}", "-o", "{tmp}/nowhere/o.mcap", "--dbc", "ecocar"],
     "error: {tmp}/nowhere/o.mcap: cannot write: folder {tmp}/nowhere does not exist"),
    (["convert", "{log}", "-o", "{tmp}/o.mcap", "--dbc", "radar="],
     "error: --dbc radar=: no path after 'radar='"),
    (["inspect", "{log}"], "error: {log}: not a readable MCAP file"),
    (["convert", "{tmp}/bad.log", "-o", "{tmp}/o.mcap", "--strict"],
     "error: {tmp}/bad.log:line 1: skipped a line python-can cannot parse"),
])
def test_errors_are_one_line_and_name_the_file(
        capsys: pytest.CaptureFixture[str], log: Path, tmp_path: Path, argv: list[str],
        message: str) -> None:
    (tmp_path / "drive.xyz").write_text("")
    (tmp_path / "broken.dbc").write_text("BO_ nonsense\n")
    (tmp_path / "bad.log").write_text("not candump\n")
    fill = {"tmp": str(tmp_path), "log": str(log)}
    code, _, err = run(capsys, *[a.format(**fill) for a in argv])
    assert code == 1
    lines = err.strip().splitlines()
    assert lines[-1].startswith(message.format(**fill)), err
    assert len([line for line in lines if line.startswith("error:")]) == 1
    assert "Traceback" not in err
    assert not (tmp_path / "o.mcap").exists()


def test_debug_shows_the_traceback(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(capsys, "--debug", "convert", str(tmp_path / "missing.blf"), "-o",
                       str(tmp_path / "o.mcap"))
    assert code == 1
    assert "Traceback" in err and "InputError" in err
    assert err.strip().splitlines()[-1].startswith("error: ")


def test_skipped_lines_are_summarised(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    bad = tmp_path / "bad.log"
    bad.write_text("(1700000000.0) can0 100#00\nnot candump\n(1700000000.1) can0 101#01\n")
    code, out, _ = run(capsys, "convert", str(bad), "-o", str(tmp_path / "o.mcap"))
    assert code == 0
    assert "skipped in the inputs: 1" in out
    assert f"{bad}:line 2: skipped a line" in out


def test_the_progress_bar_shows_frames_rate_and_eta() -> None:
    text = ProgressBar.render(50_000, 0.25, 2.0, width=8)
    assert text == "[##......]  25%       50,000 frames      25,000 frames/s  ETA 00:06"
    assert ProgressBar.render(10, None, 1.0).strip() == "10 frames          10 frames/s"


def test_the_console_script_runs(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "bridge", "--version"], capture_output=True,
                            text=True, check=True)
    assert result.stdout.startswith("tankviz ")


def test_remote_frames_and_the_bundled_sample(capsys: pytest.CaptureFixture[str],
                                              write_log: WriteLog, tmp_path: Path) -> None:
    log = write_log("remote.log", [can.Message(timestamp=T0, arbitration_id=5,
                                               is_remote_frame=True, dlc=2)])
    code, out, _ = run(capsys, "convert", str(log), "-o", str(tmp_path / "r.mcap"))
    assert code == 0 and "1 frames" in out
