"""Sources: the raw CAN frames of a recorded drive (an MCAP tankviz wrote), and what it holds.

A drive that ``tankviz convert``, ``live`` or ``simulate`` recorded keeps every raw frame on
``/can/<bus>/frames`` (``tankviz.CanFrame``), its databases and profile as attachments at the
start of the file, and the ``tankviz`` metadata record at its end. With them the whole pipeline
can run again on the drive (``tankviz convert DRIVE.mcap``, ``tankviz replay DRIVE.mcap
--profile P``). This module only reads: it gives frames, raw attachment bytes and the metadata
values; loading databases and a profile from them is the pipeline's and the apps' business.

- :func:`is_drive`: a path with the ``.mcap`` suffix is read as a drive, not as a CAN log.
- :func:`read_drive`: the drive's attachments (name → bytes, in file order), its ``tankviz``
  metadata (JSON values decoded; empty for a file cut short before it was finished), its size
  and SHA-256. A file that is not an MCAP, or an MCAP without raw-frame topics, is an
  :class:`~bridge.errors.InputError` naming the file and what it lacks.
- :class:`ArchiveSource`: every raw frame in the order it was recorded (the order the pipeline saw
  them when the drive was made: log-time order, with any step back of the clock where it
  happened, so re-deriving reproduces the drive). The file is streamed record by record, so a
  drive cut short (a power loss) gives every frame of its complete chunks; where reading stops
  is one :class:`~bridge.io.logs.SourceIssue` that points to ``tankviz recover``. A frame whose
  bytes are not a ``tankviz.CanFrame`` is skipped and reported; the others go on.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, DataEnd, Footer, Message, Metadata
from mcap.stream_reader import StreamReader

from bridge.errors import InputError
from bridge.frame import Frame
from bridge.io.logs import IssueKind, SourceIssue
from bridge.pb.can_frame_pb2 import CanFrame

#: The suffix of a recorded drive.
DRIVE_SUFFIX = ".mcap"
#: The name of tankviz' metadata record (as :mod:`bridge.sinks.mcap` writes it).
METADATA_NAME = "tankviz"
#: The raw-frame topics (``bridge.topics.frames_topic``).
FRAMES_TOPIC = re.compile(r"/can/[^/]+/frames")
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
    """The attachments and metadata of the drive at ``path``; refuses what is not a drive."""
    path = Path(path)
    attachments: dict[str, bytes] = {}
    metadata: dict[str, Any] = {}
    topics: set[str] = set()
    complete = True
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
        except Exception:  # a file cut short or damaged: mcap raises many types
            complete = False
            stream.seek(0)
            try:
                for record in StreamReader(stream).records:
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
    if not any(FRAMES_TOPIC.fullmatch(t) for t in topics):
        if not complete:
            raise InputError(path, "cut short or damaged before any raw CAN frame "
                             "(/can/<bus>/frames) could be read: nothing to decode again "
                             "(tankviz recover salvages what is complete)")
        raise InputError(path, "not a tankviz drive: it has no raw CAN frames "
                         "(/can/<bus>/frames), so there is nothing to decode again")
    return ArchiveContents(path, size, digest, metadata, attachments, complete)


@dataclass
class ArchiveSource:
    """Every raw frame of a recorded drive, in the order it was recorded.

    Iterate once. As :class:`~bridge.io.logs.LogSource`: ``issues`` lists what could not be read
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
        channels: set[int] = set()
        last_ns: int | None = None
        with _open(self.path) as stream:
            self._stream = stream
            reader = StreamReader(stream)
            try:
                for record in reader.records:
                    if isinstance(record, Message):
                        if record.channel_id not in channels:
                            continue
                        try:
                            f = CanFrame.FromString(record.data)
                        except DecodeError as exc:
                            self._problem(f"frame {self.frames + 1}", f"skipped a frame that is "
                                          f"not a tankviz.CanFrame ({exc})", "skip",
                                          "not a tankviz.CanFrame")
                            continue
                        t = record.log_time
                        if last_ns is not None and t < last_ns:
                            self.backwards += 1
                        last_ns = t
                        self.frames += 1
                        yield Frame(t, f.bus, f.id, f.data, f.extended, f.fd, f.error, f.remote,
                                    f.bitrate_switch, f.error_state_indicator, f.dlc)
                    elif isinstance(record, Channel):
                        if FRAMES_TOPIC.fullmatch(record.topic):
                            channels.add(record.id)
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
