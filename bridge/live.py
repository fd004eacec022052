"""``tankviz live``: CAN buses in, Foxglove live, every drive recorded.

Each bus is read by its own thread (python-can's own bus creation: any interface, several at
once). When a bus fails (adapter unplugged, interface down) its thread says so, retries with
backoff and says when it is back; the pipeline keeps running, viewers get a ``foxglove.Log`` on
``/log``, and the recording marks the gap. The pipeline thread turns frames into the recording
(never dropping one) and the live scene (never waiting for a viewer).
"""

from __future__ import annotations

import contextlib
import gc
import math
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

from bridge.decode import Decoder
from bridge.errors import OutputError, UsageError
from bridge.frame import Frame
from bridge.perception import DEFAULT_SCENE_RATE, Output
from bridge.pipeline import Pipeline, describe_drive, new_health_monitor
from bridge.profile import Profile
from bridge.recorder import Recorder
from bridge.scene import timestamp
from bridge.server import LiveServer
from bridge.source import to_ns
from bridge.topics import LOG_TOPIC

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


class BusReader(threading.Thread):
    """Reads one bus into ``out`` until stopped; reopens it with backoff when it fails."""

    def __init__(self, spec: BusSpec, out: queue.SimpleQueue[Any], *,
                 open_bus: Callable[[BusSpec], can.BusABC] = BusSpec.open,
                 backoff: tuple[float, float] = (0.2, 5.0)) -> None:
        super().__init__(name=f"tankviz-bus-{spec.name}", daemon=True)
        self.spec = spec
        self.out = out
        self.open_bus = open_bus
        self.backoff = backoff
        self.stopping = threading.Event()
        #: set once the bus was opened, or failed to open, for the first time
        self.tried = threading.Event()
        self.frames = 0

    def stop(self) -> None:
        self.stopping.set()

    def _frame(self, message: can.Message) -> Frame:
        return Frame(
            to_ns(message.timestamp), self.spec.name, message.arbitration_id,
            bytes(message.data), message.is_extended_id, message.is_fd, message.is_error_frame,
            message.is_remote_frame, message.bitrate_switch, message.error_state_indicator,
            message.dlc)

    def _read_batch(self, bus: can.BusABC, first: can.Message) -> None:
        """``first`` and what the interface has already received, as one batch (a list of
        frames: the pipeline is woken once for all of them)."""
        batch = [self._frame(first)]
        try:
            while len(batch) < _BATCH and (message := bus.recv(0)) is not None:
                batch.append(self._frame(message))
        finally:  # the bus may fail halfway: what was read is kept
            self.frames += len(batch)
            self.out.put(batch)

    def run(self) -> None:
        name, out = self.spec.name, self.out
        delay = self.backoff[0]
        down = False
        while not self.stopping.is_set():
            bus: can.BusABC | None = None
            try:
                try:
                    bus = self.open_bus(self.spec)
                finally:
                    self.tried.set()
                if down:
                    out.put(BusEvent(name, True, time.time_ns()))
                    down = False
                delay = self.backoff[0]
                while not self.stopping.is_set():
                    message = bus.recv(0.1)
                    if message is not None:
                        self._read_batch(bus, message)
                        # Let frames gather: a batch every few ms, not a wake-up per frame.
                        time.sleep(READ_PAUSE_S)
                # Stopping: keep what the interface has already received (a bounded while, as a
                # busy bus never runs dry).
                until = time.monotonic() + 0.25
                while time.monotonic() < until and (message := bus.recv(0)) is not None:
                    self._read_batch(bus, message)
            except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
                if not down:
                    out.put(BusEvent(name, False, time.time_ns(),
                                     f"{type(exc).__name__}: {exc}".strip()))
                    down = True
                self.stopping.wait(delay)
                delay = min(delay * 2, self.backoff[1])
            finally:
                if bus is not None:
                    with contextlib.suppress(Exception):  # a broken adapter may fail to close
                        bus.shutdown()


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


#: Most frames a reader hands over at once.
_BATCH = 256
#: A reader's pause after each batch (s): at most this much later in the scene, and the
#: interface buffers what comes meanwhile (a socketcan socket holds thousands of frames).
READ_PAUSE_S = 0.002


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
        self.recorder.write_frame(frame, payload)
        self.frames += 1

    def write_decoded(self, timestamp_ns: int, decoded: Any) -> None:
        self.recorder.write_decoded(timestamp_ns, decoded)

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


def log_message(t_ns: int, level: Any, text: str) -> Output:
    return Output(LOG_TOPIC, Log(timestamp=timestamp(t_ns), level=level, message=text,
                                 name="tankviz"), t_ns)


@dataclass
class LiveReport:
    frames: int
    files: list[Path]
    gaps: list[Gap]
    dropped: int


class Live:
    """The live pipeline: bus readers, the pipeline thread's loop, recorder and server."""

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
        self.queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.readers = [BusReader(spec, self.queue, open_bus=open_bus) for spec in buses]
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
        """Open the buses (each in its reader thread); returns once each was tried."""
        for reader in self.readers:
            if not reader.is_alive():
                reader.start()
        for reader in self.readers:
            reader.tried.wait(timeout)

    def run(self) -> LiveReport:
        """Until :meth:`stop`: read, record, serve. Files are finished cleanly on the way out."""
        self.start()
        # What is loaded by now (databases, profile, schemas) lives as long as the process: out
        # of the collector's way, or every full collection walks it (a 15-30 ms pause each).
        gc.freeze()
        pipeline, q = self.pipeline, self.queue
        process = pipeline.process
        last_frame_ns: int | None = None
        last_frame_at = time.monotonic()
        period = 1.0 / self.scene_rate
        try:
            while not self.stopping.is_set():
                try:
                    item = q.get(timeout=period / 2)
                except queue.Empty:
                    item = None
                batches: list[list[Frame]] = []
                while item is not None:
                    if isinstance(item, list):  # a reader's batch of frames
                        batches.append(item)
                    else:
                        self._bus_event(item)
                    try:
                        item = q.get_nowait()
                    except queue.Empty:
                        item = None
                if batches:
                    frames = merge_batches(batches)
                    for frame in frames:
                        process(frame)
                    last_frame_ns, last_frame_at = frames[-1].timestamp_ns, time.monotonic()
                if last_frame_ns is not None:
                    # No frame for a while (a silent bus): the scene goes on in log time.
                    idle = time.monotonic() - last_frame_at
                    if idle > period:
                        pipeline.advance(last_frame_ns + math.floor(idle * 1e9))
                if self.recorder is not None:
                    self.recorder.tick()
        finally:
            for reader in self.readers:
                reader.stop()
            for reader in self.readers:
                reader.join(2.0)
            rest: list[list[Frame]] = []  # what the readers had read before they stopped
            while True:
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    break
                if isinstance(item, list):
                    rest.append(item)
            for frame in merge_batches(rest) if rest else ():
                process(frame)
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

