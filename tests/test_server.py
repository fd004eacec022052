"""The live server speaks foxglove.websocket.v1 to a real client, and a stalled client hurts
nobody else."""

from __future__ import annotations

import asyncio
import base64
import dataclasses
import inspect
import json
import socket
import struct
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from types import SimpleNamespace
from typing import Any

import pytest
import websockets
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from waiting import wait_for
from websockets.frames import Frame, Opcode
from websockets.streams import StreamReader

from bridge.pb.can_frame_pb2 import CanFrame
from bridge.sinks.server import SEND_BUFFER_BYTES, ClientStats, ServerError, ViewerServer, internals
from bridge.sinks.server.client import ClientQueue

SUBPROTOCOL = websockets.Subprotocol("foxglove.websocket.v1")


@asynccontextmanager
async def client(server: ViewerServer, **kwargs: Any) -> AsyncIterator[Any]:
    async with websockets.connect(server.url, subprotocols=[SUBPROTOCOL], **kwargs) as ws:
        yield ws


async def next_json(ws: Any, op: str, timeout: float = 5.0) -> dict[str, Any]:
    """The next JSON message with ``op`` (skipping others)."""
    while True:
        raw = await asyncio.wait_for(ws.recv(), timeout)
        if isinstance(raw, str):
            message: dict[str, Any] = json.loads(raw)
            if message["op"] == op:
                return message


async def next_binary(ws: Any, timeout: float = 5.0) -> bytes:
    while True:
        raw = await asyncio.wait_for(ws.recv(), timeout)
        if isinstance(raw, bytes):
            return raw


def decoder_for(channel: dict[str, Any]) -> Any:
    """Build the message class from an advertised channel, as a Foxglove viewer does."""
    assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


def test_the_protocol_from_hello_to_unsubscribe() -> None:
    with ViewerServer(port=0) as server:
        scene = server.channel("/scene/ego", SceneUpdate)
        frames = server.channel("/can/can0/frames", CanFrame)

        async def session() -> None:
            async with client(server) as ws:
                assert ws.subprotocol == "foxglove.websocket.v1"
                info = await next_json(ws, "serverInfo")
                assert info["name"] == "tankviz"
                assert info["sessionId"] == server.session_id
                advertised = await next_json(ws, "advertise")
                channels = {c["topic"]: c for c in advertised["channels"]}
                assert set(channels) == {"/scene/ego", "/can/can0/frames"}
                scene_class = decoder_for(channels["/scene/ego"])
                assert not server.wanted(scene)

                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 7, "channelId": channels["/scene/ego"]["id"]}]}))
                assert await asyncio.to_thread(wait_for, lambda: server.wanted(scene))
                server.publish(frames, 1, b"nobody subscribed to this")
                update = SceneUpdate()
                update.entities.add(id="ego", frame_id="vehicle")
                server.publish(scene, 1_700_000_000_123_456_789, update.SerializeToString())

                data = await next_binary(ws)
                opcode, subscription, stamp = struct.unpack_from("<BIQ", data)
                assert (opcode, subscription, stamp) == (1, 7, 1_700_000_000_123_456_789)
                decoded = scene_class.FromString(data[13:])
                assert [e.id for e in decoded.entities] == ["ego"]

                await ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [7]}))
                assert await asyncio.to_thread(wait_for, lambda: not server.wanted(scene))

        asyncio.run(session())


def test_messages_leave_at_once_without_nagle() -> None:
    """With Nagle's algorithm on, the end of a scene waited for the viewer's delayed ACK and
    came with the next scene (a scene period late): the server's sockets set TCP_NODELAY."""
    with ViewerServer(port=0) as server:

        def connections() -> list[Any]:
            return list(server._server._clients) if server._server is not None else []

        async def session() -> list[int]:
            async with client(server) as ws:
                await next_json(ws, "serverInfo")
                assert await asyncio.to_thread(wait_for, lambda: len(connections()) == 1)
                return [state.connection.transport.get_extra_info("socket").getsockopt(
                    socket.IPPROTO_TCP, socket.TCP_NODELAY) for state in connections()]

        assert asyncio.run(session()) == [1]


def test_a_viewers_kernel_send_buffer_is_bounded() -> None:
    """A viewer that stops reading is seen to stall after SEND_BUFFER_BYTES, not after the
    4 MB Linux lets a send buffer grow to (tens of thousands of messages written for nobody)."""
    with ViewerServer(port=0) as server:

        async def session() -> list[int]:
            async with client(server) as ws:
                await next_json(ws, "serverInfo")
                assert await asyncio.to_thread(wait_for, lambda: bool(server._server._clients))
                return [state.connection.transport.get_extra_info("socket").getsockopt(
                    socket.SOL_SOCKET, socket.SO_SNDBUF) for state in server._server._clients]

        (size,) = asyncio.run(session())
        assert size <= 2 * SEND_BUFFER_BYTES  # (the kernel doubles it for its bookkeeping)


