"""The data path for one drive: frames → decode → perception → sinks (recorder, live server).

:class:`Pipeline` is what convert, live, demo and replay run for every frame. The recorder gets
every raw frame and every decoded message; the live server gets the scene and perception topics
always, and raw frames and decoded signals only while a client subscribes to them. Each message
is serialized once for both sinks.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from typing import Any

from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap_protobuf.schema import build_file_descriptor_set

from bridge import __version__
from bridge.decode.decoder import DatabaseFile, Decoder, MessageCodec
from bridge.frame import Frame
from bridge.health.monitor import HealthMonitor, alarm_entities, fov_entities
from bridge.pb.can_frame_pb2 import CanFrame
from bridge.pipeline.perception import DEFAULT_SCENE_RATE, Perception
from bridge.profile.model import Profile
from bridge.scene import entities as scene
from bridge.sinks.mcap import FrameSink, Recorder, frame_payload
from bridge.sinks.websocket import LiveServer
from bridge.topics import HEALTH_CATEGORY, LOG_TOPIC, TopicMessage, frames_topic, scene_topic

INF = float("inf")


class Pipeline:
    """Runs one drive's frames through decoding and perception into the sinks given."""

    def __init__(self, decoder: Decoder, *, profile: Profile | None = None,
                 scene_rate: float = DEFAULT_SCENE_RATE, recorder: FrameSink | None = None,
                 server: LiveServer | None = None, health: HealthMonitor | None = None) -> None:
        self.decoder = decoder
        self.profile = profile
        self.scene_rate = scene_rate
        self.recorder = recorder
        self.server = server
        self.perception = (Perception(profile, scene_rate=scene_rate)
                           if profile is not None else None)
        self.health = health
        self._wanted = self.perception.messages if self.perception is not None else frozenset()
        #: whether perception takes a codec's messages (filled as they come)
        self._fed: dict[MessageCodec, bool] = {}
        self._next_tick: int | float = (float("-inf") if self.perception is not None
                                        or health is not None else float("inf"))
        self._server_channels: dict[str, int] = {}
        self._frame_channels: dict[str, int] = {}
        self._codec_channels: dict[MessageCodec, int] = {}
        self.frames = 0
        self.last_ns: int | None = None

    def process(self, frame: Frame) -> None:
        """One frame through every stage."""
        t = frame.timestamp_ns
        if t >= self._next_tick:
            self.advance(t)
        recorder, server = self.recorder, self.server
        payload = None
        if recorder is not None:
            payload = frame_payload(frame)
            recorder.write_frame(frame, payload)
        if server is not None:
            channel = self._frame_channels.get(frame.bus)
            if channel is None:
                channel = self._frame_channel(server, frame.bus)
            if payload is not None:
                server.publish(channel, t, payload)  # (sent only to who subscribed)
            elif server.wanted(channel):
                server.publish(channel, t, frame_payload(frame))
        decoded = self.decoder.decode(frame)
        if self.health is not None:
            self.health.on_frame(frame, decoded)
        if decoded is not None:
            if recorder is not None:
                recorder.write_decoded(t, decoded)
            codec = decoded.codec
            if server is not None:
                channel = self._codec_channels.get(codec)
                if channel is None:
                    channel = self._codec_channels[codec] = self._server_channel(
                        server, codec.topic, codec.schema.full_name,
                        codec.schema.file_descriptor_set)
                server.publish(channel, t, decoded.payload)
            fed = self._fed.get(codec)
            if fed is None:
                fed = self._fed[codec] = codec.message.name in self._wanted
            if fed and self.perception is not None:
                self.perception.feed(codec.message.name, decoded.signals, t)
        self.frames += 1
        self.last_ns = t

    def advance(self, t_ns: int) -> None:
        """Emit the scenes and health checks due before log time ``t_ns`` (also when no frame
        comes)."""
        perception, health = self.perception, self.health
        outputs: list[TopicMessage] = []
        if perception is not None:
            outputs = perception.advance(t_ns)
            if outputs and health is not None:
                outputs.append(self._health_scene(perception, health, outputs[0].t_ns))
        if health is not None:
            outputs += health.advance(t_ns)
        self.emit(outputs)
        self._next_tick = min(perception.next_tick_ns if perception is not None else INF,
                              health.next_tick_ns if health is not None else INF)

    def _health_scene(self, perception: Perception, health: HealthMonitor,
                      t_ns: int) -> TopicMessage:
        """The health checks look at the world of this scene tick; the scene shows the alarms
        beside the ego and each sensor's field of view (red when alarmed)."""
        assert self.profile is not None
        health.on_world(t_ns, perception.world, perception.lanes)
        alarms = health.active_alarms()
        entities = alarm_entities(alarms, t_ns) + fov_entities(self.profile, alarms, t_ns)
        topic = scene_topic(HEALTH_CATEGORY)
        update = scene.update(topic, entities, t_ns, perception.scene_state)
        return TopicMessage(topic, update, t_ns)

    def finish(self) -> None:
        """Emit what is still due at the end of the drive."""
        if self.last_ns is None:
            return
        if self.perception is not None:
            outputs = self.perception.finish(self.last_ns)
            if outputs and self.health is not None:
                outputs.append(self._health_scene(self.perception, self.health,
                                                  outputs[0].t_ns))
            self.emit(outputs)
        if self.health is not None:
            self.emit(self.health.finish(self.last_ns))

    def emit(self, outputs: Iterable[TopicMessage]) -> None:
        """Scene, perception and other messages to every sink: the live server first (viewers
        wait for them; the recorder does not)."""
        recorder, server = self.recorder, self.server
        serialized = [(out, type(out.message), out.message.SerializeToString())
                      for out in outputs]
        if server is not None and serialized:
            for out, cls, payload in serialized:
                server.publish(self._server_channel(server, out.topic, cls.DESCRIPTOR.full_name,
                                                    lambda cls=cls: _fds(cls)),
                               out.t_ns, payload)
            server.flush()
        if recorder is not None:
            for out, cls, payload in serialized:
                recorder.write_payload(out.topic, cls, payload, out.t_ns)

    def _frame_channel(self, server: LiveServer, bus: str) -> int:
        channel = self._frame_channels[bus] = self._server_channel(
            server, frames_topic(bus), "tankviz.CanFrame", lambda: _fds(CanFrame))
        return channel

    def _server_channel(self, server: LiveServer, topic: str, schema_name: str,
                        schema: Any) -> int:
        channel = self._server_channels.get(topic)
        if channel is None:
            channel = self._server_channels[topic] = server.channel_for_schema(
                topic, schema_name, schema())
        return channel

    def advertise(self, buses: Iterable[str]) -> None:
        """Advertise every channel before any frame arrives (live): the scene and perception
        topics, /log, and all that these buses can carry."""
        server = self.server
        if server is None:
            return
        topics = self.perception.topics() if self.perception is not None else []
        if self.health is not None:
            topics += self.health.topics()
            if self.perception is not None:
                topics.append((scene_topic(HEALTH_CATEGORY), SceneUpdate))
        for topic, cls in [*topics, (LOG_TOPIC, Log)]:
            self._server_channel(server, topic, cls.DESCRIPTOR.full_name,
                                 lambda cls=cls: _fds(cls))
        for bus in buses:
            self._server_channel(server, frames_topic(bus), "tankviz.CanFrame",
                                 lambda: _fds(CanFrame))
            for codec in self.decoder.codecs_for(bus):
                self._server_channel(server, codec.topic, codec.schema.full_name,
                                     codec.schema.file_descriptor_set)


