"""Vehicle profiles: what the DBC signals of one car *mean*; this module is the model.

A :class:`Profile` names the sensors, object groups, lead vehicle, lane lines, ego signals and
mark rules. Its parts are frozen dataclasses that check nothing themselves: a profile comes from
:func:`bridge.profile.loader.load_profile`, which has checked every name, and one that cannot be
used is a :class:`ProfileError`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from functools import cached_property
from pathlib import Path
from typing import Any

from bridge.errors import FileError
from bridge.profile.expr import Expression


class ProfileError(FileError):
    """A profile that cannot be used: ``path: key: reason`` (``path: reason`` without a key)."""

    def __init__(self, path: Path | str, key: str, reason: str) -> None:
        super().__init__(path, f"{key}: {reason}" if key else reason)
        self.key = key
        self.reason = reason


class ObjectClass(str, Enum):
    """What an object is, whatever the sensor's own enumeration."""

    UNKNOWN = "unknown"
    CAR = "car"
    TWO_WHEELER = "two_wheeler"
    PEDESTRIAN = "pedestrian"
    STATIONARY = "stationary"


class SensorKind(str, Enum):
    RADAR = "radar"
    CAMERA = "camera"
    FUSION = "fusion"


@dataclass(frozen=True)
class Mount:
    """A sensor's pose in the vehicle frame: metres, and yaw in degrees (positive to the left)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class Sensor:
    """A sensor and the conventions of what it reports."""

    name: str
    kind: SensorKind
    mount: Mount = Mount()
    #: Which way the sensor's positive lateral distance (and azimuth) points: "left" or "right".
    lateral: str = "left"
    #: "cartesian" (x, y) or "polar" (range, azimuth).
    coordinates: str = "cartesian"
    #: Unit of the azimuth for polar sensors: "deg" or "rad".
    angle_unit: str = "deg"
    #: Multiplies every distance the sensor reports (e.g. 0.01 for centimetres).
    distance_scale: float = 1.0
    #: Field of view: maximum range (m) and half opening angle (degrees), if known.
    fov_range: float | None = None
    fov_azimuth_deg: float | None = None

    @property
    def lateral_sign(self) -> float:
        return 1.0 if self.lateral == "left" else -1.0

    @cached_property
    def rotation(self) -> tuple[float, float]:
        """cos and sin of the mount's yaw (computed once: every position needs them)."""
        yaw = math.radians(self.mount.yaw_deg)
        return math.cos(yaw), math.sin(yaw)


#: ``{i}`` or ``{i:0Nd}`` in a template (the object index; a width of at most 2 digits).
INDEX_PLACEHOLDER = re.compile(r"\{i(?::0?(\d{1,2})d)?\}")


def expand(template: str, index: int) -> str:
    """``RadarObj{i}_A`` with ``{i}`` (or ``{i:02d}``) replaced by the index."""

    def fill(match: re.Match[str]) -> str:
        width = match.group(1)
        return f"{index:0{int(width)}d}" if width else str(index)

    return INDEX_PLACEHOLDER.sub(fill, template)


@dataclass(frozen=True)
class SignalRef:
    """One signal of one DBC message, with a linear unit conversion: value·scale + offset.

    In an object group, message and signal are templates: ``{i}`` stands for the object index.
    """

    message: str
    signal: str
    scale: float = 1.0
    offset: float = 0.0

    def at(self, index: int | None) -> SignalRef:
        """The reference for object ``index`` of a family."""
        if index is None:
            return self
        return SignalRef(expand(self.message, index), expand(self.signal, index), self.scale,
                         self.offset)

    @property
    def messages(self) -> tuple[str, ...]:
        return (self.message,)

    @property
    def signals(self) -> tuple[tuple[str, str], ...]:
        """(message, signal) of every signal the field reads: this one."""
        return ((self.message, self.signal),)

    @property
    def label(self) -> str:
        """``Message.Signal``, for people."""
        return f"{self.message}.{self.signal}"

    def read(self, values: Mapping[str, Any]) -> float | None:
        raw = values.get(self.signal)
        if raw is None:
            return None
        return float(raw) * self.scale + self.offset

    def value(self, latest: Mapping[str, Mapping[str, Any]]) -> float | None:
        """The value from the latest messages (by name); None when missing or not finite."""
        found = latest.get(self.message)
        if found is None:
            return None
        raw = found.get(self.signal)
        if raw is None:
            return None
        value = float(raw) * self.scale + self.offset
        return value if math.isfinite(value) else None


