"""A bus that cannot work is a configuration error at start (one line, exit 1, nothing recorded);
only a bus that worked and was lost is retried (tests/test_live.py covers the retries)."""

from __future__ import annotations

import os
import queue
import subprocess
import sys
from pathlib import Path

import can
import pytest
from conftest import timeout_scale
from harness import Opener
from waiting import wait_for

from bridge.errors import UsageError
from bridge.io.buses import BusEvent, BusLink, BusSpec


def live(tmp_path: Path, dbc: Path, *bus: str) -> subprocess.CompletedProcess[str]:
    """tankviz live on ``bus`` with a database that is not ecocar's, no python-can configuration
    anywhere (HOME and the working folder are empty), stopping by itself after 20 s at most."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAN_")}
    env["HOME"] = str(tmp_path)
    return subprocess.run(
        [sys.executable, "-m", "bridge", "live", *[a for b in bus for a in ("--bus", b)],
         "--dbc", str(dbc / "ESR.dbc"), "--drives", str(tmp_path / "drives"), "--no-server",
         "--for", "20"],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=60)


@pytest.mark.slow
def test_a_bus_named_without_python_can_configuration_is_an_error_at_start(
        tmp_path: Path, shared_dbc: Path) -> None:
    result = live(tmp_path, shared_dbc, "radar")
    assert result.returncode == 1, result.stdout + result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith("error: --bus radar: python-can's configuration has no interface "
                           "for radar"), line
    assert "--bus radar=INTERFACE:CHANNEL" in line
    assert not list((tmp_path / "drives").glob("*.mcap"))


@pytest.mark.slow
def test_a_misspelt_interface_is_an_error_at_start(tmp_path: Path, shared_dbc: Path) -> None:
    result = live(tmp_path, shared_dbc, "radar=socketcn:vcan0")
    assert result.returncode == 1, result.stdout + result.stderr
    (line,) = result.stderr.splitlines()
    assert line == ('error: --bus radar=socketcn:vcan0: python-can has no interface "socketcn" '
                    '(did you mean socketcan?)'), line
    assert not list((tmp_path / "drives").glob("*.mcap"))


@pytest.mark.slow
def test_one_bad_bus_among_good_ones_stops_the_start(tmp_path: Path, shared_dbc: Path) -> None:
    result = live(tmp_path, shared_dbc, f"front=virtual:ok-{os.getpid()}", "rear=nosuch:x")
    assert result.returncode == 1, result.stdout + result.stderr
    assert result.stderr.strip().startswith('error: --bus rear=nosuch:x: python-can has no '
                                            'interface "nosuch"')


@pytest.mark.parametrize("error", [
    can.CanInterfaceNotImplementedError('Unknown interface type "socketcn"'),
    ValueError("invalid literal for int() with base 10: 'fast'"),
    ImportError("no module named 'usb'"),
])
def test_a_configuration_error_at_the_first_open_is_not_retried(error: Exception) -> None:
    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    opener = Opener(error)
    link = BusLink(BusSpec("radar", "socketcn", "vcan0"), events, open_bus=opener,
                   backoff=(0.01, 0.01))
    link.start()
    assert link.tried.wait(5 * timeout_scale())
    # the opener gives up by itself (a retry every 10 ms would keep it going)
    assert wait_for(lambda: not link._opener.is_alive(), 5 * timeout_scale())
    link.stop()
    assert opener.opens == 1
    assert isinstance(link.error, UsageError)
    assert str(link.error).startswith("--bus radar=socketcn:vcan0: ")
    assert events.empty()  # not a lost bus: nothing to retry, no gap


def test_an_adapter_missing_at_the_first_open_is_waited_for() -> None:
    """An adapter not plugged in yet (or an interface still down at boot) may come: retried."""
    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    opener = Opener(can.CanInitializationError("No such device"))
    link = BusLink(BusSpec("radar", "socketcan", "can0"), events, open_bus=opener,
                   backoff=(0.01, 0.01))
    link.start()
    assert link.tried.wait(5 * timeout_scale())
    assert wait_for(lambda: opener.opens >= 3, 10 * timeout_scale())
    link.stop()
    assert opener.opens >= 3 and link.error is None
    # not a lost bus (it never opened): no gap; live waits for it at most OPEN_WAIT_S
    assert events.empty() and link.failure == "CanInitializationError: No such device"
