"""A Foxglove viewer that marks, as Foxglove Studio's Publish panel does: it advertises ``/marks``
(encoding ``json``) and publishes JSON marks on it; it reads everything the server sends in the
background (statuses, advertisements, the messages of what it subscribed to)."""

from __future__ import annotations

import asyncio
import json
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import websockets

SUBPROTOCOL = websockets.Subprotocol("foxglove.websocket.v1")
#: A message's header from the server: opcode 1, subscription id, log time (ns).
MESSAGE_HEADER = struct.Struct("<BIQ")


def mark_json(text: str | None = None, category: str | None = None, **more: Any) -> bytes:
    """A mark as the Publish panel sends it (JSON in UTF-8)."""
    content = {k: v for k, v in (("text", text), ("category", category)) if v is not None}
    return json.dumps({**content, **more}).encode()


def client_message(channel: int, payload: bytes) -> bytes:
    """The protocol's client message data: opcode 1, the client's channel id, the payload."""
    return struct.pack("<BI", 1, channel) + payload


@dataclass
class Marker:
    """One connection; :meth:`open` it, then advertise, publish and wait for what comes."""

    url: str
    ws: Any = None
    info: dict[str, Any] = field(default_factory=dict)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)  # by topic
    #: (topic, log time, payload) of every message of a subscribed channel
    got: list[tuple[str, int, bytes]] = field(default_factory=list)
    closed: bool = False
    _subscribed: dict[int, str] = field(default_factory=dict)
    _reader: asyncio.Task[None] | None = None

    async def open(self) -> Marker:
        self.ws = await websockets.connect(self.url, subprotocols=[SUBPROTOCOL],
                                           max_size=None)
        self._reader = asyncio.get_running_loop().create_task(self._read())
        await self.until(lambda: bool(self.info))
        return self

    @property
    def address(self) -> str:
        """This viewer's address as the server sees it (``host:port``)."""
        host, port = self.ws.local_address[:2]
        return f"{host}:{port}"

    async def close(self) -> None:
        await self.ws.close()
        if self._reader is not None:
            await self._reader

    async def _read(self) -> None:
        try:
            async for raw in self.ws:
                if isinstance(raw, str):
                    message = json.loads(raw)
                    if message["op"] == "serverInfo":
                        self.info = message
                    elif message["op"] == "status":
                        self.statuses.append(message)
                    elif message["op"] == "advertise":
                        self.channels.update({c["topic"]: c for c in message["channels"]})
                elif raw[0] == 1:
                    _, sub, t_ns = MESSAGE_HEADER.unpack_from(raw)
                    self.got.append((self._subscribed.get(sub, "?"), t_ns,
                                     raw[MESSAGE_HEADER.size:]))
        except websockets.ConnectionClosed:
            pass
        finally:
            self.closed = True

    async def until(self, condition: Callable[[], bool], timeout: float = 30.0) -> None:
        """Waits until ``condition`` holds (AssertionError after ``timeout`` s)."""
        loop = asyncio.get_running_loop()
        until = loop.time() + timeout
        while not condition():
            if loop.time() > until:
                raise AssertionError(f"waited {timeout:g} s in vain; statuses: "
                                     f"{self.statuses[-3:]}")
            await asyncio.sleep(0.01)

    async def subscribe(self, *topics: str) -> None:
        await self.until(lambda: all(t in self.channels for t in topics))
        subscriptions = []
        for topic in topics:
            channel = self.channels[topic]["id"]
            self._subscribed[channel] = topic
            subscriptions.append({"id": channel, "channelId": channel})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    async def advertise(self, channel: int, topic: str = "/marks", encoding: str = "json",
                        schema_name: str = "tankviz.Mark") -> None:
        await self.ws.send(json.dumps({"op": "advertise", "channels": [
            {"id": channel, "topic": topic, "encoding": encoding, "schemaName": schema_name}]}))

    async def publish(self, channel: int, payload: bytes) -> None:
        await self.ws.send(client_message(channel, payload))

    def latest(self, topic: str | None = None) -> int:
        """The log time of the latest message got (of ``topic``), 0 before any."""
        return max((t for name, t, _ in self.got if topic in (None, name)), default=0)

    def logged(self, text: str) -> list[int]:
        """The log times of the ``/log`` lines got that hold ``text``."""
        from foxglove_schemas_protobuf.Log_pb2 import Log

        return [t for name, t, payload in self.got
                if name == "/log" and text in Log.FromString(payload).message]
