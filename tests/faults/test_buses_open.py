"""A bus that never opens (a socketcand server that is down, an address that is not one, an
interface that is not there) is one line and exit 1 after a bounded wait, not a retry for ever;
a bad ``--bus`` prints nothing before its error; python-can's own log lines are one per cause.

Only a bus that opened once and was then lost is retried for as long as the run goes on
(tests/test_live.py)."""

from __future__ import annotations

import logging
import os
import queue
import socket
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest
from conftest import timeout_scale
from harness import Opener

from bridge.errors import UsageError
from bridge.io.buses import BusEvent, BusLink, BusSpec, CanLogLimiter, one_line


def live(tmp_path: Path, *args: str, timeout: float = 90) -> subprocess.CompletedProcess[str]:
    """tankviz live with ``args`` (database not ecocar's), python-can's configuration only what
    the test writes into ``tmp_path`` (its HOME)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAN_")}
    env["HOME"] = str(tmp_path)
    return subprocess.run(
        [sys.executable, "-m", "bridge", "live", "--profile", "ecocar",
         "--drives", str(tmp_path / "drives"), *args],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=timeout * timeout_scale())


def closed_port() -> int:
    """A local TCP port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.slow
@pytest.mark.parametrize("bus", ["can0=udp_multicast:notanaddress", "can0=socketcan:can9"])
def test_a_bus_that_never_opens_is_one_error_line_and_exit_1_by_the_end_of_for(
        tmp_path: Path, bus: str) -> None:
    """``--for 2``: the run ends when it says, having recorded nothing, with one line naming the
    bus and why it did not open (not ``0 bus gaps`` and exit 0)."""
    started = time.monotonic()
    result = live(tmp_path, "--bus", bus, "--no-server", "--for", "2")
    assert time.monotonic() - started < 60 * timeout_scale()  # ended, not hung
    assert result.returncode == 1, result.stdout + result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, result.stderr
    assert errors[0].startswith(f"error: --bus {bus}: did not open"), errors[0]
    assert "bus gaps" not in result.stdout
    assert not list((tmp_path / "drives").glob("*.mcap"))
    python_can = [line for line in result.stderr.splitlines() if not line.startswith("error:")]
    assert len(python_can) <= 4, result.stderr  # one per cause, then a count


@pytest.mark.slow
def test_a_socketcand_server_that_is_down_is_one_line_per_cause_not_a_flood(
        tmp_path: Path) -> None:
    """python-can's socketcand tries to connect for 10 s in a busy loop, logging a warning for
    every try (hundreds of thousands of lines): each cause is said once, then counted."""
    (tmp_path / "can.conf").write_text(
        f"[radar]\ninterface = socketcand\nchannel = can0\nhost = 127.0.0.1\n"
        f"port = {closed_port()}\n")
    result = live(tmp_path, "--bus", "radar", "--no-server", "--for", "2")
    assert result.returncode == 1, result.stdout + result.stderr[:3000]
    lines = result.stderr.splitlines()
    assert len(lines) <= 6, result.stderr[:3000]
    assert lines[-1].startswith("error: --bus radar (python-can config): did not open"), lines
    assert any("Failed to connect to server" in line for line in lines), lines


@pytest.mark.slow
def test_a_bad_bus_prints_nothing_before_its_error(tmp_path: Path) -> None:
    """``--bus nosuch``: not "Foxglove: open connection" and "Ctrl+C stops" first."""
    result = live(tmp_path, "--bus", "nosuch", "--port", "0")
    assert result.returncode == 1, result.stdout + result.stderr
    assert result.stdout == ""
    (line,) = result.stderr.splitlines()
    assert line.startswith("error: --bus nosuch: python-can's configuration has no interface")


@pytest.mark.slow
def test_a_bus_that_never_opens_is_an_error_after_the_wait_and_no_gap() -> None:
    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.live_engine import Live

    opener = Opener(can.CanInitializationError("No such device\nmore detail"))
    live = Live([BusSpec("radar", "socketcan", "can9")], load_stages([], "ecocar"), drives=None,
                open_bus=opener, open_wait_s=0.5, say=lambda text: None)
    with pytest.raises(UsageError) as raised:
        live.start()
    assert str(raised.value) == ("--bus radar=socketcan:can9: did not open in 0.5 s: "
                                 f"CanInitializationError: No such device ({opener.opens} "
                                 "tries)")
    assert opener.opens >= 2  # retried while waiting
    assert live.events.empty()  # never opened: not a lost bus, no gap


