"""Sources: CAN frames from log files (python-can's readers), merged in time order.

The readers are python-can's own, chosen by suffix. What tankviz adds is what a drive archive
needs around them: integer-nanosecond timestamps, bus names, and resilience. python-can's readers
stop at the first line or object they cannot parse; :class:`LogSource` records the place and the
reason and carries on after it, so everything readable is converted and nothing is skipped
silently. With ``strict=True`` the first such problem is an :class:`~bridge.errors.InputError`.

- Text logs: a line python-can cannot parse is reported with its line and a fresh reader, primed
  with the log's header (the lines before its first frame, at most 1,000), resumes after it. Each
  fresh reader must read a line of the file past the one its predecessor failed on: one that
  fails again before (at the end of the file, or in the header it was primed with) ends the
  reading, with a stop reported if the file goes on; a reader that fails at the end of the file
  (a log cut inside its header) reports the cut. So every reader ends, however the file is
  cut. ASC, candump (``.log``), TRC and CSV lines are counted against the frames they give: a line
  that gives none is reported (python-can skips some silently: an ASC frame with a time lacking
  its dot, a status line, the frame python-can's header scan swallows, a TRC line of a type it
  does not read), except blank lines, comments and the lines of a header (ASC's header and
  trigger block, TRC's ``;`` lines, CSV's column names). A line holding zero bytes is damaged
  data (a block of zeros written over the file joins the line it begins in to the line it ends
  in): whatever python-can makes of it, no frame is kept from it, and it is reported with its
  line and the number of zero bytes. A last line without its newline is a file cut short: its
  frame is not kept, and the cut is reported.
- BLF: damaged objects and containers are skipped, each damage reported with its byte offset,
  and the frames before and after it kept (:mod:`bridge.io.blf`).
- SQLite (``.db``) and MF4: a row python-can cannot read ends the reading, a stop naming it.
- A frame with no readable timestamp (None, text, NaN: a damaged SQLite row) is skipped and
  reported as such; a frame stamped before 1970 or after 2262 (a negative, huge or infinite time:
  more than an MCAP can hold) is skipped and reported; the others go on.
- Every :class:`SourceIssue` says what it did to the reading (its ``kind``, :data:`ISSUE_KINDS`:
  ``stop``, ``damage``, ``skip`` or ``note``) and its family (``group``), so that a summary can
  put stops first and count repeated issues together.
- A log of no frame, a folder or a file of unknown format is an :class:`~bridge.errors.InputError`.
- candump error frames of every class are error frames (:mod:`bridge.io.candump`).

Time: a log's absolute time is kept (an ASC without a date starts at 0), rounded to whole
microseconds (python-can's float seconds resolve a quarter of one at Unix-epoch magnitudes).
"""

from __future__ import annotations

import heapq
import io
import itertools
import logging
import re
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Literal, get_args

import can
from can.io.generic import MessageReader, TextIOMessageReader
from can.io.player import MESSAGE_READERS

from bridge.errors import InputError, not_a_file
from bridge.fences import PYTHON_CAN
from bridge.frame import Frame
from bridge.io.blf import BlfReader, Bytes
from bridge.io.candump import candump_error, error_frame
from bridge.io.gzipped import GzipReader

#: The bus name for frames whose log names no channel (CSV, SQLite, some error frames).
DEFAULT_BUS = "can0"

#: Formats whose reader tankviz can resume after a bad line (python-can reads them line by line).
_LINE_FORMATS = {".asc", ".log", ".trc", ".csv"}

#: The lines that give no frame and need no word, by format: for the formats listed, every other
#: line that gives no frame is reported (python-can skips some silently).
_QUIET_LINES = {
    ".log": re.compile(r"\s*$"),
    ".asc": re.compile(r"\s*($|//|date\s|base\s|(no\s+)?internal\s+events\s+logged|"
                       r"begin\s+triggerblock\b|end\s+triggerblock\b|"
                       r"\d+\.\d+\s+start\s+of\s+measurement\b)", re.IGNORECASE),
    ".trc": re.compile(r"\s*($|;)"),  # comments and the header's settings
    ".csv": re.compile(r"\s*($|timestamp,)"),  # the column names
}

#: The most lines before the first frame remembered as the log's header (python-can's formats
#: have a few tens): a long run of lines without a frame is not held in memory.
_HEADER_LINES = 1000

