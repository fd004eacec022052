"""The records of a broken MCAP as :mod:`bridge.apps.recover` reads them: the report, the input
that never reads past a record's end, and what is checked of a record (its header, its fields'
size, an attachment's CRC). How a recovery goes is in :mod:`bridge.apps.recover_salvage`.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO

from mcap.data_stream import RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    DataEnd,
    Header,
    McapRecord,
    Metadata,
    Schema,
)
from mcap.stream_reader import CRCValidationError
from zstandard import ZstdError

#: Name of the metadata record that says what was recovered.
METADATA_NAME = "tankviz.recover"

MAGIC = b"\x89MCAP0\r\n"
CHUNK_SIZE = 4 * 1024 * 1024  # of the recovered file, as the recorder writes them

Progress = Callable[[int, float | None], None]
"""Called now and then with (messages so far, fraction of the input read or None)."""

_OPCODES = {int(op) for op in Opcode}
_RECORD_HEADER = struct.Struct("<BQ")
_INDEX_HEADER = struct.Struct("<BQHI")  # a message index: record header, channel, entries length
#: The records a damaged stretch is stepped over to when no summary says where the next one is:
#: each can prove itself intact (CRC, or fields that take exactly its length).
_RESYNC = {Opcode.CHUNK, Opcode.ATTACHMENT, Opcode.METADATA, Opcode.DATA_END}
_RESYNC_OPCODE = re.compile(b"[" + re.escape(bytes(sorted(_RESYNC))) + b"]")
_REPAIRABLE = {"chunk record": Opcode.CHUNK, "attachment record": Opcode.ATTACHMENT,
               "metadata record": Opcode.METADATA}
_RESYNC_LIMIT = 1 << 30  # a longer record is not read to check it
_SCAN_BLOCK = 1 << 20
_AFTER_DATA = " — after the data section, so no data was lost"
_BLOCK = 1 << 24  # the largest single read from the input
# What mcap, zstd and lz4 raise on bytes that are not what they should be.
_DAMAGE = (McapError, ValueError, struct.error, EOFError, ZstdError, RuntimeError, MemoryError,
           OverflowError)


@dataclass
class RecoverReport:
    """What :func:`recover` found and wrote."""

    messages: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)
    metadata: int = 0
    attachments: int = 0
    #: Every byte before this offset was read (the damaged or cut record starts here).
    bytes_read: int = 0
    bytes_total: int = 0
    #: Why reading stopped, or None if the file was complete (summary, footer, closing magic).
    stopped: str | None = None
    first_ns: int | None = None
    last_ns: int | None = None
    #: Offset of the record where reading stopped (the same as ``bytes_read``), or None.
    stopped_at: int | None = None
    #: Damaged records that were skipped (a chunk or an attachment whose CRC fails), one line each.
    skipped: list[str] = field(default_factory=list)
    #: Records whose damaged header was repaired from the summary's indexes, one line each.
    repaired: list[str] = field(default_factory=list)
    #: Messages dropped because their channel was defined only in a skipped chunk.
    dropped: int = 0

    @property
    def complete(self) -> bool:
        return self.stopped is None

    @property
    def duration_s(self) -> float:
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9


@dataclass
class _Skipped:
    at: int
    what: str
    why: str
    lost: int | None = None  # messages, counted from the message indexes after a chunk


class _Unreadable(Exception):
    """The input raised an OSError: the disk cannot give these bytes."""


class _Input:
    """The broken file as mcap's stream reader reads it.

    It counts bytes, lets :class:`_Salvage` peek at the next record header, never reads past
    ``end`` (the end of the record being parsed) and notes any read that came back short.
    """

    def __init__(self, raw: IO[bytes]) -> None:
        self._raw = raw
        self._pending = b""  # peeked, not yet read
        self.count = 0
        self.end: int | None = None
        self.short = False
        self.eof = False
        self.last = b""

    def _raw_read(self, n: int) -> bytes:
        parts = []
        while n > 0:
            try:
                piece = self._raw.read(min(n, _BLOCK))
            except OSError as exc:
                raise _Unreadable(exc.strerror or str(exc)) from exc
            if not piece:
                self.eof = True
                break
            parts.append(piece)
            n -= len(piece)
        return b"".join(parts)

    def peek(self, n: int) -> bytes:
        if len(self._pending) < n:
            self._pending += self._raw_read(n - len(self._pending))
        return self._pending[:n]

    def read(self, n: int) -> bytes:
        wanted = n
        if self.end is not None:
            n = min(n, self.end - self.count)
        if n <= 0:
            data = b""
        elif self._pending:
            data, self._pending = self._pending[:n], self._pending[n:]
            if len(data) < n:
                data += self._raw_read(n - len(data))
        else:
            data = self._raw_read(n)
        self.count += len(data)
        self.short = self.short or len(data) < wanted
        self.last = data
        return data


def _index_problem(head: bytes) -> str | None:
    """What is wrong with a message index record that starts with ``head`` (its record header,
    channel id and entries length), or None: its fields must take exactly its length."""
    if len(head) < _INDEX_HEADER.size:
        return None  # too short to be checked: mcap's reader will tell
    _, length, _, entries = _INDEX_HEADER.unpack(head)
    if entries % 16:
        return f"its entries take {entries:,} bytes, not a multiple of 16"
    if length != 6 + entries:
        return f"its length field says {length:,} bytes, its fields take {6 + entries:,}"
    return None


def _next_record(known: list[tuple[int, int, str]], at: int) -> tuple[int | None, str | None]:
    """Where the record after the one at ``at`` starts, and what ``at`` holds, from the
    summary's ``known`` records; (None, None) if it does not say."""
    for start, end, kind in known:
        if start <= at < end:
            return end, kind
    later = [start for start, _, _ in known if start > at]
    return (min(later), None) if later else (None, None)


