"""A hangup (the terminal or SSH session of ``live`` or ``demo`` goes away: SIGHUP) finishes the
drive as SIGTERM does: exit 0, a complete MCAP (footer and summary: no ``tankviz recover``).
Once the terminal is gone, writing to it fails (EIO on a hung-up terminal, EPIPE on a pipe whose
reader left): the drive is finished all the same, and no traceback is attempted. A ``replay``
ends the same way (it exited 129, killed by the signal).
"""

from __future__ import annotations

import fcntl
import os
import select
import signal
import subprocess
import sys
import termios
from pathlib import Path

import pytest
from conftest import summary_counts, timeout_scale
from multicast import Sender, multicast_or_skip, unique_group
from waiting import wait_for

#: seconds a run may take to start, or to finish once stopped (scaled)
LIMIT_S = 60.0


def command(kind: str, tmp_path: Path) -> list[str]:
    """``tankviz demo`` (the simulated car) or ``tankviz live`` on a udp_multicast bus."""
    drives = ["--drives", str(tmp_path / "drives"), "--no-server"]
    if kind == "demo":
        return [sys.executable, "-m", "bridge", "demo", *drives]
    return [sys.executable, "-m", "bridge", "live", "--bus", f"can0=udp_multicast:{kind}",
            "--profile", "ecocar", *drives]


def become_controlled_by_the_terminal() -> None:
    """In the child: the terminal on its standard input becomes its controlling terminal (it
    leads a session of its own), so closing that terminal hangs it up, as closing a window
    or losing an SSH session does."""
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def read_until(fd: int, wanted: bytes, process: subprocess.Popen[bytes]) -> bytes:
    seen = b""

    def read_or_ended() -> bool:  # True once ``wanted`` came or nothing more can
        nonlocal seen
        if select.select([fd], [], [], 0.1)[0]:
            try:
                chunk = os.read(fd, 4096)
            except OSError:  # the terminal's process ended (EIO)
                return True
            if not chunk:
                return True
            seen += chunk
        return wanted in seen

    wait_for(read_or_ended, LIMIT_S * timeout_scale(), step=0.0)
    assert wanted in seen, seen.decode(errors="replace")
    return seen


def drive_grew(tmp_path: Path) -> None:
    """Waits until the drive's file has grown past its start (frames flushed to it)."""
    first: dict[Path, int] = {}

    def grew() -> bool:
        for path in (tmp_path / "drives").glob("*.mcap"):
            size = path.stat().st_size
            if first.setdefault(path, size) < size:
                return True
        return False

    assert wait_for(grew, LIMIT_S * timeout_scale()), list((tmp_path / "drives").glob("*"))


def assert_finished(tmp_path: Path) -> None:
    """The drive is complete: one MCAP whose footer and summary read, holding frames."""
    drives = list((tmp_path / "drives").glob("*.mcap"))
    assert len(drives) == 1, drives
    counts = summary_counts(drives[0])  # a cut file has no summary: recover would be needed
    assert counts.get("/can/can0/frames", 0) > 0, counts
    assert [p.name for p in (tmp_path / "drives").iterdir() if p.name.startswith(".")] == []


def ended(process: subprocess.Popen[bytes]) -> int:
    try:
        return process.wait(LIMIT_S * timeout_scale())
    except subprocess.TimeoutExpired:
        process.kill()
        pytest.fail("it did not end after the hangup")


@pytest.fixture(params=["demo", "live"])
def kind(request: pytest.FixtureRequest) -> str:
    """``demo``, or the group of a ``live`` udp_multicast bus a car process sends to."""
    if request.param == "demo":
        return "demo"
    multicast_or_skip()
    group = unique_group()
    sender = Sender(group)
    request.addfinalizer(sender.stop)
    return group


@pytest.mark.slow
def test_closing_the_terminal_finishes_the_drive(tmp_path: Path, kind: str) -> None:
    master, slave = os.openpty()
    process = subprocess.Popen(command(kind, tmp_path), stdin=slave, stdout=slave,
                               stderr=slave, cwd=tmp_path, start_new_session=True,
                               preexec_fn=become_controlled_by_the_terminal)
    os.close(slave)
    try:
        read_until(master, b"Ctrl+C stops", process)
        drive_grew(tmp_path)
    finally:
        os.close(master)  # the terminal goes away: SIGHUP; writing to it now fails with EIO
    assert ended(process) == 0
    assert_finished(tmp_path)


@pytest.mark.slow
def test_a_hangup_whose_output_pipes_are_gone_finishes_the_drive(tmp_path: Path) -> None:
    """An SSH session that ends: its pipes' reader is gone (EPIPE), then the hangup."""
    process = subprocess.Popen(command("demo", tmp_path), stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, cwd=tmp_path)
    assert process.stdout is not None
    read_until(process.stdout.fileno(), b"Ctrl+C stops", process)
    drive_grew(tmp_path)
    process.stdout.close()  # the reader left: writing now fails with EPIPE
    process.send_signal(signal.SIGHUP)
    assert ended(process) == 0
    assert_finished(tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGTERM])
def test_a_hangup_ends_a_run_as_sigterm_does(tmp_path: Path, signum: int) -> None:
    """``kill -HUP`` with the terminal still there: the same end as SIGTERM's, summary too."""
    process = subprocess.Popen(command("demo", tmp_path), stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, cwd=tmp_path)
    assert process.stdout is not None
    seen = read_until(process.stdout.fileno(), b"Ctrl+C stops", process)
    drive_grew(tmp_path)
    process.send_signal(signum)
    out = (seen + process.communicate(timeout=LIMIT_S * timeout_scale())[0]).decode()
    assert process.returncode == 0, out
    assert "Traceback" not in out, out
    lines = out.splitlines()
    assert any(line.startswith("recorded ") for line in lines), lines
    assert lines[-1].startswith("the simulated car sent "), lines
    assert_finished(tmp_path)


def replay_command(drive: Path) -> list[str]:
    """``tankviz replay`` of a drive, looping, on a free port."""
    return [sys.executable, "-m", "bridge", "replay", str(drive), "--port", "0", "--loop"]


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGTERM])
def test_a_hangup_ends_a_replay_as_sigterm_does(tmp_path: Path, sample_drive: Path,
                                                signum: int) -> None:
    process = subprocess.Popen(replay_command(sample_drive), stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, cwd=tmp_path)
    assert process.stdout is not None
    seen = read_until(process.stdout.fileno(), b"Foxglove: open connection", process)
    process.send_signal(signum)
    out = (seen + process.communicate(timeout=LIMIT_S * timeout_scale())[0]).decode()
    assert process.returncode == 0, out
    assert "Traceback" not in out, out
    assert out.splitlines()[-1].startswith("replayed "), out


@pytest.mark.slow
def test_closing_the_terminal_ends_a_replay(tmp_path: Path, sample_drive: Path) -> None:
    master, slave = os.openpty()
    process = subprocess.Popen(replay_command(sample_drive), stdin=slave, stdout=slave,
                               stderr=slave, cwd=tmp_path, start_new_session=True,
                               preexec_fn=become_controlled_by_the_terminal)
    os.close(slave)
    try:
        read_until(master, b"Foxglove: open connection", process)
    finally:
        os.close(master)  # the terminal goes away: SIGHUP; writing to it now fails with EIO
    assert ended(process) == 0
