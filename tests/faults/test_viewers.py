"""Viewers cannot hurt the live bridge, and a laptop can find it.

(issue #13, item 5.) A viewer that sends garbage — text that is not JSON, JSON that is not a
message, an op the server does not take, binary junk — gets a status message saying what was
wrong and leaves one line on the console, never a traceback; the drive, the recording and the
other viewers go on. A viewer that subscribed to everything and closes without reading what it
was sent is released at once (it was counted, and every channel kept wanted, for the 10 s of
websockets' close timeout). ``--host 0.0.0.0`` prints the machine's addresses, which a laptop
can use, rather than ``ws://0.0.0.0:…``.

The live case drives another car than ecocar: a Bosch radar (opendbc's tesla_radar_bosch.dbc
and tests/profiles/bosch_radar.toml).
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import cantools
import pytest
import websockets
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from harness import SUBPROTOCOL, Viewer, assert_survived, start

from bridge.frame import NS, Frame
from bridge.pb.can_frame_pb2 import CanFrame
from bridge.sinks.server import ViewerServer

try:
    from conftest import SHARED_DBC, timeout_scale
    from waiting import wait_for
except ImportError:  # in the car's process (livecar.py), which only reads the radar's DBC
    SHARED_DBC = Path(__file__).resolve().parents[3] / "shared" / "data" / "dbc"

PROFILE = Path(__file__).resolve().parents[1] / "profiles" / "bosch_radar.toml"
RADAR_DBC = SHARED_DBC / "tesla_radar_bosch.dbc"

#: What a confused or hostile viewer sends; each gets a status message and one console line.
GARBAGE: list[str | bytes] = [
    "this is not JSON {",
    "[1, 2, 3]",  # JSON, not a message
    '{"no": "op"}',
    '{"op": "fly"}',  # an op nobody knows
    '{"op": "advertise", "channels": [{"id": 1, "topic": "/x"}]}',  # input: the server takes none
    '{"op": "subscribe", "subscriptions": "everything"}',
    '{"op": "subscribe", "subscriptions": [{"id": "a"}]}',
    b"\x00",  # binary, too short for any op
    b"\x02\x00\x00",  # a service call cut short
    b"\x01\x05\x00\x00\x00payload",  # a message on a channel it never advertised
    b"\xff" * 32,  # an opcode nobody knows
]


def radar_drive(duration_s: float = 5.0, rate_hz: float = 100.0) -> Iterator[tuple[float, Any]]:
    """A Bosch radar car at 20 m/s with one valid object 30 m ahead, stamped with the wall
    clock."""
    db = cantools.database.load_file(RADAR_DBC)
    speed = db.get_message_by_name("Msg169_ESP_wheelSpeeds")
    point = db.get_message_by_name("RadarPoint0_A")
    now = time.time_ns()
    for i in range(round(duration_s * rate_hz)):
        at = i / rate_hz
        stamp = now + round(at * NS)
        for message, values in (
                (speed, {"ESP_wheelSpeedReL_HS": 72.0}),
                (point, {"LongDist": 30.0, "LatDist": 0.0, "ProbExist": 90.625, "Valid": 1})):
            signals = {s.name: values.get(s.name, 0) for s in message.signals}
            data = message.encode(signals, strict=False)
            yield at, Frame(stamp, "can0", message.frame_id, data, dlc=len(data))


async def send_garbage(url: str) -> tuple[list[dict[str, Any]], str, bytes]:
    """Send every piece of GARBAGE and wait for its status; then subscribe as a viewer does.
    The statuses, this viewer's address as the server sees it, and a message it then got."""
    wait = 10.0 * timeout_scale()
    statuses: list[dict[str, Any]] = []
    channels: dict[str, int] = {}
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL]) as ws:
        host, port = ws.local_address[:2]

        async def next_message() -> str | bytes:
            raw: str | bytes = await asyncio.wait_for(ws.recv(), wait)
            if isinstance(raw, str):
                message = json.loads(raw)
                if message["op"] == "status":
                    statuses.append(message)
                elif message["op"] == "advertise":
                    channels.update({c["topic"]: c["id"] for c in message["channels"]})
            return raw

        for piece in GARBAGE:
            before = len(statuses)
            await ws.send(piece)
            while len(statuses) == before:
                await next_message()
        # still a viewer like any other
        while "/scene/ego" not in channels:
            await next_message()
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 1, "channelId": channels["/scene/ego"]}]}))
        while True:
            raw = await next_message()
            if isinstance(raw, bytes) and raw[0] == 1:
                return statuses, f"{host}:{port}", raw