def test_a_bus_that_opens_within_the_wait_is_used() -> None:
    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    tries = [0]

    def open_late(spec: BusSpec) -> can.BusABC:
        tries[0] += 1
        if tries[0] < 3:
            raise can.CanInitializationError("not yet")
        return can.Bus(interface="virtual", channel=f"late-{os.getpid()}")

    link = BusLink(BusSpec("radar", "virtual", "x"), events, open_bus=open_late,
                   backoff=(0.01, 0.01))
    link.start()
    assert link.opened.wait(10)
    link.stop()
    link.close()
    assert events.empty()  # no "lost" and "back" for a bus that was not there yet


def test_a_lost_bus_reason_is_one_line() -> None:
    """python-can's socketcand puts a whole traceback into its error's message."""
    exc = can.CanOperationError("Failed to receive: boom  Traceback (most recent call last):\n"
                                '  File "socketcand.py", line 3\nValueError: boom')
    assert one_line(exc) == "CanOperationError: Failed to receive: boom"
    assert one_line(OSError(19, "No such device")) == "OSError: [Errno 19] No such device"
    assert one_line(TimeoutError()) == "TimeoutError"


class BrokenBus(can.BusABC):
    """A bus that opens, then fails as socketcand does: a traceback in the error's message."""

    def __init__(self) -> None:
        super().__init__(channel="x")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        raise can.CanOperationError(
            "Failed to receive: [Errno 104] Connection reset by peer  Traceback (most recent "
            'call last):\n  File "socketcand.py", line 263, in _recv_internal\nConnectionReset'
            "Error: [Errno 104] Connection reset by peer\n")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise NotImplementedError


def test_a_lost_bus_event_carries_one_line() -> None:
    """What goes to the console, ``/log`` and ``bus_gaps.reason``."""
    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    link = BusLink(BusSpec("radar", "socketcand", "can0"), events,
                   open_bus=lambda spec: BrokenBus(), backoff=(10.0, 10.0))
    link.start()
    assert link.opened.wait(10)
    assert link.poll() == []
    link.stop()
    event = events.get(timeout=5)
    assert not event.up
    assert event.reason == ("CanOperationError: Failed to receive: [Errno 104] Connection reset "
                            "by peer")


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_python_can_log_lines_are_one_per_cause_then_counted() -> None:
    said: list[str] = []
    clock = Clock()
    limiter = CanLogLimiter(said.append, clock=clock, every_s=10.0)
    log = logging.getLogger("can.test_limiter")
    log.addHandler(limiter)
    log.propagate = False
    try:
        for i in range(1000):
            clock.now = i * 0.005  # 5 s of a busy loop
            log.warning(f"Failed to connect to server: <class 'ConnectionRefusedError'> "
                        f"Message: [Errno 111] Connection refused (try {i})")
        log.error("Failed to receive: x  Traceback (most recent call last):\n  File ...")
        assert said == [
            "python-can: Failed to connect to server: <class 'ConnectionRefusedError'> "
            "Message: [Errno 111] Connection refused (try 0)",
            "python-can: Failed to receive: x",
        ]
        clock.now = 10.0
        log.warning("Failed to connect to server: <class 'ConnectionRefusedError'> Message: "
                    "[Errno 111] Connection refused (try 1000)")
        assert said[2:] == ["python-can: Failed to connect to server: <class "
                            "'ConnectionRefusedError'> Message: [Errno 111] Connection refused "
                            "(try 1000) (repeated 1,000 times in the last 10 s)"]
        log.warning("Failed to connect to server: <class 'ConnectionRefusedError'> Message: "
                    "[Errno 111] Connection refused (try 1001)")
        clock.now = 14.0
        limiter.close()  # the counts not yet said are said at the end
        assert said[3:] == ["python-can: Failed to connect to server: <class "
                            "'ConnectionRefusedError'> Message: [Errno 111] Connection refused "
                            "(try 1001) (repeated 1 time in the last 4 s)"]
    finally:
        log.removeHandler(limiter)
