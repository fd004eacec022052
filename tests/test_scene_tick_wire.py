"""The scene tick builds its entities as wire bytes (bridge.scene.wire.WireEntity): each is the
message that setting its fields one by one makes, byte for byte."""

from __future__ import annotations

import math
import random

import pytest
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

from bridge.frame import timestamp
from bridge.pipeline.drive import load_stages
from bridge.profile.model import ObjectClass
from bridge.scene import entities, wire
from bridge.scene.labels import Block
from bridge.topics import VEHICLE_FRAME
from bridge.world.model import LaneCurve, LaneModel, steering_curve
from bridge.world.observe import ObjectObservation

_EDGES = [0.0, -0.0, 1.5, -3.25, 1e300, 5e-324]


def _number(rnd: random.Random) -> float:
    return rnd.choice(_EDGES) if rnd.random() < 0.3 else rnd.uniform(-300.0, 300.0)


def _by_fields(block: Block, t_ns: int, lifetime_s: float) -> SceneEntity:
    """A block's entity set field by field: the entity it names' id and lifetime, add_text,
    then a leader line."""
    e = entities.entity(t_ns, "x", lifetime_s)
    entities.add_text(e, block.x, block.y, block.z, block.text)
    if block.leader is not None:
        leader = e.lines.add(type=LinePrimitive.LINE_STRIP, thickness=entities.LEADER_PX,
                             scale_invariant=True)
        entities.set_pose(leader.pose, 0.0, 0.0, 0.0)
        for x, y, z in block.leader:
            leader.points.add(x=x, y=y, z=z)
        leader.color.CopyFrom(entities.color(entities.LEADER_COLOR))
    return e


@pytest.mark.parametrize("seed", range(3))
def test_labels_drawn_as_wire_bytes_are_the_messages_set_field_by_field(seed: int) -> None:
    rnd = random.Random(seed)
    for _ in range(200):
        lifetime_s = rnd.choice([0.0, 0.1, 0.3, 2.5])
        owner = wire.WireEntity("x", [], lifetime_s)
        leader = None
        if rnd.random() < 0.5:
            leader = ((_number(rnd), _number(rnd), _number(rnd)),
                      (_number(rnd), _number(rnd), _number(rnd)))
        text = rnd.choice(["", "car", "TrackID: 3\nx: 41.00\ny: -0.20", "Lead · 40 m",
                           "x" * 200])
        block = Block(owner, _number(rnd), _number(rnd), _number(rnd), text, (), leader)
        t_ns = rnd.randrange(2**62)
        drawn: list[wire.WireEntity] = []
        entities.draw_labels(drawn, [block], t_ns)
        got = wire.scene_update(drawn).entities[0]
        assert got.SerializeToString() == _by_fields(block, t_ns, lifetime_s).SerializeToString()


def test_a_scene_update_of_wire_entities_keeps_their_order_and_bytes() -> None:
    made = [SceneEntity(id=f"e{i}", frame_id=VEHICLE_FRAME, metadata=[{"key": "k",
                                                                          "value": "v" * i}])
            for i in range(0, 300, 37)]
    as_wire = [wire.WireEntity(e.id, [e.SerializeToString()]) for e in made]
    assert wire.scene_update(as_wire).SerializeToString() == \
        SceneUpdate(entities=made).SerializeToString()
    assert wire.scene_update([]).SerializeToString() == b""


@pytest.mark.parametrize("x, y", [(40.0, 0.2), (0.0, -0.0), (-3.5, 1e300), (123.456, -7.25)])
def test_the_lead_box_as_wire_bytes_is_the_message_set_field_by_field(x: float,
                                                                        y: float) -> None:
    lead = ObjectObservation("tracks", 7, 10**9, x, y, True, 1.0, None, None, ObjectClass.CAR)
    into: list[wire.WireEntity] = []
    (label,) = entities.lead_entities(into, lead, 5 * 10**9 + 7, 0.3, None, ("radar: car",))
    e = SceneEntity()
    e.MergeFrom(entities._lead_template(0.3))
    e.timestamp.CopyFrom(timestamp(5 * 10**9 + 7))
    position = e.cubes[0].pose.position
    position.x, position.y = x + entities.LEAD_BOX[0] / 2, y
    e.metadata.add(key="label", value=label.text)
    assert wire.scene_update(into).entities[0].SerializeToString() == e.SerializeToString()
    assert label.text.endswith("\nradar: car")