@pytest.mark.slow
def test_garbage_from_a_viewer_gets_a_status_and_one_line_and_everyone_goes_on(
        tmp_path: Path, shared_dbc: Path) -> None:
    """A laptop on the car's network (``--host 0.0.0.0``, the printed address) sends garbage
    while another watches the scene."""
    car = start(tmp_path, f"{__file__}:radar_drive", "--dbc", str(RADAR_DBC),
                "--profile", str(PROFILE), "--host", "0.0.0.0")
    (line,) = [line for _, line in car.lines if "Foxglove: open connection" in line]
    assert "0.0.0.0" not in line, line
    assert "this machine only" not in car.output
    viewer = Viewer(car.url)
    car.when("Ctrl+C")
    statuses, address, message = asyncio.run(send_garbage(car.url))
    fault_ended = time.time()
    assert_survived(car, viewer, fault_ended=fault_ended, on_log=None)

    assert len(statuses) == len(GARBAGE)
    for status in statuses:
        assert status["level"] in (1, 2) and status["message"], status  # warning or error
    assert "not JSON" in statuses[0]["message"]
    assert "fly" in statuses[3]["message"]
    assert message[1:5] == (1).to_bytes(4, "little")  # its subscription's message, after all
    said = [text for _, text in car.lines if address in text]
    assert len(said) == len(GARBAGE), "".join(said)  # one line each
    assert "Traceback" not in car.output


# --- a viewer that leaves without reading ---------------------------------------------------

def publish_until(server: ViewerServer, channels: list[int], stop: threading.Event) -> None:
    """A busy scene: 200 kB on every channel, 50 times a second, flushed as the pipeline does."""
    payload = b"x" * 200_000
    i = 0
    while not stop.is_set():
        for channel in channels:
            server.publish(channel, i, payload)
        server.flush()
        i += 1
        time.sleep(0.02)


@contextlib.contextmanager
def busy_server() -> Iterator[tuple[ViewerServer, list[int]]]:
    """A live server with two channels kept busy (:func:`publish_until`) while in the block."""
    with ViewerServer(port=0, queue_limit=100) as server:
        channels = [server.channel("/scene/radar", SceneUpdate),
                    server.channel("/can/radar/frames", CanFrame)]
        stop = threading.Event()
        publisher = threading.Thread(target=publish_until, args=(server, channels, stop))
        publisher.start()
        try:
            yield server, channels
        finally:
            stop.set()
            publisher.join()


@pytest.mark.slow
@pytest.mark.parametrize("leaving", ["close", "abort"])
def test_a_viewer_that_leaves_without_reading_is_released_at_once(leaving: str) -> None:
    """It subscribed to everything, stopped reading (its buffers filled up) and left: with a
    closing handshake (``close``: which the server cannot answer behind the megabytes the viewer
    never read) or by dropping the connection (``abort``). The server forgets it at once: no
    longer counted, nothing kept wanted for it."""
    with busy_server() as (server, channels):
        released = asyncio.run(leave_without_reading(server, channels, leaving))
    assert released < 2.0 * timeout_scale(), f"released after {released:.1f} s"


