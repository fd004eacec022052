"""The live sink: a Foxglove WebSocket server (foxglove-websocket, ``foxglove.websocket.v1``).

The server runs its asyncio loop in its own thread. The pipeline hands it messages with
:meth:`LiveServer.publish`, which never blocks and costs next to nothing: it appends to an inbox
that the loop empties at once after :meth:`LiveServer.flush` (the pipeline flushes after each
scene and each read of the buses, replay before it waits), and at least every
:data:`DRAIN_INTERVAL_S`. Waking the loop for every message would cost a system call each and
hand the GIL back and forth thousands of times a second; waking it on a short timer costs
hundreds of idle wake-ups a second.

foxglove-websocket sends to its clients one after another and awaits each, so a stalled client
would hold up everyone; instead every client gets its own bounded queue and sender task here. A
slow or stalled client loses its own oldest messages (counted in :attr:`ClientStats.dropped`),
never anyone else's, and never delays the pipeline or the recorder.

Channels carry protobuf (schemas as base64 FileDescriptorSets). A channel is advertised to every
client but its messages go only to the clients that subscribed; :meth:`LiveServer.wanted` tells
the pipeline whether anyone subscribed, so it can skip work nobody looks at. The protocol has no
authentication: bind to 127.0.0.1 (the default) unless the network is trusted. Bound to every
address (``0.0.0.0``, ``::``), :attr:`LiveServer.urls` names the machine's own addresses (see
:func:`machine_addresses`), which a laptop on the car's network can open.

A viewer sends only ``subscribe`` and ``unsubscribe`` (the server advertises no capability that
takes input). Anything else — text that is not JSON, JSON that is not such a message, another
op, any binary message — is checked by :func:`client_message` before foxglove-websocket sees it:
the viewer gets the protocol's ``status`` message (level error) saying what was wrong, the
console one line (logger ``tankviz.server``, warning, no traceback; at most
:data:`REFUSALS_LOGGED` per viewer), and nothing else happens. Replies to a viewer are written
without waiting for it (never more than :data:`_REPLY_LIMIT_BYTES` behind).

A viewer that closes the connection while it still has not read what was sent to it (its socket
buffers are full) is dropped at once: the echo of its close frame could only reach it behind all
that, so the connection is aborted instead of waiting for websockets' close timeout (10 s by
default; :data:`CLOSE_TIMEOUT_S` here). It is then no longer counted (:meth:`LiveServer.viewers`)
and its subscriptions no longer keep channels wanted.
"""

from __future__ import annotations

import asyncio
import base64
import collections
import contextlib
import ipaddress
import itertools
import json
import logging
import socket
import struct
import threading
import time
import uuid
import weakref
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from foxglove_websocket.server import FoxgloveServer, FoxgloveServerListener
from foxglove_websocket.types import ChannelId, StatusLevel
from mcap_protobuf.schema import build_file_descriptor_set
from websockets.exceptions import ConnectionClosed
from websockets.frames import Frame as WebSocketFrame
from websockets.frames import Opcode
from websockets.legacy.framing import prepare_ctrl
from websockets.legacy.server import WebSocketServerProtocol
from websockets.typing import DataLike

from bridge.decode.decoder import Decoded, MessageCodec
from bridge.errors import BridgeError
from bridge.frame import Frame
from bridge.pb.can_frame_pb2 import CanFrame
from bridge.sinks.base import Channel, Serialized, Sink
from bridge.topics import frames_topic

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
#: Messages waiting per client before its oldest are dropped (about 2 s of a busy scene).
DEFAULT_QUEUE_LIMIT = 2000
#: How often the loop takes in published messages without being asked to (s): a safety net,
#: publishers flush.
DRAIN_INTERVAL_S = 0.1
#: How long the server waits for a viewer's part of a closing handshake (s; websockets: 10).
CLOSE_TIMEOUT_S = 1.0
#: Console lines for one viewer's refused messages; it gets a status for every one.
REFUSALS_LOGGED = 20

_MESSAGE_DATA = 0x01
_TIME = 0x02

log = logging.getLogger("tankviz.server")


class ServerError(BridgeError):
    """The server could not start (e.g. the port is taken)."""