#: The most messages of a BLF run or of a text log's lines converted at once (a batch small
#: enough to stay in the caches).
_BATCH = 256

#: A frame stamped at or after this (2262-04-11, 2^63 ns) cannot be recorded; nor before 1970.
_LAST_SECOND = float(2**63 // 10**9)


def supported_suffixes() -> list[str]:
    """Every log suffix python-can reads here, plus its ``.gz`` variant."""
    plain = sorted(MESSAGE_READERS)
    return plain + [f"{s}.gz" for s in plain if s not in {".db", ".mf4"}]


#: How python-can's reader numbers a log's channels, where it does not give them from 0 (its ASC
#: and BLF readers give the log's channel 1 as 0; its TRC reader gives a TRC's bus 1 as 1).
_FIRST_CHANNEL = {".trc": 1}


def bus_name(channel: Any, first: int = 0) -> str:
    """The bus name of a channel as python-can's reader gives it, which numbers the channels from
    ``first`` (:data:`_FIRST_CHANNEL`): ``can<N>`` for the (N+1)-th numbered channel (a log's
    channel 1 is ``can0``, in every format), the name itself for a named one (candump's
    interfaces), :data:`DEFAULT_BUS` where the log has no channel."""
    if channel is None or channel == "":
        return DEFAULT_BUS
    if isinstance(channel, int):
        return f"can{channel - first}"
    text = str(channel).strip()
    return text if not text.isdigit() else f"can{int(text) - first}" if first else f"can{text}"


#: What an issue did to the reading, gravest first (a summary lists them in this order):
#: ``stop`` the reading of the file ended here and what follows in it is lost (a file cut short,
#: a record python-can cannot read, a file that cannot be read on); ``damage`` a stretch of
#: damaged data was skipped (its frames lost) and the reading went on after it; ``skip`` one line
#: or frame was skipped; ``note`` nothing was lost (a frame kept at a time that jumps backwards).
IssueKind = Literal["stop", "damage", "skip", "note"]
ISSUE_KINDS: tuple[IssueKind, ...] = get_args(IssueKind)


@dataclass(frozen=True)
class SourceIssue:
    """Something in a log that could not be read as a frame, and where.

    ``kind`` is one of :data:`ISSUE_KINDS`; ``group`` names the family of the issue in a few
    words that never vary from one place to the next (the ``reason`` may quote a line or a
    python-can message): issues of one ``(kind, group)`` can be counted together. Both have
    defaults, for the issues made elsewhere with the three fields (``skip``, and no group:
    group those by their reason)."""

    path: str
    where: str
    reason: str
    kind: IssueKind = "skip"
    group: str = ""

    def __str__(self) -> str:
        return f"{self.path}:{self.where}: {self.reason}" if self.where else \
            f"{self.path}: {self.reason}"


def _suffix(path: Path) -> tuple[str, bool]:
    """The log format suffix (``.blf``) and whether the file is gzip-compressed."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        return (suffixes[-2] if len(suffixes) >= 2 else ""), True
    return (suffixes[-1] if suffixes else ""), False


class _Lines:
    """The line iterator python-can's text readers consume, counting lines as they go.

    Until the first frame has been read it remembers the lines it served (the log's header, at
    most :data:`_HEADER_LINES` of them: ``capped`` when there were more), so a fresh reader can be
    primed with them to carry on after a line python-can could not parse.
    Each line done with (the reader asks for the next) without ``framed`` set is handed to
    ``unframed(line number, text)``; ``cut`` tells the line served last has no newline, ``ended``
    that the reader has asked for a line after the last.
    """

    def __init__(self, lines: Iterator[str], start_line: int = 0,
                 unframed: Callable[[int, str], None] | None = None) -> None:
        self._lines = lines
        self.line = start_line
        self.header: list[str] | None = []
        self.capped = False
        self.text = ""
        self.framed = True
        self.cut = False
        self.ended = False
        self.unframed = unframed

    def __iter__(self) -> _Lines:
        return self

    def __next__(self) -> str:
        if not self.framed:
            self.done()
        try:
            text = next(self._lines)
        except StopIteration:
            self.ended = True
            raise
        self.line += 1
        self.text = text
        self.framed = False
        self.cut = not text.endswith("\n")
        if self.header is not None:
            if len(self.header) < _HEADER_LINES:
                self.header.append(text)
            else:
                self.capped = True
        return text

    def done(self) -> None:
        """The line served last is done with: handed to ``unframed`` if it gave no frame."""
        if not self.framed and self.unframed is not None:
            self.unframed(self.line, self.text)
        self.framed = True

    def readline(self) -> str:
        return next(self, "")

    def close(self) -> None:
        """The underlying file is closed by :class:`LogSource`."""


@dataclass
class LogSource:
    """Every frame python-can can read from one log file, in file order.

    Iterate once. ``issues`` then lists what was skipped and where; ``frames`` counts what was
    read; ``progress()`` tells how much of the file has been read, for a progress bar. A file that
    gives no frame at all raises :class:`~bridge.errors.InputError` at the end of the iteration.
    """

    path: Path
    strict: bool = False
    issues: list[SourceIssue] = field(default_factory=list)
    frames: int = 0
    backwards: int = 0
    _raw: io.FileIO | None = field(default=None, repr=False)
    _size: int = field(default=0, repr=False)
    _where: Callable[[], str] = field(default=lambda: "", repr=False)
    _warnings: _Warnings | None = field(default=None, repr=False)
    _gzip: GzipReader | None = field(default=None, repr=False)
    _read: int = field(default=0, repr=False)  # messages taken from the reader so far
    #: the line of each message of the batch being converted (a line format's), else None
    _lines_of: list[int] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if self.path.is_dir():
            raise InputError(self.path, f"is a folder, not a log file: name the log files in it "
                             f"({self.path}/*.blf …)")
        suffix, _ = _suffix(self.path)
        if suffix not in MESSAGE_READERS or (suffix in {".db", ".mf4"} and _suffix(self.path)[1]):
            known = ", ".join(supported_suffixes())
            raise InputError(self.path, f"unknown log format {suffix or '(no suffix)'!r}; "
                             f"python-can reads {known}")
        if (why := not_a_file(self.path)) is not None:  # missing, a FIFO, a dangling link, …
            raise InputError(self.path, why)
        self._size = self.path.stat().st_size

    def _format(self) -> str:
        suffix, gzipped = _suffix(self.path)
        return suffix + (".gz" if gzipped else "")

    def progress(self) -> tuple[int, int]:
        """Bytes of the file read so far and its size."""
        if self._raw is None or self._raw.closed:
            return (self._size if self.frames else 0), self._size
        return self._raw.tell(), self._size

    def _problem(self, where: str, reason: str, kind: IssueKind = "skip",
                 group: str = "") -> None:
        reason = " ".join(reason.splitlines())  # one line, whatever python-can said
        issue = SourceIssue(str(self.path), where, reason, kind, group or reason)
        if self.strict:
            raise InputError(self.path, f"{reason} (--strict)", where=where)
        self.issues.append(issue)

    def __iter__(self) -> Iterator[Frame]:
        return itertools.chain.from_iterable(self._batches())

    def _batches(self) -> Iterator[Sequence[Frame]]:
        """The frames, in batches: the messages of a run of a BLF's intact objects converted
        :data:`_BATCH` at a time (:func:`_converted`) when none of them needs a word, else one
        at a time, each issue told after the frames before it."""
        suffix, gzipped = _suffix(self.path)
        reader_type = MESSAGE_READERS[suffix]
        last_ns: int | None = None
        # Some readers (TRC) log a warning and skip what they cannot parse: count those too.
        warnings = self._warnings = _Warnings(lambda: self._where())
        can_logger = logging.getLogger("can")
        can_logger.addHandler(warnings)
        buses: dict[Any, str] = {}
        numbered_from = _FIRST_CHANNEL.get(suffix, 0)
        frames = 0
        self._read = 0
        new = tuple.__new__
        try:
            for messages in self._messages(reader_type, suffix, gzipped):
                if len(messages) > 1 and not warnings.texts:
                    batch = _converted(messages, buses, numbered_from, last_ns)
                    if batch is not None:
                        self._read += len(batch)
                        frames += len(batch)
                        self.frames = frames
                        last_ns = batch[-1][0]  # its timestamp_ns
                        yield batch
                        continue
                lines_of = self._lines_of
                for k, message in enumerate(messages):
                    self._read += 1
                    where = self._where() if lines_of is None else f"line {lines_of[k]}"
                    if warnings.texts:
                        self._warned(warnings)
                    seconds = message.timestamp
                    ident = message.arbitration_id
                    if not (isinstance(seconds, (float, int)) and 0.0 <= seconds < _LAST_SECOND
                            and isinstance(ident, int) and 0 <= ident < 1 << 29
                            and isinstance(message.dlc, int) and len(message.data) <= 64):
                        self._problem(where, *_unrecordable(message))
                        continue
                    ns = round(seconds * 1_000_000) * 1000  # to_ns(), inlined
                    if last_ns is not None and ns < last_ns:
                        self.backwards += 1
                        self._problem(where, f"time jumps backwards by "
                                      f"{(last_ns - ns) / 1e9:.6f} s (frame kept at its own "
                                      "time)", "note", "time jumps backwards")
                    last_ns = ns
                    frames += 1
                    self.frames = frames
                    channel = message.channel
                    bus = buses.get(channel)
                    if bus is None:
                        bus = buses[channel] = bus_name(channel, numbered_from)
                    yield (new(Frame, (  # Frame(...) without its Python __new__
                        ns, bus, ident, bytes(message.data), message.is_extended_id,
                        message.is_fd, message.is_error_frame, message.is_remote_frame,
                        message.bitrate_switch, message.error_state_indicator, message.dlc)),)
            self._warned(warnings)
            if not frames:
                first = self.issues[0] if self.issues else None
                first_text = "" if first is None else \
                    f" ({first.where}: {first.reason})" if first.where else f" ({first.reason})"
                raise InputError(self.path, f"no CAN frames in this file{first_text}")
        finally:
            can_logger.removeHandler(warnings)
            self._warnings = None

    def _warned(self, warnings: _Warnings) -> None:
        """Reports the warnings python-can logged (and forgets them)."""
        for place, text in warnings.texts:
            self._problem(place, f"skipped: python-can says {_shown(text, 120)}", "skip",
                          "python-can warning")
        warnings.texts.clear()

    def _messages(self, reader_type: type[MessageReader], suffix: str,
                  gzipped: bool) -> Iterator[Sequence[can.Message]]:
        """The messages, a run of a BLF's intact objects or of a text log's lines at once, or
        one at a time; ``self._where()`` names the place of the message just read (with
        ``self._read`` counting the messages taken), ``self._lines_of`` a text log's batch's
        lines."""
        if suffix in {".db", ".mf4"}:
            yield from self._whole_file(reader_type)
            return
        with self.path.open("rb", buffering=0) as raw:
            assert isinstance(raw, io.FileIO)
            self._raw = raw
            binary: IO[bytes] = io.BufferedReader(raw, buffer_size=1 << 16)
            self._gzip = GzipReader(binary) if gzipped else None
            if self._gzip is not None:
                binary = io.BufferedReader(self._gzip, buffer_size=1 << 16)
            text = issubclass(reader_type, TextIOMessageReader) and suffix in _LINE_FORMATS
            issues = len(self.issues)
            try:
                if text:
                    lines = io.TextIOWrapper(binary, encoding="utf-8", errors="replace")
                    yield from self._text(reader_type, lines, suffix)
                else:
                    yield from self._binary(reader_type, binary)
            except (OSError, EOFError, zlib.error) as exc:
                self._problem("", f"cannot read the file any further: {exc}", "stop",
                              "file unreadable from here")
            if self._gzip is not None:
                self._unpacked(self._gzip, self._where() if text else f"byte {self._gzip.unpacked}",
                               self.issues[issues:])

    def _unpacked(self, unpacking: GzipReader, where: str, told: list[SourceIssue]) -> None:
        """Reports how the unpacking of a gzipped log ended, at ``where`` (the place in the log
        where it ends): cut (unless the reader told it cut already, in ``told``), damaged, or
        with a failed check."""
        where = where if unpacking.unpacked else ""
        if unpacking.failed_check is not None:
            self._problem(where, f"damaged data: {unpacking.failed_check}", "damage",
                          "gzip check failed")
        if unpacking.cut and not any(i.group == "file cut short" for i in told):
            self._problem(where, f"the file is cut short: it ends inside its gzip compression, "
                          f"after {unpacking.unpacked:,} bytes of the log; what followed is lost",
                          "stop", "file cut short")
        elif unpacking.problem is not None:
            self._problem(where, f"cannot read the file any further: {unpacking.problem}",
                          "stop", "file unreadable from here")

    def _text(self, reader_type: type[MessageReader], text: Iterator[str],
              suffix: str) -> Iterator[Sequence[can.Message]]:
        header: list[str] = []
        kwargs = {"relative_timestamp": False} if reader_type is can.ASCReader else {}
        quiet = _QUIET_LINES.get(suffix)
        candump = reader_type is can.CanutilsLogReader
        checked = 0  # the lines up to this one are accounted for (a fresh reader reads some again)
        warned = self._warnings
        cut = False  # the last line, without its newline, is reported

        def cut_short(line: int, what: str) -> None:
            nonlocal cut
            cut = True
            self._problem(f"line {line}", f"the file ends in the middle of this line (no "
                          f"newline): cut short, {what}", "stop", "file cut short")

        def damage(line: int, content: str) -> None:
            """A line with zero bytes: damaged data, whatever python-can made of it."""
            if warned is not None:
                warned.take(f"line {line}")  # (python-can's warning would quote the zeros)
            self._problem(f"line {line}", f"damaged data: {content.count(chr(0))} zero bytes in "
                          "this line: no frame is kept from it (the lines they overwrote are "
                          "lost)", "damage", "zero bytes in a line")

        def unframed(line: int, content: str) -> None:
            nonlocal checked
            if line > checked:
                checked = line
                said = warned.take(f"line {line}") if warned is not None else []
                if "\0" in content:
                    damage(line, content)
                elif not content.endswith("\n") and (quiet is None or not quiet.match(content)):
                    cut_short(line, "python-can makes no frame of it")
                elif said:  # python-can's word for it, in the order of the lines
                    for text in said:
                        self._problem(f"line {line}", f"skipped: python-can says "
                                      f"{_shown(text, 120)}", "skip", "python-can warning")
                elif quiet is not None and not quiet.match(content):
                    self._problem(f"line {line}", f"no frame in this line (python-can skips it): "
                                  f"{_shown(content)}", "skip", "line without a frame")

        lines = _Lines(text, unframed=unframed)

        def where() -> str:
            return f"line {lines.line}"

        self._where = where
        # The messages read since the last batch handed over, and the line of each: handed over
        # _BATCH at a time, and before any word about a line after them.
        batch: list[can.Message] = []
        batch_lines: list[int] = []

        def handed() -> list[can.Message]:
            nonlocal batch, batch_lines
            messages, self._lines_of = batch, batch_lines
            batch, batch_lines = [], []
            return messages

        failed_at = 0  # the line of the last failure: a fresh reader must read past it
        while True:
            reader = reader_type(file=lines, **kwargs)  # type: ignore[arg-type]
            try:
                for message in reader:
                    if lines.header is not None:
                        header = lines.header if lines.capped else lines.header[:-1]
                        lines.header = None
                    lines.framed = True
                    if lines.cut or "\0" in lines.text:
                        if batch:
                            yield handed()
                        if lines.cut:
                            cut_short(lines.line, "its frame is not kept")
                        else:
                            damage(lines.line, lines.text)
                        continue
                    if (candump and message.is_extended_id and not message.is_error_frame
                            and candump_error(lines.text)):
                        message = error_frame(message)
                    batch.append(message)
                    batch_lines.append(lines.line)
                    if len(batch) == _BATCH:
                        yield handed()
                if batch:
                    yield handed()
                lines.done()
                if lines.cut and not cut:  # a blank line or a comment, cut short
                    cut_short(lines.line, "whatever followed is lost")
                return
            except Exception as exc:  # python-can raises anything from ValueError to IndexError
                if batch:  # the frames before it first
                    yield handed()
                if isinstance(exc, (InputError, OSError, EOFError, zlib.error)):
                    raise  # --strict, or the file cannot be read (not: a line cannot be parsed)
                bad_line = max(checked, lines.line)
                if bad_line <= failed_at:
                    # The fresh reader failed again before reading a line of its own (in the
                    # header it was primed with, or at the end of the file): no progress.
                    if next(text, None) is not None:
                        self._problem(f"line {failed_at + 1}", "python-can cannot read on after "
                                      f"line {failed_at} ({type(exc).__name__}: {exc}): the rest "
                                      "of the file is not read", "stop", "cannot read on")
                    return
                if lines.ended or (lines.cut and bad_line == lines.line):
                    # python-can failed at the end of the file (inside its header), or on its
                    # last line, cut short
                    how = "in the middle of this line (no newline)" if lines.cut else \
                        "after this line"
                    self._problem(f"line {bad_line}", f"the file ends {how}: cut short, "
                                  f"python-can cannot read it ({type(exc).__name__}: {exc})",
                                  "stop", "file cut short")
                    return
                if "\0" in lines.text:
                    damage(bad_line, lines.text)
                else:
                    self._problem(f"line {bad_line}", f"skipped a line python-can cannot parse "
                                  f"({type(exc).__name__}: {exc})", "skip",
                                  "line python-can cannot parse")
                checked = failed_at = bad_line
                if lines.header is not None:
                    header = lines.header if lines.capped else lines.header[:-1]
                # A fresh reader, primed with the header so it knows the log's settings, carries
                # on after the bad line; its counter comes back to the bad line after the header.
                lines = _Lines(itertools.chain(header, text), bad_line - len(header), unframed)
                lines.header = None

    def _binary(self, reader_type: type[MessageReader],
                binary: IO[bytes]) -> Iterator[Sequence[can.Message]]:
        stream = Bytes(binary)

        def where() -> str:
            return f"frame {self._read}"

        self._where = where

        def damaged(offset: int, reason: str, kind: IssueKind, group: str) -> None:
            self._problem(f"byte {offset}", reason, kind, group)

        try:
            if reader_type is can.BLFReader and PYTHON_CAN.holds():
                reader: MessageReader = BlfReader(stream, damaged)
            else:
                reader = reader_type(file=stream)  # type: ignore[arg-type]
        except InputError:
            raise
        except Exception as exc:
            if self._gzip is not None and (self._gzip.cut or self._gzip.problem is not None):
                return  # the unpacking ended early: it says why
            if not stream.offset:  # as every other format says an empty file
                raise InputError(self.path, "no CAN frames in this file (an empty file)") from exc
            raise InputError(self.path, " ".join(
                f"not a readable {self._format()} log: {exc}".splitlines())) from exc
        last_failure: int | None = None
        while True:
            try:
                if isinstance(reader, BlfReader):
                    for run in reader.runs():
                        yield from self._parsed(reader, run)
                else:
                    for message in reader:
                        yield (message,)
                break
            except InputError:
                raise  # --strict
            except Exception as exc:
                if last_failure == stream.offset:
                    break  # no progress: the rest of the file is unreadable, reported below
                last_failure = stream.offset
                self._problem(f"byte {stream.offset}", f"skipped damaged data "
                              f"({type(exc).__name__}: {exc})", "damage", "damaged data skipped")
        if stream.cut_at is not None and not isinstance(reader, BlfReader):
            self._problem(f"byte {stream.cut_at}", "the file ends in the middle of an object; "
                          "frames in it are lost", "stop", "file cut short")

    def _parsed(self, reader: BlfReader, run: bytes) -> Iterator[Sequence[can.Message]]:
        """The messages python-can's parser makes of ``run``, :data:`_BATCH` at a time; one at
        a time from where it warns or fails (parsed again: each warning is placed at its
        frame, the frames before a failure come first)."""
        texts = self._warnings.texts if self._warnings is not None else []
        messages = reader._parse_data(run)
        done = 0
        while True:
            told = len(texts)
            try:
                batch = list(itertools.islice(messages, _BATCH))
            except Exception:  # python-can fails: one at a time up to the failure again
                break
            if len(texts) != told:
                del texts[told:]
                break
            if not batch:
                return
            yield batch
            done += len(batch)
        for message in itertools.islice(reader._parse_data(run), done, None):
            yield (message,)

    def _whole_file(self, reader_type: type[MessageReader],
                    ) -> Iterator[Sequence[can.Message]]:
        count = 0
        what = "row" if reader_type is can.SqliteReader else "record"

        def where() -> str:
            return f"{what} {count}"

        self._where = where

        try:
            reader = reader_type(file=str(self.path))
        except ImportError as exc:
            raise InputError(self.path, f"reading {self.path.suffix} needs an optional package "
                             f"({exc}); install tankviz[mf4]") from exc
        except Exception as exc:
            raise InputError(self.path, " ".join(
                f"not a readable {self._format()} log: {exc}".splitlines())) from exc
        try:
            for message in reader:
                count += 1
                yield (message,)
        except Exception as exc:
            self._problem(f"{what} {count + 1}", f"stopped at {what} {count + 1}, which python-can "
                          f"cannot read ({type(exc).__name__}: {exc}): the rest of the file is "
                          "not read", "stop", f"stopped at a {what} python-can cannot read")
        finally:
            reader.stop()


def _converted(messages: Sequence[can.Message], buses: dict[Any, str], first: int,
               last_ns: int | None) -> list[Frame] | None:
    """The frames of ``messages`` when every one is recordable and none goes back in time (from
    ``last_ns`` on), as :meth:`LogSource._batches` makes them one at a time; None when one of
    them needs a word (then they are converted one at a time). ``buses`` gets each new channel's
    bus name (numbered from ``first``). The loop of about 0.6 µs a frame: local names, the
    tuple made without Frame's Python ``__new__``, ``round`` called as its method."""
    frames: list[Frame] = []
    append = frames.append
    new = tuple.__new__
    last = -1 if last_ns is None else last_ns
    for message in messages:
        seconds = message.timestamp
        ident = message.arbitration_id
        dlc = message.dlc
        data = message.data
        # the checks of _batches, narrower (an int time or a bool id goes the careful way)
        if not (type(seconds) is float and 0.0 <= seconds < _LAST_SECOND
                and type(ident) is int and 0 <= ident < 1 << 29
                and type(dlc) is int and len(data) <= 64):
            return None
        ns = (seconds * 1e6).__round__() * 1000  # to_ns()
        if ns < last:
            return None
        last = ns
        channel = message.channel
        bus = buses.get(channel)
        if bus is None:
            bus = buses[channel] = bus_name(channel, first)
        append(new(Frame, (ns, bus, ident, bytes(data), message.is_extended_id, message.is_fd,
                           message.is_error_frame, message.is_remote_frame,
                           message.bitrate_switch, message.error_state_indicator, dlc)))
    return frames


def _unrecordable(message: can.Message) -> tuple[str, IssueKind, str]:
    """Why a frame python-can made of damaged data cannot be recorded: the reason, the kind and
    the group of its :class:`SourceIssue`."""
    seconds = message.timestamp
    if not isinstance(seconds, (float, int)) or seconds != seconds:  # None, text, NaN
        shown = repr(seconds)
        return (f"skipped a frame with no readable timestamp "
                f"({shown if len(shown) <= 40 else shown[:37] + '…'})", "skip",
                "frame without a readable timestamp")
    if not 0.0 <= seconds < _LAST_SECOND:
        return (f"skipped a frame stamped {seconds!r} s: a time before 1970 or after 2262 "
                "cannot be recorded", "skip", "frame stamped out of range")
    return (f"skipped a frame with id {message.arbitration_id!r}, DLC {message.dlc!r} and "
            f"{len(message.data)} data bytes: not a CAN frame", "skip", "not a CAN frame")


def _shown(text: str, most: int = 80) -> str:
    """A line (of a log, or of python-can's) as an issue quotes it: without its newline, at most
    ``most`` characters."""
    text = text.rstrip("\r\n")
    return repr(text if len(text) <= most else text[:most - 3] + "…")


class _Warnings(logging.Handler):
    """Collects the warnings python-can's readers log while tankviz reads a file."""

    def __init__(self, where: Callable[[], str]) -> None:
        super().__init__(logging.WARNING)
        self.where = where
        self.texts: list[tuple[str, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.texts.append((self.where(), record.getMessage()))

    def take(self, place: str) -> list[str]:
        """The warnings logged at ``place`` not yet reported, forgotten here."""
        taken = [text for where, text in self.texts if where == place]
        if taken:
            self.texts[:] = [(where, text) for where, text in self.texts if where != place]
        return taken


def merge(sources: Iterable[Iterable[Frame]]) -> Iterator[Frame]:
    """Frames of several sources in time order (each source in its own order)."""
    sources = list(sources)
    if len(sources) == 1:
        return iter(sources[0])
    return heapq.merge(*sources, key=lambda f: f.timestamp_ns)
