"""The fences around other libraries' private code: which library, the releases checked, the
private names used and where.

Code behind a fence asks :meth:`Fence.holds` before it uses the private names and takes the
public path, where there is one, when it does not; either way one warning line says so, once.
"""

from __future__ import annotations

import functools
import logging
import re
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version

log = logging.getLogger("tankviz.fences")


def installed_version(distribution: str) -> str:
    """The installed release of ``distribution`` (``"?"`` when it is not installed)."""
    try:
        return version(distribution)
    except PackageNotFoundError:
        return "?"


def release(text: str) -> tuple[int, ...]:
    """The release numbers at the start of a version (``"4.6.1rc1"`` → ``(4, 6, 1)``)."""
    found = re.match(r"\d+(\.\d+)*", text)
    return tuple(int(n) for n in found.group().split(".")) if found else ()


@dataclass(frozen=True)
class Fence:
    """One library's private code used by tankviz; it holds when the installed release is in its
    checked range (the range pyproject.toml allows).

    tests/test_fences.py fails on a release the fences do not know: check the code behind the fence
    on it, then widen its range here and in pyproject.toml.
    """

    distribution: str
    #: the releases checked: from ``lowest`` on, before ``beyond`` (pyproject's bounds)
    lowest: str
    beyond: str
    #: the modules with the private code
    where: str
    #: the private names used
    private: tuple[str, ...]
    #: what is done on a release outside the range
    otherwise: str

    def checked(self) -> str:
        return f">={self.lowest},<{self.beyond}"

    def unknown(self) -> str | None:
        """The warning line when the installed release is outside the checked range."""
        installed = installed_version(self.distribution)
        found = release(installed)
        if found and release(self.lowest) <= found < release(self.beyond):
            return None
        return (f"{self.distribution} {installed} is not a release tankviz was checked on "
                f"({self.checked()}, bridge/fences.py): {self.otherwise}")

    def holds(self) -> bool:
        """Whether the installed release was checked; the first time it was not, says so."""
        return _holds(self)


@functools.cache
def _holds(fence: Fence) -> bool:
    text = fence.unknown()
    if text is not None:
        log.warning("%s", text)
    return text is None


def forget() -> None:
    """Check the installed releases again (tests that pretend another release)."""
    _holds.cache_clear()


PYTHON_CAN = Fence(
    "python-can", "4.4", "4.7", "bridge/io/blf.py, bridge/io/buses.py",
    ("can.BLFReader._parse_data", "can.BLFReader._tail", "can.BLFReader.file",
     "can.io.blf's struct layouts and object types", "can.BusABC._recv_internal",
     "can.BusABC._matches_filters"),
    "BLF logs are read by python-can's own reader (a damaged one is not read past its damage) "
    "and buses through recv")
MCAP = Fence(
    "mcap", "1.6", "1.7", "bridge/sinks/mcap.py (FastWriter)",
    ("mcap.writer.Writer.__statistics", "Writer.__chunk_builder", "Writer.__chunk_size",
     "Writer.__finalize_chunk", "ChunkBuilder.record_writer._buffer",
     "ChunkBuilder.message_indices", "mcap.writer.zstandard (chunks at another level)"),
    "messages are written by mcap's own Writer.add_message and flush, chunks at zstd level 3")
FOXGLOVE_WEBSOCKET = Fence(
    "foxglove-websocket", "0.1.4", "0.1.5", "bridge/sinks/server/internals.py",
    ("FoxgloveServer._clients", "FoxgloveServer._channels",
     "FoxgloveServer._handle_raw_client_message", "FoxgloveServer._handle_client_text_message",
     "FoxgloveServer._send_json", "FoxgloveServer._send_status", "ClientState"),
    "the server uses them anyway (there is no public way): check tests/test_server.py")
WEBSOCKETS = Fence(
    "websockets", "12", "18", "bridge/sinks/server/internals.py, client.py",
    ("websockets.legacy.server.WebSocketServerProtocol (write_close_frame, pong, "
     "write_frame_sync, close_rcvd, transport)", "websockets.legacy.framing.prepare_ctrl",
     "the binary frame header written by hand (internals.binary_header)"),
    "the server uses them anyway (there is no public way): check tests/test_server.py")

#: Every fence.
FENCES = (PYTHON_CAN, MCAP, FOXGLOVE_WEBSOCKET, WEBSOCKETS)
