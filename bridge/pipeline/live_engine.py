"""The live engine (:class:`Live`, run by ``tankviz live`` and ``tankviz demo``): CAN buses in,
the pipeline thread's loop, the recorder and the Foxglove server.

Every bus (python-can's own bus creation: any interface, several at once) is read a few times
per scene period, just after each scene tick and between, in a process of its own
(:mod:`bridge.io.bus_reader`; a ``virtual`` bus, or ``TANKVIZ_LIVE_READER=here``: in the
pipeline thread), and the pipeline thread turns each read's frames into the recording (never
dropping one) and the live scene (never waiting for a viewer). Each bus has a thread that opens
it. Every bus is opened before the run starts (:meth:`Live.start`): a
bus that cannot work at all (an unknown interface, a NAME without python-can configuration) is an
error at once, never retried; a bus that does not open (a socketcand server that is down, an
address that is not one, an interface that is not there) is retried for at most
:data:`~bridge.io.buses.OPEN_WAIT_S` seconds (15; less if the run is stopped first), and if it
has never opened by then it is an error naming the bus and why, and nothing is recorded.
When a bus that had opened fails (adapter unplugged, interface down) live says so, retries with
backoff for as long as it runs and says when it is back; the pipeline keeps running, viewers get
a ``foxglove.Log`` on ``/log``, and the recording marks the gap (``bus_gaps``; its reason is one
line).

What the reading of a bus mends or loses (:class:`~bridge.health.receive.ReceiveCounts`: frames
stamped NaN, kept and stamped when read; what is not a frame; frames the kernel dropped because
live read too late, where python-can exposes the socket) goes to the health monitor (``/log``
warnings, the ``bus.<bus>.bad_timestamps`` and ``bus.<bus>.frames_lost`` alarms on ``/health``),
into the drive's metadata (``bus_receive``: the counts per bus) and into the run's
:class:`LiveReport`.
A full disk (or free space below ``min_free``) stops the recording, not the drive: the part is
finished, ``recorder.disk_full`` is raised on ``/log`` and ``/health``, viewers are still served
and recording resumes in a new part when there is room (:mod:`bridge.sinks.drives`).

Marks (:mod:`bridge.pipeline.marks`) asked from any thread — a viewer's (the server's
:attr:`~bridge.sinks.server.ViewerServer.on_mark`, while the drive runs), the terminal's, the
profile's rule — are made at the loop's next turn at the drive's clock then, recorded, served and
said on the console.

Log time is the frames' clock (:class:`~bridge.io.buses.ReadSchedule` follows it with the wall
clock). When it steps (:mod:`bridge.pipeline.clock`: a frame stamped more than a second before log
time, or more than two seconds after it), the pipeline re-bases its scene ticks, health windows
and lifetimes at once and says so on ``/log``, the schedule takes the new offset at once, and the
drive's metadata lists the step (``clock_steps``); every frame is recorded with its own stamp.
When the pipeline falls behind (a loaded machine), the scenes of every tick it missed are made
and recorded; viewers get the latest. Once started, the garbage collector runs with
:func:`bridge.pipeline.collector.steady_stream`'s settings (start-up frozen, rare young
collections, a full one a minute where the loop waits), and the process's own come back at the
end. The run ends with a :class:`LiveReport`: frames, files, gaps, what each viewer lost and
what each bus's reading mended or lost (the command prints it: :mod:`bridge.apps.live`).
"""

from __future__ import annotations

import dataclasses
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.errors import BridgeError, UsageError
from bridge.frame import NS, Frame, timestamp
from bridge.health.alarms import AlarmKind
from bridge.io.bus_reader import Died, Item, LinkState, Read, ReaderProcess
from bridge.io.buses import (
    OPEN_WAIT_S,
    BusEvent,
    BusLink,
    BusSpec,
    ReadSchedule,
    ReceiveCounts,
    merge_batches,
)
from bridge.pipeline import DEFAULT_SCENE_RATE
from bridge.pipeline.clock import LIVE_FORWARD_NS, StepDetector
from bridge.pipeline.collector import steady_stream
from bridge.pipeline.drive import Drive, Stages
from bridge.pipeline.marks import MarkAsked, Marks, describe
from bridge.sinks.drives import Gap
from bridge.sinks.server import ClientStats, ViewerMark, ViewerServer
from bridge.topics import LOG_TOPIC, TopicMessage, bus_segment


