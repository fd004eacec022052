"""``tankviz recover``: salvage what a power cut or a killed recorder left of a drive.

The recorder writes zstd chunks and flushes at least every second, so a drive cut by a power loss
or a SIGKILL is a valid header, a run of complete records (chunks, each followed by its message
indexes; metadata and attachments between them) and a partial last record, with no summary and no
footer; a file system may also leave zero bytes where the last data never reached the disk.
:func:`recover` reads such a file record by record with mcap's :class:`StreamReader`, steps over
damaged records where it can (below), stops cleanly at the first record it cannot read, and
writes every schema, channel, message (log time, publish time, sequence and data unchanged, in
file order), metadata record and attachment it found into a complete new MCAP (zstd chunks, with
a summary), plus a ``tankviz.recover`` metadata record saying what was recovered and where and why
reading stopped.

How a record is read. Before mcap parses a record, its 9-byte header (opcode, length) is checked:
a known opcode, and a length that fits in what is left of the file (so a cut record is recognised
without reading it, and a damaged length cannot make us allocate gigabytes). While mcap parses it,
no read goes past its declared end, and a record whose fields do not take exactly its length is
damaged (MCAP lets later versions append fields to a record, but the records tankviz copies have
none: extra bytes mean a damaged length, and skipping them would skip records unseen). Message
index records are not needed (the writer builds new ones): their fields are checked against their
length, and they are only counted; a file cut right after a chunk keeps every message of the chunk.
Where the file ends, where the disk cannot read it, or where the bytes are damaged and nothing
intact follows, reading stops: the record's offset and the reason are the report's ``stopped_at``
and ``stopped``.

A damaged record is stepped over, and reading goes on, wherever the file says where the next
record starts (only a file that can seek). If the file still has an intact summary (it ends with
a footer and the magic), its chunk, attachment and metadata indexes give where each of those
records, and each chunk's run of message indexes, starts and ends: a chunk, attachment or metadata
record whose header is damaged is read again with the opcode and length its index gives it (the
report's ``repaired``), and any other damaged record is stepped over to the end of what the index
says it is in (a damaged message index: to the end of its chunk's message indexes, losing no
message), or to the next record the indexes know. Without a summary (a drive cut before its end)
the next chunk, attachment, metadata or data end record that proves itself intact is searched for
byte by byte (a chunk or an attachment by its CRC, every one by fields that take exactly its
length). A record cut by the end of the file has nothing intact after it, so a cut file is read up
to its cut record exactly as before. So a cut never leads to a skip, and damage that is not a cut
(a byte changed on the disk or in a copy) loses only the damaged record.

A chunk whose CRC fails (or that does not decompress) is skipped and reading goes on: its record
framing being intact (known opcode, length within the file, its fields add up to exactly its
length), the damage is confined to the compressed payload that the CRC covers, the next record
starts where the length says, and every later chunk carries its own CRC: skipping loses the
messages of that one chunk (counted from the message indexes after it) instead of the rest of the
drive, which is what ``mcap recover`` does too. An attachment whose CRC fails is skipped the same
way. Messages whose channel was defined only in a skipped chunk are dropped and counted, unless
the file still has its summary, whose copies of the schemas and channels then stand in. Skipped
records are listed in the report (``skipped``, each with its offset, what was wrong and where
reading went on); a cut file never has any, so what it recovers is exactly a prefix of its
messages. Metadata records and attachments are copied wherever they are read intact: tankviz
writes a drive's databases and profile as attachments at its start, so a cut drive keeps them.

A file that does not start with the whole MCAP magic (an empty file, another format) is not
recovered: :class:`~bridge.errors.InputError`, and nothing is written.

The input is only ever read. :func:`recover_file` writes ``.<name>.partial`` beside the output and
renames it when the new MCAP is complete.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import re
import struct
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, cast

from mcap.data_stream import RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk
from mcap.summary import Summary
from mcap.writer import CompressionType
from zstandard import ZstdError

from bridge import __version__
from bridge.apps.options import Subparsers
from bridge.apps.progress import ProgressBar
from bridge.errors import InputError, OutputError
from bridge.frame import format_time
from bridge.sinks.mcap import FastWriter as Writer  # mcap's Writer, faster add_message
from bridge.sinks.mcap import atomic_output, check_output

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


class _Salvage:
    """One recovery: reads records from ``source``, writes what they hold with ``writer``."""

    def __init__(self, raw: IO[bytes], source: _Input, writer: Writer, start: int,
                 total: int | None, report: RecoverReport, progress: Progress | None) -> None:
        self.raw, self.source, self.writer = raw, source, writer
        self.start, self.total, self.report, self.progress = start, total, report, progress
        self.started = False
        self.library = ""
        self.schemas: dict[int, int] = {}  # schema id in the broken file → in the fixed file
        self.channels: dict[int, tuple[int, str]] = {}  # channel id → (fixed id, topic)
        self.per_topic: dict[str, int] = {}
        self.skipped: list[_Skipped] = []
        self.after_skip = False  # message indexes that follow belong to a skipped chunk
        self._summary: tuple[dict[int, Schema], dict[int, Channel]] | None = None
        self._full_summary: Summary | None = None
        self.repaired: dict[int, str] = {}  # record header repaired from the summary, by offset
        self._summary_read = False
        #: the data section's records from the summary's indexes, and where the summary starts
        self._layout: tuple[list[tuple[int, int, str]], int | None] | None = None

    # -- the records -------------------------------------------------------------------------

    def run(self) -> None:
        """Read the whole file or up to the first record that cannot be read or stepped over."""
        source = self.source
        source.read(len(MAGIC))  # :func:`recover` has checked it
        records = self.reader()
        in_summary = False
        every = 0
        while True:
            at = source.count
            head = source.peek(_INDEX_HEADER.size)[:_RECORD_HEADER.size]
            problem = self.check_header(head, at, in_summary)
            after_data = in_summary or head[:1] == bytes([Opcode.DATA_END])
            if problem is None and head[0] == Opcode.MESSAGE_INDEX:
                problem = _index_problem(source.peek(_INDEX_HEADER.size))
            if problem is not None:
                if not in_summary and self.step_over(at, head, problem):
                    records = self.reader()
                    in_summary = self.in_summary(source.count)
                    continue
                self.stop(at, problem + (_AFTER_DATA if after_data else ""))
                return
            opcode, length = _RECORD_HEADER.unpack(head)
            end = at + _RECORD_HEADER.size + length
            if opcode == Opcode.MESSAGE_INDEX or opcode not in _OPCODES:
                data = source.read(end - at)  # not needed: only counted
                if len(data) < end - at:  # a stream: its length was not known
                    self.stop(at, f"the file ends inside a {_kind(opcode)}")
                    return
                self.pass_over(opcode, data)
                continue
            source.end, source.short = end, False
            try:
                record = next(records, None)
            except _Unreadable as exc:
                self.stop(at, f"the disk cannot read this {_kind(opcode)}: {exc}")
                return
            except _DAMAGE as exc:
                record, reason = None, _describe(exc)
            else:
                reason = "its fields do not add up to its length"
            if record is not None and not source.short and source.count == end:
                size = None if in_summary else _fields_size(record)
                if size is not None and size != length:
                    record, reason = None, (f"its length field says {length:,} bytes, its fields "
                                            f"take {size:,}")
            elif source.eof and self.total is None:  # a stream: its length was not known
                self.stop(at, f"the file ends inside a {_kind(opcode)}"
                          + (_AFTER_DATA if after_data else ""))
                return
            else:
                record = None
            if record is None:
                source.end = None
                if not in_summary and self.step_over(at, head, reason):
                    records = self.reader()
                    in_summary = self.in_summary(source.count)
                    continue
                self.stop(at, f"this {_kind(opcode)} is damaged: {reason}"
                          + (_AFTER_DATA if after_data else ""))
                return
            source.end = None
            self.after_skip = False
            if not self.started:
                self.begin(record if isinstance(record, Header) else None)
            if isinstance(record, Footer):
                self.finish_footer()
                return
            if isinstance(record, DataEnd):
                in_summary = True
            elif not in_summary:
                self.take(record, at)
            every += 1
            if self.progress is not None and every % 64 == 0:
                self.progress(self.report.messages,
                              source.count / self.total if self.total else None)

    def reader(self) -> Iterator[McapRecord]:
        """mcap's records from where the input is now (again after a damaged record)."""
        return StreamReader(cast(IO[bytes], self.source), skip_magic=True, emit_chunks=True,
                            record_size_limit=None).records

    # -- stepping over a damaged record -------------------------------------------------------

    def step_over(self, at: int, head: bytes, problem: str) -> bool:
        """Go on after the damaged record at ``at``, if the file says where the next one starts.

        Only a file that can seek: where its summary is intact, its indexes give where every
        chunk, message index run, attachment and metadata record starts and ends; otherwise the
        next chunk, attachment, metadata or data end record that proves itself (CRC, fields that
        take exactly its length) is searched for. A record cut by the end of the file (nothing
        after it proves itself) is not stepped over: reading stops there, as before.
        """
        if len(head) < _RECORD_HEADER.size or self.total is None or not self.raw.seekable():
            return False
        known = self.known_records()
        target, kind = _next_record(known, at)
        if self.repair(at, head, known, problem):
            return True
        if target is not None and not self.starts_record(target):
            target, kind = None, None
        how = "where the summary's indexes say the next record starts"
        if target is None:
            target, how = self.scan(at), "the next record found intact"
            kind = None
        if target is None:
            return False
        opcode, length = _RECORD_HEADER.unpack(head)
        what = kind or (_kind(opcode) if opcode in _OPCODES else "record")
        why = self.damage(at, opcode, length, problem)
        if kind == "message index record":  # the end of the chunk's message indexes
            why += "; no message lost (message indexes are not needed)"
        elif kind is None and self.index_run_ends_at(at, target):
            why += "; no message lost (message indexes are not needed)"
            what = "message index record"
        else:
            why += f"; reading went on at byte {target:,}, {how}"
        self.skip(at, what, why)
        if what != "chunk record":  # only a chunk's message indexes count its lost messages
            self.after_skip = False
        self.jump(target)
        return True

    def repair(self, at: int, head: bytes, known: list[tuple[int, int, str]],
               problem: str) -> bool:
        """Read the record at ``at`` again with the opcode and length the summary's index gives
        it, if they differ from its header's (once: a record still damaged then is skipped)."""
        extent = next(((end, kind) for start, end, kind in known if start == at), None)
        if extent is None or at in self.repaired or extent[1] not in _REPAIRABLE:
            return False
        opcode, length = _RECORD_HEADER.unpack(head)
        fixed = _RECORD_HEADER.pack(_REPAIRABLE[extent[1]],
                                    extent[0] - at - _RECORD_HEADER.size)
        if fixed == head:
            return False
        self.repaired[at] = (f"{extent[1]} at byte {at:,}: "
                             f"{self.damage(at, opcode, length, problem)}; read with the opcode "
                             "and length the summary's index gives it")
        self.jump(at)
        self.source._pending = fixed
        self.raw.seek(self.start + at + _RECORD_HEADER.size)
        return True

    def damage(self, at: int, opcode: int, length: int, problem: str) -> str:
        """What is wrong with the record at ``at``, which is damaged (not cut by the end)."""
        assert self.total is not None
        left = self.total - at - _RECORD_HEADER.size
        if not opcode and not length:
            return "its header is zero bytes"
        if opcode not in _OPCODES and opcode < 0x80:
            return f"its opcode 0x{opcode:02x} is no MCAP record's"
        if length > left:
            return (f"its length field says {length:,} bytes, more than the {left:,} left in "
                    "the file")
        return problem

    def jump(self, target: int) -> None:
        """Read on from ``target`` (an offset from where the input started)."""
        source = self.source
        self.raw.seek(self.start + target)
        source._pending, source.count, source.end = b"", target, None
        source.eof = source.short = False

    def in_summary(self, at: int) -> bool:
        return self._layout is not None and self._layout[1] is not None and at >= self._layout[1]

    def known_records(self) -> list[tuple[int, int, str]]:
        """(start, end, kind) of the data section's records, from an intact summary, sorted."""
        if self._layout is None:
            self._layout = [], None
            found = self.full_summary()
            summary_start = self.summary_start()
            if found is not None and summary_start is not None:
                known = []
                for c in found.chunk_indexes:
                    end = c.chunk_start_offset + c.chunk_length
                    known.append((c.chunk_start_offset, end, "chunk record"))
                    if c.message_index_length:
                        known.append((end, end + c.message_index_length, "message index record"))
                known += [(a.offset, a.offset + a.length, "attachment record")
                          for a in found.attachment_indexes]
                known += [(m.offset, m.offset + m.length, "metadata record")
                          for m in found.metadata_indexes]
                data_end = summary_start - _RECORD_HEADER.size - 4
                known.append((data_end, summary_start, "data end record"))
                self._layout = sorted(known), summary_start
        return self._layout[0]

    def summary_start(self) -> int | None:
        """Where the summary section starts, if the file ends with a footer and the magic."""
        assert self.total is not None
        size = _RECORD_HEADER.size + 20 + len(MAGIC)
        if self.total < size + len(MAGIC):
            return None
        tail = self.read_at(self.total - size, size)
        if tail is None or tail[:9] != _RECORD_HEADER.pack(Opcode.FOOTER, 20) or (
                tail[-8:] != MAGIC):
            return None
        (start,) = struct.unpack_from("<Q", tail, 9)
        return start if 0 < start < self.total else None

    def read_at(self, at: int, n: int) -> bytes | None:
        """``n`` bytes at ``at`` (or fewer at the end), the input's position kept."""
        position = self.raw.tell()
        try:
            self.raw.seek(self.start + at)
            return self.raw.read(n)
        except OSError:
            return None
        finally:
            self.raw.seek(position)

    def starts_record(self, at: int) -> bool:
        """Whether an intact message index record, or any record :meth:`record_at` finds
        intact, starts at ``at``."""
        head = self.read_at(at, _INDEX_HEADER.size) or b""
        if head[:1] == bytes([Opcode.MESSAGE_INDEX]) and len(head) == _INDEX_HEADER.size:
            return _index_problem(head) is None
        return self.record_at(at) is not None

    def record_at(self, at: int) -> McapRecord | None:
        """The record at ``at`` if it proves itself intact, else None.

        A chunk must pass its CRC, an attachment its CRC, and every record's fields must take
        exactly its length; a metadata or data end record (no CRC) must be followed by a record
        header that could be one.
        """
        assert self.total is not None
        head = self.read_at(at, _RECORD_HEADER.size)
        if head is None or len(head) < _RECORD_HEADER.size:
            return None
        opcode, length = _RECORD_HEADER.unpack(head)
        end = at + _RECORD_HEADER.size + length
        if opcode not in _RESYNC or end > self.total or length > _RESYNC_LIMIT:
            return None
        data = self.read_at(at, end - at)
        if data is None or len(data) != end - at:
            return None
        try:
            record = next(StreamReader(io.BytesIO(data), skip_magic=True, emit_chunks=True,
                                       record_size_limit=None).records)
            if _fields_size(record) != length:
                return None
            if isinstance(record, Chunk):
                if not record.uncompressed_crc:
                    return None
                breakup_chunk(record, validate_crc=True)
            elif isinstance(record, Attachment):
                if not int.from_bytes(data[-4:], "little") or not _attachment_crc_ok(
                        record, data[-4:]):
                    return None
            else:
                after = self.read_at(end, _RECORD_HEADER.size) or b""
                if len(after) == _RECORD_HEADER.size:
                    if after[0] not in _OPCODES or _RECORD_HEADER.unpack(after)[1] > (
                            self.total - end - _RECORD_HEADER.size):
                        return None
                elif after != MAGIC[:len(after)] or not isinstance(record, DataEnd):
                    return None
        except (*_DAMAGE, StopIteration):
            return None
        return record

    def scan(self, at: int) -> int | None:
        """The offset of the first record after ``at`` that proves itself intact, or None."""
        assert self.total is not None
        position = at + 1
        while position + _RECORD_HEADER.size <= self.total:
            block = self.read_at(position, _SCAN_BLOCK + _RECORD_HEADER.size)
            if not block:
                return None
            for match in _RESYNC_OPCODE.finditer(block, 0, _SCAN_BLOCK):
                candidate = position + match.start()
                if match.start() + _RECORD_HEADER.size > len(block):
                    break
                (length,) = struct.unpack_from("<Q", block, match.start() + 1)
                if length <= self.total - candidate - _RECORD_HEADER.size and (
                        self.record_at(candidate) is not None):
                    return candidate
            position += _SCAN_BLOCK
        return None

    def index_run_ends_at(self, at: int, target: int) -> bool:
        """Whether the bytes from ``at`` to ``target`` are message index records (their
        entries' lengths lead exactly to ``target``, whatever their opcodes and lengths say)."""
        position = at
        while position < target:
            head = self.read_at(position, _INDEX_HEADER.size)
            if head is None or len(head) < _INDEX_HEADER.size:
                return False
            (entries,) = struct.unpack_from("<I", head, 11)
            if entries % 16:
                return False
            position += _INDEX_HEADER.size + entries
        return position == target

    def check_header(self, head: bytes, at: int, in_summary: bool) -> str | None:
        """Why the record that starts at ``at`` cannot be read, or None if it can."""
        if not head:
            if in_summary:
                return "the file ends inside the summary section"
            if at == len(MAGIC):
                return "the file ends right after the MCAP magic"
            return ("the file ends after the last complete record (the recording was cut before "
                    "it wrote its summary)")
        if len(head) < _RECORD_HEADER.size:
            return f"the file ends inside the header of the next record ({len(head)} of 9 bytes)"
        opcode, length = _RECORD_HEADER.unpack(head)
        if not any(head):
            return ("zero bytes where the next record should start (data that never reached the "
                    "disk before the power went off?)")
        if opcode not in _OPCODES and opcode < 0x80:  # 0x80-0xff: private records, skipped
            return f"no MCAP record starts here (opcode 0x{opcode:02x}): the data is damaged"
        if self.total is not None and _RECORD_HEADER.size + length > self.total - at:
            return (f"the file ends inside a {_kind(opcode)} of {9 + length:,} bytes "
                    f"({self.total - at:,} of them are there)")
        return None

    def pass_over(self, opcode: int, data: bytes) -> None:
        """A message index (counted for a chunk just skipped) or a private record."""
        if opcode == Opcode.MESSAGE_INDEX and self.after_skip and len(data) >= 15:
            (entries_length,) = struct.unpack_from("<I", data, 11)
            skipped = self.skipped[-1]
            skipped.lost = (skipped.lost or 0) + entries_length // 16

    def take(self, record: McapRecord, at: int) -> None:
        """Copy one record of the data section into the fixed file."""
        if isinstance(record, Chunk):
            try:
                inner = breakup_chunk(record, validate_crc=True)
            except _DAMAGE as exc:
                when = (f"log time {format_time(record.message_start_time)} to "
                        f"{format_time(record.message_end_time)}")
                self.skip(at, f"chunk ({when})", _describe(exc))
                return
            for r in inner:
                self.take(r, at)
        elif isinstance(record, Message):
            self.message(record)
        elif isinstance(record, Channel):
            self.define_channel(record)
        elif isinstance(record, Schema):
            self.define_schema(record)
        elif isinstance(record, Metadata):
            self.writer.add_metadata(record.name, dict(record.metadata))
            self.report.metadata += 1
        elif isinstance(record, Attachment):
            if not _attachment_crc_ok(record, self.source.last):  # its last 4 bytes
                self.skip(at, f"attachment {record.name!r}",
                          "its CRC does not match its content")
                return
            self.writer.add_attachment(record.create_time, record.log_time, record.name,
                                       record.media_type, record.data)
            self.report.attachments += 1
        # Header, data end and summary records carry nothing to copy.

    def skip(self, at: int, what: str, why: str) -> None:
        self.skipped.append(_Skipped(at, what, why))
        self.repaired.pop(at, None)  # repaired, and still damaged
        self.after_skip = True

    def message(self, m: Message) -> None:
        target = self.channels.get(m.channel_id)
        if target is None:
            target = self.channel_from_summary(m.channel_id)
            if target is None:
                self.report.dropped += 1
                return
        channel_id, topic = target
        self.writer.add_message(channel_id, m.log_time, m.data, m.publish_time, m.sequence)
        self.per_topic[topic] = self.per_topic.get(topic, 0) + 1
        report = self.report
        report.messages += 1
        t = m.log_time
        if report.first_ns is None or t < report.first_ns:
            report.first_ns = t
        if report.last_ns is None or t > report.last_ns:
            report.last_ns = t

    # -- schemas and channels ----------------------------------------------------------------

    def define_schema(self, schema: Schema) -> None:
        if schema.id != 0 and schema.id not in self.schemas:
            self.schemas[schema.id] = self.writer.register_schema(
                schema.name, schema.encoding, schema.data)

    def define_channel(self, channel: Channel) -> None:
        if channel.id in self.channels:
            return
        schema_id = self.schema_id(channel.schema_id)
        if schema_id is None:  # its schema was lost with a skipped chunk: drop its messages
            return
        fixed = self.writer.register_channel(channel.topic, channel.message_encoding, schema_id,
                                             dict(channel.metadata))
        self.channels[channel.id] = (fixed, channel.topic)

    def schema_id(self, original: int) -> int | None:
        if original != 0 and original not in self.schemas:
            schema = self.summary()[0].get(original)
            if schema is None:
                return None
            self.define_schema(schema)
        return self.schemas.get(original, 0)

    def channel_from_summary(self, original: int) -> tuple[int, str] | None:
        channel = self.summary()[1].get(original)
        if channel is not None:
            self.define_channel(channel)
        return self.channels.get(original)

    def summary(self) -> tuple[dict[int, Schema], dict[int, Channel]]:
        """The summary section's schemas and channels, if the file still has an intact one.

        Only read when a message's channel is missing (defined in a skipped chunk).
        """
        if self._summary is None:
            found = self.full_summary()
            self._summary = ({}, {}) if found is None else (dict(found.schemas),
                                                            dict(found.channels))
        return self._summary

    def full_summary(self) -> Summary | None:
        """The summary section, if the file still has an intact one (read once, when needed)."""
        if not self._summary_read:
            self._summary_read = True
            if self.start == 0 and self.raw.seekable():
                position = self.raw.tell()
                try:
                    self.raw.seek(0)
                    self._full_summary = make_reader(self.raw).get_summary()
                except (*_DAMAGE, OSError):
                    pass  # no intact summary
                finally:
                    self.raw.seek(position)
        return self._full_summary

    # -- the ends ----------------------------------------------------------------------------

    def begin(self, header: Header | None) -> None:
        self.started = True
        if header is not None:
            self.library = header.library
        self.writer.start(profile=header.profile if header is not None else "",
                          library=f"tankviz {__version__} (recover)")

    def finish_footer(self) -> None:
        """After the footer: the closing magic, then the file is complete."""
        at = self.source.count
        if self.source.read(len(MAGIC)) != MAGIC:
            self.stop(at, "the closing MCAP magic is missing or damaged" + _AFTER_DATA)
        else:
            self.report.bytes_read = self.source.count

    def stop(self, at: int, reason: str) -> None:
        self.report.stopped_at = self.report.bytes_read = at
        self.report.stopped = reason

    def finish(self) -> None:
        """Count what is left of the input, then write the recover record and the summary."""
        report, source = self.report, self.source
        if self.total is None:  # a stream that cannot seek: read to its end to count it
            source.end = None
            try:
                while source.read(_BLOCK):
                    pass
            except _Unreadable:
                pass
            self.total = source.count
        report.bytes_total = self.total
        report.per_topic = dict(sorted(self.per_topic.items()))
        report.skipped = [
            f"{s.what} at byte {s.at:,}: {s.why}"
            + ("" if s.lost is None else f"; {s.lost:,} messages lost")
            for s in self.skipped
        ]
        report.repaired = [self.repaired[at] for at in sorted(self.repaired)]
        if not self.started:
            self.begin(None)

    def record(self, source_name: str) -> dict[str, str]:
        """The ``tankviz.recover`` metadata record."""
        r = self.report
        values: dict[str, object] = {
            "tankviz_version": __version__,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "source": source_name,
            "source_library": self.library,
            "bytes_read": r.bytes_read,
            "bytes_total": r.bytes_total,
            "complete": r.complete,
            "stopped_at": r.stopped_at,
            "stopped": r.stopped or "",
            "skipped": r.skipped,
            "repaired": r.repaired,
            "messages": r.messages,
            "messages_per_topic": r.per_topic,
            "dropped_messages": r.dropped,
            "metadata": r.metadata,
            "attachments": r.attachments,
            "first_ns": r.first_ns,
            "last_ns": r.last_ns,
        }
        return {k: v if isinstance(v, str) else json.dumps(v, sort_keys=True)
                for k, v in values.items()}