class ViewerInputError(BridgeError):
    """A message from a viewer that the server does not take (the reason, in one line)."""


@dataclass
class ClientStats:
    """What one client was sent and what it lost (how many messages of which topics)."""

    address: str
    sent: int = 0
    dropped: int = 0
    #: messages lost per topic (filled in by :meth:`LiveServer.client_stats`)
    topics: collections.Counter[str] = field(default_factory=collections.Counter)
    #: messages lost per channel id
    channels: collections.Counter[int] = field(default_factory=collections.Counter)

    def lost(self, items: Iterable[tuple[Any, ...]]) -> None:
        """Queued ``(channel, time, payload)`` items that were dropped."""
        for item in items:
            self.channels[item[0]] += 1
            self.dropped += 1


@dataclass
class _Client:
    """Our side of one connection: its bounded queue and its sender task.

    The queue holds the pipeline's own ``(channel, time, payload)`` items, shared by every client;
    the message header (this client's subscription id) is made when the message is sent, so a
    message that is dropped costs next to nothing.
    """

    state: Any  # foxglove_websocket's ClientState: .connection, .subscriptions_by_channel
    stats: ClientStats
    limit: int
    queue: collections.deque[tuple[Any, ...]] = field(init=False)
    control: collections.deque[Any] = field(default_factory=collections.deque)
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = None
    idle: bool = False  # the sender task waits for messages (past the handshake)

    def __post_init__(self) -> None:
        self.queue = collections.deque(maxlen=self.limit)  # a full one drops its oldest

    def put(self, items: list[tuple[Any, ...]]) -> None:
        """Queue messages; a full queue drops its oldest (counted)."""
        queue = self.queue
        before = len(queue)
        excess = before + len(items) - self.limit
        if excess > 0:
            self.stats.lost(itertools.chain(itertools.islice(queue, min(excess, before)),
                                            items[:max(0, excess - before)]))
        queue.extend(items)
        self.ready.set()

    def put_control(self, frame: Any) -> None:
        self.control.append(frame)
        self.ready.set()

    async def run(self) -> None:
        state = self.state
        connection = state.connection
        # foxglove-websocket sends serverInfo and the channel list when a client connects; hold
        # our own control messages until that handshake is surely done (the client subscribed,
        # or a second passed). Data only flows after a subscription anyway.
        loop = asyncio.get_running_loop()
        settled = loop.time() + 1.0
        while not state.subscriptions_by_channel and loop.time() < settled:
            await asyncio.sleep(0.02)
        control, queue = self.control, self.queue
        try:
            while True:
                self.idle = True
                await self.ready.wait()
                self.idle = False
                self.ready.clear()
                while control or queue:
                    await connection.ensure_open()
                    self._write(self._next_frames(_FAIR_SHARE))
                    await connection.drain()  # websockets' flow control
                    # Let the loop take in new messages and serve the other clients.
                    await asyncio.sleep(0)
        except Exception:  # the connection closed; foxglove-websocket forgets the client
            return
        finally:
            self.idle = False

    def write_now(self) -> None:
        """Send what is queued in this turn of the loop, while the socket takes it at once.

        A scene reaches an idle client without waiting for its sender task's turn: every turn
        of the loop is a trip through the selector, which gives up the GIL, and getting it back
        from a busy pipeline can take a switch interval (5 ms). A client that is behind (its
        socket buffer full) is left to its sender task and websockets' flow control.
        """
        if not self.idle:
            return
        connection = self.state.connection
        while ((self.control or self.queue) and connection.open
               and connection.transport.get_write_buffer_size() < _WRITE_NOW_BYTES):
            self._write(self._next_frames(_FAIR_SHARE))
        if not self.control and not self.queue:
            self.ready.clear()  # nothing left for the sender task

    def _write(self, frames: list[WebSocketFrame]) -> None:
        """Several messages, one write: each still its own WebSocket message, framed by
        websockets itself."""
        if frames:
            connection = self.state.connection
            connection.transport.write(b"".join(
                frame.serialize(mask=False, extensions=connection.extensions)
                for frame in frames))
            self.stats.sent += len(frames)

    def _next_frames(self, limit: int) -> list[WebSocketFrame]:
        """Up to ``limit`` queued messages as WebSocket frames, control messages first."""
        frames: list[WebSocketFrame] = []
        control, queue = self.control, self.queue
        # (a new mapping at every (un)subscribe: read it now)
        subscriptions = self.state.subscriptions_by_channel
        while len(frames) < limit and (control or queue):
            if control:
                data = control.popleft()
                frames.append(WebSocketFrame(Opcode.TEXT, data.encode()) if isinstance(data, str)
                              else WebSocketFrame(Opcode.BINARY, data))
                continue
            channel_id, t_ns, payload = queue.popleft()
            subscription = subscriptions.get(channel_id)
            if subscription is not None:  # else unsubscribed since
                frames.append(WebSocketFrame(Opcode.BINARY, _HEADER.pack(
                    _MESSAGE_DATA, subscription, t_ns) + payload))
        return frames


