"""Semantic messages: the world as typed protobuf (schemas/perception.proto) to plot and analyse."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Mapping, Sequence
from functools import lru_cache

from bridge.frame import NS, timestamp
from bridge.pb.perception_pb2 import (
    EgoState,
    LaneLine,
    Lanes,
    LeadVehicle,
    ObjectClass,
    PerceivedObject,
    PerceivedObjects,
)
from bridge.profile.model import ObjectClass as Kind
from bridge.profile.model import Profile
from bridge.protowire import varint
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


# An object of PerceivedObjects as wire bytes (what :func:`perceived` makes, serialised): parsed
# at once into the group's message, faster than building each object. Fields by number: id 1
# (varint), x 2, y 3, vx 4, vy 5, probability 6 (doubles), object_class 7 (varint), distance 8,
# age 9 (doubles), twins 10 (packed varints); the objects are field 6 of PerceivedObjects, whose
# other fields (timestamp 1, frame_id 2, group 3, sensor 4, count 5: a varint) are written
# before them, and the whole message is parsed at once. A field written with its default value
# (proto3, not optional) is dropped when parsed, as if not set: the message is the same
# (tests/test_semantic_wire.py, tests/test_drive_bytes.py).
_DOUBLE = struct.Struct("<Bd")
_XY = struct.Struct("<BdBd")
_TAIL = struct.Struct("<BdBd")


#: The one-byte varints (0 to 127).
_SMALL = [bytes((n,)) for n in range(0x80)]
#: The first field of an object (its id 1, a varint) as wire bytes, for the ids under 128.
_SMALL_IDS = [b"\x08" + n for n in _SMALL]
#: Each class's field (object_class 7, a varint) as wire bytes.
#: (by the class's value: a str hashes faster than an Enum member)
_CLASS_FIELDS = {kind._value_: b"\x38" + varint(value) for kind, value in _CLASSES.items()}


def _object_bytes(o: ObjectObservation, t_ns: int, twins: Sequence[int]) -> bytes:
    x, y = o.x, o.y
    i = o.object_id
    parts = [_SMALL_IDS[i] if i < 0x80 else b"\x08" + varint(i), _XY.pack(0x11, x, 0x19, y)]
    if o.vx is not None:
        parts.append(_DOUBLE.pack(0x21, o.vx))
    if o.vy is not None:
        parts.append(_DOUBLE.pack(0x29, o.vy))
    if o.probability is not None:
        parts.append(_DOUBLE.pack(0x31, o.probability))
    parts += (_CLASS_FIELDS[o.object_class._value_],
              _TAIL.pack(0x41, math.hypot(x, y), 0x49, (t_ns - o.t_ns) / NS))
    if twins:
        others = b"".join([_SMALL[t] if t < 0x80 else varint(t) for t in twins if t != i])
        if others:
            n = len(others)
            parts += (b"\x52", _SMALL[n] if n < 0x80 else varint(n), others)
    data = b"".join(parts)
    n = len(data)
    return b"\x32" + (_SMALL[n] if n < 0x80 else varint(n)) + data


@lru_cache(maxsize=64)
def _objects_head(group: str, sensor: str) -> bytes:
    """PerceivedObjects' frame, group and sensor as wire bytes."""
    data: bytes = PerceivedObjects(frame_id=VEHICLE_FRAME, group=group,
                                   sensor=sensor).SerializeToString()
    return data


@lru_cache(maxsize=4)
def _stamp_field(t_ns: int) -> bytes:
    """PerceivedObjects' timestamp (field 1) as wire bytes."""
    data: bytes = timestamp(t_ns).SerializeToString()
    return b"\x0a" + varint(len(data)) + data


def objects(group: str, sensor: str, found: Iterable[ObjectObservation], t_ns: int,
            twins: Mapping[int, Sequence[int]] | None = None) -> PerceivedObjects:
    """Every object of a group, each with its twins (id -> its set, :func:`twin_sets`): each
    object as :func:`perceived` makes it."""
    twins = twins or {}
    items = [_object_bytes(o, t_ns, twins.get(o.object_id, ()))
             for o in sorted(found, key=lambda o: o.object_id)]
    msg: PerceivedObjects = PerceivedObjects.FromString(b"".join([
        _stamp_field(t_ns), _objects_head(group, sensor), b"\x28", varint(len(items)),
        *items]))
    return msg


def lead(check: MioCheck, t_ns: int, steady: SteadyLead | None = None) -> LeadVehicle:
    """The lead and its MIO check; ``steady`` gives its serial number and why it changed."""
    msg = LeadVehicle(timestamp=timestamp(t_ns), frame_id=VEHICLE_FRAME,
                      present=check.lead is not None, expected_present=check.expected is not None,
                      mio_ok=check.ok, mio_reason=check.reason)
    if steady is not None:
        msg.lead_number, msg.change = steady.serial, steady.change
    # each object as perceived() makes it, from its wire bytes (:func:`_object_bytes`, the
    # field of PerceivedObjects: 6, as LeadVehicle's expected; its object is field 4)
    if check.lead is not None:
        msg.MergeFromString(b"\x22" + _object_bytes(check.lead, t_ns, ())[1:])
    if check.expected is not None:
        msg.MergeFromString(_object_bytes(check.expected, t_ns, ()))
    return msg


def lanes(model: LaneModel, t_ns: int) -> Lanes:
    return Lanes(timestamp=timestamp(t_ns), frame_id=VEHICLE_FRAME, source=model.source,
                 camera_age=model.camera_age_s,
                 lines=[LaneLine(name=line.name, c0=line.coefficients[0],
                                 c1=line.coefficients[1], c2=line.coefficients[2],
                                 c3=line.coefficients[3]) for line in model.lines])


def ego(world: World, profile: Profile, t_ns: int) -> EgoState:
    state = world.ego
    msg = EgoState(timestamp=timestamp(t_ns), speed=state.speed or 0.0,
                   yaw_rate=state.yaw_rate or 0.0,
                   steering_wheel_angle=state.steering_wheel_angle or 0.0)
    if state.steering_wheel_angle is not None:
        msg.curvature = steering_curvature(state.steering_wheel_angle,
                                           profile.vehicle.wheelbase_m,
                                           profile.vehicle.steering_ratio)
    return msg
