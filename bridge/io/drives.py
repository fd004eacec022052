"""Sources: the raw CAN frames of a recorded drive (an MCAP tankviz wrote), and what it holds.

This module only reads. :class:`ArchiveSource` gives every raw frame in the order it was
recorded, so re-deriving reproduces the drive; a drive cut short gives every frame of its
complete chunks and one issue pointing to ``tankviz recover``; a file that is not a drive is an
:class:`~bridge.errors.InputError` saying what it lacks.
"""

from __future__ import annotations

import hashlib
import heapq
import json
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, DataEnd, Footer, Message, Metadata, Schema

from bridge.errors import InputError, check_input_path
from bridge.frame import NEVER_NS, Frame
from bridge.io.can_logs import IssueKind, SourceIssue
from bridge.pb.can_frame_pb2 import CanFrame, CanFrameBlock
from bridge.pb.marks_pb2 import Mark
from bridge.topics import MARKS_TOPIC

if TYPE_CHECKING:
    from mcap.reader import McapReader

# mcap's reader and its decompressors are imported where a drive is read: converting logs (every
# convert asks is_drive) never needs them.

#: The suffix of a recorded drive.
DRIVE_SUFFIX = ".mcap"
#: The name of tankviz' metadata record (as :mod:`bridge.sinks.mcap` writes it).
METADATA_NAME = "tankviz"
#: The raw-frame topics (``bridge.topics.frames_topic``).
FRAMES_TOPIC = re.compile(r"/can/(?P<bus>[^/]+)/frames")
#: The schema of raw frames in blocks (``bridge.sinks.raw``); any other is one frame a message.
BLOCK_SCHEMA = CanFrameBlock.DESCRIPTOR.full_name
_MAGIC = b"\x89MCAP0\r\n"


def is_drive(path: Path | str) -> bool:
    """Whether ``path`` names a recorded drive (an MCAP) rather than a CAN log."""
    return Path(path).suffix.lower() == DRIVE_SUFFIX


@dataclass(frozen=True)
class ArchiveContents:
    """What a recorded drive holds besides its frames."""

    path: Path
    size: int
    sha256: str
    #: the ``tankviz`` metadata record, JSON values decoded; empty when the file has none
    metadata: dict[str, Any]
    #: attachment name → bytes, in file order (the first of a name)
    attachments: dict[str, bytes] = field(repr=False)
    #: whether the file was finished (it has its summary and footer)
    complete: bool = True
    #: its marks (``/marks``), in the order of their numbers
    marks: list[Mark] = field(default_factory=list, repr=False)
    #: ``/marks`` messages that are not a ``tankviz.Mark`` (left out of ``marks``)
    unreadable_marks: int = 0


def _values(record: Metadata) -> dict[str, Any]:
    values: dict[str, Any] = {}
    for key, text in record.metadata.items():
        try:
            values[key] = json.loads(text) if text[:1] in "[{" or text in {"null"} else text
        except ValueError:
            values[key] = text
    return values


def _open(path: Path) -> IO[bytes]:
    if path.is_dir():
        raise InputError(path, "is a folder, not a drive (MCAP file)")
    check_input_path(path)
    try:
        stream = path.open("rb")
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    head = stream.read(len(_MAGIC))
    stream.seek(0)
    if head != _MAGIC:
        stream.close()
        raise InputError(path, f"not an MCAP file (it starts with {head!r})")
    return stream


