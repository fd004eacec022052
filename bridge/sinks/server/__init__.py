"""The live sink: a Foxglove WebSocket server (foxglove-websocket, ``foxglove.websocket.v1``).

:class:`ViewerServer` runs its own asyncio loop in a thread; the pipeline publishes to it without
ever waiting, every viewer gets its own bounded queue (a slow one loses its own oldest messages,
never anyone else's), and a viewer may only subscribe and unsubscribe (and, on a live server,
publish marks). The protocol has no authentication: bind to 127.0.0.1 (the default) unless the
network is trusted. Bound to every address (``0.0.0.0``, ``::``), :attr:`ViewerServer.urls` names
the machine's own addresses, which a laptop on the car's network can open.

The package, one concern a module:

- :mod:`~bridge.sinks.server.viewer_server`: :class:`ViewerServer` (its thread, channels, the
  inbox and its control messages, the listening socket).
- :mod:`~bridge.sinks.server.client`: one viewer's bounded queue and sender task, and
  :class:`ClientStats` (what it was sent and lost).
- :mod:`~bridge.sinks.server.viewer_input`: what a viewer may send (:func:`client_message`,
  :class:`ViewerInputError`; marks: :class:`ViewerMark`, their limits).
- :mod:`~bridge.sinks.server.addresses`: the URLs to print and the machine's own addresses
  (:func:`machine_addresses`).
- :mod:`~bridge.sinks.server.internals`: the fence; every use of foxglove-websocket's and
  websockets' private internals, with the versions it was written against.
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