def recover(broken: IO[bytes], fixed: IO[bytes], *, source_name: str = "",
            progress: Progress | None = None) -> RecoverReport:
    """Copy every complete record of the MCAP ``broken`` into a complete new MCAP on ``fixed``.

    Reads ``broken`` from its current position; a cut or damaged file never raises, its report
    says where and why reading stopped. Raises :class:`InputError` (naming ``source_name``) if
    ``broken`` does not start like an MCAP at all; then nothing is written to ``fixed``.
    """
    name = source_name or "input"
    start, total = 0, None
    if broken.seekable():
        start = broken.tell()
        total = broken.seek(0, os.SEEK_END) - start
        broken.seek(start)
    source = _Input(broken)
    try:
        head = source.peek(len(MAGIC))
    except _Unreadable as exc:
        raise InputError(name, f"cannot read: {exc}") from None
    if not head:
        raise InputError(name, "not an MCAP file (it is empty)")
    if head != MAGIC[:len(head)]:
        raise InputError(name, f"not an MCAP file (it starts with {head!r}, not {MAGIC!r})")
    if len(head) < len(MAGIC):
        raise InputError(name, f"not an MCAP file (its {len(head)} bytes are the start of the "
                         "MCAP magic, nothing more)")
    report = RecoverReport()
    writer = Writer(fixed, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
    salvage = _Salvage(broken, source, writer, start, total, report, progress)
    try:
        salvage.run()
    except _Unreadable as exc:  # reading the rest to count it, or the closing magic
        salvage.stop(source.count, f"the disk cannot read the file here: {exc}")
    salvage.finish()
    writer.add_metadata(METADATA_NAME, salvage.record(source_name))
    writer.finish()  # type: ignore[no-untyped-call]
    if progress is not None:
        progress(report.messages, 1.0)
    return report


def recover_file(broken: Path | str, fixed: Path | str, *, force: bool = False,
                 progress: Progress | None = None) -> RecoverReport:
    """Recover the MCAP file ``broken`` into ``fixed``, which is refused if it exists (unless
    ``force``) or is ``broken`` itself; a failed recovery leaves no output file."""
    broken, fixed = Path(broken), Path(fixed)
    if not broken.exists():
        raise InputError(broken, "no such file")
    if broken.is_dir():
        raise InputError(broken, "is a directory, not an MCAP file")
    if fixed.exists() and fixed.resolve() == broken.resolve():
        raise OutputError(fixed, "is the file to recover; write the recovered drive to a new file")
    check_output(fixed, force=force)
    try:
        source = broken.open("rb")
    except OSError as exc:
        raise InputError(broken, f"cannot read: {exc.strerror or exc}") from None
    with source, atomic_output(fixed) as stream:
        return recover(source, stream, source_name=str(broken), progress=progress)


def format_report(report: RecoverReport, broken_path: Path | str, fixed_path: Path | str) -> str:
    """The lines ``tankviz recover`` prints."""
    r = report
    topics = len(r.per_topic)
    if r.messages and r.first_ns is not None and r.last_ns is not None:
        lines = [f"recovered {r.messages:,} messages in {topics} topic{'s' * (topics != 1)} "
                 f"spanning {r.duration_s:.3f} s (from {format_time(r.first_ns)} to "
                 f"{format_time(r.last_ns)})"]
    else:
        lines = ["recovered no messages"]
    width = max((len(t) for t in r.per_topic), default=0)
    digits = max((len(f"{n:,}") for n in r.per_topic.values()), default=0)
    lines += [f"  {topic:<{width}}  {n:>{digits},}" for topic, n in r.per_topic.items()]
    lines.append(f"  {r.metadata} metadata record{'s' * (r.metadata != 1)}, "
                 f"{r.attachments} attachment{'s' * (r.attachments != 1)}")
    share = ""
    if r.bytes_total:  # rounded down: a file that was not read to its end never shows 100.0 %
        share = f" ({math.floor(1000 * r.bytes_read / r.bytes_total) / 10:.1f} %)"
    lines.append(f"read {r.bytes_read:,} of {r.bytes_total:,} bytes of {broken_path}{share}")
    if r.stopped is None:
        lines.append("the file was complete"
                     + (", but damaged inside" if r.skipped or r.repaired else ""))
        if r.bytes_read < r.bytes_total:
            lines.append(f"  {r.bytes_total - r.bytes_read:,} bytes after its end were ignored")
    else:
        lines.append(f"stopped at byte {r.stopped_at or 0:,}: {r.stopped}")
    for text in r.skipped:
        lines.append(f"skipped the damaged {text}")
    for text in r.repaired:
        lines.append(f"repaired the damaged {text}")
    if r.dropped:
        lines.append(f"dropped {r.dropped:,} messages whose channel was defined only in a "
                     "skipped chunk")
    lines.append(f"wrote {fixed_path} (its {METADATA_NAME} metadata record says what was "
                 "recovered)")
    return "\n".join(lines)


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "recover", help="salvage a drive (MCAP) cut short by a power loss or a crash",
        description="Copy every complete record of an MCAP file that was cut short (power loss, "
        "killed recorder) into a complete new MCAP, and say what was recovered and where and why "
        "reading stopped. Damaged records are skipped (or repaired from the file's indexes) and "
        "reported.")
    parser.add_argument("input", type=Path, metavar="BROKEN.mcap")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="FIXED.mcap",
                        help="the complete MCAP to write")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no report")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    bar = ProgressBar(sys.stderr, unit="messages") if not args.quiet else None
    try:
        report = recover_file(args.input, args.output, force=args.force, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        print(format_report(report, args.input, args.output))
    return 0