def test_frame_transforms_are_the_messages_set_field_by_field() -> None:
    profile = load_stages([], "ecocar").profile
    assert profile is not None
    t_ns = 1_800_000_000 * 10**9 + 123
    expected = FrameTransforms()
    for sensor in profile.sensors.values():
        yaw = math.radians(sensor.mount.yaw_deg)
        expected.transforms.append(FrameTransform(
            timestamp=timestamp(t_ns), parent_frame_id=VEHICLE_FRAME,
            child_frame_id=sensor.name,
            translation=Vector3(x=sensor.mount.x, y=sensor.mount.y, z=sensor.mount.z),
            rotation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))))
    assert len(expected.transforms) > 1
    for _ in range(2):  # built, then from the profile's cached bytes
        got = entities.frame_transforms(profile, t_ns)
        assert got.SerializeToString() == expected.SerializeToString()


def test_a_cube_of_the_lead_is_where_the_lead_is() -> None:
    lead = ObjectObservation("tracks", 7, 0, 30.0, -1.0, True)
    into: list[wire.WireEntity] = []
    entities.lead_entities(into, lead, 0, 0.3)
    (cube,) = wire.scene_update(into).entities[0].cubes
    assert isinstance(cube, CubePrimitive)
    assert (cube.pose.position.x, cube.pose.position.y, cube.pose.position.z) == (
        30.0 + entities.LEAD_BOX[0] / 2, -1.0, entities.LEAD_BOX[2] / 2)


def _lane_by_fields(line: LaneCurve, rgba: entities.RGBA, source: str,
                    t_ns: int) -> SceneEntity:
    """A lane line's entity set field by field, its points added one by one."""
    e = entities.entity(t_ns, f"lane-{line.name}", 0.0)
    drawn = e.lines.add(type=LinePrimitive.LINE_STRIP, thickness=entities.LANE_THICKNESS,
                        scale_invariant=False)
    entities.set_pose(drawn.pose, 0.0, 0.0, 0.0)
    for x, y in line.points:
        drawn.points.add(x=x, y=y, z=entities.LANE_Z)
    drawn.color.CopyFrom(entities.color(rgba))
    e.metadata.add(key="source", value=source)
    return e


def test_lane_lines_as_wire_bytes_are_the_messages_set_field_by_field() -> None:
    t_ns = 3 * 10**9 + 1
    for source, curvature in (("camera", 0.0), ("camera", 0.004), ("steering", -0.02)):
        lines = tuple(steering_curve(name, offset, curvature, 60.0) for name, offset in (
            ("left", 1.8), ("right", -1.8), ("next_left", 5.4)))
        model = LaneModel(source, lines, 0.0)
        colors = ([entities.STEERING_LANE_COLOR] * 3 if source == "steering" else
                  [entities.CAMERA_LANE_COLOR] * 2 + [entities.NEIGHBOUR_LANE_COLOR])
        expected = SceneUpdate(entities=[_lane_by_fields(line, rgba, source, t_ns)
                                         for line, rgba in zip(lines, colors, strict=True)])
        for _ in range(2):  # made, then held
            drawn: list[wire.WireEntity] = []
            entities.lane_entities(drawn, model, t_ns)
            assert [e.id for e in drawn] == ["lane-left", "lane-right", "lane-next_left"]
            assert wire.scene_update(drawn).SerializeToString() == \
                expected.SerializeToString()