async def leave_without_reading(server: ViewerServer, channels: list[int], leaving: str) -> float:
    """Seconds from the viewer's leaving until the server no longer counts it."""
    ws = await websockets.connect(server.url, subprotocols=[SUBPROTOCOL], max_size=None,
                                  max_queue=1, close_timeout=30.0)
    advertised: list[int] = []
    while len(advertised) < len(channels):
        raw = await asyncio.wait_for(ws.recv(), 10.0 * timeout_scale())
        if isinstance(raw, str) and json.loads(raw)["op"] == "advertise":
            advertised += [c["id"] for c in json.loads(raw)["channels"]]
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": c} for i, c in enumerate(advertised)]}))
    ws.transport.pause_reading()  # from now on it reads nothing at all
    assert await asyncio.to_thread(wait_for, lambda: all(map(server.wanted, channels)),
                                   10.0 * timeout_scale())
    # its buffers are full: the server has dropped messages for it
    assert await asyncio.to_thread(
        wait_for, lambda: any(s.dropped for s in server.client_stats()), 10.0 * timeout_scale())
    left = time.monotonic()
    closing = asyncio.ensure_future(ws.close()) if leaving == "close" else None
    if leaving == "abort":
        ws.transport.abort()
    released = await asyncio.to_thread(
        wait_for, lambda: server.viewers() == 0 and not any(map(server.wanted, channels)),
        15.0 * timeout_scale())
    took = time.monotonic() - left
    assert released, "still counted"
    if closing is not None:
        ws.transport.abort()  # the viewer gives up too, rather than after its close_timeout
        await asyncio.wait_for(closing, 10.0 * timeout_scale())
    return took


@pytest.mark.slow
def test_a_stalled_viewer_that_pings_stays_and_nothing_is_logged(
        caplog: pytest.LogCaptureFixture) -> None:
    """Python's websockets pings every 20 s: the pong to a viewer that has stopped reading used
    to wait for its full socket beside the server's own sender, which websockets does not allow
    ("data transfer failed", a traceback, and the viewer thrown out)."""
    with busy_server() as (server, channels):
        asyncio.run(ping_without_reading(server, channels))
    errors = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert not errors, [r.getMessage() for r in errors]


async def ping_without_reading(server: ViewerServer, channels: list[int]) -> None:
    ws = await websockets.connect(server.url, subprotocols=[SUBPROTOCOL], max_size=None,
                                  max_queue=1, ping_interval=None)
    advertised: list[int] = []
    while len(advertised) < len(channels):
        raw = await asyncio.wait_for(ws.recv(), 10.0 * timeout_scale())
        if isinstance(raw, str) and json.loads(raw)["op"] == "advertise":
            advertised += [c["id"] for c in json.loads(raw)["channels"]]
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": c} for i, c in enumerate(advertised)]}))
    ws.transport.pause_reading()
    assert await asyncio.to_thread(
        wait_for, lambda: any(s.dropped for s in server.client_stats()), 10.0 * timeout_scale())
    for _ in range(3):
        await ws.ping()
    # the server reads in order: once this is done, so were the pings
    await ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [0]}))
    assert await asyncio.to_thread(wait_for, lambda: not server.wanted(channels[0]),
                                   10.0 * timeout_scale())
    assert server.viewers() == 1 and server.wanted(channels[1])
    ws.transport.abort()


# --- the URL to open ------------------------------------------------------------------------

def test_serving_every_address_prints_the_machines_addresses() -> None:
    """``--host 0.0.0.0``: ws://0.0.0.0 means nothing to a laptop. The server names each of the
    machine's own IPv4 addresses (not loopback) it can be reached on, and each one works."""
    with ViewerServer(host="0.0.0.0", port=0) as server:
        urls = server.urls
        if urls == [f"ws://localhost:{server.port}"]:
            pytest.skip("this machine has no network address but loopback")
        assert server.url == urls[0]
        for url in urls:
            parts = urlsplit(url)
            assert parts.scheme == "ws" and parts.port == server.port, url
            address = ipaddress.ip_address(parts.hostname or "")
            assert address.version == 4 and not address.is_loopback, url
            assert not address.is_unspecified, url
            assert asyncio.run(server_name(url)) == "tankviz"


def test_a_loopback_server_is_on_localhost() -> None:
    with ViewerServer(port=0) as server:
        assert server.urls == [f"ws://localhost:{server.port}"] == [server.url]


async def server_name(url: str) -> str:
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL]) as ws:
        while True:
            raw = await asyncio.wait_for(ws.recv(), 10.0 * timeout_scale())
            if isinstance(raw, str) and json.loads(raw)["op"] == "serverInfo":
                name: str = json.loads(raw)["name"]
                return name

