"""tankviz replay: a drive or a CAN log served in log time, with server time for the viewer."""

from __future__ import annotations

import asyncio
import json
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import pytest
import websockets
from conftest import timeout_scale

from bridge.apps.replay import replay_log, replay_mcap
from bridge.cli import main
from bridge.errors import UsageError
from bridge.frame import NS
from bridge.pipeline.drive import load_stages
from bridge.sim.ecocar import simulate
from bridge.sinks.server import ViewerServer

PROTO = [websockets.Subprotocol("foxglove.websocket.v1")]


def watch(server: ViewerServer, topic: str, run: Callable[[], object], *,
          enough: tuple[int, threading.Event] | None = None) -> tuple[list[int], list[int]]:
    """Run the replay in a thread, subscribe to ``topic`` once it is advertised, and collect
    the message times and the server times until the replay ends. ``enough``: (n, stop): the
    event is set once n messages came (what ends a looping replay: on a loaded machine a fixed
    time may pass before the first one)."""
    messages: list[int] = []
    times: list[int] = []
    replaying = threading.Thread(target=run)

    async def session() -> None:
        async with websockets.connect(server.url, subprotocols=PROTO, max_size=None) as ws:
            replaying.start()
            channel = None
            while channel is None:
                raw = await asyncio.wait_for(ws.recv(), 10)
                if isinstance(raw, bytes):  # server time before the channel: not yet
                    continue
                message = json.loads(raw)
                channel = next((c["id"] for c in message.get("channels", [])
                                if c["topic"] == topic), None)
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": channel}]}))
            while replaying.is_alive():
                try:
                    data = await asyncio.wait_for(ws.recv(), 0.5)
                except asyncio.TimeoutError:
                    continue
                if isinstance(data, bytes) and data[0] == 1:
                    messages.append(struct.unpack_from("<BIQ", data)[2])
                    if enough is not None and len(messages) >= enough[0]:
                        enough[1].set()
                elif isinstance(data, bytes) and data[0] == 2:
                    times.append(struct.unpack("<BQ", data)[1])

    asyncio.run(session())
    replaying.join(10)
    return messages, times


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("replay") / "drive.mcap"
    assert main(["simulate", "-o", str(path), "--duration", "3"]) == 0
    return path


@pytest.mark.slow
def test_a_drive_is_served_in_log_time_with_server_time(drive: Path) -> None:
    with ViewerServer(port=0, server_time=True) as server:
        started = time.monotonic()
        messages, times = watch(server, "/scene/ego", lambda: replay_mcap(
            drive, server, speed=1.5, start_s=1.0))
        took = time.monotonic() - started
    # what follows the subscription (a new client's adverts settle for up to 1 s)
    assert messages == sorted(messages) and len(messages) >= 5
    assert messages[0] - 1_767_268_800_000_000_000 >= 1.0 * NS  # --start 1
    assert times and times == sorted(times)  # the viewer follows log time
    assert 1.0 < took < 5 * timeout_scale()  # 2 s of drive at 1.5x


@pytest.mark.slow
def test_a_can_log_goes_through_the_pipeline(tmp_path: Path) -> None:
    log = tmp_path / "drive.blf"
    with can.Logger(log) as logger:
        for f in simulate(duration_s=1.5):
            logger.on_message_received(can.Message(
                timestamp=f.timestamp_ns / 1e9, arbitration_id=f.arbitration_id, data=f.data,
                is_fd=f.is_fd, dlc=f.dlc, channel=0))
    stages = load_stages([], "ecocar")
    with ViewerServer(port=0, server_time=True) as server:
        loops: list[int] = []

        def run() -> None:
            loops.append(replay_log([log], stages, server, speed=5.0, loop=True,
                                    stopping=stop).loops)

        stop = threading.Event()
        # 1.5 s of log makes at most 32 scenes (20 Hz, and one at the clock step back to the
        # start of the next pass): 40 of them come from two passes at least
        deadline = threading.Timer(60 * timeout_scale(), stop.set)  # a replay that never ends
        deadline.start()
        try:
            messages, _ = watch(server, "/scene/radar", run, enough=(40, stop))
        finally:
            deadline.cancel()
    assert len(messages) >= 40
    assert loops == [loops[0]] and loops[0] >= 2  # --loop started it again


def test_nonsense_speed_and_start_are_refused(drive: Path) -> None:
    with ViewerServer(port=0) as server:
        with pytest.raises(UsageError, match=r"--speed 0: must be above 0"):
            replay_mcap(drive, server, speed=0)
        with pytest.raises(UsageError, match=r"--start -1: must not be negative"):
            replay_mcap(drive, server, start_s=-1)


@pytest.mark.parametrize(("options", "says"), [
    (["--speed", "0"], "error: --speed 0: must be above 0"),
    (["--start", "-1"], "error: --start -1: must not be negative"),
    (["--start", "100"], "error: --start 100: the drive is only 3.0 s long")])
def test_nonsense_speed_and_start_are_refused_before_a_word_is_printed(
        capsys: pytest.CaptureFixture[str], drive: Path, options: list[str], says: str) -> None:
    """#33 item 12: replay printed the connection and the layout to import, then refused."""
    assert main(["replay", str(drive), "--port", "0", *options]) == 1
    out, err = capsys.readouterr()
    assert (out, err.strip()) == ("", says)


def test_a_scene_rate_out_of_range_is_one_line(capsys: pytest.CaptureFixture[str],
                                              tmp_path: Path) -> None:
    assert main(["convert", "--sample", "-o", str(tmp_path / "o.mcap"), "--scene-rate",
                 "80"]) == 1
    assert capsys.readouterr().err.strip() == (
        "error: --scene-rate 80: must be above 0 and at most 50 Hz")


def test_layouts_list_and_export(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["layouts"]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in ("tank-viz", "engineer", "can-debug", "bring-up"))
    assert main(["layouts", "--export", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.glob("*.json")) == [
        "bring-up.json", "can-debug.json", "engineer.json", "tank-viz.json"]
    assert main(["layouts", "--export", str(tmp_path)]) == 1  # no overwriting without --force
