"""The perception topics: the world as typed protobuf messages (schemas/perception.proto) to plot
and analyse, each parsed from its wire bytes in one call (the message that setting its fields
makes)."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Mapping, Sequence
from functools import lru_cache
from operator import attrgetter

from bridge.frame import NS
from bridge.pb.perception_pb2 import (
    EgoState,
    Lanes,
    LeadVehicle,
    ObjectClass,
    PerceivedObject,
    PerceivedObjects,
)
from bridge.profile.model import ObjectClass as Kind
from bridge.profile.model import Profile
from bridge.protowire import DOUBLE, ONE_BYTE, field, string, varint
from bridge.scene.wire import stamp_field
from bridge.topics import VEHICLE_FRAME
from bridge.world.lead import SteadyLead
from bridge.world.model import LaneModel, MioCheck, World, steering_curvature
from bridge.world.observe import ObjectObservation

_CLASSES = {
    Kind.UNKNOWN: ObjectClass.OBJECT_CLASS_UNKNOWN,
    Kind.CAR: ObjectClass.OBJECT_CLASS_CAR,
    Kind.TWO_WHEELER: ObjectClass.OBJECT_CLASS_TWO_WHEELER,
    Kind.PEDESTRIAN: ObjectClass.OBJECT_CLASS_PEDESTRIAN,
    Kind.STATIONARY: ObjectClass.OBJECT_CLASS_STATIONARY,
}


def perceived(o: ObjectObservation, t_ns: int, twins: Sequence[int] = ()) -> PerceivedObject:
    """One object; ``twins``: its set of twins (itself included, as twin_sets gives it)."""
    msg = PerceivedObject(id=o.object_id, x=o.x, y=o.y, object_class=_CLASSES[o.object_class],
                          distance=math.hypot(o.x, o.y), age=(t_ns - o.t_ns) / NS,
                          twins=[i for i in twins if i != o.object_id])
    if o.vx is not None:
        msg.vx = o.vx
    if o.vy is not None:
        msg.vy = o.vy
    if o.probability is not None:
        msg.probability = o.probability
    return msg


# An object of PerceivedObjects as wire bytes (what :func:`perceived` makes, serialised). Fields
# by number: id 1 (varint), x 2, y 3, vx 4, vy 5, probability 6 (doubles), object_class 7
# (varint), distance 8, age 9 (doubles), twins 10 (packed varints); the objects are field 6 of
# PerceivedObjects, whose other fields (timestamp 1, frame_id 2, group 3, sensor 4, count 5: a
# varint) are written before them. A field written with its default value (proto3, not
# optional) is dropped when parsed, as if not set: the message is the same.
_TWO_DOUBLES = struct.Struct("<BdBd")
#: A double field (tag, value). Bound here: a method of an imported name is looked up slower.
_double = DOUBLE.pack
#: The first field of an object (its id 1, a varint) as wire bytes, for the ids under 128.
_SMALL_IDS = [b"\x08" + n for n in ONE_BYTE]
#: Each class's field (object_class 7, a varint) as wire bytes.
#: (by the class's value: a str hashes faster than an Enum member)
_CLASS_FIELDS = {kind._value_: b"\x38" + varint(value) for kind, value in _CLASSES.items()}


def _object_bytes(o: ObjectObservation, t_ns: int, twins: Sequence[int]) -> bytes:
    x, y = o.x, o.y
    i = o.object_id
    parts = [_SMALL_IDS[i] if i < 0x80 else b"\x08" + varint(i),
             _TWO_DOUBLES.pack(0x11, x, 0x19, y)]
    if o.vx is not None:
        parts.append(_double(0x21, o.vx))
    if o.vy is not None:
        parts.append(_double(0x29, o.vy))
    if o.probability is not None:
        parts.append(_double(0x31, o.probability))
    parts += (_CLASS_FIELDS[o.object_class._value_],
              _TWO_DOUBLES.pack(0x41, math.hypot(x, y), 0x49, (t_ns - o.t_ns) / NS))
    if twins:
        others = b"".join([ONE_BYTE[t] if t < 0x80 else varint(t) for t in twins if t != i])
        if others:
            parts.append(field(b"\x52", others))
    data = b"".join(parts)
    n = len(data)
    return b"\x32" + (ONE_BYTE[n] if n < 0x80 else varint(n)) + data  # field(b"\x32", data)


@lru_cache(maxsize=64)
def _objects_head(group: str, sensor: str) -> bytes:
    """PerceivedObjects' frame, group and sensor as wire bytes."""
    data: bytes = PerceivedObjects(frame_id=VEHICLE_FRAME, group=group,
                                   sensor=sensor).SerializeToString()
    return data


