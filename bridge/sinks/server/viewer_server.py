"""The server itself: :class:`ViewerServer`, its thread and loop, channels, the inbox.

The server runs its asyncio loop in its own thread. :meth:`ViewerServer.publish` never blocks: it
appends a message (``(channel, time, payload)``) or a control message (:class:`AdvertiseChannel`,
:class:`ServerTime`) to an inbox, which the loop hands to each client
(:class:`~bridge.sinks.server.client.ClientQueue`) at once after :meth:`ViewerServer.flush` and at
least every :data:`DRAIN_INTERVAL_S`; :meth:`ViewerServer.flush_batched` (live's raw frames and
signals) wakes the loop at most once per :data:`BATCH_S`. Channels carry protobuf; a channel is
advertised to every client, its messages go only to those that subscribed
(:meth:`ViewerServer.wanted`). A live server (not publishing its time) takes marks
(:mod:`~bridge.sinks.server.viewer_input`) and hands each to :attr:`ViewerServer.on_mark`, in the
server's thread; a replay takes none. A viewer that left is no longer counted
(:meth:`ViewerServer.viewers`) and no longer keeps channels wanted.
"""

from __future__ import annotations

import asyncio
import base64
import collections
import contextlib
import json
import socket
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from foxglove_websocket.server import FoxgloveServer, FoxgloveServerListener, TimeDataHeader
from foxglove_websocket.types import BinaryOpcode, ChannelId
from mcap_protobuf.schema import build_file_descriptor_set

from bridge.decode.codec import Decoded, MessageCodec
from bridge.errors import ServerError, ViewerInputError
from bridge.pb.can_frame_pb2 import CanFrameBlock
from bridge.sinks.base import Channel, Serialized, Sink
from bridge.sinks.raw import RawBlock
from bridge.sinks.server import internals
from bridge.sinks.server.addresses import viewer_urls
from bridge.sinks.server.client import ClientQueue, ClientStats
from bridge.sinks.server.viewer_input import MARK_ENCODING, ViewerMark
from bridge.topics import frames_topic

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
#: Messages waiting per client before its oldest are dropped (about 2 s of a busy scene).
DEFAULT_QUEUE_LIMIT = 2000
#: How often the loop takes in published messages without being asked to (s): a safety net,
#: publishers flush.
DRAIN_INTERVAL_S = 0.1
#: The longest live's raw frames and decoded signals wait for a scene's flush to take them
#: along (s): :meth:`ViewerServer.flush_batched`.
BATCH_S = 0.02
#: How long the server waits for a viewer's part of a closing handshake (s; websockets: 10).
CLOSE_TIMEOUT_S = 1.0
#: The largest message a viewer may send (bytes); a larger one closes its connection (1009).
VIEWER_MESSAGE_BYTES = 2**20
#: Kernel send buffer per connection: about half a second of a busy scene, 25 MB/s at 20 ms
#: round trip (the kernel doubles it for its bookkeeping).
SEND_BUFFER_BYTES = 256 * 1024


@dataclass(frozen=True, slots=True)
class AdvertiseChannel:
    """Inbox: a new channel, for every client (and then one a client may subscribe to)."""

    channel: dict[str, Any]  # the protocol's channel: id, topic, encoding, schema...


@dataclass(frozen=True, slots=True)
class ServerTime:
    """Inbox: the protocol's server time, for every client (replays)."""

    t_ns: int


#: What the inbox holds: a message ``(channel, time, payload)`` or a control message.
InboxItem = tuple[int, int, bytes] | AdvertiseChannel | ServerTime


class _Subscriptions(FoxgloveServerListener):  # type: ignore[misc]
    """Keeps the set of channels anyone subscribed to (first subscribe, last unsubscribe)."""

    def __init__(self, wanted: set[int]) -> None:
        self.wanted = wanted

    def on_subscribe(self, server: FoxgloveServer, channel_id: ChannelId) -> None:
        self.wanted.add(channel_id)

    def on_unsubscribe(self, server: FoxgloveServer, channel_id: ChannelId) -> None:
        self.wanted.discard(channel_id)