@dataclass(frozen=True)
class Computed:
    """A value computed from several signals: an expression, then value·scale + offset.

    ``reads`` resolves every name the expression reads to its message and signal (plain names
    and ``Message.Signal`` alike, checked when the profile loads). In an object group, the value
    is that of the first object, and ``objects`` holds each object's own (``{i}`` filled in).
    """

    expression: Expression
    #: (name in the expression, message, signal) for every name it reads
    reads: tuple[tuple[str, str, str], ...]
    scale: float = 1.0
    offset: float = 0.0
    #: in an object group: each object's value, by index
    objects: Mapping[int, Computed] = field(default_factory=dict, repr=False, compare=False)

    @property
    def text(self) -> str:
        return self.expression.text

    @cached_property
    def messages(self) -> tuple[str, ...]:
        """Every message the value reads, in the order of their first name in the expression."""
        columns = self.expression.columns
        ordered = sorted(self.reads, key=lambda read: columns.get(read[0], 0))
        return tuple(dict.fromkeys(message for _, message, _ in ordered))

    @property
    def message(self) -> str:
        """The first message the value reads."""
        return self.messages[0] if self.messages else ""

    @property
    def signals(self) -> tuple[tuple[str, str], ...]:
        """(message, signal) of every signal the value reads."""
        return tuple(dict.fromkeys((message, signal) for _, message, signal in self.reads))

    @property
    def label(self) -> str:
        """The expression as written, for people."""
        return self.text

    def at(self, index: int | None) -> Computed:
        """The value of object ``index`` of a family."""
        if index is None:
            return self
        return self.objects.get(index, self)

    def value(self, latest: Mapping[str, Mapping[str, Any]]) -> float | None:
        """The value from the latest messages (by name); None when it cannot be computed (a
        signal missing, ``none``, division by zero) or is not finite."""
        values: dict[str, Any] = {}
        for name, message, signal in self.reads:
            found = latest.get(message)
            if found is not None:
                raw = found.get(signal)
                if raw is not None:
                    values[name] = raw
        result = self.expression.value(values)
        if result is None:
            return None
        result = result * self.scale + self.offset
        return result if math.isfinite(result) else None


#: A mapped field: one signal, or a value computed from several.
Field = SignalRef | Computed


@dataclass(frozen=True)
class Rule:
    """A validity rule over plain signal names and ``Message.Signal`` names."""

    expression: Expression
    #: (name in the rule, message, signal) for every Message.Signal name it reads
    qualified: tuple[tuple[str, str, str], ...] = ()

    @property
    def text(self) -> str:
        return self.expression.text

    @property
    def names(self) -> frozenset[str]:
        return self.expression.names

    def _values(self, values: Mapping[str, Any],
                by_message: Mapping[str, Mapping[str, Any]] | None) -> Mapping[str, Any]:
        """``values`` by plain name, with each qualified name read from ``by_message``."""
        if self.qualified and by_message is not None:
            values = dict(values)
            for name, message, signal in self.qualified:
                found = by_message.get(message)
                if found is not None and signal in found:
                    values[name] = found[signal]
        return values

    def test(self, values: Mapping[str, Any],
             by_message: Mapping[str, Mapping[str, Any]] | None = None) -> bool:
        """Whether the rule holds; ``values`` by plain name, ``by_message`` for qualified ones."""
        return self.expression.test(self._values(values, by_message))

    def judge(self, values: Mapping[str, Any],
              by_message: Mapping[str, Mapping[str, Any]] | None = None) -> tuple[bool, str]:
        """Whether the rule holds, and why it could not be evaluated, naming the rule ("" when
        it could: :meth:`Expression.judge <bridge.profile.expr.Expression.judge>`)."""
        holds, why = self.expression.judge(self._values(values, by_message))
        return holds, f"rule '{self.text}': {why}" if why else ""


@dataclass(frozen=True)
class MarkRule:
    """``[marks]``: a rule over signals of any message (``reads`` resolves each name it reads
    to its message and signal); each time it becomes true, the drive is marked with ``text``
    (default: the rule itself) and ``category``."""

    expression: Expression
    #: (name in the rule, message, signal) for every name it reads
    reads: tuple[tuple[str, str, str], ...]
    text: str
    category: str = ""

    @property
    def when(self) -> str:
        """The rule as written."""
        return self.expression.text

    @property
    def messages(self) -> frozenset[str]:
        """Every message the rule reads: a frame of one of them may make a mark."""
        return frozenset(message for _, message, _ in self.reads)


@dataclass(frozen=True)
class FamilyMember:
    """One message of an object family and the object index it carries."""

    template: str
    index: int | None


@dataclass(frozen=True)
class Pages:
    """A multiplexed message of an object family: sent in pages, each a value of its multiplexor
    signal(s) and carrying some of its signals; the pages of one object are merged within a
    cycle (:mod:`bridge.world.pages`)."""

    #: the multiplexor signals: their values say which page a frame is
    multiplexors: tuple[str, ...]
    #: the signals only some pages carry (the others are in every page)
    paged: frozenset[str]