def read_drive(path: Path | str) -> ArchiveContents:
    """The attachments (in file order) and metadata (empty for a file cut short) of the drive at
    ``path``, with its marks, size and SHA-256; a file that is not a drive is an
    :class:`~bridge.errors.InputError` saying what it lacks.
    """
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader

    path = Path(path)
    attachments: dict[str, bytes] = {}
    metadata: dict[str, Any] = {}
    topics: set[str] = set()
    complete = True
    marks: list[Mark] = []
    unreadable = 0
    with _open(path) as stream:
        sha = hashlib.sha256()
        while chunk := stream.read(1 << 20):
            sha.update(chunk)
        digest, size = sha.hexdigest(), stream.tell()
        stream.seek(0)
        try:
            reader = make_reader(stream)
            summary = reader.get_summary()
            if summary is None:
                raise McapError("no summary")
            topics = {c.topic for c in summary.channels.values()}
            for a in reader.iter_attachments():
                attachments.setdefault(a.name, bytes(a.data))
            for m in reader.iter_metadata():
                if m.name == METADATA_NAME:
                    metadata = _values(m)
            marks, unreadable = read_marks(reader)
        except Exception:  # a file cut short or damaged: mcap raises many types
            complete = False
            stream.seek(0)
            found = _MarksFound()
            try:
                for record in StreamReader(stream).records:
                    found.see(record)
                    if isinstance(record, Attachment):
                        attachments.setdefault(record.name, bytes(record.data))
                    elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                        metadata = _values(record)
                    elif isinstance(record, Channel):
                        topics.add(record.topic)
                    elif isinstance(record, (DataEnd, Footer)):
                        break
            except Exception:  # the end of what can be read: ArchiveSource reports it
                pass
            marks, unreadable = by_number(found.marks), found.unreadable
    if not any(FRAMES_TOPIC.fullmatch(t) for t in topics):
        if not complete:
            raise InputError(path, "cut short or damaged before any raw CAN frame "
                             "(/can/<bus>/frames) could be read: nothing to decode again "
                             "(tankviz recover salvages what is complete)")
        raise InputError(path, "not a tankviz drive: it has no raw CAN frames "
                         "(/can/<bus>/frames), so there is nothing to decode again")
    return ArchiveContents(path, size, digest, metadata, attachments, complete, marks,
                           unreadable)