class ViewerServer(Sink):
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
        #: whether viewers may publish marks (``clientPublish``): a live server's do
        self.takes_marks = mode == "live" and not server_time
        #: called with each mark a viewer published (in the server's thread); until it is set,
        #: marks are refused
        self.on_mark: Callable[[ViewerMark], None] | None = None
        self.session_id = f"tankviz-{uuid.uuid4().hex[:12]}"
        self.port = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: FoxgloveServer | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stop: asyncio.Event | None = None
        self._inbox: collections.deque[InboxItem] = collections.deque()
        self._wake_pending = False
        self._woken = 0.0  # when the loop was last woken (time.monotonic)
        self._timer: asyncio.TimerHandle | None = None
        self._lock = threading.Lock()
        self._channel_ids: dict[str, int] = {}  # topic → channel id
        self._next_channel = 0
        self._wanted: set[int] = set()
        self._clients: dict[int, ClientQueue] = {}
        self.departed: list[ClientStats] = []  # the stats of clients that left
        # the pipeline's channels, looked up once per bus and codec
        self._frame_channels: dict[str, int] = {}
        self._codec_channels: dict[MessageCodec, int] = {}

    # --- life cycle -----------------------------------------------------------------------

    def start(self, timeout: float = 10.0) -> None:
        """Start the server thread and wait until it listens (``port`` is then the real one)."""
        self._thread = threading.Thread(target=self._run, name="tankviz-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise ServerError(self.host, self.requested_port,
                              f"the WebSocket server did not start within {timeout:g} s")
        if self._error is not None:
            raise ServerError(self.host, self.requested_port, str(self._error)) from self._error

    def stop(self, timeout: float = 5.0) -> None:
        if self._loop is not None and self._stop is not None and self._thread is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(timeout)

    def __enter__(self) -> ViewerServer:
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
        """Where viewers connect (:func:`~bridge.sinks.server.addresses.viewer_urls`):
        ``localhost`` for a loopback server; for one on every address (``0.0.0.0``, ``::``)
        each of the machine's own addresses (``localhost`` when it has none); else the address
        it was given."""
        return viewer_urls(self.host, self.port)

    def viewers(self) -> int:
        """How many viewers are connected now."""
        return len(internals.clients(self._server))

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
        if self.takes_marks:
            capabilities.append("clientPublish")
        server = internals.Server(None, None, self.name, marks=self.takes_marks,
                                  capabilities=capabilities,
                                  supported_encodings=[MARK_ENCODING] if self.takes_marks else [],
                                  session_id=self.session_id,
                                  metadata={"tankviz": self.mode}, logger=internals.log,
                                  # No keepalive pings: websockets' legacy protocol cannot have a
                                  # ping and our sender wait on one full socket at the same time.
                                  server_kwargs={"compression": None, "sock": sock,
                                                 "max_size": VIEWER_MESSAGE_BYTES,
                                                 "ping_interval": None,
                                                 "create_protocol": internals.Connection,
                                                 "close_timeout": CLOSE_TIMEOUT_S})
        server.set_listener(_Subscriptions(self._wanted))
        server.take_mark = self._take_mark
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

    def _take_mark(self, mark: ViewerMark) -> None:
        on_mark = self.on_mark
        if on_mark is None:
            raise ViewerInputError("no drive is taking marks now")
        on_mark(mark)

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
            channel_id = self._channel_ids.get(topic)
            if channel_id is not None:
                return channel_id
            channel_id = self._channel_ids[topic] = self._next_channel
            self._next_channel += 1
        text = (base64.b64encode(schema).decode("ascii") if schema_encoding == "protobuf"
                else schema.decode("utf-8", errors="replace"))
        self._post(AdvertiseChannel({
            "id": channel_id, "topic": topic, "encoding": encoding, "schemaName": schema_name,
            "schema": text, "schemaEncoding": schema_encoding}))
        return channel_id

    def wanted(self, channel_id: int) -> bool:
        """Whether any client subscribed to the channel (skip the work otherwise)."""
        return channel_id in self._wanted

    def subscribers(self, channel_id: int) -> int:
        """How many clients subscribed to the channel."""
        return sum(channel_id in c.subscriptions_by_channel
                   for c in internals.clients(self._server))

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

    def flush_batched(self) -> None:
        """:meth:`flush`, unless the loop was woken less than :data:`BATCH_S` ago: what was
        published since then goes with the next flush (live's next scene), at the latest with
        a call of this once :data:`BATCH_S` has passed."""
        if self._inbox and time.monotonic() - self._woken >= BATCH_S:
            self._wake()

    # --- the Sink interface, for the pipeline (its thread only) -------------------------------

    def on_raw(self, blocks: Sequence[RawBlock], /) -> None:
        for block in blocks:
            channel = self._frame_channels.get(block.bus)
            if channel is None:
                channel = self._frame_channels[block.bus] = self.channel(
                    frames_topic(block.bus), CanFrameBlock)
            self.publish(channel, block.t_ns, block.payload)

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
        channel_ids = self._channel_ids
        for topic, message_class, payload, t_ns in messages:
            channel = channel_ids.get(topic)
            if channel is None:
                channel = self.channel(topic, message_class)
            self.publish(channel, t_ns, payload)
        self.flush()

    def advertise(self, channels: Sequence[Channel], /) -> None:
        for channel in channels:
            if channel.topic not in self._channel_ids:
                self.channel_for_schema(channel.topic, channel.schema_name, channel.schema())

    def finish(self) -> None:
        self.flush()

    def broadcast_time(self, t_ns: int) -> None:
        """The protocol's server time, so viewers follow log time (replay)."""
        self._post(ServerTime(t_ns))

    def client_stats(self) -> list[ClientStats]:
        """Every client connected now and every one that left (with the topics it lost)."""
        stats = [c.stats for c in list(self._clients.values())] + self.departed
        topics = {channel: topic for topic, channel in list(self._channel_ids.items())}
        for s in stats:
            s.topics = collections.Counter({topics.get(c, f"channel {c}"): n
                                            for c, n in s.channels.items()})
        return stats

    def _post(self, item: AdvertiseChannel | ServerTime) -> None:
        self._inbox.append(item)
        self._wake()

    def _wake(self) -> None:
        if not self._wake_pending and self._loop is not None:
            self._wake_pending = True
            self._woken = time.monotonic()
            with contextlib.suppress(RuntimeError):  # the loop closed: the server is stopping
                self._loop.call_soon_threadsafe(self._drain)

    # --- the loop's side --------------------------------------------------------------------

    def _sync_clients(self) -> None:
        current = {id(state): state for state in internals.clients(self._server)}
        for key in [k for k in self._clients if k not in current]:
            gone = self._clients.pop(key)
            if gone.task is not None:
                gone.task.cancel()
            self.departed.append(gone.stats)
        for key, state in current.items():
            if key not in self._clients:
                client = ClientQueue(state, ClientStats(internals.viewer_name(state.connection)),
                                     self.queue_limit)
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
            if not isinstance(item, tuple):
                _control(server, item, clients, server_time=self.server_time)
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


def _control(server: internals.Server, item: AdvertiseChannel | ServerTime,
             clients: list[ClientQueue], *, server_time: bool) -> None:
    """A control message, queued for every client ahead of its messages. A server that
    publishes its time advertises its channels from its first time on: Foxglove Studio takes
    the time it has when the first channels come as the start of its timeline, zero without
    one."""
    data: list[str | bytes] = []
    channels: list[dict[str, Any]] = []
    match item:
        case AdvertiseChannel(channel):
            if server_time and server.latest_time_ns is None:
                server.held_channels.append(channel)
                return
            channels.append(channel)
        case ServerTime(t_ns):
            data.append(TimeDataHeader.pack(BinaryOpcode.TIME, t_ns))
            server.latest_time_ns = t_ns  # (internals.Server: a viewer that comes gets it)
            channels, server.held_channels = server.held_channels, []
    for channel in channels:
        internals.add_channel(server, channel)  # then clients may subscribe to it
    if channels:
        data.append(json.dumps({"op": "advertise", "channels": channels}, separators=(",", ":")))
    for client in clients:
        for control in data:
            client.put_control(control)


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
