"""One viewer's side of the server: its bounded queue, its sender task, what it was sent and lost.

foxglove-websocket sends to its clients one after another and awaits each, so a stalled client
would hold up everyone; instead every client gets its own bounded queue and sender task here. A
slow or stalled client loses its own oldest messages (counted in :attr:`ClientStats.dropped`),
never anyone else's, and never delays the pipeline or the recorder.
"""

from __future__ import annotations

import asyncio
import collections
import itertools
import operator
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from foxglove_websocket.server import MessageDataHeader
from foxglove_websocket.types import BinaryOpcode
from websockets.frames import Frame, Opcode

from bridge.sinks.server import internals

#: Messages one client's sender writes at once before letting the others have a turn.
FAIR_SHARE = 64
#: A client whose socket buffer holds less than this gets its messages written at once
#: (websockets' own default write limit).
WRITE_NOW_BYTES = 2**16
#: How long a new client's control messages wait for foxglove-websocket's handshake (s).
HANDSHAKE_S = 1.0

_MESSAGE_DATA = BinaryOpcode.MESSAGE_DATA
_pack_header = MessageDataHeader.pack
_HEADER_SIZE = MessageDataHeader.size
_channel_of = operator.itemgetter(0)


@dataclass
class ClientStats:
    """What one client was sent and what it lost (how many messages of which topics)."""

    address: str
    sent: int = 0
    dropped: int = 0
    #: messages lost per topic (filled in by
    #: :meth:`~bridge.sinks.server.viewer_server.ViewerServer.client_stats`)
    topics: collections.Counter[str] = field(default_factory=collections.Counter)
    #: messages lost per channel id
    channels: collections.Counter[int] = field(default_factory=collections.Counter)

    def lost(self, items: Iterable[tuple[Any, ...]], count: int) -> None:
        """``count`` queued ``(channel, time, payload)`` items that were dropped."""
        self.channels.update(map(_channel_of, items))  # (counted in C)
        self.dropped += count


@dataclass
class ClientQueue:
    """Our side of one connection: its bounded queue and its sender task.

    The queue holds the pipeline's own ``(channel, time, payload)`` items, shared by every client;
    the message header (this client's subscription id) is made when the message is sent, so a
    message that is dropped costs next to nothing. Control messages (advertisements, the server
    time: already encoded, text or binary) go first and are never dropped.
    """

    state: Any  # foxglove_websocket's ClientState: .connection, .subscriptions_by_channel
    stats: ClientStats
    limit: int
    queue: collections.deque[tuple[Any, ...]] = field(init=False)
    control: collections.deque[str | bytes] = field(default_factory=collections.deque)
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
                                            items[:max(0, excess - before)]), excess)
        queue.extend(items)
        self.ready.set()

    def put_control(self, data: str | bytes) -> None:
        """Queue a control message (text: JSON; bytes: a binary message), sent before data."""
        self.control.append(data)
        self.ready.set()

    async def run(self) -> None:
        state = self.state
        connection = state.connection
        # foxglove-websocket sends serverInfo and the channel list when a client connects; hold
        # our own control messages until that handshake is surely done (the client subscribed,
        # or a second passed). Data only flows after a subscription anyway.
        loop = asyncio.get_running_loop()
        settled = loop.time() + HANDSHAKE_S
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
                    await internals.ensure_open(connection)
                    self._write(self._next_frames(FAIR_SHARE))
                    await internals.drain(connection)  # websockets' flow control
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
               and connection.transport.get_write_buffer_size() < WRITE_NOW_BYTES):
            self._write(self._next_frames(FAIR_SHARE))
        if not self.control and not self.queue:
            self.ready.clear()  # nothing left for the sender task

    def _write(self, messages: tuple[list[bytes], int]) -> None:
        chunks, count = messages
        if chunks:
            internals.write_serialized(self.state.connection, chunks)
            self.stats.sent += count

    def _next_frames(self, limit: int) -> tuple[list[bytes], int]:
        """Up to ``limit`` queued messages as WebSocket frames, control messages first: their
        bytes (a message may be several chunks) and how many messages."""
        chunks: list[bytes] = []
        count = 0
        control, queue = self.control, self.queue
        connection = self.state.connection
        plain = internals.plain(connection)
        # (a new mapping at every (un)subscribe: read it now)
        subscriptions = self.state.subscriptions_by_channel
        add, header, frame_header = chunks.append, _pack_header, internals.binary_header
        while count < limit and (control or queue):
            if control:
                data = control.popleft()
                chunks.append(internals.serialized(connection, Frame(Opcode.TEXT, data.encode())
                                                   if isinstance(data, str)
                                                   else Frame(Opcode.BINARY, data)))
                count += 1
                continue
            channel_id, t_ns, payload = queue.popleft()
            subscription = subscriptions.get(channel_id)
            if subscription is None:  # unsubscribed since
                continue
            if plain:  # framed here, as websockets would (and without copying the payload)
                add(frame_header(_HEADER_SIZE + len(payload)))
                add(header(_MESSAGE_DATA, subscription, t_ns))
                add(payload)
            else:
                add(internals.serialized(connection, Frame(
                    Opcode.BINARY, header(_MESSAGE_DATA, subscription, t_ns) + payload)))
            count += 1
        return chunks, count
