"""Perception: decoded messages → observations → world → scene and semantic topics, in log time.

:class:`Perception` runs the profile, world and scene stages for convert, replay and live alike,
driven by frame times: at each tick of the scene rate it emits the scene, the semantic topics and
the sensor frames for that tick's log time, from everything observed before it.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import partial
from typing import Any

from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bridge.errors import UsageError
from bridge.frame import NEVER_NS, NS
from bridge.pb.perception_pb2 import EgoState, Lanes, LeadVehicle, PerceivedObjects
from bridge.pipeline import DEFAULT_SCENE_RATE
from bridge.profile.model import Profile
from bridge.scene import entities as scene
from bridge.scene import semantic
from bridge.scene.camera import VIEWS, view_cameras
from bridge.topics import (
    EGO_TOPIC,
    LANES_TOPIC,
    LEAD_TOPIC,
    TF_TOPIC,
    TopicMessage,
    objects_topic,
    scene_topic,
)
from bridge.world.lead import same_twins, twin_sets
from bridge.world.model import LaneModel, World
from bridge.world.observe import Observer, copies

MAX_SCENE_RATE = 50.0
#: The ticks of a gap longer than this are not all made: its first minute, then the latest.
MAX_FILL_NS = 60 * NS


#: ``TopicMessage`` of a tuple of its fields, without its Python-level ``__new__`` (a dozen a tick)
_topic_message = partial(tuple.__new__, TopicMessage)


def check_scene_rate(rate: float) -> float:
    if not 0 < rate <= MAX_SCENE_RATE:
        raise UsageError("--scene-rate", "must be above 0 and at most "
                         f"{MAX_SCENE_RATE:g} Hz", value=f"{rate:g}")
    return rate


class Perception:
    """The profile, world and scene stages for one drive: :meth:`advance` with each frame's time,
    :meth:`feed` with each decoded message.

    Every tick is made, also a gap's (up to a minute of them), and a clock step is re-based at once
    (:meth:`rebase`). Between ticks only the newest message of each name is kept, and the world at a
    tick is the same as if every message had been observed on arrival (except an object renumbered
    twice between two ticks); a group without an index range and multiplexed object messages are
    observed frame by frame. Two groups that read the same fields of the same messages are observed
    once (:func:`bridge.world.observe.copies`).
    """

    def __init__(self, profile: Profile, *, scene_rate: float = DEFAULT_SCENE_RATE) -> None:
        self.profile = profile
        self.period_ns = round(NS / check_scene_rate(scene_rate))
        self.observer = Observer(profile)
        self.world = World(profile)
        self.scene_state = scene.SceneState({})
        #: the views the scene's labels are laid out for (the generated layouts' cameras)
        self.cameras = view_cameras(profile)
        #: log time of the next scene; frames at or after it make it happen
        self.next_tick_ns = NEVER_NS
        self._started = False
        self.ticks = 0
        self.messages = self.observer.messages
        #: the lane model of the latest tick
        self.lanes: LaneModel | None = None
        #: the newest (values, time) of each message fed since the last tick, in arrival order
        self._pending: dict[str, tuple[Mapping[str, Any], int]] = {}
        #: every frame of a list message (one object per frame) fed since the last tick
        self._every_frame = self.observer.every_frame
        #: each scene category's topic, each group's /perception topic
        self._topics = {category: scene_topic(category) for category in
                        ("ego", "lanes", "lead", "mio", *profile.groups,
                         *map(scene.label_category, VIEWS))}
        self._objects_topics = {name: objects_topic(name) for name in profile.groups}
        self._pending_frames: list[tuple[str, Mapping[str, Any], int]] = []

    def topics(self) -> list[tuple[str, Any]]:
        """Every topic :meth:`tick` emits, with its message class (to advertise them early)."""
        profile = self.profile
        categories = ["ego", "lanes", *profile.groups]
        if profile.lead is not None:
            categories += ["lead", "mio"]
        categories += map(scene.label_category, VIEWS)
        out: list[tuple[str, Any]] = [(scene_topic(c), SceneUpdate) for c in categories]
        out.append((TF_TOPIC, FrameTransforms))
        out += [(objects_topic(name), PerceivedObjects) for name in profile.groups]
        if profile.lead is not None:
            out.append((LEAD_TOPIC, LeadVehicle))
        if profile.lanes is not None:
            out.append((LANES_TOPIC, Lanes))
        out.append((EGO_TOPIC, EgoState))
        return out

    def feed(self, message: str, values: Mapping[str, Any], t_ns: int) -> None:
        """Take one decoded message (call :meth:`advance` with its time first); the next tick
        observes it."""
        if message in self.messages:
            if message in self._every_frame:
                self._pending_frames.append((message, values, t_ns))
                return
            pending = self._pending
            pending.pop(message, None)
            pending[message] = (values, t_ns)

    @property
    def pending(self) -> bool:
        """Whether messages were fed since the last tick (at the end of the input: a final tick
        draws them)."""
        return bool(self._pending or self._pending_frames)

    def observe_pending(self) -> None:
        """Observe the messages fed since the last tick into the world: the newest of each name,
        and every frame of a list message (a group without an index range: one object per
        frame, so the newest alone would lose the others)."""
        pending, frames = self._pending, self._pending_frames
        apply_all = self.world.apply_all
        if pending:
            apply_all(self.observer.observe_latest(pending))
            pending.clear()
        if frames:
            observe = self.observer.observe
            for message, values, t_ns in frames:
                apply_all(observe(message, values, t_ns))
            frames.clear()

    def due_ticks(self, t_ns: int) -> list[int]:
        """The log times of the scene ticks due before log time ``t_ns``, in order (none most
        of the time); they are then no longer due: call :meth:`tick` with each.

        Every tick is due, also after a gap (a quiet log, a live pipeline that fell behind):
        the recording gets every scene of log time. After a gap longer than
        :data:`MAX_FILL_NS` (a clock step is re-based before: :meth:`rebase`), the ticks of
        its first minute and then the latest."""
        if not self._started:
            self._started = True
            self.next_tick_ns = (t_ns // self.period_ns + 1) * self.period_ns
            return []
        if t_ns < self.next_tick_ns:
            return []
        period = self.period_ns
        tick = self.next_tick_ns
        due = (t_ns - tick) // period + 1
        limit = MAX_FILL_NS // period
        ticks = list(range(tick, tick + min(due, limit) * period, period))
        if due > limit:
            ticks.append(tick + (due - 1) * period)
        self.next_tick_ns = ticks[-1] + period
        return ticks

    def advance(self, t_ns: int) -> list[TopicMessage]:
        """The scenes due before log time ``t_ns`` (:meth:`due_ticks`), one tick after the
        other."""
        return [out for tick in self.due_ticks(t_ns) for out in self.tick(tick)]

    def rebase(self, shift_ns: int, t_ns: int) -> None:
        """The clock stepped by ``shift_ns`` to log time ``t_ns`` (a frame's stamp): every log
        time held is shifted as if no time had passed (the world's observations and lifetimes,
        each object's latest position, the messages not yet observed), and the next tick is the
        one on the scene rate's grid at or just before ``t_ns``, made at once."""
        self.world.shift(shift_ns)
        self.observer.shift(shift_ns)
        self._pending = {name: (values, t + shift_ns)
                         for name, (values, t) in self._pending.items()}
        self._pending_frames = [(name, values, t + shift_ns)
                                for name, values, t in self._pending_frames]
        if self._started:  # the tick at or just before the frame: a clock that steps away and
            # back (one frame stamped a year off) leaves no tick of either timeline unmade
            self.next_tick_ns = t_ns // self.period_ns * self.period_ns

    def update_world(self, t_ns: int) -> LaneModel:
        """The world brought up to the tick at log time ``t_ns``: the messages fed since the
        last tick observed, stale objects expired; returns the tick's lane model."""
        self.ticks += 1
        self.observe_pending()
        self.world.expire(t_ns)
        lanes = self.lanes = self.world.lane_model(t_ns)
        return lanes

    def tick(self, t_ns: int) -> list[TopicMessage]:
        """Scene, semantic topics and frames at log time ``t_ns``."""
        lanes = self.update_world(t_ns)
        world, profile = self.world, self.profile
        steady = world.lead(lanes, t_ns)
        check = world.mio_check(lanes, steady.lead)
        twins: dict[str, dict[int, tuple[int, ...]]] = {}
        aliases = self.observer.aliases
        for name in profile.groups:  # a group observed with another: often the same twins
            objects = world.objects[name]
            same = aliases.get(name)
            twins[name] = (twins[same] if same is not None and same_twins(world.objects[same],
                                                                         objects)
                           else twin_sets(objects.values()))
        from_tracks = profile.lead is not None and profile.lead.source == "tracks"
        topics = self._topics
        out = [_topic_message((topics[category], update, t_ns)) for category, update
               in scene.scene_updates(world, lanes, check, t_ns, self.scene_state,
                                      lead_track=steady.lead if from_tracks else None,
                                      twins=twins, cameras=self.cameras).items()]
        out.append(_topic_message((TF_TOPIC, scene.frame_transforms(profile, t_ns), t_ns)))
        perceived: dict[str, PerceivedObjects] = {}
        for name, group in profile.groups.items():
            objects = world.objects[name]
            same = aliases.get(name)
            perceived[name] = message = (  # a group observed with another: often the same
                semantic.regrouped(perceived[same], name, group.sensor.name)
                if same is not None and copies(world.objects[same], objects)
                else semantic.objects(name, group.sensor.name, objects.values(), t_ns,
                                      twins[name]))
            out.append(_topic_message((self._objects_topics[name], message, t_ns)))
        if profile.lead is not None:
            out.append(TopicMessage(LEAD_TOPIC, semantic.lead(check, t_ns, steady), t_ns))
        if profile.lanes is not None:
            out.append(TopicMessage(LANES_TOPIC, semantic.lanes(lanes, t_ns), t_ns))
        out.append(TopicMessage(EGO_TOPIC, semantic.ego(world, profile, t_ns), t_ns))
        return out
