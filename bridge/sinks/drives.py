"""Per-drive files: one MCAP per drive in a folder, split into complete parts, flushed often.

:class:`PartsRecorder` is ``tankviz live``'s recorder: every part starts with the drive's
attachments and ends described. A full disk never stops the drive: recording pauses and resumes
in a new part, and each part's metadata lists the pauses. A drives folder that cannot be written
is an error at once, when the recorder is made.
"""

from __future__ import annotations

import contextlib
import copy
import errno
import io
import os
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, ClassVar, cast

from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.decode.codec import Decoded
from bridge.errors import FileError
from bridge.frame import timestamp
from bridge.health.alarms import AlarmKind, Notice, alarm_notice
from bridge.sinks.base import Serialized, Sink
from bridge.sinks.mcap import METADATA_NAME, Recorder
from bridge.sinks.outputs import lock
from bridge.sinks.raw import RawBlock
from bridge.topics import LOG_TOPIC

#: The file in a drives folder that keeps room for finishing a part when the disk is full.
RESERVE_NAME = ".tankviz-reserve"
MB = 1_000_000


def free_bytes(folder: Path) -> int:
    """Bytes an unprivileged writer may still use on the file system of ``folder``."""
    st = os.statvfs(folder)
    return st.f_bavail * st.f_frsize


class _PartFile(io.RawIOBase):
    """A part's file: a write the disk has no room for calls ``release`` (which frees the
    reserve) and is retried; :attr:`full` then says that the disk filled. It is locked while it
    is open: a part being recorded, not one cut short (``tankviz catalog`` tells them apart)."""

    def __init__(self, path: Path, release: Callable[[], bool]) -> None:
        super().__init__()
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        lock(self._fd, wait=False)  # held while it is written: tankviz catalog leaves it alone
        self._release = release
        self.full = False

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        while True:
            try:
                return os.write(self._fd, data)
            except OSError as exc:
                if exc.errno != errno.ENOSPC or not self._release():
                    raise
                self.full = True

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        return os.lseek(self._fd, offset, whence)

    def tell(self) -> int:
        return os.lseek(self._fd, 0, os.SEEK_CUR)

    def fileno(self) -> int:
        return self._fd

    def close(self) -> None:
        if not self.closed:
            try:
                super().close()
            finally:
                os.close(self._fd)


def drive_name(start_ns: int, part: int) -> str:
    """``2026-11-21T05-40-12Z.mcap``, and ``…_part002.mcap`` for the parts after the first."""
    stamp = datetime.fromtimestamp(start_ns / 1e9, tz=timezone.utc).strftime("%Y-%m-%dT%H-%M-%SZ")
    return f"{stamp}.mcap" if part == 1 else f"{stamp}_part{part:03d}.mcap"


@dataclass
class Gap:
    bus: str
    start_ns: int
    end_ns: int | None
    reason: str


#: Decode statistics that are not counts (kept as the describe callback gives them).
_NOT_COUNTS = {"last_decode_error", "last_rule_error", "message_bytes", "longest"}


def part_counts(now: Any, before: Any, key: str = "") -> Any:
    """The counts of ``now`` less those of ``before`` (nested dicts of ints: the decode
    statistics): what a part alone holds. Entries that become zero are left out, except the
    buses of ``frames``; what is not a count (texts, a longer frame's byte sizes) is kept."""
    if key in _NOT_COUNTS:
        return now
    if isinstance(now, dict):
        previous = before if isinstance(before, dict) else {}
        out: dict[Any, Any] = {}
        for k, v in now.items():
            own = part_counts(v, previous.get(k), k)
            if key == "frames" or (own != 0 and not (isinstance(own, dict)
                                                     and own.get("frames", 1) == 0)):
                out[k] = own
        return out
    if type(now) is int and type(before) is int:
        return now - before
    return now