@dataclass(frozen=True)
class ObjectGroup:
    """A group of objects (detections of one sensor, or tracks) from a family of messages.

    Its ``role`` says which: a radar's track slots are tracks as much as a fusion's output, so one
    sensor can serve a detections group and a tracks group.

    Object ``i`` is described by the messages ``templates`` with ``{i}`` replaced; the first
    template carries the position and makes a new observation, the others (companions) add their
    latest signals to it. Without an index range, a single message carries one object per frame
    and the ``id`` signal says which.
    """

    name: str
    sensor: Sensor
    templates: tuple[str, ...]
    #: Message name -> (template position, object index); built from the templates.
    members: Mapping[str, FamilyMember]
    x: Field | None
    y: Field | None
    range: Field | None
    azimuth: Field | None
    vx: Field | None = None
    vy: Field | None = None
    probability: Field | None = None
    class_signal: Field | None = None
    classes: Mapping[int, ObjectClass] = field(default_factory=dict)
    id: Field | None = None
    #: the validity rule of each object (index); empty: every object is valid
    valid: Mapping[int | None, Rule] = field(default_factory=dict)
    lifetime_s: float = 0.1
    #: "detections" or "tracks" (red, labelled, candidates for ``[lead] source = "tracks"``);
    #: None: from the sensor's kind (fusion: tracks, else detections)
    role: str | None = None
    #: each multiplexed message of the family (by name) and its pages; empty: none is
    pages: Mapping[str, Pages] = field(default_factory=dict)

    @property
    def is_tracks(self) -> bool:
        if self.role is not None:
            return self.role == "tracks"
        return self.sensor.kind is SensorKind.FUSION


@dataclass(frozen=True)
class LeadSpec:
    """The lead vehicle (most important object): its own message(s), or chosen from tracks."""

    #: "message": read from ``group``; "tracks": the closest valid track inside the ego lane.
    source: str
    group: ObjectGroup | None = None
    lifetime_s: float = 0.3


@dataclass(frozen=True)
class LaneLine:
    """One lane line: y = c0 + c1·x + c2·x² + c3·x³ in the sensor frame, from one message."""

    name: str
    message: str
    c0: Field
    c1: Field | None
    c2: Field | None
    c3: Field | None
    valid: Rule | None = None


@dataclass(frozen=True)
class LaneSpec:
    #: The camera whose frame the lines are in; None without camera lines (steering lanes only).
    sensor: Sensor | None
    #: Camera lines by name; empty for a car without a lane camera: lanes from the steering only.
    lines: Mapping[str, LaneLine]
    #: Camera lanes older than this (s) are stale: the steering fallback takes over.
    stale_after_s: float = 0.5
    #: Length drawn ahead of the vehicle (m).
    length_m: float = 100.0
    #: Lateral offsets of the fallback (steering) lanes in the vehicle frame (y left), metres.
    fallback_left_m: float = 1.8
    fallback_right_m: float = -1.8


@dataclass(frozen=True)
class EgoSpec:
    """Ego signals, converted to m/s, rad/s and the steering wheel angle in radians (left +)."""

    speed: Field | None = None
    yaw_rate: Field | None = None
    steering_wheel_angle: Field | None = None


@dataclass(frozen=True)
class Vehicle:
    wheelbase_m: float = 2.8
    steering_ratio: float = 15.0
    length_m: float = 2.5
    width_m: float = 1.5
    height_m: float = 1.0
    #: Where the vehicle frame's origin is on the car: one of :data:`ORIGINS`.
    origin: str = "centre"
    #: For ``origin = "rear_axle"``: how far (m) the box's rear is behind the origin.
    rear_overhang_m: float = 1.0

    #: "centre": the box centred on the origin; "rear_axle": its rear ``rear_overhang_m`` behind
    #: the origin; "front_bumper": its front at the origin.
    ORIGINS = ("centre", "rear_axle", "front_bumper")

    @property
    def box_centre_x(self) -> float:
        """x of the ego box's centre in the vehicle frame, as the origin says."""
        if self.origin == "rear_axle":
            return self.length_m / 2 - self.rear_overhang_m
        if self.origin == "front_bumper":
            return -self.length_m / 2
        return 0.0


@dataclass(frozen=True)
class Profile:
    name: str
    path: Path
    vehicle: Vehicle
    sensors: Mapping[str, Sensor]
    groups: Mapping[str, ObjectGroup]
    lead: LeadSpec | None
    lanes: LaneSpec | None
    ego: EgoSpec
    #: Databases the profile names (bus or "*" -> paths), used when no --dbc is given.
    databases: Mapping[str, tuple[Path, ...]] = field(default_factory=dict)
    #: Nominal bitrate per bus (bit/s), for the bus load; and the CAN FD data bitrate.
    bitrates: Mapping[str, int] = field(default_factory=dict)
    data_bitrates: Mapping[str, int] = field(default_factory=dict)
    #: The rules that mark the drive when they become true (``[marks]``).
    marks: tuple[MarkRule, ...] = ()

    def message_names(self) -> set[str]:
        """Every DBC message the profile reads."""
        names = {m for g in self.groups.values() for m in g.members}
        if self.lead is not None and self.lead.group is not None:
            names |= set(self.lead.group.members)
        if self.lanes is not None:
            names |= {line.message for line in self.lanes.lines.values()}
        for ref in (self.ego.speed, self.ego.yaw_rate, self.ego.steering_wheel_angle):
            if ref is not None:
                names.update(ref.messages)
        for rule in self.marks:
            names |= rule.messages
        return names