def log_message(t_ns: int, level: Any, text: str) -> TopicMessage:
    return TopicMessage(LOG_TOPIC, Log(timestamp=timestamp(t_ns), level=level, message=text,
                                       name="tankviz"), t_ns)


def duration(ns: int) -> str:
    """A gap's length: in ms below a second (a reopen takes a few), else in seconds."""
    return f"{ns / 1e6:.0f} ms" if ns < NS else f"{ns / 1e9:.1f} s"


@dataclass
class LiveReport:
    """What a live run did: frames read, files recorded, bus gaps, messages dropped for slow
    viewers."""

    frames: int
    files: list[Path]
    gaps: list[Gap]
    dropped: int
    #: every viewer, with what it lost
    viewers: list[ClientStats] = field(default_factory=list)
    #: what each bus's reading mended or lost
    receive: dict[str, ReceiveCounts] = field(default_factory=dict)
    #: why the run ended before it was stopped (the process reading the buses died), if so
    failure: str | None = None


_NOTHING = ReceiveCounts()
#: Where live reads its buses: ``process`` (a process of their own), ``here`` (the pipeline's);
#: by default in a process of their own unless a bus is ``virtual`` (which connects only the
#: buses of one process).
READER_ENV = "TANKVIZ_LIVE_READER"


def reads_in_process(buses: Sequence[BusSpec], open_bus: Callable[[BusSpec], can.BusABC],
                     reader: str | None) -> bool:
    """Whether live reads ``buses`` in a process of their own (:data:`READER_ENV`)."""
    reader = reader or os.environ.get(READER_ENV) or None
    if reader not in (None, "process", "here"):
        raise UsageError(READER_ENV, "must be process or here", value=reader)
    if reader is not None:
        return reader == "process"
    return open_bus is BusSpec.open and all(b.interface != "virtual" for b in buses)