def new_health_monitor(decoder: Decoder, profile: Profile | None,
                       bitrates: Mapping[str, int] | None = None) -> HealthMonitor:
    """The health monitor of a drive; bitrates given here override the profile's."""
    rates = dict(profile.bitrates) if profile is not None else {}
    rates.update(bitrates or {})
    return HealthMonitor(profile, decoder, bitrates=rates,
                         data_bitrates=profile.data_bitrates if profile is not None else None)


def _fds(cls: Any) -> bytes:
    return bytes(build_file_descriptor_set(cls).SerializeToString())


def attachment_names(files: Iterable[DatabaseFile]) -> dict[str, str]:
    """Attachment name per database sha256: the file name, made unique where two collide."""
    names: dict[str, str] = {}
    for f in files:
        name = f.path.name
        if name in names.values():
            name = f"{f.sha256[:8]}-{name}"
        names.setdefault(f.sha256, name)
    return names


def describe_drive(recorder: Recorder, decoder: Decoder, profile: Profile | None,
                   scene_rate: float, extra: dict[str, Any]) -> dict[str, Any]:
    """Attach the databases and the profile, and write the ``tankviz`` metadata record.

    Returns the decode statistics that went into it.
    """
    names = attachment_names(decoder.files)
    for f in decoder.files:
        recorder.add_attachment(names[f.sha256], f.content)
    if profile is not None:
        recorder.add_attachment(f"profile-{profile.path.name}", profile.path.read_bytes(),
                                media="application/toml")
    buses: dict[str, list[str]] = {}
    for f in decoder.files:
        for bus in decoder.buses_for(f):
            buses.setdefault(bus, []).append(names[f.sha256])
    statistics = decoder.stats.to_dict(decoder.codecs())
    recorder.add_metadata({
        "tankviz_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "profile": ({"name": profile.name, "attachment": f"profile-{profile.path.name}",
                     "scene_rate_hz": scene_rate} if profile is not None else None),
        "databases": [{"name": f.name, "attachment": names[f.sha256], "sha256": f.sha256,
                       "path": str(f.path), "buses": decoder.buses_for(f)}
                      for f in decoder.files],
        "bus_databases": buses,
        "statistics": statistics,
        **extra,
    })
    return statistics