def _kind(opcode: int) -> str:
    """``chunk record``, ``message index record``, … for an opcode."""
    try:
        return Opcode(opcode).name.lower().replace("_", " ") + " record"
    except ValueError:
        return f"record of opcode 0x{opcode:02x}"


def _describe(exc: BaseException) -> str:
    """What a decoding exception says about the bytes, in a few words."""
    if isinstance(exc, CRCValidationError):
        return (f"its CRC does not match its content (stored {exc.expected:#010x}, "
                f"computed {exc.actual:#010x})")
    if isinstance(exc, ZstdError):
        return f"it does not decompress (zstd: {exc})"
    if isinstance(exc, EOFError | struct.error) or (isinstance(exc, McapError) and not str(exc)):
        return "its contents run past its end"
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


#: The records whose fields must take exactly their record's length: the data-section records
#: tankviz copies, and the header and data end around them. (A message takes its length by
#: construction: its data is what the length leaves; summary records are not checked.)
_SIZED = (Chunk, Attachment, Metadata, Schema, Channel, Header, DataEnd)


def _serialised(record: McapRecord) -> RecordBuilder:
    """``record`` as mcap writes it: opcode, length and fields (an attachment's fields end with
    the CRC that mcap computes over them)."""
    builder = RecordBuilder()
    record.write(builder)
    return builder


def _fields_size(record: McapRecord) -> int | None:
    """How many bytes the fields of a data-section record take, as mcap writes them.

    mcap writes what its reader kept, so a record with something the reader drops is found
    damaged: a metadata map (or a channel's) that holds a key twice keeps one value, and its
    serialisation is shorter than the record's length.
    """
    if not isinstance(record, _SIZED):
        return None
    return _serialised(record).count - _RECORD_HEADER.size


def _attachment_crc_ok(a: Attachment, stored: bytes) -> bool:
    """Whether an attachment matches ``stored``, the CRC that ends its record.

    The CRC is the one mcap computes when it writes the attachment (over its fields, log time to
    data). Two things mcap cannot give: the stored CRC (its reader reads it but neither checks
    nor keeps it, so it is taken from the record's last 4 bytes as read), and that a stored 0
    means "written without a CRC" (its writer always writes a computed CRC).
    """
    crc = int.from_bytes(stored, "little")
    if crc == 0:  # written without a CRC
        return True
    written: bytes = _serialised(a).end()  # type: ignore[no-untyped-call]
    return int.from_bytes(written[-4:], "little") == crc
