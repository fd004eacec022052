"""How the scene is encoded: its messages' fields as protobuf wire bytes (on
:mod:`bridge.protowire`). An entity of a scene tick is the bytes of its fields (a
:class:`WireEntity`), and a category's SceneUpdate is parsed from its entities' bytes in one
call (:func:`scene_update`): the message that setting each field makes, byte for byte.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from functools import lru_cache

from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from google.protobuf.message import Message

from bridge.frame import timestamp
from bridge.protowire import ONE_BYTE, field, tag, varint


def _tag(message: type[Message], name: str) -> bytes:
    """The tag of ``message``'s length-delimited field ``name``."""
    return tag(message.DESCRIPTOR.fields_by_name[name].number, 2)


#: SceneEntity's length-delimited fields' tags (its timestamp: :func:`stamp_field`).
ID_TAG, METADATA_TAG, CUBES_TAG, SPHERES_TAG, CYLINDERS_TAG, LINES_TAG, TEXTS_TAG = (
    _tag(SceneEntity, name) for name in (
        "id", "metadata", "cubes", "spheres", "cylinders", "lines", "texts"))
#: SceneUpdate's entities' tag.
ENTITIES_TAG = _tag(SceneUpdate, "entities")
#: TextPrimitive's text's tag (the string a label shows).
TEXT_STRING_TAG = _tag(TextPrimitive, "text")
#: LinePrimitive's points' tag, a number (:data:`VECTOR`'s first byte).
POINTS_TAG = LinePrimitive.DESCRIPTOR.fields_by_name["points"].number << 3 | 2

#: A Vector3 or Point3 as a field: its one-byte tag, its length 27, then x, y and z (fields 1, 2,
#: 3: doubles), as ``VECTOR.pack(tag, 27, 0x09, x, 0x11, y, 0x19, z)``. Tags: a pose's
#: position 0x0A, a primitive's size 0x12, a line's point :data:`POINTS_TAG`.
VECTOR = struct.Struct("<BBBdBdBd")
#: No rotation (a zero quaternion, protobuf's default, would make a primitive invisible).
IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
#: A pose's orientation (Pose field 2): no rotation.
ORIENTATION = field(b"\x12", IDENTITY.SerializeToString())
#: A primitive's pose (field 1 of every primitive) up to its position: its tag and length.
POSE_HEAD = b"\x0a" + varint(VECTOR.size + len(ORIENTATION))


@lru_cache(maxsize=4)
def stamp_field(t_ns: int) -> bytes:
    """A message's timestamp at ``t_ns``, field 1 of every message stamped here (SceneEntity,
    FrameTransform and the perception messages)."""
    return field(b"\x0a", timestamp(t_ns).SerializeToString())


def metadata_key(name: str) -> bytes:
    """A metadata item's key (KeyValuePair field 1), for :func:`metadata`."""
    return field(b"\x0a", name.encode())


def metadata(key: bytes, value: str) -> bytes:
    """A SceneEntity's metadata item: a KeyValuePair of ``key`` (:func:`metadata_key`) and ``value``
    (field 2)."""
    data = value.encode()
    n = len(data)
    if n < 0x80:  # the common case: the item's and the value's lengths each one byte
        m = len(key) + 2 + n
        if m < 0x80:
            return b"".join((METADATA_TAG, ONE_BYTE[m], key, b"\x12", ONE_BYTE[n], data))
    return field(METADATA_TAG, key + field(b"\x12", data))


def line_points(points: Iterable[tuple[float, float]], z: float) -> bytes:
    """A LinePrimitive's ``points`` (x, y) at height ``z``: its points' fields only."""
    pack, tag = VECTOR.pack, POINTS_TAG
    return b"".join([pack(tag, 27, 0x09, x, 0x11, y, 0x19, z) for x, y in points])


def sphere_parts(color: Color) -> tuple[bytes, bytes]:
    """A SpherePrimitive of ``color`` as a SceneEntity's field, around its position and size:
    the bytes before its position, and after its size (its colour). Between them: the
    position (a :data:`VECTOR` of tag 0x0A), :data:`ORIENTATION` and the size (tag 0x12)."""
    tail = field(b"\x1a", color.SerializeToString())  # SpherePrimitive.color
    length = len(POSE_HEAD) + VECTOR.size + len(ORIENTATION) + VECTOR.size + len(tail)
    return SPHERES_TAG + varint(length) + POSE_HEAD, tail


def without(message: Message, name: str) -> bytes:
    """``message``'s bytes without its field ``name``."""
    copy = type(message)()
    copy.CopyFrom(message)
    copy.ClearField(name)
    data: bytes = copy.SerializeToString()
    return data


class WireEntity:
    """A SceneEntity being built as the wire bytes of its fields (``parts``, in order), its
    ``id`` and lifetime (its label's, when it has one); :func:`scene_update` parses the
    entities of a category at once."""

    __slots__ = ("id", "lifetime_s", "parts")

    def __init__(self, entity_id: str, parts: list[bytes], lifetime_s: float = 0.0) -> None:
        self.id = entity_id
        self.parts = parts
        self.lifetime_s = lifetime_s


def scene_update(entities: Iterable[WireEntity]) -> SceneUpdate:
    """A SceneUpdate of ``entities``, in order, parsed from their wire bytes in one call."""
    items: list[bytes] = []
    for e in entities:
        data = b"".join(e.parts)
        n = len(data)
        items += (ENTITIES_TAG, ONE_BYTE[n] if n < 0x80 else bytes((n & 0x7F | 0x80, n >> 7))
                  if n < 0x4000 else varint(n), data)  # varint(n), its one or two bytes inline
    update: SceneUpdate = SceneUpdate.FromString(b"".join(items))
    return update