class Live:
    """The live pipeline: the buses, the pipeline thread's loop, recorder and server
    (``bring_up``: with the bring-up topics, :mod:`bridge.bringup.monitor`)."""

    def __init__(self, buses: Sequence[BusSpec], stages: Stages, *,
                 scene_rate: float = DEFAULT_SCENE_RATE,
                 drives: Path | None = Path("drives"), server: ViewerServer | None = None,
                 split_size: int | None = None, split_duration_s: float | None = None,
                 min_free: int = 0,
                 open_bus: Callable[[BusSpec], can.BusABC] = BusSpec.open,
                 open_wait_s: float = OPEN_WAIT_S,
                 say: Callable[[str], None] = print, bring_up: bool = True,
                 reader: str | None = None) -> None:
        names = [b.name for b in buses]
        if len(set(names)) != len(names):
            raise UsageError("--bus", f"a bus name is used twice ({', '.join(names)})")
        segments: dict[str, str] = {}
        for name in names:
            other = segments.setdefault(bus_segment(name), name)
            if other != name:
                raise UsageError(f"--bus {other} and --bus {name}", "would share the topics "
                                 f"/can/{bus_segment(name)}/...: rename one")
        self.buses = list(buses)
        self.scene_rate = scene_rate
        self.server = server
        self.say = say
        self.open_wait_s = open_wait_s
        self.events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
        #: the buses are read in a process of their own (:mod:`bridge.io.bus_reader`)
        self.split = reads_in_process(buses, open_bus, reader)
        self._open_bus = open_bus
        self.links = ([] if self.split else
                      [BusLink(spec, self.events, open_bus=open_bus) for spec in buses])
        self.reader: ReaderProcess | None = None
        self.drive = Drive(stages, scene_rate=scene_rate,
                           bitrates={b.name: b.bitrate for b in buses if b.bitrate is not None},
                           extra={"buses": [str(b) for b in self.buses]}, bring_up=bring_up)
        #: what each bus's reading mended or lost, as last told (in the metadata: bus_receive)
        self.receive: dict[str, ReceiveCounts] = {}
        self._receive_record: dict[str, dict[str, Any]] = {}
        self.drive.extra["bus_receive"] = self._receive_record
        # Live knows log time from the wall clock too: a step a few seconds ahead is one.
        self.drive.pipeline.clock = StepDetector(forward_ns=LIVE_FORWARD_NS)
        if server is not None:
            # first: viewers wait for a scene, the recorder does not; and viewers may get fewer
            # scenes when the pipeline catches up, the recording gets every one
            self.drive.pipeline.add_viewer(server)
        self.recorder = (self.drive.record_parts(drives, split_size=split_size,
                                                 split_duration_s=split_duration_s)
                         if drives is not None else None)
        if self.recorder is not None:
            self.recorder.min_free = min_free
            self.recorder.check_space()
        self.pipeline = self.drive.pipeline
        #: the marks of this drive: :meth:`Marks.ask` from any thread, made in the loop
        self.marks = self.pipeline.marks = Marks()
        self._said = 0  # the marks said on the console
        if server is not None:
            server.on_mark = self._viewer_mark
        self.pipeline.advertise(names)
        self.stopping = threading.Event()
        self._down: dict[str, Gap] = {}
        #: what the reading process sent while the buses were opening
        self._early: list[Item] = []
        #: each bus's receive counts as the reading process last sent them
        self._receive_told: dict[str, ReceiveCounts] = {}

    def stop(self) -> None:
        self.stopping.set()

    def start(self) -> None:
        """Open the buses (each by its opener thread); returns once each is open. A bus that
        cannot work (:func:`bridge.io.buses.configuration_error`) raises its ``UsageError`` at
        once; a bus that has not opened after :attr:`open_wait_s` seconds (or when the run is
        stopped first) raises one saying so. Then the buses are closed and nothing is
        recorded."""
        if self.split and self.reader is None:  # (a process starts once)
            self.reader = ReaderProcess(self.buses, round(NS / self.scene_rate),
                                        open_bus=self._open_bus)
        for link in self.links:
            link.start()
        began = time.monotonic()
        died: Died | None = None
        while True:
            if self.reader is not None:
                for item in self.reader.take(0.02):
                    if isinstance(item, Died):
                        died = item
                    self._early.append(item)  # (reads of the buses open first: kept)
            states = self._link_states()
            error: BridgeError | None = next(
                (link.error for link in states if link.error is not None), None)
            if died is not None:
                error = BridgeError(died.reason)
            waiting = [link for link in states if not link.opened]
            if (error is not None or not waiting or self.stopping.is_set()
                    or time.monotonic() - began >= self.open_wait_s):
                break
            if self.reader is None:
                self.stopping.wait(0.02)
        if error is None and not waiting:
            return
        took = time.monotonic() - began
        for link in self.links:
            link.stop()
            link.close()
        if self.reader is not None:
            self.reader.stop()
            self.reader.close()
        if self.recorder is not None:
            self.recorder.finish()
        if error is None:
            state = waiting[0]
            when = (f"in {self.open_wait_s:g} s" if took >= self.open_wait_s else
                    f"before the run was stopped after {took:.1f} s")
            tries = f"{state.tries} tr{'y' if state.tries == 1 else 'ies'}"
            why = (f"{state.failure} ({tries})" if state.failure else
                   "python-can's first try to open it had not ended")
            error = UsageError("--bus", f"did not open {when}: {why}", value=state.spec)
        raise error

    def _link_states(self) -> list[LinkState]:
        """Each bus's opening: as the reading process told it, or its link's."""
        if self.reader is not None:
            return self.reader.links
        return [LinkState(link.spec, link.opened.is_set(), link.error, link.failure, link.tries)
                for link in self.links]

    def _poll(self) -> list[Frame]:
        """Every bus's new frames, in time order."""
        polled = [frames for link in self.links if (frames := link.poll())]
        return merge_batches(polled) if polled else []

    def run(self) -> LiveReport:
        """Until :meth:`stop`: read, record, serve. Files are finished cleanly on the way out."""
        self.start()
        # What is loaded by now (databases, profile, schemas) lives as long as the process:
        # frozen out of the collector's way; full collections only at quiet moments.
        collector = steady_stream()
        pipeline = self.pipeline
        schedule = ReadSchedule(round(NS / self.scene_rate))
        failure: str | None = None
        try:
            if self.reader is not None:
                failure = self._run_split(schedule, collector)
            else:
                self._run_here(schedule, collector)
        finally:
            if self.reader is not None:
                self._finish_split(schedule)
            else:
                self._finish_here()
            self._receive_state()
            if self.server is not None:
                self.server.on_mark = None  # (the drive ends: viewers are told)
            if pipeline.last_ns is not None:
                self._take_marks(pipeline.last_ns)
            self.drive.finish()
            if self.recorder is not None:
                for text in self.recorder.take_notices():
                    self.say(text)
            collector.restore()
        viewers = self.server.client_stats() if self.server else []
        return LiveReport(pipeline.frames, self.recorder.files if self.recorder else [],
                          self.recorder.gaps if self.recorder else [],
                          sum(s.dropped for s in viewers), viewers, dict(self.receive),
                          failure)

    def _run_here(self, schedule: ReadSchedule, collector: Any) -> None:
        """The loop, the buses read in this thread."""
        pipeline, events = self.pipeline, self.events
        process = pipeline.process_many
        while not self.stopping.is_set():
            collector.quiet()  # (where the loop waits: a full collection when one is due)
            schedule.wait()
            while True:
                try:
                    self._bus_event(events.get_nowait(), schedule.offset_ns or 0)
                except queue.Empty:
                    break
            frames = self._poll()
            if frames:
                read_ns = time.time_ns()
                schedule.saw(frames[-1].timestamp_ns, read_ns)
                steps = len(pipeline.steps)
                process(frames)
                if len(pipeline.steps) != steps:  # the clock stepped: log time with it
                    schedule.restart(frames[-1].timestamp_ns, read_ns)
            # Every frame stamped before this was read: the scenes due go out now, whether
            # or not a later frame came (a quiet or silent bus).
            self._turn(schedule.log_time(time.time_ns()))

    def _finish_here(self) -> None:
        for link in self.links:
            link.stop()
        # What the interfaces have already received (a bounded while: a busy bus never
        # runs dry).
        until = time.monotonic() + 0.25
        while time.monotonic() < until and (frames := self._poll()):
            self.pipeline.process_many(frames)
        for link in self.links:
            link.close()

    def _run_split(self, schedule: ReadSchedule, collector: Any) -> str | None:
        """The loop, the buses read by the reading process: each of its reads processed in
        turn, then the scenes due by the time of the newest read. Returns why the reading
        process died, if it did."""
        assert self.reader is not None
        early, self._early = self._early, []
        while not self.stopping.is_set():
            collector.quiet()  # (where the loop waits: a full collection when one is due)
            items = early or self.reader.take(0.1)
            early = []
            read_ns, died = self._take(items, schedule)
            if died is not None:
                return self._reader_died(died)
            # Every frame stamped before this was read by then, and is processed.
            self._turn(schedule.log_time(read_ns) if read_ns is not None else None)
        return None

    def _finish_split(self, schedule: ReadSchedule) -> None:
        """What the reading process still reads once asked to stop (it reads for at most
        ``DRAIN_S``), processed; then it ends."""
        assert self.reader is not None
        self.reader.stop()
        until = time.monotonic() + 5.0
        while not self.reader.ended and time.monotonic() < until:
            self._take(self.reader.take(0.1), schedule)
        self.reader.close()

    def _take(self, items: list[Item], schedule: ReadSchedule) -> tuple[int | None, Died | None]:
        """Items of the reading process, in order: reads processed as :meth:`_run_here`
        processes its own. Returns the newest read's wall time, and a death."""
        pipeline = self.pipeline
        read_ns: int | None = None
        died: Died | None = None
        for item in items:
            if isinstance(item, Read):
                pack = item.pack
                if pack is not None:
                    newest = pack.t[-1]
                    schedule.saw(newest, item.read_ns)
                    schedule.next_read_ns(item.read_ns)  # (a smaller offset, once a second)
                    steps = len(pipeline.steps)
                    pipeline.process_many(pack)
                    if len(pipeline.steps) != steps:  # the clock stepped: log time with it
                        schedule.restart(newest, item.read_ns)
                read_ns = item.read_ns
            elif isinstance(item, BusEvent):
                self._bus_event(item, schedule.offset_ns or 0)
            elif isinstance(item, Died):
                died = item
            else:
                self._receive_told[item[0]] = item[1]
        return read_ns, died

    def _turn(self, log_now: int | None) -> None:
        """After a read: the marks asked and the scenes due by ``log_now``, the viewers'
        batches, the recorder's flush and what the recorder and the reading say."""
        pipeline = self.pipeline
        if log_now is not None:
            self._take_marks(log_now)  # (before the first frame, marks wait for one)
            pipeline.advance(log_now)
        if self.server is not None:
            # raw frames and signals for who subscribed to them, with the next scene
            self.server.flush_batched()
        if self.recorder is not None:
            self.recorder.tick()
            self._recorder_state()
        self._receive_state()

    def _reader_died(self, died: Died) -> str:
        """The reading process died: said on ``/log`` and the console; the drive ends."""
        t = max(time.time_ns(), self.pipeline.last_ns or 0)
        text = f"{died.reason}: the drive is finished here"
        self.pipeline.emit([log_message(t, Log.ERROR, text)])
        self.say(text)
        return text

    def _viewer_mark(self, mark: ViewerMark) -> None:
        """A mark a viewer published (the server's thread): taken at the loop's next turn."""
        self.marks.ask(MarkAsked(mark.text, mark.category, "viewer", mark.by))

    def _take_marks(self, t_ns: int) -> None:
        """The marks asked for since the last call, made at ``t_ns`` (the drive's clock now),
        recorded and shown; every mark made since the last call (the car's too, made by the
        pipeline as it decodes) said on the console."""
        made = self.marks.take(t_ns)
        if made:
            self.pipeline.emit(made)
        for mark in self.marks.made[self._said:]:
            self.say(describe(mark))
        self._said = len(self.marks.made)

    def _receive_state(self) -> None:
        """What each bus's reading mended or lost, when it changed: to the health monitor
        (``/log``, ``/health``) and into the metadata (``bus_receive``)."""
        told = (self._receive_told.items() if self.reader is not None else
                [(link.spec.name, link.receive) for link in self.links])
        for name, counts in told:
            if counts != self.receive.get(name, _NOTHING):
                copy = self.receive[name] = dataclasses.replace(counts)
                self.drive.health.note_receive(name, copy)
                self._receive_record[name] = copy.to_dict()

    def _recorder_state(self) -> None:
        """What the recorder says (the disk filled, recording resumed) on ``/log``, and its
        ``recorder.disk_full`` condition to the health monitor."""
        assert self.recorder is not None
        for notice in self.recorder.take_notices():
            t = max(time.time_ns(), self.pipeline.last_ns or 0)
            self.pipeline.emit([log_message(t, notice.level, notice)])
            self.say(notice)
        self.drive.health.hold(AlarmKind.DISK_FULL, "recorder", self.recorder.disk_full)

    def _bus_event(self, event: BusEvent, offset_ns: int) -> None:
        """A bus lost or back, noted at the log time it happened (its wall time plus the
        offset the frames tell: an adapter's own clock, a clock step), never before the last
        frame."""
        t = max(event.t_ns + offset_ns, self.pipeline.last_ns or 0)
        if not event.up:
            gap = self._down[event.bus] = Gap(event.bus, t, None, event.reason)
            if self.recorder is not None:
                self.recorder.gaps.append(gap)
            text = f"bus {event.bus} lost: {event.reason}; retrying"
            self.pipeline.emit([log_message(t, Log.WARNING, text)])
        else:
            gap = self._down.pop(event.bus, Gap(event.bus, t, None, ""))
            gap.end_ns = t
            text = f"bus {event.bus} is back after {duration(t - gap.start_ns)}: " + (
                f"about {event.missed:,} frames missed (an estimate: {event.rate:,.0f} frames/s "
                "before, times how long it was down)"
                if event.missed is not None and event.rate is not None else
                "the frames sent meanwhile were missed (how many is not known: it was up less "
                "than a second before)")
            self.pipeline.emit([log_message(t, Log.INFO, text)])
        self.say(text)
