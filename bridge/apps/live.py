"""``tankviz live``: CAN buses in, Foxglove live, every drive recorded.

The pipeline thread reads every bus (python-can's own bus creation: any interface, several at
once) a few times per scene period, just after each scene tick and between, and turns the frames
into the recording (never dropping one) and the live scene (never waiting for a viewer). Each
bus has a thread that opens it: when the bus fails (adapter unplugged, interface down) it says
so, retries with backoff and says when it is back; the pipeline keeps running, viewers get a
``foxglove.Log`` on ``/log``, and the recording marks the gap.
"""

from __future__ import annotations

import contextlib
import gc
import operator
import queue
import re
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import can
from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.decode.decoder import Decoder
from bridge.errors import OutputError, UsageError
from bridge.frame import NS, Frame, to_ns
from bridge.pipeline.perception import DEFAULT_SCENE_RATE
from bridge.pipeline.pipeline import Pipeline, describe_drive, new_health_monitor
from bridge.profile.model import Profile
from bridge.scene.entities import timestamp
from bridge.sinks.mcap import Recorder
from bridge.sinks.websocket import LiveServer
from bridge.topics import LOG_TOPIC, TopicMessage

_BUS = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_.-]*)(=(?P<interface>[A-Za-z0-9_]+):"
                  r"(?P<channel>[^@]+)(@(?P<bitrate>\d+))?)?$")


@dataclass(frozen=True)
class BusSpec:
    """One bus: a name for the topics, and how python-can opens it.

    ``NAME=INTERFACE:CHANNEL[@BITRATE]`` (``radar=socketcan:can0``,
    ``car=pcan:PCAN_USBBUS1@500000``) or just ``NAME``: the section of that name in python-can's
    configuration file.
    """

    name: str
    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None

    @classmethod
    def parse(cls, text: str) -> BusSpec:
        match = _BUS.match(text.strip())
        if match is None:
            raise UsageError(f"--bus {text}: expected NAME=INTERFACE:CHANNEL[@BITRATE] "
                             "(e.g. radar=socketcan:can0) or the NAME of a python-can config "
                             "section")
        bitrate = match.group("bitrate")
        return cls(match.group("name"), match.group("interface"), match.group("channel"),
                   int(bitrate) if bitrate else None)

    def open(self) -> can.BusABC:
        """The bus, as python-can creates it."""
        if self.interface is None:
            return can.Bus(context=self.name)
        kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.bitrate is not None:
            kwargs["bitrate"] = self.bitrate
        return can.Bus(**kwargs)

    def __str__(self) -> str:
        if self.interface is None:
            return f"{self.name} (python-can config)"
        rate = f"@{self.bitrate}" if self.bitrate else ""
        return f"{self.name}={self.interface}:{self.channel}{rate}"


@dataclass(frozen=True)
class BusEvent:
    """A bus went away or came back."""

    bus: str
    up: bool
    t_ns: int
    reason: str = ""