class _Subscriptions(FoxgloveServerListener):  # type: ignore[misc]
    """Keeps the set of channels anyone subscribed to (first subscribe, last unsubscribe)."""

    def __init__(self, wanted: set[int]) -> None:
        self.wanted = wanted

    def on_subscribe(self, server: FoxgloveServer, channel_id: ChannelId) -> None:
        self.wanted.add(channel_id)

    def on_unsubscribe(self, server: FoxgloveServer, channel_id: ChannelId) -> None:
        self.wanted.discard(channel_id)


#: The ops a viewer may send (the server advertises no capability that takes more).
CLIENT_OPS = ("subscribe", "unsubscribe")


def client_message(raw: str | bytes) -> dict[str, Any]:
    """A viewer's message as a JSON object the server takes, or :class:`ViewerInputError` saying
    in one line why not (nothing of the message but a short op name is repeated)."""
    if not isinstance(raw, str):
        raise ViewerInputError(f"a binary message ({len(raw)} bytes): this server takes none "
                               "(no client publishing, no services)")
    try:
        message = json.loads(raw)
    except ValueError as exc:  # json.JSONDecodeError, or a number too long to convert
        raise ViewerInputError(f"not JSON ({exc})") from None
    if not isinstance(message, dict):
        raise ViewerInputError(f"a JSON {type(message).__name__}, not an object with an \"op\"")
    op = message.get("op")
    if not isinstance(op, str):
        raise ViewerInputError("a JSON object without an \"op\" string")
    if op not in CLIENT_OPS:
        shown = json.dumps(op[:40] + ("…" if len(op) > 40 else ""), ensure_ascii=True)
        raise ViewerInputError(f"op {shown} is not taken here (only {' and '.join(CLIENT_OPS)})")
    if op == "subscribe":
        subscriptions = message.get("subscriptions")
        if not (isinstance(subscriptions, list) and all(
                isinstance(sub, dict) and _is_int(sub.get("id"))
                and _is_int(sub.get("channelId")) for sub in subscriptions)):
            raise ViewerInputError('subscribe: "subscriptions" must be a list of '
                                   '{"id": integer, "channelId": integer}')
    else:
        ids = message.get("subscriptionIds")
        if not (isinstance(ids, list) and all(map(_is_int, ids))):
            raise ViewerInputError('unsubscribe: "subscriptionIds" must be a list of integers')
    return message


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _viewer(connection: Any) -> str:
    address = connection.remote_address
    return f"{address[0]}:{address[1]}" if address else "?"


