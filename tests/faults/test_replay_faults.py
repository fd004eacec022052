"""``tankviz replay`` when its input is stuck, or shorter than ``--start`` (issue #23): ``--for``
and SIGTERM stop it even while a read never returns, and a start past the end is one line.

The replays run as child processes (they install their own signal handlers); a child that
outlives its time budget is a hang and fails the test (and is killed).
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import timeout_scale
from mcap.writer import IndexType, Writer
from waiting import wait_for

from bridge.apps.replay import replay_mcap
from bridge.cli import main
from bridge.errors import InputError, UsageError
from bridge.io.readahead import THREAD_ITEMS, read_in_thread
from bridge.sim.ecocar import simulate
from bridge.sinks.can_log_writer import write_log
from bridge.sinks.server import ViewerServer

#: What a replay asked to stop may take at most to end: a hang fails, not freezes, the suite.
LIMIT_S = 60.0

#: ``tankviz`` whose log reads hang after 200 frames, as a read from a network file that went
#: away does; it says "stuck" when they do.
STUCK = """
import sys, time
from bridge.io import can_logs
read = can_logs.LogSource.__iter__
def stuck(self):
    for n, frame in enumerate(read(self)):
        if n == 200:
            sys.stdout.write("stuck\\n")  # one write: the pipeline's thread prints too
            sys.stdout.flush()
            time.sleep(3600)
        yield frame
can_logs.LogSource.__iter__ = stuck
from bridge.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three seconds of the simulated car, as a candump log."""
    path = tmp_path_factory.mktemp("replay") / "drive.log"
    write_log(simulate(duration_s=3.0), path, ".log")
    return path


def replay(*args: str, script: str | None = None) -> subprocess.Popen[str]:
    command = [sys.executable, "-c", script] if script else [sys.executable, "-m", "bridge"]
    return subprocess.Popen([*command, "replay", *args, "--port", "0", "--speed", "50"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def ended(process: subprocess.Popen[str]) -> tuple[str, str]:
    """What the replay wrote, once it ended (within :data:`LIMIT_S`: else a hang)."""
    try:
        return process.communicate(timeout=LIMIT_S * timeout_scale())
    except subprocess.TimeoutExpired:
        process.kill()
        out, err = process.communicate()
        pytest.fail(f"the replay did not end (a hang); it wrote: {out}{err}")


def wait_for_line(process: subprocess.Popen[str], wanted: str, limit_s: float = LIMIT_S) -> None:
    """Reads the replay's output until the line ``wanted`` (within ``limit_s``), from the pipe's
    descriptor: lines that come together are all seen (a buffered readline() would keep the
    later ones where select() cannot see them)."""
    assert process.stdout is not None
    fd = process.stdout.fileno()
    seen = b""

    def said_or_ended() -> bool:
        nonlocal seen
        if select.select([fd], [], [], 0.1)[0]:
            chunk = os.read(fd, 4096)
            if not chunk:
                return True
            seen += chunk
        return wanted in seen.decode(errors="replace").splitlines()

    wait_for(said_or_ended, limit_s * timeout_scale(), step=0.0)
    if wanted in seen.decode(errors="replace").splitlines():
        return
    process.kill()
    pytest.fail(f"the replay never said {wanted!r}; it said: {seen.decode(errors='replace')}")


def test_a_line_that_comes_with_the_one_before_it_is_seen() -> None:
    """Two lines written at once are both read (select() on the pipe said nothing of the second,
    already in the reader's buffer: the wait went on until its limit)."""
    process = subprocess.Popen([sys.executable, "-c", "import sys, time; "
                                "sys.stdout.write('a line\\nstuck\\n'); sys.stdout.flush(); "
                                "time.sleep(30)"], stdout=subprocess.PIPE, text=True)
    try:
        wait_for_line(process, "stuck", limit_s=5.0)
    finally:
        process.kill()
        process.communicate()


@pytest.mark.slow
def test_replay_for_ends_on_time_while_its_input_is_stuck(log: Path) -> None:
    process = replay(str(log), "--for", "1", script=STUCK)
    out, err = ended(process)
    assert process.returncode == 0, err
    assert "stuck" in out.splitlines()  # the read did hang
    assert out.splitlines()[-1].startswith("replayed ")


@pytest.mark.slow
def test_sigterm_ends_a_replay_whose_input_is_stuck(log: Path) -> None:
    process = replay(str(log), script=STUCK)
    wait_for_line(process, "stuck")
    process.send_signal(signal.SIGTERM)
    out, err = ended(process)
    assert process.returncode == 0, err
    assert out.splitlines()[-1].startswith("replayed ")
    assert "Traceback" not in err


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["log", "mcap"])
def test_a_start_past_the_end_of_the_drive_is_one_line_naming_its_length(
        log: Path, tmp_path: Path, kind: str) -> None:
    path = log
    if kind == "mcap":
        path = tmp_path / "drive.mcap"
        assert main(["convert", str(log), "-o", str(path), "--quiet"]) == 0
    process = replay(str(path), "--start", "1000", "--for", str(LIMIT_S))
    _, err = ended(process)
    assert process.returncode == 1
    assert err.splitlines() == ["error: --start 1000: the drive is only 3.0 s long"]