def test_a_flush_sends_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Publishers flush (after a scene, before they wait): what they published leaves at once,
    not at the next DRAIN_INTERVAL_S (the safety net for what nobody flushed, which the protocol
    test above relies on)."""
    # no safety net:
    monkeypatch.setattr("bridge.sinks.server.viewer_server.DRAIN_INTERVAL_S", 3600.0)
    with ViewerServer(port=0) as server:
        scene = server.channel("/scene/ego", SceneUpdate)

        async def session() -> tuple[int, int]:
            async with client(server) as ws:
                channel = (await next_json(ws, "advertise"))["channels"][0]["id"]
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 1, "channelId": channel}]}))
                assert await asyncio.to_thread(wait_for, lambda: server.wanted(scene))
                server.publish(scene, 1, b"")
                server.publish(scene, 2, b"")
                server.flush()
                first = struct.unpack_from("<BIQ", await next_binary(ws))[2]
                second = struct.unpack_from("<BIQ", await next_binary(ws))[2]
                return first, second

        assert asyncio.run(session()) == (1, 2)


@pytest.mark.slow
def test_a_channel_added_later_is_advertised_to_connected_clients() -> None:
    with ViewerServer(port=0) as server:

        async def session() -> None:
            async with client(server) as ws:
                await next_json(ws, "serverInfo")  # (no advertise: there is no channel yet)
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": []}))
                server.channel("/scene/lanes", SceneUpdate)
                late = await next_json(ws, "advertise")
                assert [c["topic"] for c in late["channels"]] == ["/scene/lanes"]

        asyncio.run(session())


def test_server_time_for_replays() -> None:
    with ViewerServer(port=0, server_time=True) as server:
        server.broadcast_time(41_000_000_000)
        scene = server.channel("/scene/ego", SceneUpdate)

        async def session() -> None:
            async with client(server) as ws:
                info = await next_json(ws, "serverInfo")
                assert "time" in info["capabilities"]
                await next_json(ws, "advertise")
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 1, "channelId": scene}]}))
                await asyncio.to_thread(wait_for, lambda: server.wanted(scene))
                server.broadcast_time(42_000_000_000)
                data = await next_binary(ws)
                assert struct.unpack("<BQ", data) == (2, 42_000_000_000)

        asyncio.run(session())


@pytest.mark.slow
def test_a_viewer_hears_the_time_before_the_first_channel() -> None:
    """Foxglove Studio takes its clock when the first channels come as the start of the
    timeline, zero without a time: a replay advertising its channels before its first frame made
    a drive on a since-boot clock start at 0 and last 12 hours (#33). A server that publishes
    its time advertises no channel before its first time."""
    with ViewerServer(port=0, server_time=True) as server:

        async def session() -> list[str | bytes]:
            async with client(server) as ws:
                await next_json(ws, "serverInfo")
                server.channel("/scene/ego", SceneUpdate)  # the pipeline's, advertised early
                server.broadcast_time(46_411_900_000_000)  # then the first frame's time
                return [await asyncio.wait_for(ws.recv(), 5.0) for _ in range(2)]

        first, second = asyncio.run(session())
        assert isinstance(first, bytes) and struct.unpack("<BQ", first) == (2, 46_411_900_000_000)
        assert isinstance(second, str) and json.loads(second)["op"] == "advertise"


def test_every_start_is_a_new_session() -> None:
    with ViewerServer(port=0) as a, ViewerServer(port=0) as b:
        assert a.session_id != b.session_id
        assert a.port != b.port != 0


def test_a_taken_port_is_a_clear_error() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ServerError, match=rf"cannot serve on 127\.0\.0\.1:{port}: "):
            ViewerServer(port=port).start()


@pytest.mark.slow
def test_a_stalled_client_loses_its_own_oldest_messages_and_nobody_waits() -> None:
    """One client never reads; another keeps receiving every message at the scene rate."""
    rate, seconds = 50, 3.0
    payload = b"x" * 200_000  # a big scene: the stalled client's buffers fill within a second
    with ViewerServer(port=0, queue_limit=100) as server:
        scene = server.channel("/scene/radar", SceneUpdate)

        async def session() -> tuple[list[int], float]:
            stalled = await websockets.connect(server.url, subprotocols=[SUBPROTOCOL],
                                               max_size=None, max_queue=1)
            await next_json(stalled, "serverInfo")
            await next_json(stalled, "advertise")
            await stalled.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": scene}]}))
            stalled.transport.pause_reading()  # from now on it reads nothing at all
            received: list[int] = []
            async with client(server, max_size=None) as reader:
                await next_json(reader, "advertise")
                await reader.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 2, "channelId": scene}]}))
                await asyncio.to_thread(wait_for, lambda: server.subscribers(scene) == 2)
                worst_publish = 0.0
                started = time.monotonic()
                for i in range(int(rate * seconds)):
                    t0 = time.perf_counter()
                    server.publish(scene, i, payload)
                    worst_publish = max(worst_publish, time.perf_counter() - t0)
                    # As the pipeline does after each scene: sent now, not at the drain timer's
                    # next turn (which would pace the test at 10 messages a second, not 50).
                    server.flush()
                    data = await next_binary(reader, timeout=1.0)
                    received.append(struct.unpack_from("<BIQ", data)[2])
                    await asyncio.sleep(max(0.0, started + (i + 1) / rate - time.monotonic()))
            stalled.transport.abort()
            return received, worst_publish

        received, worst_publish = asyncio.run(session())
        assert received == list(range(int(rate * seconds)))  # nothing lost, in order
        assert worst_publish < 0.05  # publish never waits for a client
        assert wait_for(lambda: any(s.dropped > 0 for s in server.client_stats()))
        stalled_stats = max(server.client_stats(), key=lambda s: s.dropped)
        assert stalled_stats.dropped > 0 and stalled_stats.sent < rate * seconds


def test_a_full_queue_drops_its_oldest_and_counts_them() -> None:
    viewer = ClientQueue(SimpleNamespace(subscriptions_by_channel={3: 1}), ClientStats("viewer"),
                     limit=3)
    viewer.put([(3, 0, b"a"), (3, 1, b"b")])
    assert viewer.stats.dropped == 0
    viewer.put([(3, t, b"c") for t in range(2, 6)])
    assert [t for _, t, _ in viewer.queue] == [3, 4, 5]  # the newest three
    assert viewer.stats.dropped == 3 and viewer.ready.is_set()
    assert viewer.stats.channels == {3: 3}


def test_a_message_queued_before_an_unsubscribe_is_not_sent() -> None:
    """A viewer that unsubscribed gets nothing more of that channel, even what was queued."""
    state = SimpleNamespace(subscriptions_by_channel={3: 1, 4: 2},
                            connection=SimpleNamespace(extensions=[]))
    queued = ClientQueue(state, ClientStats("viewer"), limit=10)
    for t in range(3):
        queued.put([(3, t, b"radar"), (4, t, b"lanes")])
    # foxglove-websocket swaps in a new mapping at every (un)subscribe
    state.subscriptions_by_channel = {4: 2}
    chunks, count = queued._next_frames(limit=64)
    frames = websocket_frames(b"".join(chunks))
    assert count == len(frames) == 3
    headers = [struct.unpack_from("<BIQ", f.data) for f in frames]
    assert headers == [(1, 2, 0), (1, 2, 1), (1, 2, 2)]  # subscription 2 only, in order
    assert all(f.data.endswith(b"lanes") for f in frames) and not queued.queue


def websocket_frames(data: bytes) -> list[Frame]:
    """The WebSocket frames a server wrote, as websockets' own parser reads them."""
    reader = StreamReader()
    reader.feed_data(data)
    frames = []
    while reader.buffer:  # (every byte is there: each parse ends without asking for more)
        with pytest.raises(StopIteration) as done:
            next(Frame.parse(reader.read_exact, mask=False))
        frames.append(done.value.value)
    return frames


@pytest.mark.parametrize("length", [0, 1, 125, 126, 127, 65535, 65536, 70000])
def test_a_binary_message_is_framed_as_websockets_frames_it(length: int) -> None:
    """The server frames its binary messages itself (internals.binary_header): the bytes
    websockets' Frame.serialize writes, which its parser reads back."""
    payload = bytes(range(256)) * (length // 256) + bytes(length % 256)
    framed = internals.binary_header(length) + payload
    assert framed == Frame(Opcode.BINARY, payload).serialize(mask=False, extensions=[])
    assert websocket_frames(framed)[0].data == payload


def test_messages_on_a_connection_with_an_extension_are_framed_by_websockets() -> None:
    """Only a plain connection's messages are framed by hand; with an extension (never
    offered, but the code does not assume it) websockets frames them."""
    class Mark:
        def encode(self, frame: Frame) -> Frame:
            return dataclasses.replace(frame, data=b"!" + frame.data)

    state = SimpleNamespace(subscriptions_by_channel={3: 1},
                            connection=SimpleNamespace(extensions=[Mark()]))
    queued = ClientQueue(state, ClientStats("viewer"), limit=10)
    queued.put([(3, 7, b"radar")])
    chunks, count = queued._next_frames(limit=64)
    assert count == 1
    assert websocket_frames(b"".join(chunks))[0].data == (
        b"!" + struct.pack("<BIQ", 1, 1, 7) + b"radar")


def test_an_idle_viewer_gets_its_messages_at_once_unless_its_socket_is_full() -> None:
    """write_now sends without another turn of the loop, but leaves a backed-up viewer to its
    sender task and websockets' flow control."""
    written: list[bytes] = []
    buffered = [0]
    transport = SimpleNamespace(write=written.append, get_write_buffer_size=lambda: buffered[0])
    connection = SimpleNamespace(open=True, transport=transport, extensions=[])
    viewer = ClientQueue(SimpleNamespace(connection=connection, subscriptions_by_channel={3: 1}),
                     ClientStats("viewer"), limit=10)
    viewer.idle = True
    buffered[0] = 2**16  # the socket holds 64 KiB not yet sent: the viewer is behind
    viewer.put([(3, 0, b"scene")])
    viewer.write_now()
    assert written == [] and len(viewer.queue) == 1 and viewer.ready.is_set()
    buffered[0] = 0
    viewer.write_now()
    assert len(written) == 1 and written[0].endswith(b"scene") and not viewer.queue
    assert viewer.stats.sent == 1 and not viewer.ready.is_set()


def test_as_a_sink_the_server_sends_a_scene_at_once_and_frames_to_subscribers_only(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The pipeline's messages of a tick leave at once (the server flushes them); raw frames
    go only to who subscribed to their bus; what the pipeline advertises is advertised once."""
    from bridge.frame import Frame
    from bridge.sinks.base import Channel, Serialized
    from bridge.sinks.raw import cut

    # no safety net:
    monkeypatch.setattr("bridge.sinks.server.viewer_server.DRAIN_INTERVAL_S", 3600.0)
    frame = Frame(5, "radar", 0x100, b"\x01", dlc=1)
    with ViewerServer(port=0) as server:
        server.advertise([Channel("/scene/ego", "foxglove.SceneUpdate", lambda: b""),
                          Channel("/can/radar/frames", "tankviz.CanFrameBlock", lambda: b"")])
        server.advertise([Channel("/scene/ego", "foxglove.SceneUpdate", lambda: b"")])

        async def session() -> tuple[list[str], list[int]]:
            async with client(server) as ws:
                channels = (await next_json(ws, "advertise"))["channels"]
                ids = {c["topic"]: c["id"] for c in channels}
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 1, "channelId": ids["/scene/ego"]}]}))
                assert await asyncio.to_thread(wait_for,
                                               lambda: server.wanted(ids["/scene/ego"]))
                server.on_raw(cut([frame]))  # nobody subscribed to the radar's frames
                server.on_messages([Serialized("/scene/ego", SceneUpdate, b"", 7),
                                    Serialized("/scene/ego", SceneUpdate, b"", 8)])
                times = [struct.unpack_from("<BIQ", await next_binary(ws))[2] for _ in "ab"]
                return [c["topic"] for c in channels], times

        topics, times = asyncio.run(session())
    assert sorted(topics) == ["/can/radar/frames", "/scene/ego"]
    assert times == [7, 8]


@pytest.mark.parametrize("mode", ["live", "replay"])
def test_server_info_says_whether_it_is_live_or_a_replay(mode: str) -> None:
    with ViewerServer(port=0, mode=mode) as server:
        async def hello() -> dict[str, Any]:
            async with client(server) as ws:
                info: dict[str, Any] = await next_json(ws, "serverInfo")
                return info

        assert asyncio.run(hello())["metadata"] == {"tankviz": mode}



# --- the fence: the library internals bridge.sinks.server.internals relies on -----------------

def test_foxglove_websocket_is_a_release_the_fence_was_checked_against() -> None:
    """A new foxglove-websocket release fails here: run the tests below against it, then widen
    FOXGLOVE_WEBSOCKET (bridge/fences.py) and pyproject's bound."""
    from bridge.fences import FOXGLOVE_WEBSOCKET, WEBSOCKETS

    assert FOXGLOVE_WEBSOCKET.unknown() is None, FOXGLOVE_WEBSOCKET.unknown()
    assert WEBSOCKETS.unknown() is None, WEBSOCKETS.unknown()


def parameters(function: Any) -> list[str]:
    return list(inspect.signature(function).parameters)


def test_the_private_foxglove_websocket_methods_the_server_overrides_or_calls_are_unchanged(
        ) -> None:
    from foxglove_websocket.server import FoxgloveServer
    from foxglove_websocket.server.client_state import ClientState

    expected = {  # name: parameters (all coroutines)
        "_handle_raw_client_message": ["self", "client", "raw_message"],  # overridden
        "_handle_client_text_message": ["self", "client", "message"],  # called with what passed
        "_send_json": ["self", "connection", "msg"],  # overridden: replies never wait
        "_send_status": ["self", "connection", "level", "msg", "id"],  # called: refusals
    }
    for name, names in expected.items():
        method = getattr(FoxgloveServer, name)
        assert inspect.iscoroutinefunction(method), name
        assert parameters(method) == names, name
    # read (the connected clients) and written (the channels they may subscribe to)
    assert {"_clients", "_channels"} <= set(FoxgloveServer.__annotations__)
    assert {"connection", "subscriptions_by_channel"} <= {
        f.name for f in dataclasses.fields(ClientState)}

    async def made() -> tuple[Any, Any]:
        server = FoxgloveServer(None, None, "fence")
        return server._clients, server._channels

    clients, channels = asyncio.run(made())
    assert clients == () and channels == {}


def test_the_private_websockets_legacy_methods_the_connection_uses_are_unchanged() -> None:
    from websockets.legacy.framing import prepare_ctrl
    from websockets.legacy.server import WebSocketServerProtocol

    assert parameters(WebSocketServerProtocol.write_close_frame) == ["self", "close", "data"]
    assert parameters(WebSocketServerProtocol.pong) == ["self", "data"]
    assert parameters(WebSocketServerProtocol.write_frame_sync) == [
        "self", "fin", "opcode", "data"]
    assert parameters(prepare_ctrl) == ["data"]
    assert parameters(WebSocketServerProtocol.ensure_open) == ["self"]
    assert parameters(WebSocketServerProtocol.drain) == ["self"]
    for name in ("write_close_frame", "pong", "ensure_open", "drain"):
        assert inspect.iscoroutinefunction(getattr(WebSocketServerProtocol, name)), name
    assert isinstance(WebSocketServerProtocol.open, property)

    async def made() -> Any:
        return WebSocketServerProtocol(lambda *_: None, None)  # (transport: once connected)

    protocol = asyncio.run(made())
    assert protocol.close_rcvd is None and protocol.extensions == []


def test_the_message_headers_are_the_librarys() -> None:
    """The server packs its messages with foxglove-websocket's own headers and opcodes."""
    from foxglove_websocket.server import MessageDataHeader, TimeDataHeader
    from foxglove_websocket.types import BinaryOpcode

    assert MessageDataHeader.format == "<BIQ" and TimeDataHeader.format == "<BQ"
    assert (BinaryOpcode.MESSAGE_DATA, BinaryOpcode.TIME) == (1, 2)


def test_what_is_published_between_scenes_waits_for_the_next_flush_but_not_long(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Live's raw frames and signals go with the next scene (flush_batched wakes the loop only
    if it was not woken within BATCH_S), and still leave at most BATCH_S after the last wake;
    a scene (flush) wakes it at once."""
    from bridge.sinks.server import viewer_server
    from bridge.sinks.server.viewer_server import BATCH_S

    now = [1000.0]
    monkeypatch.setattr(viewer_server, "time", SimpleNamespace(monotonic=lambda: now[0]))
    with ViewerServer(port=0) as server:
        channel = server.channel("/can/can0/frames", CanFrame)
        server._wanted.add(channel)  # (as a subscriber would)
        wakes: list[float] = []
        wake = server._wake

        def counted() -> None:
            wakes.append(now[0])
            wake()

        monkeypatch.setattr(server, "_wake", counted)
        server.flush_batched()
        assert wakes == []  # nothing published: nothing to send
        server.publish(channel, 1, b"frames")
        server.flush()  # a scene: at once
        assert len(wakes) == 1
        now[0] += BATCH_S / 2
        server.publish(channel, 2, b"frames")
        server.flush_batched()  # just after a scene: with the next one
        assert len(wakes) == 1
        now[0] += BATCH_S  # no scene for BATCH_S: now
        server.flush_batched()
        assert len(wakes) == 2