class _Server(FoxgloveServer):  # type: ignore[misc]
    """foxglove-websocket's server, taking from viewers only what :func:`client_message` lets
    through, and replying without waiting for the viewer to read."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._refusals: weakref.WeakKeyDictionary[Any, int] = weakref.WeakKeyDictionary()

    async def _handle_raw_client_message(self, client: Any, raw_message: str | bytes) -> None:
        try:
            message = client_message(raw_message)
            await self._handle_client_text_message(client, message)
        except ConnectionClosed:
            pass
        except ViewerInputError as exc:
            await self._refuse(client.connection, str(exc))
        except Exception as exc:  # checked, and foxglove-websocket refused it all the same
            await self._refuse(client.connection, f"{type(exc).__name__}: {exc}")

    async def _refuse(self, connection: Any, problem: str) -> None:
        count = self._refusals[connection] = self._refusals.get(connection, 0) + 1
        if count <= REFUSALS_LOGGED:
            log.warning("viewer %s: %s: ignored%s", _viewer(connection), problem,
                        " (its next ones are not logged)" if count == REFUSALS_LOGGED else "")
        await self._send_status(connection, StatusLevel.ERROR, problem)

    async def _send_json(self, connection: Any, msg: Any) -> None:
        """Written at once, never awaited: only our sender task waits for a viewer's socket
        (websockets' legacy connections cannot have two waiting at once)."""
        transport = connection.transport
        if connection.open and transport.get_write_buffer_size() < _REPLY_LIMIT_BYTES:
            transport.write(WebSocketFrame(
                Opcode.TEXT, json.dumps(msg, separators=(",", ":")).encode()).serialize(
                    mask=False, extensions=connection.extensions))


class _Connection(WebSocketServerProtocol):
    """websockets' server connection, which lets a viewer go at once when it closes without
    having read what was sent to it, and answers its pings without waiting.

    Only our sender task may wait for a full socket (websockets' legacy connections fail with an
    AssertionError, logged with its traceback, when two wait at once): the echo of a close frame
    and a pong are written and never waited for.
    """

    async def write_close_frame(self, close: Any, data: Any = None) -> None:
        transport = self.transport
        if (self.close_rcvd is not None
                and transport.get_write_buffer_size() > transport.get_write_buffer_limits()[0]):
            # The viewer said goodbye; the echo would wait behind all it never read.
            transport.abort()
            return
        await super().write_close_frame(close, data)

    async def pong(self, data: DataLike = b"") -> None:
        await self.ensure_open()
        self.write_frame_sync(True, Opcode.PONG, prepare_ctrl(data))


class LiveServer(Sink):
    """A Foxglove WebSocket server in a thread of its own; every public method is thread-safe
    and non-blocking apart from :meth:`start` and :meth:`stop`.

    As the pipeline's :class:`~bridge.sinks.base.Sink` (called from one thread) it publishes
    every frame, decoded message and made message on its topic's channel, and sends a batch of
    made messages at once. It goes on serving when a drive is finished; :meth:`stop` stops it.
    """

    def __init__(self, *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 name: str = "tankviz", queue_limit: int = DEFAULT_QUEUE_LIMIT,
                 server_time: bool = False, mode: str = "live") -> None:
        self.host = host
        #: what it serves, in serverInfo's metadata (``tankviz``): ``live`` or ``replay``
        self.mode = mode
        self.requested_port = port
        self.name = name
        self.queue_limit = queue_limit
        self.server_time = server_time
        self.session_id = f"tankviz-{uuid.uuid4().hex[:12]}"
        self.port = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: FoxgloveServer | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stop: asyncio.Event | None = None
        self._inbox: collections.deque[tuple[int, int, bytes] | _Control] = collections.deque()
        self._wake_pending = False
        self._timer: asyncio.TimerHandle | None = None
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._next_channel = 0
        self._wanted: set[int] = set()
        self._clients: dict[int, _Client] = {}
        self.finished: list[ClientStats] = []
        # the pipeline's channels, looked up once per bus and codec
        self._frame_channels: dict[str, int] = {}
        self._codec_channels: dict[MessageCodec, int] = {}

    # --- life cycle -----------------------------------------------------------------------

    def start(self, timeout: float = 10.0) -> None:
        """Start the server thread and wait until it listens (``port`` is then the real one)."""
        self._thread = threading.Thread(target=self._run, name="tankviz-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise ServerError(f"the WebSocket server did not start within {timeout:g} s")
        if self._error is not None:
            raise ServerError(f"cannot serve on {self.host}:{self.requested_port}: "
                              f"{self._error}") from self._error

    def stop(self, timeout: float = 5.0) -> None:
        if self._loop is not None and self._stop is not None and self._thread is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(timeout)

    def __enter__(self) -> LiveServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def url(self) -> str:
        """Where a viewer connects: the first of :attr:`urls`."""
        return self.urls[0]

    @property
    def urls(self) -> list[str]:
        """Where viewers connect: ``localhost`` for a loopback server; for one on every address
        (``0.0.0.0``, ``::``) each of the machine's own addresses (:func:`machine_addresses`;
        ``localhost`` when it has none); else the address it was given."""
        if self.host in ("0.0.0.0", "::", ""):
            hosts = [_url_host(a) for a in machine_addresses()] or ["localhost"]
        elif self.host in ("127.0.0.1", "::1", "localhost"):
            hosts = ["localhost"]
        else:
            hosts = [_url_host(self.host)]
        return [f"ws://{host}:{self.port}" for host in hosts]

    def viewers(self) -> int:
        """How many viewers are connected now."""
        return len(self._server._clients) if self._server is not None else 0

    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # reported to start() or logged
            self._error = exc
            self._ready.set()

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        try:  # bind here, so that a taken port is an error now and port 0 gets its number
            sock = _listening_socket(self.host, self.requested_port)
        except OSError as exc:
            self._error = exc
            self._ready.set()
            return
        capabilities = ["time"] if self.server_time else []
        server = _Server(None, None, self.name,
                         capabilities=capabilities, supported_encodings=[],
                         session_id=self.session_id,
                         metadata={"tankviz": self.mode}, logger=log,
                         # No keepalive pings: websockets' legacy protocol cannot have a ping
                         # and our sender wait on one full socket at the same time.
                         server_kwargs={"compression": None, "sock": sock,
                                        "ping_interval": None,
                                        "create_protocol": _Connection,
                                        "close_timeout": CLOSE_TIMEOUT_S})
        server.set_listener(_Subscriptions(self._wanted))
        self._server = server
        server.start()
        opened = await server.wait_opened()
        sockets = opened.sockets or []
        self.port = sockets[0].getsockname()[1] if sockets else self.requested_port
        self._ready.set()
        self._drain_now_and_then()
        await self._stop.wait()
        if self._timer is not None:
            self._timer.cancel()
        for client in self._clients.values():
            if client.task is not None:
                client.task.cancel()
        server.close()
        with contextlib.suppress(asyncio.TimeoutError):  # a stalled client cannot hold us up
            await asyncio.wait_for(server.wait_closed(), 2.0)

    # --- channels and messages (any thread) ------------------------------------------------

    def channel(self, topic: str, message_class: Any) -> int:
        """The channel id of ``topic`` carrying protobuf ``message_class``; advertised once."""
        return self.channel_for_schema(
            topic, message_class.DESCRIPTOR.full_name,
            build_file_descriptor_set(message_class).SerializeToString())

    def channel_for_schema(self, topic: str, schema_name: str, schema: bytes, *,
                           encoding: str = "protobuf", schema_encoding: str = "protobuf") -> int:
        """The channel id of ``topic``; advertised once. Binary schemas are sent as base64."""
        with self._lock:
            channel_id = self._channels.get(topic)
            if channel_id is not None:
                return channel_id
            channel_id = self._channels[topic] = self._next_channel
            self._next_channel += 1
        text = (base64.b64encode(schema).decode("ascii") if schema_encoding == "protobuf"
                else schema.decode("utf-8", errors="replace"))
        self._post(_Control("channel", {
            "id": channel_id, "topic": topic, "encoding": encoding, "schemaName": schema_name,
            "schema": text, "schemaEncoding": schema_encoding}))
        return channel_id

    def wanted(self, channel_id: int) -> bool:
        """Whether any client subscribed to the channel (skip the work otherwise)."""
        return channel_id in self._wanted

    def subscribers(self, channel_id: int) -> int:
        """How many clients subscribed to the channel."""
        clients = self._server._clients if self._server is not None else ()
        return sum(channel_id in c.subscriptions_by_channel for c in clients)

    def publish(self, channel_id: int, t_ns: int, payload: bytes) -> None:
        """Send a serialized message to the channel's subscribers; never blocks. It leaves at
        once after :meth:`flush`, at the latest after :data:`DRAIN_INTERVAL_S`."""
        if channel_id in self._wanted:
            self._inbox.append((channel_id, t_ns, payload))

    def flush(self) -> None:
        """Have what was published so far sent now (call it after a scene, and before waiting
        for more to publish); costs nothing when nothing was published."""
        if self._inbox:
            self._wake()

    # --- the Sink interface, for the pipeline (its thread only) -------------------------------

    def on_frame(self, frame: Frame, payload: bytes, /) -> None:
        channel = self._frame_channels.get(frame.bus)
        if channel is None:
            channel = self._frame_channels[frame.bus] = self.channel(frames_topic(frame.bus),
                                                                     CanFrame)
        if channel in self._wanted:  # (publish, inlined: once per frame)
            self._inbox.append((channel, frame.timestamp_ns, payload))

    def on_decoded(self, t_ns: int, decoded: Decoded, /) -> None:
        codec = decoded.codec
        channel = self._codec_channels.get(codec)
        if channel is None:
            channel = self._codec_channels[codec] = self.channel_for_schema(
                codec.topic, codec.schema.full_name, codec.schema.file_descriptor_set())
        if channel in self._wanted:
            self._inbox.append((channel, t_ns, decoded.payload))

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        """Published and sent at once: viewers wait for a scene."""
        channels = self._channels
        for topic, message_class, payload, t_ns in messages:
            channel = channels.get(topic)
            if channel is None:
                channel = self.channel(topic, message_class)
            self.publish(channel, t_ns, payload)
        self.flush()

    def advertise(self, channels: Sequence[Channel], /) -> None:
        for channel in channels:
            if channel.topic not in self._channels:
                self.channel_for_schema(channel.topic, channel.schema_name, channel.schema())

    def finish(self) -> None:
        self.flush()

    def broadcast_time(self, t_ns: int) -> None:
        """The protocol's server time, so viewers follow log time (replay)."""
        self._post(_Control("time", t_ns))

    def client_stats(self) -> list[ClientStats]:
        """Every client connected now and every one that left (with the topics it lost)."""
        stats = [c.stats for c in list(self._clients.values())] + self.finished
        topics = {channel: topic for topic, channel in list(self._channels.items())}
        for s in stats:
            s.topics = collections.Counter({topics.get(c, f"channel {c}"): n
                                            for c, n in s.channels.items()})
        return stats

    def _post(self, item: _Control) -> None:
        self._inbox.append(item)
        self._wake()

    def _wake(self) -> None:
        if not self._wake_pending and self._loop is not None:
            self._wake_pending = True
            with contextlib.suppress(RuntimeError):  # the loop closed: the server is stopping
                self._loop.call_soon_threadsafe(self._drain)

    # --- the loop's side --------------------------------------------------------------------

    def _sync_clients(self) -> None:
        assert self._server is not None
        current = {id(state): state for state in self._server._clients}
        for key in [k for k in self._clients if k not in current]:
            gone = self._clients.pop(key)
            if gone.task is not None:
                gone.task.cancel()
            self.finished.append(gone.stats)
        for key, state in current.items():
            if key not in self._clients:
                address = state.connection.remote_address
                client = _Client(state, ClientStats(f"{address[0]}:{address[1]}"
                                                    if address else "?"), self.queue_limit)
                client.task = asyncio.get_running_loop().create_task(client.run())
                self._clients[key] = client

    def _drain_now_and_then(self) -> None:
        """The safety net: whatever was published and not flushed, every DRAIN_INTERVAL_S."""
        if self._inbox:
            self._drain()
        self._timer = asyncio.get_running_loop().call_later(DRAIN_INTERVAL_S,
                                                            self._drain_now_and_then)

    def _drain(self) -> None:
        self._wake_pending = False
        server = self._server
        if server is None:
            return
        self._sync_clients()
        clients = list(self._clients.values())
        inbox = self._inbox
        # Each client's share of this drain, handed over at once; who subscribed to a channel is
        # looked up once per channel and drain (a stalled viewer of every raw frame is a deque
        # extend, not a call per message).
        shares: dict[int, list[tuple[Any, ...]]] = {}  # by client
        targets: dict[int, list[list[tuple[Any, ...]]]] = {}  # by channel: its clients' shares
        while inbox:
            item = inbox.popleft()
            if isinstance(item, _Control):
                if item.kind == "channel":
                    channel = item.value
                    server._channels[ChannelId(channel["id"])] = channel
                    text = json.dumps({"op": "advertise", "channels": [channel]},
                                      separators=(",", ":"))
                    for client in clients:
                        client.put_control(text)
                else:  # the time
                    frame = _TIME_HEADER.pack(_TIME, item.value)
                    for client in clients:
                        client.put_control(frame)
                continue
            channel_id = item[0]  # a message: (channel, time, payload)
            channel_shares = targets.get(channel_id)
            if channel_shares is None:
                channel_shares = targets[channel_id] = [
                    shares.setdefault(id(client), []) for client in clients
                    if channel_id in client.state.subscriptions_by_channel]
            for share in channel_shares:
                share.append(item)
        for client in clients:
            if id(client) in shares:
                client.put(shares[id(client)])
        for client in clients:
            client.write_now()


class _Control(NamedTuple):
    """An inbox item for every client (a message is a plain ``(channel, time, payload)``)."""

    kind: str  # "channel" (advertise it) or "time" (the server time)
    value: Any


#: Messages one client's sender writes at once before letting the others have a turn.
_FAIR_SHARE = 64
#: A client whose socket buffer holds less than this gets its messages written at once
#: (websockets' own default write limit).
_WRITE_NOW_BYTES = 2**16

#: A viewer this far behind (bytes not yet taken by its socket) gets no more replies.
_REPLY_LIMIT_BYTES = 2**20

#: Kernel send buffer per connection: about half a second of a busy scene, 25 MB/s at 20 ms
#: round trip (the kernel doubles it for its bookkeeping).
SEND_BUFFER_BYTES = 256 * 1024
_HEADER = struct.Struct("<BIQ")  # opcode, subscription id, timestamp (ns)
_TIME_HEADER = struct.Struct("<BQ")


def _listening_socket(host: str, port: int) -> socket.socket:
    """A TCP listening socket whose connections send at once.

    Made with protocol ``IPPROTO_TCP`` (``socket.create_server`` leaves it 0): asyncio turns
    Nagle's algorithm off (TCP_NODELAY) only for such sockets. With Nagle on, the last part of a
    scene waited in the kernel for the viewer's delayed ACK, and arrived with the next scene.

    Its connections' kernel send buffers are :data:`SEND_BUFFER_BYTES` (Linux lets them grow to
    4 MB otherwise): a viewer that stops reading is then seen to be stalled after a fraction of
    a second of its messages, not after tens of thousands written for nobody.
    """
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)  # inherited
        sock.bind((host, port))
        sock.listen()
    except OSError:
        sock.close()
        raise
    return sock


def machine_addresses() -> list[str]:
    """This machine's IPv4 addresses but loopback, in interface order: read from the network
    interfaces (Linux's SIOCGIFADDR), then what the host name resolves to. Asks no network and
    no name server beyond the host's own resolver."""
    found: list[str] = []
    try:
        import fcntl

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            for _, name in socket.if_nameindex():
                with contextlib.suppress(OSError):  # (an interface without an IPv4 address)
                    request = struct.pack("256s", name.encode()[:15])
                    found.append(socket.inet_ntoa(
                        fcntl.ioctl(probe.fileno(), _SIOCGIFADDR, request)[20:24]))
    except (ImportError, OSError):  # not Linux, or no interfaces to list
        pass
    with contextlib.suppress(OSError):
        found += [str(info[4][0]) for info in socket.getaddrinfo(
            socket.gethostname(), None, socket.AF_INET, socket.SOCK_STREAM)]
    addresses = [ipaddress.ip_address(a) for a in found]
    return list(dict.fromkeys(str(a) for a in addresses
                              if not (a.is_loopback or a.is_unspecified)))


_SIOCGIFADDR = 0x8915  # Linux: an interface's address


def _url_host(address: str) -> str:
    return f"[{address}]" if ":" in address else address


def wait_for(condition: Callable[[], bool], timeout: float = 5.0, step: float = 0.01) -> bool:
    """Poll ``condition`` until true or ``timeout`` (for tools and tests)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step)
    return condition()