@pytest.mark.slow
def test_a_start_within_the_drive_is_kept(log: Path) -> None:
    process = replay(str(log), "--start", "2.5")
    out, err = ended(process)
    assert process.returncode == 0, err
    assert int(out.splitlines()[-1].split()[1].replace(",", "")) > 0


def test_replay_names_what_its_files_are(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["replay", "--help"])
    usage = capsys.readouterr().out
    positional = usage.split("positional arguments:")[1].split("options:")[0]
    assert positional.split()[0] == "FILE"
    assert ".mcap" in positional and ".blf" in positional, positional


# --- the reading thread under it ---


def test_read_in_thread_gives_every_item_in_order_then_the_error_that_ended_the_reading() -> None:
    def items() -> Iterator[int]:
        yield from range(3 * THREAD_ITEMS)  # more than it holds ahead
        raise InputError("drive.log", "no CAN frames in this file", where="line 9")

    got: list[int] = []
    with pytest.raises(InputError, match=r"^drive\.log:line 9: no CAN frames"):
        got.extend(read_in_thread(items(), threading.Event()))
    assert got == list(range(3 * THREAD_ITEMS))


def test_read_in_thread_ends_at_its_stop_while_a_read_never_returns() -> None:
    released = threading.Event()
    stopping = threading.Event()

    def items() -> Iterator[int]:
        yield from (1, 2, 3)
        released.wait()  # a read that does not return until the test is over
        yield 4

    got: list[int] = []

    def consume() -> None:
        for item in read_in_thread(items(), stopping):
            got.append(item)
            if item == 3:
                stopping.set()

    consumer = threading.Thread(target=consume, daemon=True)
    consumer.start()
    consumer.join(LIMIT_S * timeout_scale())
    released.set()
    assert not consumer.is_alive(), "the stop was not seen while the read blocked"
    assert got == [1, 2, 3]


def unindexed_mcap(path: Path, seconds: list[float]) -> Path:
    """An MCAP without statistics (as some writers make them): one message at each time."""
    with path.open("wb") as stream:
        writer = Writer(stream, use_statistics=False, index_types=IndexType.NONE,
                        use_summary_offsets=False)
        writer.start()
        schema = writer.register_schema("Tick", "jsonschema", b"{}")
        channel = writer.register_channel("/tick", "json", schema)
        for s in seconds:
            writer.add_message(channel, log_time=int(s * 1e9), data=b"{}", publish_time=0)
        writer.finish()
    return path


def test_a_start_in_an_mcap_without_statistics_is_kept_and_checked(tmp_path: Path) -> None:
    path = unindexed_mcap(tmp_path / "plain.mcap", [100.0, 101.0, 102.0])
    with ViewerServer(port=0, server_time=True) as server:
        assert replay_mcap(path, server, speed=100, start_s=1.5).messages == 1
        with pytest.raises(UsageError, match=r"^--start 5: the drive is only 2\.0 s long$"):
            replay_mcap(path, server, speed=100, start_s=5)


@pytest.mark.slow
def test_a_replay_tells_viewers_it_is_a_replay(log: Path) -> None:
    """serverInfo's metadata said ``{"tankviz": "live"}`` for a replay too."""
    from websockets.sync.client import connect

    process = subprocess.Popen([sys.executable, "-m", "bridge", "replay", str(log), "--port",
                                "0", "--speed", "0.1", "--for", "30"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        url = line.split("open connection ")[1].split()[0]
        with connect(url, subprotocols=["foxglove.websocket.v1"]) as ws:  # type: ignore[list-item]
            info = json.loads(ws.recv(timeout=LIMIT_S))
        assert info["op"] == "serverInfo" and info["metadata"] == {"tankviz": "replay"}
    finally:
        process.terminate()
        ended(process)
