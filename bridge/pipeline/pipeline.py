"""The data path of one drive (:class:`Pipeline`): frames → decode → perception, health and
bring-up → sinks.

Every frame, alone, in a read or packed, takes the same step: log time reaches it, it goes into
its raw block, is counted by health and bring-up, and its decoded message goes to every sink,
perception and the ``[marks]`` rules. Each message is serialized once for all sinks.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Callable, Iterable, Mapping
from functools import partial
from itertools import islice
from operator import le, sub
from typing import TYPE_CHECKING, Any, Literal

from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap_protobuf.schema import build_file_descriptor_set

from bridge.decode.codec import Decoded, MessageCodec
from bridge.decode.decoder import Decoder
from bridge.decode.outcome import Outcome
from bridge.frame import END_NS, NEVER_NS, Frame
from bridge.health.monitor import HealthMonitor
from bridge.packed import PackedFrames
from bridge.pb.can_frame_pb2 import CanFrameBlock
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline import DEFAULT_SCENE_RATE
from bridge.pipeline.clock import ClockStep, StepDetector
from bridge.pipeline.marks import Marks, MarkWatch
from bridge.sinks.base import Channel, Serialized, Sink
from bridge.sinks.raw import BlockCutter, RawBlock
from bridge.topics import (
    HEALTH_CATEGORY,
    LOG_TOPIC,
    MARKS_CATEGORY,
    MARKS_TOPIC,
    TopicMessage,
    frames_topic,
    scene_topic,
)

if TYPE_CHECKING:  # (bring-up brings numpy, a profile its stages: a drive without them does
    # not import them)
    from bridge.bringup.monitor import BringUpMonitor
    from bridge.pipeline.perception import Perception
    from bridge.profile.model import Profile

#: What a codec's decoded messages are fed to (message name, signals, time): perception, the
#: mark watch, or both.
Feed = Callable[[str, Mapping[str, Any], int], None]


class Pipeline:
    """Runs one drive's frames through decoding, perception and health into its sinks.

    When log time reaches a frame, a clock step re-bases every stage and the ticks due before it are
    made. Every scene tick is recorded; a viewer (:meth:`add_viewer`) gets only the latest of a
    catch-up.
    """

    def __init__(self, decoder: Decoder, *, profile: Profile | None = None,
                 scene_rate: float = DEFAULT_SCENE_RATE, sinks: Iterable[Sink] = (),
                 health: HealthMonitor | None = None,
                 clock: StepDetector | None = None,
                 bringup: BringUpMonitor | None = None) -> None:
        self.decoder = decoder
        self.profile = profile
        self.scene_rate = scene_rate
        self.sinks: list[Sink] = []
        self.perception: Perception | None = None
        if profile is not None:
            from bridge.pipeline.perception import Perception

            self.perception = Perception(profile, scene_rate=scene_rate)
        self.health = health
        #: the bring-up topics' stage (None: none of them)
        self.bringup = bringup
        if bringup is not None:
            bringup.envelope = Serialized
        self._wanted = self.perception.messages if self.perception is not None else frozenset()
        #: the profile's [marks] rules, watched on the frames of the messages they read (set
        #: None before the first frame to make none of their marks: a re-derived drive's
        #: recorded marks have them)
        self.mark_watch = (MarkWatch(profile.marks) if profile is not None and profile.marks
                           else None)
        #: what each codec's messages are fed to (filled as they come; False: nothing)
        self._fed: dict[MessageCodec, Feed | Literal[False]] = {}
        self._next_tick = (NEVER_NS if self.perception is not None or health is not None
                           or bringup is not None else END_NS)
        self.frames = 0
        self.last_ns: int | None = None
        #: tells clock steps from the frames (and, live, from the wall clock: :meth:`advance`)
        self.clock = clock or StepDetector()
        #: every clock step so far
        self.steps: list[ClockStep] = []
        #: the sinks that get the latest scene only when the pipeline catches up several ticks
        #: (live servers: :meth:`add_viewer`), and those that get every scene
        self.latest_only: list[Sink] = []
        self._every_scene: list[Sink] = []
        #: whether each sink records files (:attr:`~bridge.sinks.base.Sink.records`), and those
        #: that do not
        self._records: list[bool] = []
        self._showing: list[Sink] = []
        self._cutter = BlockCutter(self._emit_raw)
        self._on_decoded: list[Callable[[int, Decoded], None]] = []
        for sink in sinks:
            self.add_sink(sink)
        #: the drive's marks, where it takes them (live; a drive re-derived with its marks; a
        #: profile with [marks] rules, whose marks it makes): its channels then have /marks and
        #: /scene/marks
        self.marks: Marks | None = Marks() if self.mark_watch is not None else None

    def add_sink(self, sink: Sink) -> None:
        """One more sink, after those there are (before the first frame)."""
        self.sinks.append(sink)
        self._every_scene = [s for s in self.sinks if s not in self.latest_only]
        self._on_decoded = [s.on_decoded for s in self.sinks]
        self._records = [getattr(s, "records", False) for s in self.sinks]
        self._showing = [s for s, records in zip(self.sinks, self._records, strict=True)
                         if not records]
        if self.bringup is not None:
            self.bringup.everyone = not all(self._records)

    def process(self, frame: Frame) -> None:
        """One frame through every stage (:meth:`process_many` of it alone)."""
        self._step((frame,), self.decoder.decode)

    def process_many(self, frames: Iterable[Frame]) -> None:
        """Frames through every stage, one by one (live: a read of the buses); the decoded
        messages are handed to the sinks a run at a time (:meth:`~bridge.sinks.base.Sink.
        on_decoded_many`): those of the frames up to the next clock step or tick go before
        it, so each sink gets every message in the order of the frames, but for raw blocks,
        which may come before the decoded messages of the frames before them."""
        self._step(frames, self.decoder.decode)

    def _step(self, frames: Iterable[Frame], decode: Callable[[Frame], Outcome]) -> None:
        """The step of every frame taken one by one, ``decode`` telling what each decodes to:
        log time reaches it (:meth:`_reach`), then it goes into its raw block, is counted by
        health and bring-up, and its decoded message, with those of its run, to the sinks and
        perception (:meth:`_hand`)."""
        cutter, health, sinks, bringup = self._cutter, self.health, self.sinks, self.bringup
        check = self.clock.check
        keep = (bringup.pending if bringup is not None else []).append
        run: list[tuple[int, Decoded]] = []
        t = None
        for frame in frames:
            t = frame.timestamp_ns
            step = check(t)
            if step is not None or t >= self._next_tick:
                if run:
                    self._hand(run)
                    run = []
                if bringup is not None and bringup.made:
                    self._hand_made(bringup)
                self._reach(t, step)
            if sinks:
                cutter.add(frame)
            decoded = decode(frame)
            if health is not None:
                health.on_frame(frame, decoded)
            if type(decoded) is Decoded:
                if bringup is not None:  # BringUpMonitor.on_frame, inlined
                    keep(frame)
                run.append((t, decoded))
            elif bringup is not None:
                keep(frame)
                bringup.on_undecoded(frame)
            self.frames += 1
        if run:
            self._hand(run)
        if bringup is not None:
            if bringup.made:
                self._hand_made(bringup)
            bringup.bound()
        if t is not None:
            self.last_ns = t

    def _reach(self, t_ns: int, step: ClockStep | None) -> None:
        """Log time reaches a frame's ``t_ns``: the clock step it makes (``step``, from
        :meth:`~bridge.pipeline.clock.StepDetector.check`) re-bases, and what is due before it
        is made (:meth:`advance`)."""
        if step is not None:
            self.rebase(step)
        if t_ns >= self._next_tick:
            self.advance(t_ns)

    def process_packed(self, pack: PackedFrames) -> None:
        """A pack of frames through every stage, as :meth:`process_many` of its frames (the
        same messages on every topic, and the same statistics; topics interleave otherwise in
        the file). Each (bus, id) column of the pack is decoded in one step
        (:meth:`~bridge.decode.decoder.Decoder.decode_packed`: decoding depends on no time, and
        the decoder's counts are read only when a drive is described). Then the pack goes
        through the other stages a run of rows at a time: a run ends where a frame steps the
        clock or comes at or after the next scene, health or bring-up tick (which are made
        before it: :meth:`_reach`), or where the health monitor needs it to
        (:attr:`~bridge.health.traffic.PackedCount.cuts`). A run's frames are counted by health
        in bulk (:meth:`~bridge.health.traffic.TrafficCounting.count_rows`), then go through
        the other stages (:meth:`_rows`). A pack whose health must be counted frame by frame
        (a bus with too many kinds of frame) takes the step of :meth:`process_many`."""
        decoded = self.decoder.decode_packed(pack)
        health = self.health
        counting = health.count_packed(pack, decoded) if health is not None else None
        if health is not None and counting is None:
            outcomes = iter(decoded)
            self._step(pack, lambda _frame: next(outcomes))
            return
        ts = pack.t
        n = len(ts)
        cuts = iter([*counting.cuts, n] if counting is not None else [n])
        cut = next(cuts)
        clock = self.clock
        back, forward = clock.back_ns, clock.forward_ns
        # frames in time order, none far after the one before: a run ends at a tick (or a cut)
        steady = n < 2 or (all(map(le, ts, islice(ts, 1, None)))
                           and max(map(sub, islice(ts, 1, None), ts)) <= forward)
        i = 0
        while i < n:
            # the first frame of a run: a clock step or a tick may come before it
            t = ts[i]
            self._reach(t, clock.check(t))
            # the run: the frames up to the next that steps the clock or makes a tick
            while cut <= i:
                cut = next(cuts)
            due, now = self._next_tick, clock.now_ns
            assert now is not None
            if steady:  # (no frame after the first can step the clock)
                j = bisect_left(ts, due, i + 1, cut)
                now = max(now, ts[j - 1])
            else:
                j = i + 1
                while j < cut:
                    t = ts[j]
                    if t >= due:
                        break
                    if t > now:
                        if t - now > forward:
                            break
                        now = t
                    elif now - t > back:
                        break
                    j += 1
            clock.now_ns = now
            if counting is not None:
                assert health is not None
                health.count_rows(counting, i, j)
            self._rows(pack, decoded, i, j)
            i = j

    def _rows(self, pack: PackedFrames, decoded: list[Outcome], i: int, j: int) -> None:
        """Rows ``i`` to ``j`` of a pack, counted by health, through the other stages: their
        raw blocks (:meth:`~bridge.sinks.raw.BlockCutter.add_rows`), bring-up
        (:meth:`~bridge.bringup.monitor.BringUpMonitor.on_rows`), and their decoded messages to
        the sinks and perception (:meth:`_hand`)."""
        if self.sinks:
            self._cutter.add_rows(pack, i, j)
        ts = pack.t
        self._hand([(ts[r], d) for r, d in enumerate(decoded[i:j], i) if type(d) is Decoded])
        bringup = self.bringup
        if bringup is not None:
            bringup.on_rows(pack, i, j)
            if bringup.made:
                self._hand_made(bringup)
        self.frames += j - i
        self.last_ns = ts[j - 1]

    def _hand(self, run: list[tuple[int, Decoded]]) -> None:
        """The decoded messages of a run of frames (between two ticks or clock steps) to the
        sinks at once (one alone as such: :meth:`~bridge.sinks.base.Sink.on_decoded`), and to
        perception in order."""
        if len(run) == 1:
            t, decoded = run[0]
            for on_decoded in self._on_decoded:
                on_decoded(t, decoded)
        else:
            for sink in self.sinks:
                sink.on_decoded_many(run)
        if self.perception is not None:  # (there are [marks] rules only with a profile)
            fed_of = self._fed
            for t, d in run:
                codec = d.codec
                feed = fed_of.get(codec)
                if feed is None:
                    feed = fed_of[codec] = self._feed_of(codec)
                if feed:
                    feed(codec.message.name, d.signals, t)

    def _feed_of(self, codec: MessageCodec) -> Feed | Literal[False]:
        """What a codec's decoded messages are fed to: perception, the mark watch, both, or
        nothing (False)."""
        name = codec.message.name
        perceived = self.perception is not None and name in self._wanted
        watch = self.mark_watch
        marked = watch is not None and name in watch.messages
        if perceived and marked:
            return self._perceive_and_mark
        if perceived:
            assert self.perception is not None
            return self.perception.feed
        return self._mark if marked else False

    def _mark(self, message: str, signals: Mapping[str, Any], t_ns: int) -> None:
        """A decoded frame of a message a [marks] rule reads: the marks it makes, emitted."""
        assert self.mark_watch is not None and self.marks is not None
        for asked in self.mark_watch.on_message(message, signals):
            self.emit(self.marks.make(asked, t_ns))

    def _perceive_and_mark(self, message: str, signals: Mapping[str, Any], t_ns: int) -> None:
        assert self.perception is not None
        self.perception.feed(message, signals, t_ns)
        self._mark(message, signals, t_ns)

    def _hand_made(self, bringup: BringUpMonitor) -> None:
        """Bring-up's ``/can/<bus>/unknown`` messages made since the last hand-over: all of them
        to the sinks that record no file, those files keep to the others."""
        made, kept = bringup.take_made()
        files = made if all(kept) else [m for m, k in zip(made, kept, strict=True) if k]
        for sink, records in zip(self.sinks, self._records, strict=True):
            if not records:
                sink.on_messages(made)
            elif files:
                sink.on_messages(files)

    def add_viewer(self, sink: Sink) -> None:
        """One more sink that may get fewer scenes (a live server): when the pipeline catches
        up several scene ticks at once, it gets the latest only; every other sink gets all."""
        self.latest_only.append(sink)
        self.add_sink(sink)

    def rebase(self, step: ClockStep) -> None:
        """The clock stepped: scene ticks, health windows and lifetimes go on from the new log
        time at once; the step is said on ``/log`` and noted (:attr:`steps`)."""
        self.steps.append(step)
        self.flush_raw()  # the frames before the step, before those after it
        if self.perception is not None:
            self.perception.rebase(step.shift_ns, step.to_ns)
        if self.health is not None:
            self.health.rebase(step.shift_ns, step.to_ns)
        if self.bringup is not None:
            self.bringup.rebase(step.shift_ns, step.to_ns)
        self._next_tick = self._next_due()
        self.emit([step.log()])

    def advance(self, t_ns: int) -> None:
        """Emit the scenes and health checks due before log time ``t_ns`` (also when no frame
        comes: live's clock), every scene tick in turn, each with the health checks due by
        then."""
        self.clock.passed(t_ns)
        if self._cutter.due(t_ns):
            self._cutter.flush_due(t_ns)
        perception, health = self.perception, self.health
        if perception is not None:
            ticks = perception.due_ticks(t_ns)
            last = ticks[-1] if ticks else None
            for tick in ticks:
                outputs = perception.tick(tick)
                if health is not None:
                    outputs.append(self._health_scene(perception, health, tick))
                self.emit(outputs, catching_up=tick != last)
                if health is not None:
                    self.emit(health.advance(tick))
        if health is not None:
            self.emit(health.advance(t_ns))
        if self.bringup is not None:
            published = self.bringup.advance(t_ns)
            self.emit(published.messages, files=published.files)
        self._next_tick = self._next_due()

    def _next_due(self) -> int:
        return min(self.perception.next_tick_ns if self.perception is not None else END_NS,
                   self.health.next_tick_ns if self.health is not None else END_NS,
                   self.bringup.next_tick_ns if self.bringup is not None else END_NS)

    def _health_scene(self, perception: Perception, health: HealthMonitor,
                      t_ns: int) -> TopicMessage:
        """The health checks look at the world of this scene tick; the scene shows the alarms
        beside the ego and each sensor's field of view (red when alarmed)."""
        from bridge.health.overlay import alarm_entities, fov_entities
        from bridge.scene import entities as scene

        assert self.profile is not None
        health.on_world(t_ns, perception.world, perception.lanes)
        alarms = health.active_alarms()
        entities = alarm_entities(alarms, t_ns) + fov_entities(self.profile, alarms, t_ns)
        topic = scene_topic(HEALTH_CATEGORY)
        update = scene.update(topic, entities, t_ns, perception.scene_state)
        return TopicMessage(topic, update, t_ns)

    def finish(self) -> None:
        """Emit what is still due at the end of the drive (the sinks are not stopped), and a
        final scene tick for the messages after the last one: the next tick of the grid, which
        the next frame would have made (else up to one period of frames reach no scene)."""
        if self.last_ns is None:
            return
        self.flush_raw()
        self.advance(self.last_ns + 1)
        perception = self.perception
        if perception is not None and perception.pending:
            self.advance(perception.next_tick_ns)
        if self.bringup is not None:
            published = self.bringup.finish(self.last_ns)
            self.emit(published.messages, files=published.files)

    def flush_raw(self) -> None:
        """Close the open window of raw frames now: a part of a drive that ends takes every
        frame decoded so far with it (its statistics count them)."""
        self._cutter.flush()

    def _emit_raw(self, blocks: list[RawBlock]) -> None:
        for sink in self.sinks:
            sink.on_raw(blocks)

    def emit(self, outputs: Iterable[TopicMessage], *, catching_up: bool = False,
             files: bool = True) -> None:
        """Scene, perception and other messages to every sink, serialized once (``catching_up``:
        not to :attr:`latest_only`; not ``files``: not to the sinks that record files)."""
        serialized = [Serialized(out.topic, type(out.message), out.message.SerializeToString(),
                                 out.t_ns) for out in outputs]
        if serialized:
            for sink in (self._every_scene if catching_up else self.sinks if files
                         else self._showing):
                sink.on_messages(serialized)

    def channels(self, buses: Iterable[str]) -> list[Channel]:
        """Every channel this drive can carry on these buses: the scene and perception topics,
        health, bring-up, /log, and each bus's raw frames and decoded messages."""
        topics = self.perception.topics() if self.perception is not None else []
        if self.health is not None:
            topics += self.health.topics()
            if self.perception is not None:
                topics.append((scene_topic(HEALTH_CATEGORY), SceneUpdate))
        buses = list(buses)
        if self.bringup is not None:
            topics += self.bringup.topics(buses)
        if self.marks is not None:
            topics += [(MARKS_TOPIC, Mark), (scene_topic(MARKS_CATEGORY), SceneUpdate)]
        out = [Channel(topic, cls.DESCRIPTOR.full_name, partial(_fds, cls))
               for topic, cls in dict.fromkeys([*topics, (LOG_TOPIC, Log)])]  # (health has /log)
        for bus in buses:
            out.append(Channel(frames_topic(bus), CanFrameBlock.DESCRIPTOR.full_name,
                               partial(_fds, CanFrameBlock)))
            out += [Channel(codec.topic, codec.schema.full_name,
                            codec.schema.file_descriptor_set)
                    for codec in self.decoder.codecs_for(bus)]
        return out

    def advertise(self, buses: Iterable[str]) -> None:
        """Tell every sink every channel before any frame arrives (live viewers then see every
        topic at once)."""
        channels = self.channels(buses)
        for sink in self.sinks:
            sink.advertise(channels)


def _fds(cls: Any) -> bytes:
    return bytes(build_file_descriptor_set(cls).SerializeToString())
