"""Sources: CAN frames from log files (python-can's readers), merged in time order.

The readers are python-can's own, chosen by suffix. What tankviz adds is what a drive archive
needs around them: integer-nanosecond timestamps, bus names, and resilience. python-can's readers
stop at the first line or object they cannot parse; :class:`LogSource` records the place and the
reason and carries on after it, so everything readable is converted and nothing is skipped
silently. With ``strict=True`` the first such problem is an :class:`~bridge.errors.InputError`.

Time: logs with absolute time (BLF, candump, TRC, CSV/SQLite as python-can writes them, ASC with a
dated ``Begin Triggerblock``) keep it. python-can reports float seconds, which at Unix-epoch
magnitudes resolve about a quarter of a microsecond, so times are rounded to whole microseconds
when converted to nanoseconds. Logs without a start date (an ASC without a date) start at 0.
"""

from __future__ import annotations

import gzip
import heapq
import io
import itertools
import logging
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import can
from can.io.generic import MessageReader, TextIOMessageReader
from can.io.player import MESSAGE_READERS

from bridge.errors import InputError
from bridge.frame import Frame

#: The bus name for frames whose log names no channel (CSV, SQLite, some error frames).
DEFAULT_BUS = "can0"

#: Formats whose reader tankviz can resume after a bad line (python-can reads them line by line).
_LINE_FORMATS = {".asc", ".log", ".trc", ".csv"}


def supported_suffixes() -> list[str]:
    """Every log suffix python-can reads here, plus its ``.gz`` variant."""
    plain = sorted(MESSAGE_READERS)
    return plain + [f"{s}.gz" for s in plain if s not in {".db", ".mf4"}]


def bus_name(channel: Any) -> str:
    """The bus name of a python-can channel: ``can<N>`` for numbered channels, else the name."""
    if channel is None or channel == "":
        return DEFAULT_BUS
    if isinstance(channel, int):
        return f"can{channel}"
    text = str(channel).strip()
    return f"can{text}" if text.isdigit() else text


@dataclass(frozen=True)
class SourceIssue:
    """Something in a log that could not be read as a frame, and where."""

    path: str
    where: str
    reason: str

    def __str__(self) -> str:
        return f"{self.path}:{self.where}: {self.reason}"