class _PartMetadata:
    """The recorder ``describe`` is given: it writes to the part's recorder, with the part's
    own decode statistics in the ``tankviz`` record (:func:`part_counts`)."""

    def __init__(self, recorder: Recorder, before: dict[str, Any]) -> None:
        self._recorder = recorder
        self._before = before
        #: the drive's statistics so far (what the next part counts from)
        self.drive_statistics: dict[str, Any] | None = None

    def add_metadata(self, values: dict[str, Any], name: str = METADATA_NAME) -> None:
        stats = values.get("statistics")
        if name == METADATA_NAME and isinstance(stats, dict):
            self.drive_statistics = copy.deepcopy(stats)
            values = {**values, "statistics": part_counts(stats, self._before)}
        self._recorder.add_metadata(values, name)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._recorder, name)


@dataclass
class PartsRecorder(Sink):
    """One MCAP per drive in ``folder``, split into complete parts by size or duration.

    ``attach`` is called with each part's recorder as the part is opened, before its first message;
    ``describe`` is called with each part's recorder and the part's own metadata entries
    (``drive_start``, ``part``, ``bus_gaps``, ``recording_gaps``) just before the part is finished
    (the decode statistics it writes are made the part's own). :meth:`tick` (called often) flushes
    the current chunk to disk every ``flush_interval`` seconds, so a power cut loses about that
    much; a file cut that way is salvaged with ``tankviz recover``. A due flush waits for the next
    scene to be written (at most ``flush_wait_s`` more): writing a busy second's chunk takes ~10 ms,
    and just after a scene it delays no scene.

    A full disk, with the default reserve (``reserve``, 8 MiB, or half the free space above
    ``min_free`` when that is less than twice the reserve) and ``resume_margin`` (1 MiB):

    - a write that finds the disk full frees the reserve and is retried, so the part is finished
      cleanly (its summary fits in the reserve); so is it, now and then (every
      ``check_interval_s``), when the free space is below ``min_free``;
    - recording starts when the free space is at least ``min_free`` (``--min-free``), however little
      is above it (the reserve is then smaller);
    - it stops when the free space is below ``min_free``, or when the disk is full; the raw frames
      that come meanwhile are kept in memory in their blocks (at most ``backlog_limit``, the oldest
      not recorded and counted);
    - it resumes, in a new part, when the free space is above ``min_free`` + 9 MiB (the reserve plus
      the margin). The reserve made again is then at least 4.5 MiB, and that much is recorded before
      it could stop again: stopping frees the reserve, which never makes the room to resume, so it
      never flaps. The new part starts with the frames kept; decoded messages and scenes of the
      pause are not recorded (a ``convert`` of the frames makes them again);
    - when the drive ends while recording is stopped, the frames kept are written into a last part
      if the free space is above ``min_free`` + ``resume_margin``; else they are not recorded, and
      the notice says how many.

    In the part finished when a pause began, ``recording_gaps``' ``to_ns`` and counts are None (not
    known yet); the parts before and after a pause say so on ``/log``.

    A drive is named by its UTC start (:func:`drive_name`), parts after the first get ``_partNNN``,
    and each part's decode statistics count that part alone (they sum to the drive's). On a full
    disk a reserve file (``.tankviz-reserve``) is freed so the part finishes cleanly; recording
    stops below ``min_free`` (nothing is raised; the raw frames are kept in memory, at most
    ``backlog_limit``, the rest counted), resumes in a new part above ``min_free`` + the reserve +
    ``resume_margin``, and each part's metadata lists the pauses (``recording_gaps``: ``from_ns``,
    ``to_ns``, ``reason``, ``resumed_in``, ``frames_kept``, ``frames_not_recorded``,
    ``messages_not_recorded``). :attr:`disk_full` says why, :meth:`take_notices` the lines to tell.
    """

    records: ClassVar[bool] = True
    folder: Path
    describe: Callable[[Recorder, Mapping[str, Any]], None]
    split_size: int | None = None
    split_duration_s: float | None = None
    flush_interval_s: float = 1.0
    flush_wait_s: float = 0.1
    clock: Callable[[], float] = time.monotonic
    attach: Callable[[Recorder], None] | None = None
    #: stop recording (and finish the part) below this many free bytes; 0: when the disk is full
    min_free: int = 0
    #: the room kept for finishing a part: a chunk and the summary (attachments, indexes)
    reserve: int = 8 * 1024 * 1024
    #: resuming needs this much free space above ``min_free`` and the reserve
    resume_margin: int = 1024 * 1024
    free_space: Callable[[Path], int] = free_bytes
    check_interval_s: float = 1.0
    #: raw frames kept in memory while recording is stopped
    backlog_limit: int = 1_000_000
    #: why recording is stopped (the disk is full), None while it records
    disk_full: str | None = None
    #: recording pauses that ended (the class docstring)
    recording_gaps: list[dict[str, Any]] = field(default_factory=list)
    frames_dropped: int = 0  # received while stopped and not recorded
    files: list[Path] = field(default_factory=list)
    gaps: list[Gap] = field(default_factory=list)
    frames: int = 0
    _recorder: Recorder | None = None
    _stream: Any = None
    _start_ns: int = 0
    _part_start: float = 0.0
    _last_flush: float = 0.0
    _emitted: bool = False  # a scene (or other pipeline output) was written since the last tick
    _file: _PartFile | None = None
    _next_check: float = 0.0
    _backlog: deque[RawBlock] = field(default_factory=deque)
    _backlog_frames: int = 0
    _gap: dict[str, Any] | None = None
    _notices: list[Notice] = field(default_factory=list)
    _reserve_size: int = 0
    #: the drive's decode statistics when the last part was finished
    _statistics: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FileError(self.folder, f"cannot create the drives folder: "
                            f"{exc.strerror or exc}") from None
        self._next_check = self.clock() + self.check_interval_s
        self._arm()

    def check_space(self) -> None:
        """Check the free space again (``min_free`` may have changed): before the first part,
        make the reserve again for it and stop if the free space is below ``min_free``; while
        recording, stop now if it is below ``min_free``."""
        self._next_check = self.clock() + self.check_interval_s
        if not self.files and self._recorder is None:
            self.disk_full, self._gap, self._notices = None, None, []
            self._arm()
        elif self.disk_full is None and (free := self.free_space(self.folder)) < self.min_free:
            self._stop(self._low(free))

    # --- the reserve, and stopping and resuming ------------------------------------------

    def _arm(self) -> None:
        """Before the first part: the reserve, as big as the free space allows; or stopped."""
        self._release()
        free = self.free_space(self.folder)
        if free < self.min_free:
            self._stop(self._low(free))
            return
        try:
            self._make_reserve(min(self.reserve, (free - self.min_free) // 2))
        except OSError as exc:
            if exc.errno != errno.ENOSPC:
                raise FileError(self.folder, f"cannot record: {exc.strerror or exc}") from None
            self._stop(f"disk full: no room to record in {self.folder}")
            return
        if self._reserve_size <= 0:
            self._release()
            self._stop(f"disk full: no room to record in {self.folder}")

    def _make_reserve(self, size: int) -> None:
        path = self.folder / RESERVE_NAME
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            if size > 0:
                try:
                    os.posix_fallocate(fd, 0, size)
                except OSError as exc:
                    if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
                        raise
                    block = bytes(MB)
                    for start in range(0, size, MB):
                        os.write(fd, block[:min(MB, size - start)])
                    os.fsync(fd)
        except OSError:
            os.close(fd)
            path.unlink(missing_ok=True)
            raise
        os.close(fd)
        self._reserve_size = max(size, 0)

    def _release(self) -> bool:
        """Free the reserve; False if there was none."""
        self._reserve_size = 0
        try:
            (self.folder / RESERVE_NAME).unlink()
        except OSError:
            return False
        return True

    def _low(self, free: int) -> str:
        return (f"{free / MB:.0f} MB free in {self.folder}, below --min-free "
                f"{self.min_free / MB:.0f} MB")

    def take_notices(self) -> list[Notice]:
        """What happened to the recording since the last call (recording stopped, resumed,
        a part left unfinished), one line each, to tell on ``/log``."""
        notices, self._notices = self._notices, []
        return notices

    def _note(self, text: Notice, *, record: bool) -> None:
        """A line to tell (:meth:`take_notices`), and if ``record`` on the part's own ``/log``
        (the part about to be finished: what is told comes too late for it)."""
        self._notices.append(text)
        if record and self._recorder is not None:
            t = time.time_ns()
            self._recorder.write(LOG_TOPIC, Log(timestamp=timestamp(t), level=Log.WARNING,
                                                message=text, name="tankviz.recorder"), t)

    def _stop(self, reason: str) -> None:
        """Finish the current part (if any) and stop recording until there is room again."""
        self.disk_full = reason
        if self._gap is None:
            self._gap = {"from_ns": time.time_ns(), "to_ns": None, "reason": reason,
                         "frames_kept": 0, "frames_not_recorded": 0, "messages_not_recorded": 0}
        self._note(alarm_notice(
            AlarmKind.DISK_FULL, "recorder", f"{reason}: recording stopped (viewers are still "
            "served); it resumes in a new part when more than "
            f"{(self.min_free + self.reserve + self.resume_margin) / MB:.1f} MB is free"),
            record=True)
        self._close()

    def _failed(self, exc: OSError) -> None:
        """A write failed even with the reserve freed: the part is left as it is."""
        reason = f"cannot write {self.files[-1].name if self.files else self.folder}: " \
                 f"{exc.strerror or exc}"
        self._recorder = None
        stream, self._stream = self._stream, None
        with contextlib.suppress(OSError):
            stream.close()
        self._notices.append(alarm_notice(AlarmKind.DISK_FULL, "recorder", f"{reason}; the "
                                          "part is left unfinished (tankviz recover salvages it)"))
        self._stop(reason)

    def _resume(self, *, last: bool = False) -> None:
        """Recording again, in a new part, if there is room (the class docstring; ``last``: the
        drive ends, any room above ``min_free`` and the margin will do): the frames kept go
        first."""
        free = self.free_space(self.folder)
        needed = self.min_free + self.resume_margin + (0 if last else self.reserve)
        if free <= needed:
            return
        try:
            self._make_reserve(min(self.reserve, (free - self.min_free) // 2))
            self._open(time.time_ns())
        except OSError:
            self._release()
            return
        gap, self._gap = self._gap, None
        assert gap is not None and self._recorder is not None
        gap["to_ns"] = time.time_ns()
        gap["resumed_in"] = self.files[-1].name
        gap["frames_kept"] = self._backlog_frames
        gap["frames_not_recorded"] = self.frames_dropped
        self.recording_gaps.append(gap)
        self.disk_full = None
        self._note(alarm_notice(
            AlarmKind.DISK_FULL, "recorder", f"recording resumed in {self.files[-1].name} "
            f"after {(gap['to_ns'] - gap['from_ns']) / 1e9:.1f} s; the "
            f"{gap['frames_kept']} frames received meanwhile are in it "
            f"({gap['frames_not_recorded']} not recorded for want of memory), "
            f"{gap['messages_not_recorded']} decoded messages and scenes are not", cleared=True),
            record=False)
        self.frames_dropped = 0
        write = self._recorder.write_raw
        try:
            while self._backlog:
                block = self._backlog[0]
                write(block)
                self._backlog.popleft()
                self._backlog_frames -= block.frames
                self.frames += block.frames
        except OSError as exc:
            self._failed(exc)

    def _keep(self, blocks: Sequence[RawBlock]) -> None:
        backlog = self._backlog
        for block in blocks:
            backlog.append(block)
            self._backlog_frames += block.frames
        while self._backlog_frames > self.backlog_limit:  # the oldest blocks go
            dropped = backlog.popleft()
            self._backlog_frames -= dropped.frames
            self.frames_dropped += dropped.frames

    @property
    def recorder(self) -> Recorder:
        if self._recorder is None:
            self._open(time.time_ns())
        assert self._recorder is not None
        return self._recorder

    def _open(self, t_ns: int) -> None:
        if not self.files:
            self._start_ns = t_ns
        path = self.folder / drive_name(self._start_ns, len(self.files) + 1)
        self._file = _PartFile(path, self._release)
        self._stream = io.BufferedWriter(self._file, 1 << 16)
        self.files.append(path)
        self._recorder = Recorder(self._stream, attach=self.attach)
        self._part_start = self._last_flush = self.clock()

    def _close(self) -> None:
        if self._recorder is None:
            return
        described = _PartMetadata(self._recorder, self._statistics)
        try:
            self.describe(cast(Recorder, described), {
                "drive_start": self._start_ns, "part": len(self.files),
                "bus_gaps": [{"bus": g.bus, "from_ns": g.start_ns, "to_ns": g.end_ns,
                              "reason": g.reason} for g in self.gaps],
                "recording_gaps": [*self.recording_gaps, *([{
                    **self._gap, "frames_kept": None, "frames_not_recorded": None,
                    "messages_not_recorded": None}] if self._gap else [])],  # not known yet
            })
            self._recorder.finish()
            self._stream.close()
        except OSError as exc:
            self._failed(exc)
        if described.drive_statistics is not None:
            self._statistics = described.drive_statistics
        self._recorder = None

    # the Sink interface, for the pipeline
    def _part(self) -> Recorder | None:
        """The part to write into (opened at the first frame); None while stopped."""
        if self._recorder is None and self.disk_full is None:
            try:
                self._open(time.time_ns())
            except OSError as exc:
                self._stop(f"cannot open a part: {exc.strerror or exc}")
        return self._recorder

    def on_raw(self, blocks: Sequence[RawBlock], /) -> None:
        recorder = self._recorder or self._part()
        if recorder is None:
            self._keep(blocks)
            return
        for i, block in enumerate(blocks):
            try:
                recorder.write_raw(block)
            except OSError as exc:
                self._failed(exc)
                self._keep(blocks[i:])
                return
            self.frames += block.frames

    def on_decoded(self, t_ns: int, decoded: Decoded, /) -> None:
        self.on_decoded_many(((t_ns, decoded),))

    def on_decoded_many(self, messages: Sequence[tuple[int, Decoded]], /) -> None:
        self._record(len(messages), lambda recorder: recorder.on_decoded_many(messages))

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        if self._record(len(messages), lambda recorder: recorder.on_messages(messages)):
            self._emitted = True

    def _record(self, count: int, write: Callable[[Recorder], None]) -> bool:
        """``count`` messages into the part being written (``write``); while stopped, counted
        as not recorded (False)."""
        recorder = self._recorder or self._part()
        if recorder is None:
            if self._gap is not None:
                self._gap["messages_not_recorded"] += count
            return False
        try:
            write(recorder)
        except OSError as exc:
            self._failed(exc)
        return True

    def finish(self) -> None:
        """Describe and finish the current part (after a last try to record the frames kept
        while the disk was full: the class docstring); the reserve is removed."""
        if self.disk_full is not None and self._backlog:
            self._resume(last=True)
        self._close()
        if self._backlog:
            self.frames_dropped += self._backlog_frames
            self._backlog.clear()
            self._backlog_frames = 0
        if self.disk_full is not None and self.frames_dropped:
            self._notices.append(alarm_notice(
                AlarmKind.DISK_FULL, "recorder", f"{self.frames_dropped} frames received while "
                "the disk was full are not recorded (no room for them when the drive ended)"))
        self._release()

    def tick(self) -> None:
        """Flush to disk when due; start the next part when this one is big or long enough.
        Stop recording when the disk filled (or, checked now and then, free space is below
        ``min_free``); resume when there is room again."""
        now = self.clock()
        if self.disk_full is not None:
            if now >= self._next_check:
                self._next_check = now + self.check_interval_s
                self._resume()
            return
        if self._recorder is None:
            return
        if self._file is not None and self._file.full:
            self._stop(f"disk full ({self.folder})")
            return
        if now >= self._next_check:
            self._next_check = now + self.check_interval_s
            if (free := self.free_space(self.folder)) < self.min_free:
                self._stop(self._low(free))
                return
        try:
            self._tick(now)
        except OSError as exc:
            self._failed(exc)

    def _tick(self, now: float) -> None:
        assert self._recorder is not None
        emitted, self._emitted = self._emitted, False
        since = now - self._last_flush
        if ((self.split_size is not None and self._stream.tell() >= self.split_size)
                or (self.split_duration_s is not None
                    and now - self._part_start >= self.split_duration_s)):
            self._close()
            self._open(time.time_ns())
        elif since >= self.flush_interval_s and (
                emitted or since >= self.flush_interval_s + self.flush_wait_s):
            self._recorder.flush()
            self._last_flush = now
