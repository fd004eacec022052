"""The fence: every use of foxglove-websocket's and websockets' private internals, and only here.

Written against the releases :data:`bridge.fences.FOXGLOVE_WEBSOCKET` and
:data:`bridge.fences.WEBSOCKETS` name; tests/test_server.py asserts that every private name used
here still exists with the signature used, tests/test_fences.py fails on another release. Used:
``FoxgloveServer._handle_raw_client_message``, ``_handle_client_text_message``, ``_send_status``,
``_send_json``, ``_clients`` and ``_channels`` (:class:`Server`, :func:`clients`,
:func:`add_channel`), and the legacy ``WebSocketServerProtocol``'s ``write_close_frame``,
``close_rcvd``, ``pong``, ``write_frame_sync``, ``prepare_ctrl`` and transport
(:class:`Connection`, :func:`write_frames`, :func:`write_serialized`, :func:`ensure_open`,
:func:`drain`, :func:`binary_header`).

:class:`Server` checks what a viewer sends (:class:`~bridge.sinks.server.viewer_input.ViewerInput`)
before foxglove-websocket sees it; a refusal gets the protocol's ``status`` (level error) and a
console line (logger ``tankviz.server``, warning), and nothing else happens; a mark taken goes to
:attr:`Server.take_mark`, in the server's loop. Replies never wait for the viewer (at most
:data:`REPLY_LIMIT_BYTES` behind); a server that publishes its time sends the latest time
(:attr:`Server.latest_time_ns`) before the channels, and never an ``advertise`` of no channel. A
viewer that closes while its buffers are full is aborted at once, not after the close timeout.
"""

from __future__ import annotations

import json
import logging
import struct
import time
import weakref
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from foxglove_websocket.server import FoxgloveServer, TimeDataHeader
from foxglove_websocket.types import BinaryOpcode, ChannelId, StatusLevel
from websockets.exceptions import ConnectionClosed
from websockets.frames import Frame, Opcode
from websockets.legacy.framing import prepare_ctrl
from websockets.legacy.server import WebSocketServerProtocol
from websockets.typing import DataLike

from bridge.errors import ViewerInputError
from bridge.fences import FOXGLOVE_WEBSOCKET, WEBSOCKETS
from bridge.sinks.server.viewer_input import (
    REFUSALS_LOGGED,
    TooManyMarks,
    ViewerInput,
    ViewerMark,
)

#: A viewer this far behind (bytes not yet taken by its socket) gets no more replies.
REPLY_LIMIT_BYTES = 2**20

log = logging.getLogger("tankviz.server")


def viewer_name(connection: Any) -> str:
    """``host:port`` of a viewer's connection (``?`` when unknown)."""
    address = connection.remote_address
    return f"{address[0]}:{address[1]}" if address else "?"