_ID = attrgetter("object_id")


def objects(group: str, sensor: str, found: Iterable[ObjectObservation], t_ns: int,
            twins: Mapping[int, Sequence[int]] | None = None) -> PerceivedObjects:
    """Every object of a group, each with its twins (id -> its set, :func:`twin_sets`): each
    object as :func:`perceived` makes it."""
    twins = twins or {}
    items = [_object_bytes(o, t_ns, twins.get(o.object_id, ()))
             for o in sorted(found, key=_ID)]
    msg: PerceivedObjects = PerceivedObjects.FromString(b"".join([
        stamp_field(t_ns), _objects_head(group, sensor), b"\x28",
        ONE_BYTE[len(items)] if len(items) < 0x80 else varint(len(items)),
        *items]))
    return msg


#: LeadVehicle's frame (field 2), Lanes' (field 2): the vehicle frame.
_FRAME = string(b"\x12", VEHICLE_FRAME)
#: LeadVehicle's bools: present 3, expected_present 5, mio_ok 7 (a varint 1 when true).
_PRESENT, _EXPECTED_PRESENT, _MIO_OK = b"\x18\x01", b"\x28\x01", b"\x38\x01"


def regrouped(message: PerceivedObjects, group: str, sensor: str) -> PerceivedObjects:
    """Another group's ``message`` (:func:`objects`) as the objects of ``group`` and ``sensor``:
    what :func:`objects` makes of the same observations under that group's name."""
    msg = PerceivedObjects()
    msg.CopyFrom(message)
    msg.group, msg.sensor = group, sensor
    return msg


def lead(check: MioCheck, t_ns: int, steady: SteadyLead | None = None) -> LeadVehicle:
    """The lead and its MIO check; ``steady`` gives its serial number and why it changed."""
    parts = [stamp_field(t_ns), _FRAME]
    # each object as perceived() makes it, from its wire bytes (:func:`_object_bytes`, the
    # field of PerceivedObjects: 6, as LeadVehicle's expected; its object is field 4)
    if check.lead is not None:
        parts += (_PRESENT, b"\x22", _object_bytes(check.lead, t_ns, ())[1:])
    if check.expected is not None:
        parts += (_EXPECTED_PRESENT, _object_bytes(check.expected, t_ns, ()))
    if check.ok:
        parts.append(_MIO_OK)
    parts.append(string(b"\x42", check.reason))  # mio_reason 8
    if steady is not None:  # lead_number 9 (a varint), change 10
        parts += (b"\x48", varint(steady.serial), string(b"\x52", steady.change))
    msg: LeadVehicle = LeadVehicle.FromString(b"".join(parts))
    return msg


#: A LaneLine's coefficients c0 to c3 (fields 2 to 5, doubles) as wire bytes.
_COEFFICIENTS = struct.Struct("<BdBdBdBd")


def lanes(model: LaneModel, t_ns: int) -> Lanes:
    parts = [stamp_field(t_ns), _FRAME, string(b"\x1a", model.source)]  # source 3
    pack = _COEFFICIENTS.pack
    for line in model.lines:  # lines 4: each a LaneLine (name 1, c0 to c3)
        c0, c1, c2, c3 = line.coefficients
        parts.append(field(b"\x22", string(b"\x0a", line.name)
                           + pack(0x11, c0, 0x19, c1, 0x21, c2, 0x29, c3)))
    parts.append(_double(0x29, model.camera_age_s))  # camera_age 5
    msg: Lanes = Lanes.FromString(b"".join(parts))
    return msg


#: EgoState's speed, yaw rate and steering wheel angle (fields 2, 3, 4: doubles).
_EGO = struct.Struct("<BdBdBd")


def ego(world: World, profile: Profile, t_ns: int) -> EgoState:
    state = world.ego
    parts = [stamp_field(t_ns), _EGO.pack(0x11, state.speed or 0.0, 0x19, state.yaw_rate or 0.0,
                                           0x21, state.steering_wheel_angle or 0.0)]
    if state.steering_wheel_angle is not None:  # curvature 5
        parts.append(_double(0x29, steering_curvature(
            state.steering_wheel_angle, profile.vehicle.wheelbase_m,
            profile.vehicle.steering_ratio)))
    msg: EgoState = EgoState.FromString(b"".join(parts))
    return msg
