"""What the bridge produces for a profile: its topics with their schemas, its frames, and samples.

:func:`produced` assembles the drive and keeps what the live pipeline advertises: every topic it
records with its protobuf descriptor, the vehicle and sensor frames, and sample messages
(``/health``) to check message path filters against.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool

from bridge.decode.outcome import Undecoded
from bridge.frame import Frame
from bridge.pipeline.drive import Drive, Stages, load_stages
from bridge.pipeline.marks import Marks
from bridge.sinks.base import Channel, Sink
from bridge.topics import HEALTH_TOPIC, VEHICLE_FRAME


@dataclass
class Produced:
    """Topics (name → protobuf message descriptor) and frame ids the bridge publishes."""

    topics: dict[str, Any] = field(default_factory=dict)
    frames: set[str] = field(default_factory=set)
    #: a message of each topic whose repeated elements are known in advance, to check message
    #: path filters on their :data:`SAMPLE_KEYS` against: ``/health`` with every bus, message
    #: family, sensor pair and alarm
    samples: dict[str, Any] = field(default_factory=dict)


#: The fields that say which element of a sample's repeated field an element is (a filter on
#: one of them must match an element of the sample); every other field is state that changes.
SAMPLE_KEYS: dict[str, frozenset[str]] = {
    "tankviz.BusHealth": frozenset({"bus"}),
    "tankviz.FamilyHealth": frozenset({"name", "sensor"}),
    "tankviz.SensorBias": frozenset({"pair", "sensor_a", "sensor_b"}),
    "tankviz.Alarm": frozenset({"id", "kind", "subject"}),
}


class _Announcements(Sink):
    """A sink that keeps what the pipeline advertises (topic → schema), as a viewer sees it."""

    def __init__(self) -> None:
        self.schemas: dict[str, tuple[str, bytes]] = {}

    def advertise(self, channels: Sequence[Channel], /) -> None:
        for channel in channels:
            self.schemas.setdefault(channel.topic, (channel.schema_name, channel.schema()))


def descriptor_of(schema_name: str, file_descriptor_set: bytes) -> Any:
    """The message descriptor ``schema_name`` of a serialized FileDescriptorSet."""
    files = descriptor_pb2.FileDescriptorSet.FromString(file_descriptor_set).file
    pool = descriptor_pool.DescriptorPool()
    pending = list(files)
    while pending:  # add each file after its dependencies
        ready = [f for f in pending
                 if all(d in {g.name for g in files if g not in pending} for d in f.dependency)]
        if not ready:
            # the bridge's own schemas: a bug of the bridge, not an error of its user
            raise RuntimeError(f"{schema_name}: the schema's files depend on missing files")
        for f in ready:
            pool.Add(f)
            pending.remove(f)
    return pool.FindMessageTypeByName(schema_name)


def produced(decoder: Any, profile: Any, buses: Iterable[str] = ("can0",)) -> Produced:
    """What the bridge advertises live (and records) with this decoder and profile on ``buses``.

    The live pipeline's own announcement (:meth:`~bridge.pipeline.pipeline.Pipeline.advertise`) is
    recorded, and each topic's descriptor is built from the FileDescriptorSet it is advertised
    with: the scene, perception and health topics, /log, and per bus the raw frames and every
    message its databases define. Frames: the vehicle frame and the profile's sensors. Sample:
    the pipeline's own health monitor's ``/health`` (:func:`health_sample`).
    """
    buses = list(buses)
    announcements = _Announcements()
    drive = Drive(Stages(decoder, profile), [announcements])
    drive.pipeline.marks = Marks()  # as live takes them
    drive.pipeline.advertise(buses)
    out = Produced(frames={VEHICLE_FRAME})
    if profile is not None:
        out.frames.update(profile.sensors)
    for topic, (schema_name, schema) in announcements.schemas.items():
        out.topics[topic] = descriptor_of(schema_name, schema)
    out.samples[HEALTH_TOPIC] = health_sample(drive.health, buses)
    return out


def health_sample(monitor: Any, buses: Iterable[str]) -> Any:
    """The ``/health`` message a new :class:`~bridge.health.monitor.HealthMonitor` publishes
    once each of ``buses`` has carried a frame: every bus, message family, sensor pair and alarm
    it reports (bus alarms appear with their bus). ``monitor`` is used up."""
    for bus in buses:
        monitor.on_frame(Frame(0, bus, 0, b"", is_remote=True), Undecoded.REMOTE)
    for output in monitor.tick(0):
        if output.topic == HEALTH_TOPIC:
            return output.message
    raise RuntimeError("the health monitor published no /health")  # pragma: no cover


def bundled_produced(profile: str = "ecocar", buses: Iterable[str] = ("can0",)) -> Produced:
    """What the bundled profile produces (the simulated car and ``tankviz demo`` use bus can0)."""
    decoder, loaded = load_stages([], profile)
    return produced(decoder, loaded, buses)