@dataclass
class ArchiveSource:
    """Every raw frame of a recorded drive, in the order it was recorded.

    Iterate once. As :class:`~bridge.io.can_logs.LogSource`: ``issues`` lists what could not be read
    and where, ``frames`` counts the frames, ``backwards`` the steps back of the time, and
    ``progress()`` how much of the file has been read.
    """

    path: Path
    strict: bool = False
    issues: list[SourceIssue] = field(default_factory=list)
    frames: int = 0
    backwards: int = 0
    _stream: IO[bytes] | None = field(default=None, repr=False)
    _size: int = field(default=0, repr=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        _open(self.path).close()
        self._size = self.path.stat().st_size

    def progress(self) -> tuple[int, int]:
        """Bytes of the file read so far and its size."""
        if self._stream is None or self._stream.closed:
            return (self._size if self.frames else 0), self._size
        return self._stream.tell(), self._size

    def _problem(self, where: str, reason: str, kind: IssueKind = "skip",
                 group: str = "") -> None:
        if self.strict:
            raise InputError(self.path, f"{reason} (--strict)", where=where)
        self.issues.append(SourceIssue(str(self.path), where, reason, kind, group))

    def __iter__(self) -> Iterator[Frame]:
        from mcap.stream_reader import StreamReader

        kinds: dict[int, str] = {}  # schema id -> name
        channels: dict[int, bool] = {}  # raw-frame channel id -> whether it carries blocks
        merged = BlockMerger()
        last_ns: int | None = None

        def count(frames: Iterable[Frame]) -> Iterator[Frame]:
            nonlocal last_ns
            for frame in frames:
                t = frame.timestamp_ns
                if not (0 <= t < _LAST_NS and 0 <= frame.arbitration_id < _ID_LIMIT):
                    self._problem(f"frame {self.frames + 1}", _uncarried(frame), "skip",
                                  "a frame no bus carries")
                    continue
                if last_ns is not None and t < last_ns:
                    self.backwards += 1
                last_ns = t
                self.frames += 1
                yield frame

        with _open(self.path) as stream:
            self._stream = stream
            reader = StreamReader(stream)
            try:
                for record in reader.records:
                    if isinstance(record, Message):
                        blocks = channels.get(record.channel_id)
                        if blocks is None:
                            continue
                        if blocks:
                            block = self._block(record)
                            if block is not None:
                                yield from count(merged.add(block_frames(record.log_time, block)))
                            continue
                        yield from count(merged.finish())
                        try:
                            f = CanFrame.FromString(record.data)
                        except DecodeError as exc:
                            self._problem(f"frame {self.frames + 1}", f"skipped a frame that is "
                                          f"not a tankviz.CanFrame ({exc})", "skip",
                                          "not a tankviz.CanFrame")
                            continue
                        yield from count((Frame(
                            record.log_time, f.bus, f.id, f.data, f.extended, f.fd, f.error,
                            f.remote, f.bitrate_switch, f.error_state_indicator, f.dlc),))
                    elif isinstance(record, Schema):
                        kinds[record.id] = record.name
                    elif isinstance(record, Channel):
                        if FRAMES_TOPIC.fullmatch(record.topic):
                            channels[record.id] = kinds.get(record.schema_id) == BLOCK_SCHEMA
                    elif isinstance(record, (DataEnd, Footer)):
                        break
            except InputError:
                raise  # --strict
            except (McapError, EOFError, ValueError, OSError, Exception) as exc:
                reason = " ".join(str(exc).split()) or type(exc).__name__
                self._problem(f"byte {stream.tell()}", f"the drive is cut short or damaged here "
                              f"({reason}): the frames after it are lost; tankviz recover "
                              "salvages every complete record into a new file", "stop",
                              "drive cut short")
            yield from count(merged.finish())

    def _block(self, record: Message) -> CanFrameBlock | None:
        try:
            block: CanFrameBlock = CanFrameBlock.FromString(record.data)
        except DecodeError as exc:
            self._problem(f"frame {self.frames + 1}", "skipped a block of raw frames that is not "
                          f"a tankviz.CanFrameBlock ({exc}; log time {record.log_time})",
                          "skip", "not a tankviz.CanFrameBlock")
            return None
        return block


#: A frame stamped at or after this (2262, 2^63 ns) or before 1970 cannot be held, nor an id of
#: more than 29 bits (as :class:`~bridge.io.can_logs.LogSource` skips them in logs).
_LAST_NS = 1 << 63
_ID_LIMIT = 1 << 29


def _uncarried(frame: Frame) -> str:
    """Why a frame of a drive is skipped: its id or its time."""
    if not 0 <= frame.arbitration_id < _ID_LIMIT:
        return f"skipped a frame with id {frame.arbitration_id:#x}, which no CAN bus carries"
    return (f"skipped a frame stamped {frame.timestamp_ns} ns, "
            + ("after 2262 (the latest time a drive can hold)" if frame.timestamp_ns > 0
               else "before 1970"))


def block_frames(t_ns: int, block: CanFrameBlock) -> list[Frame]:
    """The frames of one block whose log time is ``t_ns``, in their order."""
    bus = block.bus
    return [Frame(t_ns + r.offset_ns, bus, r.id, r.data, r.extended, r.fd, r.error, r.remote,
                  r.bitrate_switch, r.error_state_indicator,
                  r.dlc if r.HasField("dlc") else len(r.data))
            for r in block.frames]


class BlockMerger:
    """The frames of a drive's blocks (:mod:`bridge.sinks.raw`), given in file order, back in
    the order the pipeline saw them.

    Blocks are written in the order of their starts, and no frame is before its block's start:
    so the frames of the blocks read so far that are earlier than the start of the block just
    read can all go, merged by time (each block's in its order; two frames stamped alike in the
    order of their blocks in the file). A block that starts before the one read before it comes
    after a clock step back (or a frame of a bus stamped back): everything read so far goes
    first."""

    def __init__(self) -> None:
        self._pending: list[list[Frame]] = []
        self._last = NEVER_NS

    def add(self, frames: list[Frame]) -> list[Frame]:
        """The frames that can go now, given the next block's (in file order)."""
        if not frames:
            return []
        start = frames[0].timestamp_ns
        out = self.finish() if start < self._last else self._before(start)
        self._pending.append(frames)
        self._last = start
        return out

    def finish(self) -> list[Frame]:
        """Every frame still held, in order."""
        pending, self._pending = self._pending, []
        return _merged(pending)

    def _before(self, horizon: int) -> list[Frame]:
        ready, keep = [], []
        for frames in self._pending:
            n = 0
            for f in frames:
                if f.timestamp_ns >= horizon:
                    break
                n += 1
            if n:
                ready.append(frames[:n])
            if n < len(frames):
                keep.append(frames[n:])
        self._pending = keep
        return _merged(ready)


def _merged(lists: list[list[Frame]]) -> list[Frame]:
    if len(lists) <= 1:
        return lists[0] if lists else []
    return list(heapq.merge(*lists, key=_time))


def _time(frame: Frame) -> int:
    return frame.timestamp_ns


def raw_frame_counts(reader: McapReader) -> dict[str, int]:
    """Frames per bus held by a finished drive (``reader``: mcap's, of its file), counted from
    its raw-frame channels: their message counts (one frame a message) or, for blocks, the rows of
    every block (read: a drive's metadata says it without reading; this is for one that lost it,
    or a recovered drive, which holds fewer than its metadata says)."""
    counts: dict[str, int] = {}
    summary = reader.get_summary()
    if summary is None:
        return counts
    per_message = (summary.statistics.channel_message_counts
                   if summary.statistics is not None else {})
    blocked: list[str] = []
    for c in summary.channels.values():
        if (bus := FRAMES_TOPIC.fullmatch(c.topic)) is None:
            continue
        schema = summary.schemas.get(c.schema_id)
        if schema is not None and schema.name == BLOCK_SCHEMA:
            blocked.append(c.topic)
        else:
            counts[bus["bus"]] = counts.get(bus["bus"], 0) + per_message.get(c.id, 0)
    if blocked:
        for _, channel, message in reader.iter_messages(topics=blocked):
            bus = FRAMES_TOPIC.fullmatch(channel.topic)
            assert bus is not None
            rows = len(CanFrameBlock.FromString(message.data).frames)
            counts[bus["bus"]] = counts.get(bus["bus"], 0) + rows
    return dict(sorted(counts.items()))


def mark_time(mark: Mark) -> int:
    """A recorded mark's log time (ns)."""
    return int(mark.timestamp.ToNanoseconds())


def parse_mark(data: bytes, log_time: int) -> Mark | None:
    """A ``/marks`` message's Mark (stamped with the message's log time where it has no
    timestamp of its own); None if its bytes are not one."""
    try:
        mark: Mark = Mark.FromString(data)
    except DecodeError:
        return None
    if not mark.HasField("timestamp"):
        mark.timestamp.FromNanoseconds(log_time)
    return mark


def by_number(marks: list[Mark]) -> list[Mark]:
    """Marks in the order of their numbers (then of their times)."""
    return sorted(marks, key=lambda m: (m.number, mark_time(m)))


def read_marks(reader: McapReader) -> tuple[list[Mark], int]:
    """The marks of a finished drive (``reader``: mcap's, of its file) in the order of their
    numbers, and how many ``/marks`` messages were not a ``tankviz.Mark``: only the chunks that
    hold ``/marks`` are read (its indexes say which)."""
    summary = reader.get_summary()
    if summary is None or not any(c.topic == MARKS_TOPIC for c in summary.channels.values()):
        return [], 0
    marks: list[Mark] = []
    unreadable = 0
    for _, _, message in reader.iter_messages(topics=[MARKS_TOPIC], log_time_order=False):
        mark = parse_mark(message.data, message.log_time)
        if mark is None:
            unreadable += 1
        else:
            marks.append(mark)
    return by_number(marks), unreadable


@dataclass(frozen=True)
class DriveMarks:
    """The marks a drive recorded (:func:`drive_marks`), and where the drive starts."""

    marks: list[Mark]
    #: the log time of the drive's first message (None: it has none)
    start_ns: int | None
    #: ``/marks`` messages that are not a ``tankviz.Mark`` (skipped)
    unreadable: int = 0

    def seconds(self, mark: Mark) -> float:
        """How many seconds after the drive's first message ``mark`` is."""
        return (mark_time(mark) - (self.start_ns or 0)) / 1e9


def drive_marks(path: Path | str) -> DriveMarks:
    """The marks of the drive at ``path`` (:func:`read_marks`); a drive cut short (no summary)
    is read up to where it is cut. A file that cannot be opened or is not an MCAP is an
    :class:`~bridge.errors.InputError`."""
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader

    path = Path(path)
    with _open(path) as stream:
        try:
            reader = make_reader(stream)
            summary = reader.get_summary()
        except Exception:  # a file cut short or damaged: mcap raises many types
            summary = None
        if summary is not None and summary.statistics is not None:
            marks, unreadable = read_marks(reader)
            stats = summary.statistics
            return DriveMarks(marks, stats.message_start_time if stats.message_count else None,
                              unreadable)
        stream.seek(0)
        found = _MarksFound()
        try:
            for record in StreamReader(stream).records:
                found.see(record)
                if isinstance(record, (DataEnd, Footer)):
                    break
        except Exception:  # where the file is cut: what came before it counts
            pass
        return DriveMarks(by_number(found.marks), found.start_ns, found.unreadable)


@dataclass
class _MarksFound:
    """The marks of a drive read record by record (one cut short), and its first time."""

    marks: list[Mark] = field(default_factory=list)
    unreadable: int = 0
    start_ns: int | None = None
    _channels: set[int] = field(default_factory=set)

    def see(self, record: object) -> None:
        if isinstance(record, Message):
            t = record.log_time
            self.start_ns = t if self.start_ns is None else min(self.start_ns, t)
            if record.channel_id in self._channels:
                mark = parse_mark(record.data, t)
                if mark is None:
                    self.unreadable += 1
                else:
                    self.marks.append(mark)
        elif isinstance(record, Channel) and record.topic == MARKS_TOPIC:
            self._channels.add(record.id)
