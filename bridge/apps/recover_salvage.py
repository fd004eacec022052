"""One recovery of a broken MCAP (:class:`_Salvage`): read record by record, step over or repair
damaged records, copy what is intact. What it promises is in :mod:`bridge.apps.recover`, why it
steps over damage in DEVELOPING.md ("Why it is so"); the records and their checks are in
:mod:`bridge.apps.recover_records`.
"""

from __future__ import annotations

import io
import json
import struct
from collections.abc import Iterator
from datetime import datetime, timezone
from typing import IO, cast

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
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.summary import Summary

from bridge import __version__
from bridge.apps.recover_records import (
    _AFTER_DATA,
    _BLOCK,
    _DAMAGE,
    _INDEX_HEADER,
    _OPCODES,
    _RECORD_HEADER,
    _REPAIRABLE,
    _RESYNC,
    _RESYNC_LIMIT,
    _RESYNC_OPCODE,
    _SCAN_BLOCK,
    MAGIC,
    Progress,
    RecoverReport,
    _attachment_crc_ok,
    _describe,
    _fields_size,
    _index_problem,
    _Input,
    _kind,
    _next_record,
    _Skipped,
    _Unreadable,
)
from bridge.frame import format_time
from bridge.sinks.mcap import FastWriter as Writer  # mcap's Writer, faster add_message


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
