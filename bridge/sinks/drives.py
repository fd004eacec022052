"""Per-drive files: one MCAP per drive in a folder, split into complete parts, flushed often.

A drive is named by its UTC start time (:func:`drive_name`); parts after the first get
``_partNNN``. :class:`DriveRecorder` is the pipeline's :class:`~bridge.sinks.base.Sink` for
``tankviz live``: it opens the first part at the first frame, describes and finishes each part
when it is closed, and notes the bus gaps of the drive.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from bridge.decode.decoder import Decoded
from bridge.errors import OutputError
from bridge.frame import Frame
from bridge.sinks.base import Serialized, Sink
from bridge.sinks.mcap import Recorder


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


@dataclass
class DriveRecorder(Sink):
    """One MCAP per drive in ``folder``, split into complete parts by size or duration.

    ``describe`` is called with each part's recorder and the part's own metadata entries
    (``drive_start``, ``part``, ``bus_gaps``) just before the part is finished. :meth:`tick`
    (called often) flushes the current chunk to disk every ``flush_interval`` seconds, so a
    power cut loses about that much; a file cut that way is salvaged with ``tankviz recover``.
    A due flush waits for the next scene to be written (at most ``flush_wait_s`` more): writing
    a busy second's chunk takes ~10 ms, and just after a scene it delays no scene.
    """

    folder: Path
    describe: Callable[[Recorder, Mapping[str, Any]], None]
    split_size: int | None = None
    split_duration_s: float | None = None
    flush_interval_s: float = 1.0
    flush_wait_s: float = 0.1
    clock: Callable[[], float] = time.monotonic
    files: list[Path] = field(default_factory=list)
    gaps: list[Gap] = field(default_factory=list)
    frames: int = 0
    _recorder: Recorder | None = None
    _stream: Any = None
    _start_ns: int = 0
    _part_start: float = 0.0
    _last_flush: float = 0.0
    _emitted: bool = False  # a scene (or other pipeline output) was written since the last tick

    def __post_init__(self) -> None:
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(self.folder, f"cannot create the drives folder: "
                              f"{exc.strerror or exc}") from None

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
        try:
            self._stream = path.open("xb")
        except OSError as exc:
            raise OutputError(path, f"cannot record: {exc.strerror or exc}") from None
        self.files.append(path)
        self._recorder = Recorder(self._stream)
        self._part_start = self._last_flush = self.clock()

    def _close(self) -> None:
        if self._recorder is None:
            return
        self.describe(self._recorder, {
            "drive_start": self._start_ns, "part": len(self.files),
            "bus_gaps": [{"bus": g.bus, "from_ns": g.start_ns, "to_ns": g.end_ns,
                          "reason": g.reason} for g in self.gaps],
        })
        self._recorder.finish()
        self._stream.close()
        self._recorder = None

    # the Sink interface, for the pipeline
    def on_frame(self, frame: Frame, payload: bytes, /) -> None:
        (self._recorder or self.recorder).write_frame(frame, payload)
        self.frames += 1

    def on_decoded(self, t_ns: int, decoded: Decoded, /) -> None:
        (self._recorder or self.recorder).write_decoded(t_ns, decoded)

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        self.recorder.on_messages(messages)
        self._emitted = True

    def finish(self) -> None:
        """Describe and finish the current part."""
        self._close()

    def tick(self) -> None:
        """Flush to disk when due; start the next part when this one is big or long enough."""
        if self._recorder is None:
            return
        now = self.clock()
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

