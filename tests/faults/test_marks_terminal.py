"""Marks from live's terminal (#34 item 3): while ``tankviz live`` (here ``demo``, the same run)
has a terminal, Enter marks the moment, named by what was typed before it, and the console says
so; without a terminal (systemd, a pipe) nothing is read. The input's end (Ctrl+D) ends the
marking, not the run.
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
from conftest import timeout_scale
from harness import recorded
from test_marks_live import block_times
from waiting import wait_for

from bridge.frame import NS

#: seconds a run may take to start, to say something, or to finish once stopped (scaled)
LIMIT_S = 60.0


def demo(tmp_path: Path) -> list[str]:
    return [sys.executable, "-m", "bridge", "demo", "--no-server",
            "--drives", str(tmp_path / "drives")]


def controlled_by_the_terminal() -> None:
    """In the child: the terminal on its standard input is its controlling terminal, and the
    child is in its foreground, as a command typed in a shell."""
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


class Terminal:
    """The master side of a pty: what the program printed so far, and typing."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.seen = b""

    def until(self, wanted: bytes) -> None:
        def read_or_ended() -> bool:  # True once ``wanted`` came or nothing more can
            if select.select([self.fd], [], [], 0.1)[0]:
                try:
                    self.seen += os.read(self.fd, 4096)
                except OSError:  # the program ended (EIO)
                    return True
            return wanted in self.seen

        wait_for(read_or_ended, LIMIT_S * timeout_scale(), step=0.0)
        assert wanted in self.seen, self.seen.decode(errors="replace")

    def type(self, text: bytes) -> None:
        os.write(self.fd, text)


@pytest.mark.slow
def test_enter_in_the_terminal_marks_the_moment(tmp_path: Path) -> None:
    master, slave = os.openpty()
    process = subprocess.Popen(demo(tmp_path), stdin=slave, stdout=slave, stderr=slave,
                               cwd=tmp_path, start_new_session=True,
                               preexec_fn=controlled_by_the_terminal)
    os.close(slave)
    terminal = Terminal(master)
    try:
        terminal.until(b"Enter marks the moment (type a word first to name it).")
        terminal.until(b"Ctrl+C stops")
        terminal.type(b"\n")
        terminal.until(b"MARK 1: mark (terminal)")
        terminal.type("ghost ahead 👻\n".encode())
        terminal.until("MARK 2: ghost ahead 👻 (terminal)".encode())
        terminal.type(b"m\n")  # (as Enter alone)
        terminal.until(b"MARK 3: mark (terminal")
        terminal.type(b"\x1b[A lane\x07 \n")  # an arrow key's escape, a bell: not in the text
        terminal.until(b"MARK 4: [A lane (terminal")
        terminal.type(b"\x04")  # Ctrl+D: the input ends, the run goes on
        terminal.until(b"the terminal's input ended: Enter marks no more")
        process.send_signal(signal.SIGTERM)
        terminal.until(b"the simulated car sent")
        assert process.wait(LIMIT_S * timeout_scale()) == 0
    finally:
        if process.poll() is None:
            process.kill()
        os.close(master)
    assert b"Traceback" not in terminal.seen
    marks = recorded(tmp_path / "drives")["/marks"]
    assert [(m.number, m.text, m.source, m.by) for m in marks] == [
        (1, "mark", "terminal", "terminal"), (2, "ghost ahead 👻", "terminal", "terminal"),
        (3, "mark", "terminal", "terminal"), (4, "[A lane", "terminal", "terminal")]
    times = [m.timestamp.seconds * NS + m.timestamp.nanos for m in marks]
    blocks = block_times(tmp_path / "drives")
    # on the drive's clock, in the order typed, while frames came (the last one at most a read
    # of the buses after the last frame)
    assert times == sorted(times) and blocks[0] <= times[0] and times[-1] <= blocks[-1] + NS // 10


@pytest.mark.slow
def test_without_a_terminal_nothing_is_read(tmp_path: Path) -> None:
    """Standard input a pipe (as under systemd, or in a script): what comes on it is not read,
    and nothing is said about marking."""
    process = subprocess.Popen([*demo(tmp_path), "--for", "3"], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=tmp_path)
    assert process.stdin is not None
    process.stdin.write(b"\n" * 10 + b"ghost\n")
    process.stdin.flush()
    out = process.communicate(timeout=LIMIT_S * timeout_scale())[0].decode()
    assert process.returncode == 0, out
    assert "Enter marks" not in out and "MARK" not in out, out
    assert "/marks" not in recorded(tmp_path / "drives")
