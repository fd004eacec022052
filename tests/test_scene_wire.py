"""The wire bytes written by hand (bridge.protowire, bridge.scene.wire) are what protobuf writes
for the same fields: lengths of one, two and three bytes, metadata short and long, a sphere's
parts, a stamp."""

from __future__ import annotations

import pytest
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.internal.decoder import _DecodeVarint

from bridge.frame import timestamp
from bridge.protowire import DOUBLE, ONE_BYTE, field, string, tag, varint
from bridge.scene import entities, wire

LENGTHS = [0, 1, 127, 128, 300, 0x3FFF, 0x4000, 70_000]


@pytest.mark.parametrize("n", [*LENGTHS, 2**32 - 1, 2**63])
def test_a_varint_reads_back_as_its_number(n: int) -> None:
    assert _DecodeVarint(varint(n), 0) == (n, len(varint(n)))


def test_the_one_byte_varints_are_the_varints_under_128() -> None:
    assert [varint(n) for n in range(128)] == ONE_BYTE
    assert len(varint(128)) == 2


@pytest.mark.parametrize("n", LENGTHS)
def test_a_field_and_a_string_are_what_protobuf_writes(n: int) -> None:
    words = "é" * (n // 2) + "x" * (n % 2)  # n bytes of UTF-8
    written = string(wire.ID_TAG, words)

    assert written == field(wire.ID_TAG, words.encode())
    assert SceneEntity.FromString(written) == SceneEntity(id=words)
    if n:  # (protobuf leaves an empty string out)
        assert written == SceneEntity(id=words).SerializeToString()
    assert tag(3, 2) == wire.ID_TAG


def test_a_double_field_is_its_tag_and_eight_bytes() -> None:
    assert DOUBLE.pack(0x09, -2.5) == Vector3(x=-2.5).SerializeToString()


@pytest.mark.parametrize("n", [0, 5, 120, 121, 127, 128, 5000, 20_000])
def test_a_metadata_item_is_the_key_value_pair_protobuf_writes(n: int) -> None:
    value = "v" * n
    written = wire.metadata(wire.metadata_key("place"), value)
    expected = SceneEntity(metadata=[KeyValuePair(key="place", value=value)])

    assert SceneEntity.FromString(written) == expected
    if n:  # (protobuf leaves an empty value out)
        assert written == expected.SerializeToString()


def test_a_sphere_s_parts_around_its_position_and_size_make_the_sphere() -> None:
    color = entities.color(entities.RADAR_COLOR)
    head, tail = wire.sphere_parts(color)
    place = wire.VECTOR.pack(0x0A, 27, 0x09, 1.5, 0x11, -2.0, 0x19, 0.5)
    size = wire.VECTOR.pack(0x12, 27, 0x09, 0.5, 0x11, 0.5, 0x19, 0.25)

    expected = SceneEntity(spheres=[SpherePrimitive(
        pose=entities.pose(1.5, -2.0, 0.5), size=Vector3(x=0.5, y=0.5, z=0.25), color=color)])
    assert head + place + wire.ORIENTATION + size + tail == expected.SerializeToString()


def test_a_stamp_is_the_timestamp_field_of_an_entity() -> None:
    t_ns = 1_700_000_000 * 10**9 + 123

    assert wire.stamp_field(t_ns) == SceneEntity(timestamp=timestamp(t_ns)).SerializeToString()


def test_without_a_field_the_message_s_bytes_lack_only_it_and_the_message_is_unchanged() -> None:
    e = SceneEntity(id="ego", frame_id="vehicle", metadata=[KeyValuePair(key="k", value="v")])

    assert wire.without(e, "metadata") == SceneEntity(id="ego", frame_id="vehicle") \
        .SerializeToString()
    assert len(e.metadata) == 1
