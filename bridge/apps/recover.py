"""``tankviz recover``: salvage what a power cut or a killed recorder left of a drive.

The recorder writes zstd chunks and flushes at least every second, so a drive cut by a power loss
or a SIGKILL is a valid header, a run of complete records (chunks, each followed by its message
indexes; metadata and attachments between them) and a partial last record, with no summary and no
footer; a file system may also leave zero bytes where the last data never reached the disk.
:func:`recover` reads such a file record by record with mcap's :class:`StreamReader`, stops
cleanly at the first record it cannot read, and writes every schema, channel, message (log time,
publish time, sequence and data unchanged, in file order), metadata record and attachment it found
into a complete new MCAP (zstd chunks, with a summary), plus a ``tankviz.recover`` metadata record
saying what was recovered and where and why reading stopped.

How a record is read. Before mcap parses a record, its 9-byte header (opcode, length) is checked:
a known opcode, and a length that fits in what is left of the file (so a cut record is recognised
without reading it, and a damaged length cannot make us allocate gigabytes). While mcap parses it,
no read goes past its declared end, and a record whose fields do not take exactly its length is
damaged (MCAP lets later versions append fields to a record, but the records tankviz copies have
none: extra bytes mean a damaged length, and skipping them would skip records unseen). Where the
file ends, where the bytes are zeros or hold no record, where a record is damaged or the disk
cannot read it, reading stops: the record's offset and the reason are the report's
``stopped_at`` and ``stopped``. Message index records are not needed (the writer builds
new ones) and are only counted; a file cut right after a chunk keeps every message of the chunk.

A chunk whose CRC fails (or that does not decompress) is skipped and reading goes on. The choice:
a cut never produces a bad chunk (a cut record is caught by its length first), so a CRC failure
means bytes inside a complete record changed on the disk or in a copy. When the chunk's record
framing is intact (known opcode, length within the file, its fields add up to exactly its length),
the damage is confined to the compressed payload that the CRC covers, the next record starts where
the length says, and every later chunk carries its own CRC: skipping loses the messages of that
one chunk (counted from the message indexes after it) instead of the rest of the drive, which is
what ``mcap recover`` does too. If the framing is not intact, nothing after it can be trusted and
reading stops. An attachment whose CRC fails is skipped the same way. Messages whose channel was
defined only in a skipped chunk are dropped and counted, unless the file still has its summary,
whose copies of the schemas and channels then stand in. Skipped records are listed in the report
(``skipped``); a cut file never has any, so what it recovers is exactly a prefix of its messages.

The input is only ever read. :func:`recover_file` writes ``.<name>.partial`` beside the output and
renames it when the new MCAP is complete.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import struct
import sys
from collections.abc import Callable
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

    # -- the records -------------------------------------------------------------------------

    def run(self) -> None:
        """Read the whole file or up to the first record that cannot be read."""
        source = self.source
        if len(source.read(len(MAGIC))) < len(MAGIC):
            self.stop(0, "the file is empty" if source.count == 0 else
                      f"the file ends inside the MCAP magic ({source.count} of 8 bytes)")
            return
        records = StreamReader(cast(IO[bytes], source), skip_magic=True, emit_chunks=True,
                               record_size_limit=None).records
        in_summary = False
        every = 0
        while True:
            at = source.count
            head = source.peek(_RECORD_HEADER.size)
            problem = self.check_header(head, at, in_summary)
            after_data = in_summary or head[:1] == bytes([Opcode.DATA_END])
            if problem is not None:
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
            if record is None or source.short or source.count != end:
                if source.eof and self.total is None:  # a stream: its length was not known
                    problem = f"the file ends inside a {_kind(opcode)}"
                else:
                    problem = f"this {_kind(opcode)} is damaged: {reason}"
                self.stop(at, problem + (_AFTER_DATA if after_data else ""))
                return
            size = None if in_summary else _fields_size(record)
            if size is not None and size != length:
                self.stop(at, f"this {_kind(opcode)} is damaged: its length field says "
                          f"{length:,} bytes, its fields take {size:,}")
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
            self._summary = {}, {}
            if self.start == 0 and self.raw.seekable():
                position = self.raw.tell()
                try:
                    self.raw.seek(0)
                    found = make_reader(self.raw).get_summary()
                    if found is not None:
                        self._summary = dict(found.schemas), dict(found.channels)
                except (*_DAMAGE, OSError):
                    pass  # no intact summary: the messages are dropped
                finally:
                    self.raw.seek(position)
        return self._summary

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
    if head != MAGIC[:len(head)]:
        raise InputError(name, f"not an MCAP file (it starts with {head!r}, not {MAGIC!r})")
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
        lines.append("the file was complete" + (", but damaged inside" if r.skipped else ""))
        if r.bytes_read < r.bytes_total:
            lines.append(f"  {r.bytes_total - r.bytes_read:,} bytes after its end were ignored")
    else:
        lines.append(f"stopped at byte {r.stopped_at or 0:,}: {r.stopped}")
    for text in r.skipped:
        lines.append(f"skipped the damaged {text}")
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
        "reading stopped. Damaged chunks (CRC mismatch) are skipped and reported.")
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
