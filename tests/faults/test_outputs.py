"""Every file ``tankviz simulate`` writes holds the whole drive: read back, it gives exactly the
frames that were simulated (as many as it says it wrote). A format that cannot hold the drive is
refused before anything is written, saying why.

(issue #13, item 11: python-can's threaded SQLite writer dropped all but ~500 frames on stop;
TRC dropped every CAN FD frame with a warning each.)
"""

from __future__ import annotations

import importlib.util
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import timeout_scale
from mcap.reader import make_reader
from waiting import wait_for

from bridge.cli import main
from bridge.frame import Frame
from bridge.io.can_logs import LogSource
from bridge.io.drives import raw_frame_counts
from bridge.sim.ecocar import simulate
from bridge.topics import frames_topic

DURATION = "1.5"

#: Formats that keep the CAN FD flag and the bitrate switch of every frame.
FD_FORMATS = [".blf", ".asc", ".log", ".asc.gz", ".log.gz"]
#: Formats with no column for the CAN FD flags: id, time and every data byte are kept.
NO_FD_FLAG_FORMATS = [".csv", ".csv.gz", ".db"]
#: The optional MF4 format, where asammdf is installed.
MF4 = pytest.param(".mf4", marks=pytest.mark.skipif(
    importlib.util.find_spec("asammdf") is None,
    reason="MF4 needs the optional extra tankviz[mf4] (asammdf), not installed here"))


def simulated() -> list[Frame]:
    return list(simulate(duration_s=float(DURATION)))


def written(capsys: pytest.CaptureFixture[str], path: Path, *extra: str) -> int:
    """Simulate into ``path``; the frame count the command says it wrote."""
    assert main(["simulate", "-o", str(path), "--duration", DURATION, *extra]) == 0
    out = capsys.readouterr().out
    match = re.search(r"wrote .*: ([\d,]+) frames", out)
    assert match, out
    return int(match[1].replace(",", ""))


def key(frame: Frame, *, fd_flags: bool) -> tuple[object, ...]:
    flags = (frame.is_fd, frame.bitrate_switch) if fd_flags else ()
    return (frame.timestamp_ns, frame.arbitration_id, frame.is_extended, frame.data, *flags)


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [*FD_FORMATS, *NO_FD_FLAG_FORMATS, MF4])
def test_every_log_format_reads_back_exactly_the_frames_simulated(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], suffix: str) -> None:
    frames = simulated()
    assert any(f.is_fd for f in frames)  # the drive has CAN FD frames: the formats must hold them
    path = tmp_path / f"drive{suffix}"
    said = written(capsys, path)
    source = LogSource(path)
    back = list(source)
    assert source.issues == []
    assert said == len(back) == len(frames)
    fd_flags = suffix not in NO_FD_FLAG_FORMATS
    assert [key(f, fd_flags=fd_flags) for f in back] == [key(f, fd_flags=fd_flags)
                                                          for f in frames]


def test_a_format_without_fd_flags_says_what_it_leaves_out(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "-o", str(tmp_path / "drive.csv"), "--duration", DURATION]) == 0
    fd = sum(f.is_fd for f in simulated())
    err = capsys.readouterr().err
    assert f"warning: {tmp_path / 'drive.csv'}: " in err
    assert f"{fd} CAN FD frames" in err and "FD flag" in err


@pytest.mark.slow
def test_the_drive_as_mcap_holds_every_frame(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    from conftest import summary_counts

    path = tmp_path / "drive.mcap"
    said = written(capsys, path)
    frames = simulated()
    assert said == len(frames)
    with path.open("rb") as f:
        assert raw_frame_counts(make_reader(f)) == {"can0": len(frames)}
    assert summary_counts(path)[frames_topic("can0")] < len(frames)  # in blocks


@pytest.mark.slow
def test_forcing_over_an_sqlite_log_replaces_it(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """SQLite appends to a table that exists: --force must give the new drive alone."""
    path = tmp_path / "drive.db"
    written(capsys, path)
    said = written(capsys, path, "--force", "--seed", "3")
    back = list(LogSource(path))
    assert said == len(back) == len(list(simulate(duration_s=float(DURATION), seed=3)))


@pytest.mark.slow
def test_trc_cannot_hold_can_fd_and_is_refused_saying_why(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "bridge", "simulate", "-o", "drive.trc",
                             "--duration", DURATION], capture_output=True, text=True,
                            cwd=tmp_path, timeout=120)
    assert result.returncode == 1
    (line,) = result.stderr.splitlines()
    assert line.startswith("error: drive.trc: ") and "CAN FD" in line and ".blf" in line
    assert list(tmp_path.iterdir()) == []



TINY_DBC = """VERSION ""
BS_:
BU_: Door
BO_ 1056 DoorState: 8 Door
 SG_ Open : 0|8@1+ (1,0) [0|255] "" Door
"""


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_convert_stopped_by_a_signal_leaves_nothing_behind(tmp_path: Path, signum: int) -> None:
    """As Ctrl+C already did: SIGTERM (systemd, docker stop) and SIGHUP (the terminal closed)
    end the conversion with no partial file (``.OUT.mcap.<pid>-<random>.partial``) left over."""
    log = tmp_path / "door.log"
    log.write_text("".join(f"({1_700_000_000 + i / 1000:.6f}) can0 420#{i % 256:02X}{'00' * 7}\n"
                           for i in range(400_000)))
    (tmp_path / "door.dbc").write_text(TINY_DBC)
    out = tmp_path / "door.mcap"
    process = subprocess.Popen([sys.executable, "-m", "bridge", "convert", str(log), "-o",
                                str(out), "--dbc", str(tmp_path / "door.dbc"), "--quiet"],
                               stderr=subprocess.PIPE, text=True)
    wait_for(lambda: bool(list(tmp_path.glob(".door.mcap.*.partial")))
             or process.poll() is not None, 60 * timeout_scale())
    assert process.poll() is None, "finished before it could be stopped: make the log longer"
    process.send_signal(signum)
    _, err = process.communicate(timeout=60)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["door.dbc", "door.log"]
    assert process.returncode == 128 + signum
    assert "Traceback" not in err and len(err.splitlines()) == 1, err


@pytest.mark.slow
@pytest.mark.parametrize(("name", "partial"), [("drive.mcap", ".drive.mcap.*.partial"),
                                               ("drive.blf", ".drive_partial_*.blf"),
                                               ("drive.db", ".drive_partial_*.db")])
def test_simulate_stopped_by_sigterm_leaves_nothing_behind(tmp_path: Path, name: str,
                                                           partial: str) -> None:
    process = subprocess.Popen([sys.executable, "-m", "bridge", "simulate", "-o", name,
                                "--duration", "3600"], cwd=tmp_path, stderr=subprocess.PIPE,
                               text=True)
    wait_for(lambda: bool(list(tmp_path.glob(partial))) or process.poll() is not None,
             60 * timeout_scale())
    assert process.poll() is None, process.stderr
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert list(tmp_path.iterdir()) == []
    assert process.returncode == 128 + signal.SIGTERM
    assert err == f"stopped by SIGTERM: {name} not written\n"
