"""The recorder sink: everything the pipeline produces, into one MCAP file (mcap + mcap_protobuf).

It takes an already-open binary writer, so tests can record into ``BytesIO``. Channels are
registered when their first message arrives; protobuf schemas are FileDescriptorSets built the
way mcap_protobuf builds them. Chunks are zstd-compressed, 4 MiB (a live drive closes its chunk
every second), at zstandard's default level 3 (:data:`LIVE_LEVEL`) or, for offline conversion,
:data:`OFFLINE_LEVEL`.

Indexes: the summary (schemas, channels, statistics), a chunk index per chunk, attachment and
metadata indexes, and after each chunk one MessageIndex record per channel (16 bytes a message,
uncompressed: what made a raw-frames archive of one message per frame 2.45x its BLF; raw frames
are blocks now, :mod:`bridge.sinks.raw`). The message indexes stay: @mcap/core, the
reader the Foxglove app uses for any file with chunk indexes, refuses a chunk with messages but
no message indexes (tests/test_archive_size.py). ``index_types`` can leave them out for a reader
that does not need them (mcap's Python reader seeks by chunk indexes alone).
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
import sys
import threading
import time
from array import array
from collections.abc import Callable, Iterable, Sequence
from typing import IO, Any, ClassVar

import mcap.writer
import zstandard
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import build_file_descriptor_set

from bridge import __version__
from bridge.decode.codec import Decoded, MessageCodec
from bridge.fences import MCAP
from bridge.pb.can_frame_pb2 import CanFrameBlock
from bridge.sinks.base import Serialized, Sink
from bridge.sinks.raw import RawBlock
from bridge.topics import frames_topic

#: MCAP metadata record written by tankviz (see :func:`Recorder.add_metadata`).
METADATA_NAME = "tankviz"

_MEDIA_TYPES = {".dbc": "application/x-dbc", ".kcd": "application/xml",
                ".arxml": "application/xml", ".sym": "text/plain"}


def media_type(file_name: str) -> str:
    """The attachment media type of a signal database file."""
    suffix = file_name[file_name.rfind("."):].lower() if "." in file_name else ""
    return _MEDIA_TYPES.get(suffix, "application/octet-stream")


#: The zstd level of chunks recorded live (zstandard's default, which mcap's Writer uses).
LIVE_LEVEL = 3
#: The zstd level of chunks written offline (``convert``, ``batch``): the strongest whose
#: compression adds at most 5 % to a whole conversion's CPU (DEVELOPING.md, "Why it is so").
OFFLINE_LEVEL = 6
#: held while mcap's Writer compresses a chunk at another level than its own
_LEVEL_LOCK = threading.Lock()


class _Leveled:
    """Stands in for the ``zstandard`` module in :mod:`mcap.writer` while one chunk is written:
    its ``compress`` at a chosen level."""

    def __init__(self, level: int) -> None:
        self.compress = zstandard.ZstdCompressor(level=level).compress

    def __getattr__(self, name: str) -> Any:
        return getattr(zstandard, name)


_MESSAGE_HEADER = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, 2 times


class _MessageIndex(MessageIndex):
    """mcap's MessageIndex, its (log time, offset) pairs kept flat in an ``array('Q')``.

    A chunk of a busy second holds ~25,000 messages: as tuples in lists they cost ~5 ms to
    pack and ~2 ms to free when the chunk is written, all at once, in the pipeline's thread.
    """

    def __init__(self, channel_id: int) -> None:
        super().__init__(channel_id, [])
        self.entries = array("Q")  # log time, offset, log time, offset, ...

    def write(self, stream: Any) -> None:
        entries = self.entries
        if sys.byteorder != "little":
            entries = array("Q", entries)
            entries.byteswap()
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write(_INDEX_HEADER.pack(self.channel_id, 8 * len(entries)))
        stream.write(entries.tobytes())
        stream.finish_record()


_INDEX_HEADER = struct.Struct("<HI")  # channel id, byte length of the entries


class FastWriter(McapWriter):
    """mcap's Writer, with a faster ``add_message`` for the per-frame hot path.

    mcap's own ``add_message`` spends about 3 µs per message building a record object and
    writing it field by field, and updating the chunk's and the file's statistics; a drive writes
    a decoded message per frame. This one appends the same record bytes to the same chunk builder
    with one ``struct.pack`` and notes (log time, offset) in the chunk's message index; the
    statistics (message counts, first and last times) are worked out from those indexes just
    before mcap finishes each chunk. mcap still writes chunks, indexes and the summary. It relies
    on mcap's internals (:data:`bridge.fences.MCAP`), so it checks for them and falls back to
    mcap's method if they change or the release was not checked;
    tests/test_recorder.py checks that both give byte-identical files.
    """

    def __init__(self, output: IO[bytes], *, level: int = LIVE_LEVEL, **kwargs: Any) -> None:
        super().__init__(output, **kwargs)
        private = "_Writer__"  # mcap.writer.Writer's name-mangled attributes
        self._statistics: Any = getattr(self, private + "statistics", None)
        self._chunk: Any = getattr(self, private + "chunk_builder", None)
        self._chunk_size: Any = getattr(self, private + "chunk_size", None)
        self._finalize_chunk: Any = getattr(self, private + "finalize_chunk", None)
        self._output = output
        if not MCAP.holds():  # mcap's own Writer, without its private names
            self._statistics = self._chunk = self._chunk_size = self._finalize_chunk = None
        self._fast = (
            None not in (self._statistics, self._chunk, self._chunk_size, self._finalize_chunk)
            and hasattr(self._statistics, "channel_message_counts")
            and hasattr(getattr(self._chunk, "record_writer", None), "_buffer")
            and hasattr(self._chunk, "message_indices")
        )
        if self._fast:
            # Every way mcap finishes a chunk (by size, flush, finish, a new channel) calls this
            # attribute: the chunk's statistics are settled first.
            setattr(self, private + "finalize_chunk", self._settle_and_finalize)
        #: the zstd level of the chunks: another than mcap's own only behind the fence
        self.level = level if self._fast and hasattr(mcap.writer, "zstandard") else LIVE_LEVEL
        self._leveled = _Leveled(self.level) if self.level != LIVE_LEVEL else None

    def _settle_and_finalize(self) -> None:
        """The chunk's and the file's statistics from the chunk's message indexes, then mcap
        finishes the chunk."""
        chunk, stats = self._chunk, self._statistics
        counts = stats.channel_message_counts
        for channel_id, index in chunk.message_indices.items():
            if not isinstance(index, _MessageIndex):  # written by mcap's own add_message
                continue
            entries = index.entries
            n = len(entries) // 2
            if not n:
                continue
            times = entries[::2]
            first, last = min(times), max(times)
            if chunk.num_messages == 0 or first < chunk.message_start_time:
                chunk.message_start_time = first
            if last > chunk.message_end_time:
                chunk.message_end_time = last
            if stats.message_count == 0 or first < stats.message_start_time:
                stats.message_start_time = first
            if last > stats.message_end_time:
                stats.message_end_time = last
            counts[channel_id] += n
            chunk.num_messages += n
            stats.message_count += n
        if self._leveled is None:
            self._finalize_chunk()
            return
        with _LEVEL_LOCK:  # mcap's Writer compresses with its module's zstandard.compress
            own = mcap.writer.zstandard  # type: ignore[attr-defined]
            mcap.writer.zstandard = self._leveled  # type: ignore[attr-defined,assignment]
            try:
                self._finalize_chunk()
            finally:
                mcap.writer.zstandard = own  # type: ignore[attr-defined]

    def flush(self) -> None:
        """Close the chunk being built and push everything written so far to the disk."""
        if self._fast:
            self._settle_and_finalize()
            self._output.flush()
        else:
            super().flush()  # type: ignore[no-untyped-call]  # mcap's own: closes the chunk
        fileno = getattr(self._output, "fileno", None)
        if fileno is not None:
            with contextlib.suppress(OSError, ValueError):  # not a real file (BytesIO, a pipe)
                os.fsync(fileno())

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int = 0) -> None:
        if not self._fast:
            super().add_message(channel_id, log_time, data, publish_time, sequence)
            return
        chunk = self._chunk
        index = chunk.message_indices.get(channel_id)
        if index is None:
            index = chunk.message_indices[channel_id] = _MessageIndex(channel_id)
        buffer = chunk.record_writer._buffer
        offset = buffer.tell()
        entries = index.entries
        entries.append(log_time)
        entries.append(offset)
        n = len(data)
        buffer.write(_MESSAGE_HEADER.pack(Opcode.MESSAGE, 22 + n, channel_id, sequence,
                                          log_time, publish_time))
        buffer.write(data)
        if offset + _MESSAGE_HEADER.size + n > self._chunk_size:
            self._settle_and_finalize()


    def add_many(self, messages: Iterable[tuple[int, int, bytes]]) -> None:
        """:meth:`add_message` of each ``(channel id, log time, data)`` in turn (the log time
        is the publish time too), the records of a run written at once."""
        if not self._fast:
            for channel_id, log_time, data in messages:
                super().add_message(channel_id, log_time, data, log_time)
            return
        chunk = self._chunk
        buffer = chunk.record_writer._buffer
        offset = buffer.tell()
        limit, pack, header, message = (self._chunk_size, _MESSAGE_HEADER.pack,
                                        _MESSAGE_HEADER.size, int(Opcode.MESSAGE))
        parts: list[bytes] = []
        #: channel id -> its (log time, offset) pairs, flat, until they go into the chunk's index
        pending: dict[int, list[int]] = {}
        for channel_id, log_time, data in messages:
            entries = pending.get(channel_id)
            if entries is None:
                entries = pending[channel_id] = []
            entries += (log_time, offset)
            n = len(data)
            parts += (pack(message, 22 + n, channel_id, 0, log_time, log_time), data)
            offset += header + n
            if offset > limit:
                self._write_run(buffer, parts, pending)
                self._settle_and_finalize()
                buffer = chunk.record_writer._buffer
                offset = buffer.tell()
        self._write_run(buffer, parts, pending)

    def _write_run(self, buffer: Any, parts: list[bytes], pending: dict[int, list[int]]) -> None:
        """A run's records into the chunk, and their (log time, offset) pairs into its index."""
        buffer.write(b"".join(parts))
        parts.clear()
        indices = self._chunk.message_indices
        for channel_id, entries in pending.items():
            index = indices.get(channel_id)
            if index is None:
                index = indices[channel_id] = _MessageIndex(channel_id)
            index.entries.extend(entries)
        pending.clear()