class BusLink:
    """One bus: opened (and reopened after a failure, with backoff) by a thread of its own, and
    read without waiting by the pipeline's thread (:meth:`poll`).

    The pipeline reads every bus at once a few times per scene period, so a scene tick sees the
    frames of all buses before it, and no thread wakes up for each frame. Opening is what may
    block (an adapter that is being plugged in), so only the opener thread ever waits for it;
    it sleeps while the bus is up. Bus failures and returns are put on ``events``.
    """

    def __init__(self, spec: BusSpec, events: queue.SimpleQueue[BusEvent], *,
                 open_bus: Callable[[BusSpec], can.BusABC] = BusSpec.open,
                 backoff: tuple[float, float] = (0.2, 5.0)) -> None:
        self.spec = spec
        self.events = events
        self.open_bus = open_bus
        self.backoff = backoff
        self.stopping = threading.Event()
        #: set once the bus was opened, or failed to open, for the first time
        self.tried = threading.Event()
        self._bus: can.BusABC | None = None  # the open bus, handed over by the opener
        self._reopen = threading.Event()  # the opener is wanted
        self._reopen.set()
        self._down = False
        self._opener = threading.Thread(target=self._open_loop, daemon=True,
                                        name=f"tankviz-bus-{spec.name}")

    def start(self) -> None:
        if not self._opener.is_alive():
            self._opener.start()

    def stop(self) -> None:
        """Stops the opener; the bus stays readable until :meth:`close`."""
        self.stopping.set()
        self._reopen.set()
        if self._opener.is_alive():
            self._opener.join(2.0)

    def close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            with contextlib.suppress(Exception):  # a broken adapter may fail to close
                bus.shutdown()

    def _open_loop(self) -> None:
        delay = self.backoff[0]
        while not self.stopping.is_set():
            self._reopen.wait()
            if self.stopping.is_set():
                break
            try:
                try:
                    bus = self.open_bus(self.spec)
                finally:
                    self.tried.set()
            except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
                self._failed(exc)
                self.stopping.wait(delay)
                delay = min(delay * 2, self.backoff[1])
                continue
            delay = self.backoff[0]
            self._reopen.clear()
            if self._down:
                self._down = False
                self.events.put(BusEvent(self.spec.name, True, time.time_ns()))
            self._bus = bus
            if self.stopping.is_set():
                self.close()

    def _failed(self, exc: Exception) -> None:
        if not self._down:
            self._down = True
            self.events.put(BusEvent(self.spec.name, False, time.time_ns(),
                                     f"{type(exc).__name__}: {exc}".strip()))

    def poll(self, limit: int = 100_000) -> list[Frame]:
        """What the interface has received by now (at most ``limit`` frames), never waiting.

        When the bus fails, the frames read before are returned and the opener takes over.
        """
        bus = self._bus
        if bus is None:
            return []
        frames: list[Frame] = []
        name, to_frame = self.spec.name, _frame
        try:
            while len(frames) < limit and (message := bus.recv(0)) is not None:
                frames.append(to_frame(name, message))
        except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
            self.close()
            self._failed(exc)
            self._reopen.set()
        return frames


def _frame(bus: str, message: can.Message) -> Frame:
    return Frame(
        to_ns(message.timestamp), bus, message.arbitration_id, bytes(message.data),
        message.is_extended_id, message.is_fd, message.is_error_frame, message.is_remote_frame,
        message.bitrate_switch, message.error_state_indicator, message.dlc)


_timestamp = operator.itemgetter(0)  # of a Frame


def merge_batches(batches: list[list[Frame]]) -> list[Frame]:
    """The frames of several readers' batches in time order (each batch is in order; frames of
    one time keep their order): a scene tick then comes after every frame before it that had
    arrived, whichever bus brought it."""
    if len(batches) == 1:
        return batches[0]
    frames = [frame for batch in batches for frame in batch]
    frames.sort(key=_timestamp)  # stable, and fast on runs already in order
    return frames