def _suffix(path: Path) -> tuple[str, bool]:
    """The log format suffix (``.blf``) and whether the file is gzip-compressed."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        return (suffixes[-2] if len(suffixes) >= 2 else ""), True
    return (suffixes[-1] if suffixes else ""), False


class _Lines:
    """The line iterator python-can's text readers consume, counting lines as they go.

    Until the first frame has been read it remembers the lines it served (the log's header), so a
    fresh reader can be primed with them to carry on after a line python-can could not parse.
    """

    def __init__(self, lines: Iterator[str], start_line: int = 0) -> None:
        self._lines = lines
        self.line = start_line
        self.header: list[str] | None = []

    def __iter__(self) -> _Lines:
        return self

    def __next__(self) -> str:
        text = next(self._lines)
        self.line += 1
        if self.header is not None:
            self.header.append(text)
        return text

    def readline(self) -> str:
        return next(self, "")

    def close(self) -> None:
        """The underlying file is closed by :class:`LogSource`."""


class _Bytes:
    """The binary stream python-can's BLF reader consumes, noticing where the file is cut short."""

    def __init__(self, stream: IO[bytes]) -> None:
        self._stream = stream
        self.offset = 0
        self.cut_at: int | None = None

    def read(self, size: int = -1) -> bytes:
        data = self._stream.read(size)
        if size > 0 and 0 < len(data) < size and self.cut_at is None:
            self.cut_at = self.offset
        self.offset += len(data)
        return data

    def close(self) -> None:
        """The underlying file is closed by :class:`LogSource`."""


@dataclass
class LogSource:
    """Every frame python-can can read from one log file, in file order.

    Iterate once. ``issues`` then lists what was skipped and where; ``frames`` counts what was
    read; ``progress()`` tells how much of the file has been read, for a progress bar.
    """

    path: Path
    strict: bool = False
    issues: list[SourceIssue] = field(default_factory=list)
    frames: int = 0
    backwards: int = 0
    _raw: io.FileIO | None = field(default=None, repr=False)
    _size: int = field(default=0, repr=False)
    _where: Callable[[], str] = field(default=lambda: "", repr=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        suffix, _ = _suffix(self.path)
        if suffix not in MESSAGE_READERS or (suffix in {".db", ".mf4"} and _suffix(self.path)[1]):
            known = ", ".join(supported_suffixes())
            raise InputError(self.path, f"unknown log format {suffix or '(no suffix)'!r}; "
                             f"python-can reads {known}")
        if not self.path.is_file():
            raise InputError(self.path, "no such file")
        self._size = self.path.stat().st_size

    def progress(self) -> tuple[int, int]:
        """Bytes of the file read so far and its size."""
        if self._raw is None or self._raw.closed:
            return (self._size if self.frames else 0), self._size
        return self._raw.tell(), self._size

    def _problem(self, where: str, reason: str) -> None:
        issue = SourceIssue(str(self.path), where, reason)
        if self.strict:
            raise InputError(self.path, f"{reason} (--strict)", where=where)
        self.issues.append(issue)

    def __iter__(self) -> Iterator[Frame]:
        suffix, gzipped = _suffix(self.path)
        reader_type = MESSAGE_READERS[suffix]
        last_ns: int | None = None
        # Some readers (TRC) log a warning and skip what they cannot parse: count those too.
        warnings = _Warnings(lambda: self._where())
        can_logger = logging.getLogger("can")
        can_logger.addHandler(warnings)
        buses: dict[Any, str] = {}
        frames = 0
        try:
            for message in self._messages(reader_type, suffix, gzipped):
                if warnings.texts:
                    for place, text in warnings.texts:
                        self._problem(place, f"skipped: python-can says {text!r}")
                    warnings.texts.clear()
                ns = round(message.timestamp * 1_000_000) * 1000  # to_ns(), inlined
                if last_ns is not None and ns < last_ns:
                    self.backwards += 1
                    self._problem(self._where(), f"time jumps backwards by "
                                  f"{(last_ns - ns) / 1e9:.6f} s (frame kept at its own time)")
                last_ns = ns
                frames += 1
                self.frames = frames
                channel = message.channel
                bus = buses.get(channel)
                if bus is None:
                    bus = buses[channel] = bus_name(channel)
                yield Frame(
                    ns,
                    bus,
                    message.arbitration_id,
                    bytes(message.data),
                    message.is_extended_id,
                    message.is_fd,
                    message.is_error_frame,
                    message.is_remote_frame,
                    message.bitrate_switch,
                    message.error_state_indicator,
                    message.dlc,
                )
            for place, text in warnings.texts:
                self._problem(place, f"skipped: python-can says {text!r}")
        finally:
            can_logger.removeHandler(warnings)

    def _messages(self, reader_type: type[MessageReader], suffix: str,
                  gzipped: bool) -> Iterator[can.Message]:
        """The messages; ``self._where()`` names the place of the message just read."""
        if suffix in {".db", ".mf4"}:
            yield from self._whole_file(reader_type)
            return
        with self.path.open("rb", buffering=0) as raw:
            assert isinstance(raw, io.FileIO)
            self._raw = raw
            binary: IO[bytes] = io.BufferedReader(raw, buffer_size=1 << 16)
            if gzipped:
                binary = gzip.GzipFile(fileobj=binary, mode="rb")  # type: ignore[assignment]
            try:
                if issubclass(reader_type, TextIOMessageReader) and suffix in _LINE_FORMATS:
                    text = io.TextIOWrapper(binary, encoding="utf-8", errors="replace")
                    yield from self._text(reader_type, text)
                else:
                    yield from self._binary(reader_type, binary)
            except (OSError, EOFError, gzip.BadGzipFile) as exc:
                self._problem("", f"cannot read the file any further: {exc}")

    def _text(self, reader_type: type[MessageReader],
              text: Iterator[str]) -> Iterator[can.Message]:
        lines = _Lines(text)
        header: list[str] = []
        kwargs = {"relative_timestamp": False} if reader_type is can.ASCReader else {}

        def where() -> str:
            return f"line {lines.line}"

        self._where = where

        while True:
            reader = reader_type(file=lines, **kwargs)  # type: ignore[arg-type]
            try:
                for message in reader:
                    if lines.header is not None:
                        header = lines.header[:-1]
                        lines.header = None
                    yield message
                return
            except Exception as exc:  # python-can raises anything from ValueError to IndexError
                bad_line = lines.line
                self._problem(f"line {bad_line}", f"skipped a line python-can cannot parse "
                              f"({type(exc).__name__}: {exc})")
                if lines.header is not None:
                    header = lines.header[:-1]
                # A fresh reader, primed with the header so it knows the log's settings, carries
                # on after the bad line; its counter comes back to the bad line after the header.
                lines = _Lines(itertools.chain(header, text), bad_line - len(header))
                lines.header = None

    def _binary(self, reader_type: type[MessageReader],
                binary: IO[bytes]) -> Iterator[can.Message]:
        stream = _Bytes(binary)
        count = 0

        def where() -> str:
            return f"frame {count}"

        self._where = where

        try:
            reader = reader_type(file=stream)  # type: ignore[arg-type]
        except Exception as exc:
            raise InputError(self.path, f"not a readable {self.path.suffix} log: {exc}") from exc
        last_failure: int | None = None
        while True:
            try:
                for message in reader:
                    count += 1
                    yield message
                break
            except Exception as exc:
                if last_failure == stream.offset:
                    break  # no progress: the rest of the file is unreadable, reported below
                last_failure = stream.offset
                self._problem(f"byte {stream.offset}", f"skipped damaged data "
                              f"({type(exc).__name__}: {exc})")
        if stream.cut_at is not None:
            self._problem(f"byte {stream.cut_at}", "the file ends in the middle of an object; "
                          "frames in it are lost")

    def _whole_file(self, reader_type: type[MessageReader]) -> Iterator[can.Message]:
        count = 0

        def where() -> str:
            return f"record {count}"

        self._where = where

        try:
            reader = reader_type(file=str(self.path))
        except ImportError as exc:
            raise InputError(self.path, f"reading {self.path.suffix} needs an optional package "
                             f"({exc}); install tankviz[mf4]") from exc
        except Exception as exc:
            raise InputError(self.path, f"not a readable {self.path.suffix} log: {exc}") from exc
        try:
            for message in reader:
                count += 1
                yield message
        except Exception as exc:
            self._problem(f"record {count + 1}", f"stopped at a record python-can cannot read "
                          f"({type(exc).__name__}: {exc})")
        finally:
            reader.stop()


class _Warnings(logging.Handler):
    """Collects the warnings python-can's readers log while tankviz reads a file."""

    def __init__(self, where: Callable[[], str]) -> None:
        super().__init__(logging.WARNING)
        self.where = where
        self.texts: list[tuple[str, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.texts.append((self.where(), record.getMessage()))


def merge(sources: Iterable[Iterable[Frame]]) -> Iterator[Frame]:
    """Frames of several sources in time order (each source in its own order)."""
    sources = list(sources)
    if len(sources) == 1:
        return iter(sources[0])
    return heapq.merge(*sources, key=lambda f: f.timestamp_ns)
