"""The live sink: a Foxglove WebSocket server (foxglove-websocket, ``foxglove.websocket.v1``).

:class:`ViewerServer` (:mod:`~bridge.sinks.server.viewer_server`) runs its own asyncio loop in a
thread; the pipeline publishes to it without ever waiting; every viewer gets its own bounded queue
(:mod:`~bridge.sinks.server.client`: a slow one loses its own oldest messages, never anyone
else's); a viewer may only subscribe, unsubscribe and, on a live server, publish marks
(:mod:`~bridge.sinks.server.viewer_input`). The protocol has no authentication: bind to 127.0.0.1
(the default) unless the network is trusted; bound to every address, :attr:`ViewerServer.urls`
names the machine's own (:mod:`~bridge.sinks.server.addresses`). The private internals it uses are
fenced in :mod:`~bridge.sinks.server.internals`.
"""

from __future__ import annotations

from bridge.errors import ServerError, ViewerInputError
from bridge.sinks.server.addresses import machine_addresses
from bridge.sinks.server.client import ClientStats
from bridge.sinks.server.viewer_input import ViewerMark, client_message
from bridge.sinks.server.viewer_server import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    DEFAULT_QUEUE_LIMIT,
    SEND_BUFFER_BYTES,
    ViewerServer,
)

__all__ = [
    "DEFAULT_HOST",
    "DEFAULT_PORT",
    "DEFAULT_QUEUE_LIMIT",
    "SEND_BUFFER_BYTES",
    "ClientStats",
    "ServerError",
    "ViewerInputError",
    "ViewerMark",
    "ViewerServer",
    "client_message",
    "machine_addresses",
]