class ReadSchedule:
    """When the live pipeline reads the buses: just after each scene tick, and twice between.

    Scene ticks are multiples of the scene period in log time (the frames' timestamps). The read
    ``after_tick_ns`` after a tick takes in every frame stamped before it, so the scene is
    computed at once; the read ``before_tick_ns`` before the next tick leaves little for that
    one; one more halfway keeps a busy bus's backlog short. Frames are read in the same thread
    that processes them, so nothing wakes up for every frame.

    Log time is wall time plus an offset that the frames tell (:meth:`saw`): a frame is read
    after it was stamped, so the newest frame's stamp minus the time of reading is at most the
    offset, and the largest is close to it (0 for buses stamped with the wall clock, such as
    socketcan and virtual; something else for an adapter's own clock). A larger one counts at
    once, a smaller one (a clock that drifts) once a second, from the next read on: the read
    made just after a tick must still see that tick due.
    """

    def __init__(self, period_ns: int, *, after_tick_ns: int = 500_000,
                 before_tick_ns: int = 2_500_000) -> None:
        self.period_ns = period_ns
        self.after_tick_ns = min(after_tick_ns, period_ns // 4)
        self.phases = sorted({self.after_tick_ns, period_ns // 2,
                              max(period_ns - before_tick_ns, period_ns * 3 // 4)})
        self.offset_ns: int | None = None  # log time - wall time, once a frame was seen
        self._best: int | None = None
        self._window_end = 0
        self._next_offset: int | None = None  # the last second's best, from the next read on
        self._last_read_ns: int | None = None  # when the last read began

    def saw(self, newest_ns: int, now_ns: int) -> None:
        """The newest frame of a read (log time) and when it was read (wall time)."""
        if now_ns >= self._window_end:
            if self._best is not None:
                self._next_offset = self._best  # also if less (a drifting clock)
            self._best = None
            self._window_end = now_ns + NS
        lead = newest_ns - now_ns
        if self._best is None or lead > self._best:
            self._best = lead
        if self.offset_ns is None or lead > self.offset_ns:
            self.offset_ns = lead  # a better estimate counts at once

    def log_time(self, now_ns: int) -> int | None:
        """Log time now, minus the time frames may take to be read: every frame stamped
        before this has been read (None before the first frame)."""
        if self.offset_ns is None:
            return None
        return now_ns + self.offset_ns - self.after_tick_ns

    def reading(self, now_ns: int) -> None:
        """A read begins (wall time)."""
        self._last_read_ns = now_ns

    def wait(self, clock: Callable[[], int] = time.time_ns,
             sleep: Callable[[float], None] = time.sleep) -> None:
        """Sleep until the next read is due (again, if a sleep ends a hair early), then note
        that it begins."""
        read_at = self.next_read_ns(clock())
        while (pause := read_at - clock()) > 0:
            sleep(pause / NS)
        self.reading(clock())

    def next_read_ns(self, now_ns: int) -> int:
        """The wall time of the next read: the first after the last read began, so a read that
        ran past the next one's time is followed at once, never by skipping it (the read after a
        tick starts that scene); before any read, the first after ``now_ns``."""
        if self._last_read_ns is not None:
            now_ns = self._last_read_ns
        if self._next_offset is not None:
            best = self._best  # of this second so far
            self.offset_ns = (self._next_offset if best is None
                              else max(self._next_offset, best))
            self._next_offset = None
        offset = self.offset_ns or 0
        log_now = now_ns + offset
        tick = log_now - log_now % self.period_ns
        for phase in self.phases:
            if tick + phase > log_now:
                return tick + phase - offset
        return tick + self.period_ns + self.phases[0] - offset


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
class DriveRecorder:
    """One MCAP per drive in ``folder``, split into complete parts by size or duration.

    Behaves as the pipeline's recorder. :meth:`tick` (called often) flushes the current chunk to
    disk every ``flush_interval`` seconds, so a power cut loses about that much; a file cut that
    way is salvaged with ``tankviz recover``. A due flush waits for the next scene to be written
    (at most ``flush_wait_s`` more): writing a busy second's chunk takes ~10 ms, and just after
    a scene it delays no scene.
    """

    folder: Path
    describe: Callable[[Recorder, dict[str, Any]], None]
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

    # the recorder interface, for the pipeline
    def write_frame(self, frame: Frame, payload: bytes | None = None) -> None:
        (self._recorder or self.recorder).write_frame(frame, payload)
        self.frames += 1

    def write_decoded(self, timestamp_ns: int, decoded: Any) -> None:
        (self._recorder or self.recorder).write_decoded(timestamp_ns, decoded)

    def write_payload(self, topic: str, message_class: Any, payload: bytes,
                      timestamp_ns: int) -> None:
        self.recorder.write_payload(topic, message_class, payload, timestamp_ns)
        self._emitted = True

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

    def finish(self) -> None:
        self._close()


def log_message(t_ns: int, level: Any, text: str) -> TopicMessage:
    return TopicMessage(LOG_TOPIC, Log(timestamp=timestamp(t_ns), level=level, message=text,
                                 name="tankviz"), t_ns)


@dataclass
class LiveReport:
    frames: int
    files: list[Path]
    gaps: list[Gap]
    dropped: int


class Live:
    """The live pipeline: the buses, the pipeline thread's loop, recorder and server."""

    def __init__(self, buses: Sequence[BusSpec], decoder: Decoder, *,
                 profile: Profile | None = None, scene_rate: float = DEFAULT_SCENE_RATE,
                 drives: Path | None = Path("drives"), server: LiveServer | None = None,
                 split_size: int | None = None, split_duration_s: float | None = None,
                 open_bus: Callable[[BusSpec], can.BusABC] = BusSpec.open,
                 say: Callable[[str], None] = print) -> None:
        names = [b.name for b in buses]
        if len(set(names)) != len(names):
            raise UsageError(f"--bus: a bus name is used twice ({', '.join(names)})")
        self.buses = list(buses)
        self.decoder = decoder
        self.profile = profile
        self.scene_rate = scene_rate
        self.server = server
        self.say = say
        self.events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
        self.links = [BusLink(spec, self.events, open_bus=open_bus) for spec in buses]
        self.recorder = (DriveRecorder(drives, self._describe, split_size, split_duration_s)
                         if drives is not None else None)
        self.health = new_health_monitor(
            decoder, profile, {b.name: b.bitrate for b in buses if b.bitrate is not None})
        self.pipeline = Pipeline(decoder, profile=profile, scene_rate=scene_rate,
                                 recorder=self.recorder, server=server, health=self.health)
        self.pipeline.advertise(names)
        self.stopping = threading.Event()
        self._down: dict[str, Gap] = {}

    def _describe(self, recorder: Recorder, extra: dict[str, Any]) -> None:
        describe_drive(recorder, self.decoder, self.profile, self.scene_rate, {
            "buses": [str(b) for b in self.buses], "alarms": self.health.event_records(),
            **extra})

    def stop(self) -> None:
        self.stopping.set()

    def start(self, timeout: float = 5.0) -> None:
        """Open the buses (each by its opener thread); returns once each was tried."""
        for link in self.links:
            link.start()
        for link in self.links:
            link.tried.wait(timeout)

    def _poll(self) -> list[Frame]:
        """Every bus's new frames, in time order."""
        polled = [frames for link in self.links if (frames := link.poll())]
        return merge_batches(polled) if polled else []

    def run(self) -> LiveReport:
        """Until :meth:`stop`: read, record, serve. Files are finished cleanly on the way out."""
        self.start()
        # What is loaded by now (databases, profile, schemas) lives as long as the process: out
        # of the collector's way, or every full collection walks it (a 15-30 ms pause each).
        gc.freeze()
        pipeline, events = self.pipeline, self.events
        process = pipeline.process
        schedule = ReadSchedule(round(NS / self.scene_rate))
        try:
            while not self.stopping.is_set():
                schedule.wait()
                while True:
                    try:
                        self._bus_event(events.get_nowait())
                    except queue.Empty:
                        break
                frames = self._poll()
                if frames:
                    schedule.saw(frames[-1].timestamp_ns, time.time_ns())
                    for frame in frames:
                        process(frame)
                # Every frame stamped before this was read: the scenes due go out now, whether
                # or not a later frame came (a quiet or silent bus).
                log_now = schedule.log_time(time.time_ns())
                if log_now is not None:
                    pipeline.advance(log_now)
                if self.server is not None:
                    self.server.flush()  # raw frames and signals for who subscribed to them
                if self.recorder is not None:
                    self.recorder.tick()
        finally:
            for link in self.links:
                link.stop()
            # What the interfaces have already received (a bounded while: a busy bus never
            # runs dry).
            until = time.monotonic() + 0.25
            while time.monotonic() < until and (frames := self._poll()):
                for frame in frames:
                    process(frame)
            for link in self.links:
                link.close()
            pipeline.finish()
            if self.recorder is not None:
                self.recorder.finish()
        dropped = sum(s.dropped for s in self.server.client_stats()) if self.server else 0
        return LiveReport(pipeline.frames, self.recorder.files if self.recorder else [],
                          self.recorder.gaps if self.recorder else [], dropped)

    def _bus_event(self, event: BusEvent) -> None:
        t = max(event.t_ns, self.pipeline.last_ns or 0)
        if not event.up:
            gap = self._down[event.bus] = Gap(event.bus, t, None, event.reason)
            if self.recorder is not None:
                self.recorder.gaps.append(gap)
            text = f"bus {event.bus} lost: {event.reason}; retrying"
            self.pipeline.emit([log_message(t, Log.WARNING, text)])
        else:
            gap = self._down.pop(event.bus, Gap(event.bus, t, None, ""))
            gap.end_ns = t
            text = f"bus {event.bus} is back after {(t - gap.start_ns) / 1e9:.1f} s"
            self.pipeline.emit([log_message(t, Log.INFO, text)])
        self.say(text)


def install_stop_signals(stop: Callable[[], None]) -> None:
    """SIGINT and SIGTERM stop the live loop cleanly (files are finished)."""
    import signal

    def handler(signum: int, frame: object) -> None:
        stop()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)