class Server(FoxgloveServer):  # type: ignore[misc]
    """foxglove-websocket's server, taking from viewers only what their
    :class:`~bridge.sinks.server.viewer_input.ViewerInput` lets through (with ``marks``: marks
    too, handed to :attr:`take_mark`), and replying without waiting for the viewer to read."""

    def __init__(self, *args: Any, marks: bool = False, **kwargs: Any) -> None:
        FOXGLOVE_WEBSOCKET.holds()  # (says once when not: there is no public path)
        WEBSOCKETS.holds()
        super().__init__(*args, **kwargs)
        self.marks = marks
        #: called in the server's loop with each mark a viewer published and that was taken;
        #: a ``ViewerInputError`` it raises is the viewer's refusal
        self.take_mark: Callable[[ViewerMark], None] | None = None
        self._viewers: weakref.WeakKeyDictionary[Any, ViewerInput] = weakref.WeakKeyDictionary()
        #: the latest server time sent to the viewers (ns; set by whoever sends it), sent to a
        #: viewer that connects right after its serverInfo
        self.latest_time_ns: int | None = None
        #: channels of a server that publishes its time, held until its first time
        self.held_channels: list[dict[str, Any]] = []

    def viewer_input(self, connection: Any) -> ViewerInput:
        """What this viewer sent that the server keeps (made at its first message)."""
        viewer = self._viewers.get(connection)
        if viewer is None:
            viewer = self._viewers[connection] = ViewerInput(viewer_name(connection), self.marks,
                                                             time.monotonic)
        return viewer

    async def _handle_raw_client_message(self, client: Any, raw_message: str | bytes) -> None:
        viewer = self.viewer_input(client.connection)
        try:
            if isinstance(raw_message, str):
                message = viewer.text(raw_message)
                if message is not None:
                    await self._handle_client_text_message(client, message)
            else:
                mark = viewer.binary(raw_message)
                if mark is not None and self.take_mark is not None:
                    self.take_mark(mark)
        except ConnectionClosed:
            pass
        except ViewerInputError as exc:
            await self._refuse(client.connection, viewer, exc)
        except Exception as exc:  # checked, and foxglove-websocket refused it all the same
            await self._refuse(client.connection, viewer,
                               ViewerInputError(f"{type(exc).__name__}: {exc}"))

    async def _refuse(self, connection: Any, viewer: ViewerInput,
                      problem: ViewerInputError) -> None:
        status, line = viewer.refused(problem)
        if line:
            log.warning("viewer %s: %s: ignored%s", viewer.name, problem,
                        " (said once: the next ones are counted)"
                        if isinstance(problem, TooManyMarks) else
                        " (its next ones are not logged)"
                        if viewer.refusals == REFUSALS_LOGGED else "")
        if status:
            await self._send_status(connection, StatusLevel.ERROR, str(problem))

    async def _send_json(self, connection: Any, msg: Any) -> None:
        """Written at once, never awaited: only our sender task waits for a viewer's socket
        (websockets' legacy connections cannot have two waiting at once)."""
        if msg.get("op") == "advertise" and not msg.get("channels"):
            return  # nothing to tell, and Studio would start its timeline at zero
        if (connection.open
                and connection.transport.get_write_buffer_size() < REPLY_LIMIT_BYTES):
            frames = [Frame(Opcode.TEXT, json.dumps(msg, separators=(",", ":")).encode())]
            if (msg.get("op") == "serverInfo" and "time" in msg.get("capabilities", ())
                    and self.latest_time_ns is not None):
                frames.append(Frame(Opcode.BINARY, TimeDataHeader.pack(BinaryOpcode.TIME,
                                                                       self.latest_time_ns)))
            write_frames(connection, frames)


def clients(server: FoxgloveServer | None) -> tuple[Any, ...]:
    """The connected clients (foxglove-websocket's ``ClientState`` s); none before the server
    runs."""
    return tuple(server._clients) if server is not None else ()


def add_channel(server: FoxgloveServer, channel: dict[str, Any]) -> None:
    """Make ``channel`` (an ``advertise`` entry, with its ``id``) one that clients may subscribe
    to; advertising it is the caller's business."""
    server._channels[ChannelId(channel["id"])] = channel


class Connection(WebSocketServerProtocol):
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


def write_frames(connection: Any, frames: Sequence[Frame] | Iterable[Frame]) -> None:
    """Several messages, one write to the connection's transport: each still its own WebSocket
    message, framed by websockets itself. Never waits."""
    extensions = connection.extensions
    connection.transport.write(b"".join(frame.serialize(mask=False, extensions=extensions)
                                        for frame in frames))


def serialized(connection: Any, frame: Frame) -> bytes:
    """One message as websockets writes it to this connection (server side: unmasked)."""
    return bytes(frame.serialize(mask=False, extensions=connection.extensions))


def plain(connection: Any) -> bool:
    """Whether the connection's messages go out as bare RFC 6455 frames (no extension: the
    server offers no compression), so that :func:`binary_header` frames them as websockets
    would."""
    return not connection.extensions


_BINARY = 0x80 | Opcode.BINARY  # FIN, and the binary opcode
_SHORT = struct.Struct("!BB")
_MEDIUM = struct.Struct("!BBH")
_LONG = struct.Struct("!BBQ")


def binary_header(length: int) -> bytes:
    """The header websockets' ``Frame.serialize`` writes before a whole binary message of
    ``length`` bytes from a server (unmasked) on a :func:`plain` connection: the same bytes,
    without a ``Frame`` and a buffer per message (1.7 µs a message there, 0.2 here)."""
    if length < 126:
        return _SHORT.pack(_BINARY, length)
    if length < 65536:
        return _MEDIUM.pack(_BINARY, 126, length)
    return _LONG.pack(_BINARY, 127, length)


def write_serialized(connection: Any, chunks: list[bytes]) -> None:
    """Messages already framed (:func:`serialized`, :func:`binary_header`), one write to the
    connection's transport. Never waits."""
    connection.transport.write(b"".join(chunks))


async def ensure_open(connection: Any) -> None:
    """Raises websockets' ``ConnectionClosed`` once the connection is closing or closed."""
    await connection.ensure_open()


async def drain(connection: Any) -> None:
    """Waits while the connection's transport holds more than its write limit (websockets'
    flow control)."""
    await connection.drain()