#: Called with a recorder: when it starts, to attach what its drive is decoded with (databases,
#: profile), so that a file cut before its end still has them; and just before it is finished, to
#: note what describes its drive (the metadata record).
Describe = Callable[["Recorder"], None]


class Recorder(Sink):
    """Writes frames, decoded messages and any protobuf message into one MCAP stream.

    As a :class:`~bridge.sinks.base.Sink` it records everything the pipeline hands it. ``attach``
    adds the drive's attachments right after the file's header, before any message (a file cut
    short still has them); :meth:`finish` has ``describe`` add its metadata first. A topic
    carries one message type: a second one is refused (``ValueError``), as mcap_protobuf's
    writer refuses it. Attachments are stamped with the time they are added, or with
    ``attachment_time_ns`` where given (a re-derived drive: the same inputs, the same bytes).
    ``index_types``: the indexes written, as mcap's Writer takes them (default all; see the
    module's docstring).
    """

    records: ClassVar[bool] = True

    def __init__(self, output: IO[bytes], *, chunk_size: int = 4 * 1024 * 1024,
                 compression: CompressionType = CompressionType.ZSTD,
                 describe: Describe | None = None, attach: Describe | None = None,
                 attachment_time_ns: int | None = None,
                 index_types: IndexType = IndexType.ALL, level: int = LIVE_LEVEL) -> None:
        self._writer = FastWriter(output, chunk_size=chunk_size, compression=compression,
                                  index_types=index_types, level=level)
        #: the create time of the attachments (ns); None: when each is added
        self.attachment_time_ns = attachment_time_ns
        self._writer.start(profile="", library=f"tankviz {__version__}")
        self.describe = describe
        self._schemas: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._channel_schemas: dict[str, str] = {}
        self._payload_channels: dict[str, tuple[int, Any]] = {}
        self._frame_channels: dict[str, int] = {}
        self._codec_channels: dict[MessageCodec, int] = {}
        self.messages = 0
        self._finished = False
        if attach is not None:
            attach(self)

    def _schema(self, name: str, data: bytes) -> int:
        schema_id = self._schemas.get(name)
        if schema_id is None:
            schema_id = self._writer.register_schema(name, SchemaEncoding.Protobuf, data)
            self._schemas[name] = schema_id
        return schema_id

    def channel(self, topic: str, schema_name: str, schema_data: bytes) -> int:
        """The id of a protobuf channel, registered on first use; a topic has one schema."""
        channel_id = self._channel_ids.get(topic)
        if channel_id is None:
            channel_id = self._writer.register_channel(
                topic, MessageEncoding.Protobuf, self._schema(schema_name, schema_data)
            )
            self._channel_ids[topic] = channel_id
            self._channel_schemas[topic] = schema_name
        elif self._channel_schemas[topic] != schema_name:
            raise ValueError(f"topic {topic!r} has type {self._channel_schemas[topic]}, "
                             f"cannot write a {schema_name}")
        return channel_id

    def write_raw(self, block: RawBlock) -> None:
        """A block of raw frames on ``/can/<bus>/frames`` (:mod:`bridge.sinks.raw`)."""
        channel_id = self._frame_channels.get(block.bus)
        if channel_id is None:
            channel_id = self._frame_channels[block.bus] = self.channel(
                frames_topic(block.bus), CanFrameBlock.DESCRIPTOR.full_name,
                build_file_descriptor_set(CanFrameBlock).SerializeToString())
        t = block.t_ns
        self._writer.add_message(channel_id, t, block.payload, t)
        self.messages += 1

    def write_decoded(self, timestamp_ns: int, decoded: Decoded) -> None:
        """A decoded message on ``/can/<bus>/<Message>``."""
        codec = decoded.codec
        channel_id = self._codec_channels.get(codec)
        if channel_id is None:
            channel_id = self._codec_channels[codec] = self.channel(
                codec.topic, codec.schema.full_name, codec.schema.file_descriptor_set())
        self._writer.add_message(channel_id, timestamp_ns, decoded.payload, timestamp_ns)
        self.messages += 1

    def write(self, topic: str, message: Any, timestamp_ns: int) -> None:
        """Any protobuf message (scene, perception, health) on its topic."""
        self.write_payload(topic, type(message), message.SerializeToString(), timestamp_ns)

    def write_payload(self, topic: str, message_class: Any, payload: bytes,
                      timestamp_ns: int) -> None:
        """An already serialized protobuf message of ``message_class`` on its topic."""
        known = self._payload_channels.get(topic)
        if known is not None and known[1] is message_class:
            channel_id = known[0]
        else:
            channel_id = self.channel(topic, message_class.DESCRIPTOR.full_name,
                                      build_file_descriptor_set(message_class).SerializeToString())
            self._payload_channels[topic] = (channel_id, message_class)
        self._writer.add_message(channel_id, timestamp_ns, payload, timestamp_ns)
        self.messages += 1

    # the Sink interface, for the pipeline
    on_decoded = write_decoded

    def on_decoded_many(self, messages: Sequence[tuple[int, Decoded]], /) -> None:
        channels = self._codec_channels
        run: list[tuple[int, int, bytes]] = []
        for t_ns, decoded in messages:
            channel_id = channels.get(decoded.codec)
            if channel_id is None:
                self._writer.add_many(run)  # (what came before the new channel, first)
                run = []
                codec = decoded.codec
                channel_id = channels[codec] = self.channel(
                    codec.topic, codec.schema.full_name, codec.schema.file_descriptor_set())
            run.append((channel_id, t_ns, decoded.payload))
        self._writer.add_many(run)
        self.messages += len(messages)

    def on_raw(self, blocks: Sequence[RawBlock], /) -> None:
        for block in blocks:
            self.write_raw(block)

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        write = self.write_payload
        for topic, message_class, payload, t_ns in messages:
            write(topic, message_class, payload, t_ns)

    def flush(self) -> None:
        """Everything recorded so far onto the disk (the current chunk is closed early)."""
        self._writer.flush()

    def add_metadata(self, values: dict[str, Any], name: str = METADATA_NAME) -> None:
        """A metadata record; values that are not strings are stored as JSON."""
        self._writer.add_metadata(
            name, {k: v if isinstance(v, str) else json.dumps(v, sort_keys=True)
                   for k, v in values.items()})

    def add_attachment(self, name: str, data: bytes, *, media: str | None = None,
                       log_time: int = 0) -> None:
        created = time.time_ns() if self.attachment_time_ns is None else self.attachment_time_ns
        self._writer.add_attachment(created, log_time, name, media or media_type(name), data)

    def finish(self) -> None:
        """Describe the drive (if a ``describe`` was given), write the summary and footer; the
        file is complete after this. Once: later calls do nothing."""
        if not self._finished:
            self._finished = True
            if self.describe is not None:
                self.describe(self)
            self._writer.finish()  # type: ignore[no-untyped-call]
