"""Lane lines are drawn with few points, within LANE_TOLERANCE_M of their cubic, and made once.

A cubic over 100 m is smooth: its polyline needs points only where it bends. The drawn line of
every lane (camera or steering) stays within ``LANE_TOLERANCE_M`` (1 cm) of the exact curve from
x = 0 to length - 1 m, with points closer together where the line bends more and two for a
straight one. A line whose coefficients (or steering angle) have not changed is the same
``LaneCurve`` tick after tick, and so is its drawn entity. The cars here are made up (the small
DBC and profiles of tests/test_profile_lanes.py, written in tmp_path), not ecocar.
"""

from __future__ import annotations

import math
from itertools import pairwise
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from test_profile_lanes import NO_CAMERA, WITH_CAMERA, car, load

from bridge.frame import NS
from bridge.profile.model import Mount, Sensor, SensorKind
from bridge.scene.entities import STEERING_LANE_COLOR, lane_entities
from bridge.scene.wire import WireEntity, line_points, scene_update
from bridge.world.model import (
    LANE_TOLERANCE_M,
    LaneCurve,
    LaneModel,
    World,
    camera_curve,
    polynomial,
    steering_curvature,
    steering_curve,
)
from bridge.world.observe import EgoObservation, LaneObservation

LENGTH = 100.0


def deviation(xs: list[float], ys: list[float], c: tuple[float, ...]) -> float:
    """The largest lateral distance between the polyline (xs, ys) and the cubic ``c``, on a
    1 cm grid over the polyline's x range."""
    worst = 0.0
    for (x0, y0), (x1, y1) in pairwise(zip(xs, ys, strict=True)):
        steps = max(1, math.ceil((x1 - x0) / 0.01))
        for i in range(steps + 1):
            x = x0 + (x1 - x0) * i / steps
            drawn = y0 + (y1 - y0) * (x - x0) / (x1 - x0)
            worst = max(worst, abs(drawn - polynomial(c, x)))
    return worst


ROADS = {  # coefficients, and how many points they need at most (100 before)
    "straight": ((1.8, 0.0, 0.0, 0.0), 2),
    "slanted": ((-1.7, 0.03, 0.0, 0.0), 2),
    "gentle bend": ((-1.8, 0.01, 0.0004, -1e-6), 15),  # radius 1250 m
    "tight bend": ((1.8, -0.02, -0.006, 2e-5), 35),  # radius 83 m, opening up
    "S-bend": ((0.0, 0.0, 0.002, -4e-5), 40),  # radius 250 m, then 50 m the other way
}


@pytest.mark.parametrize(("c", "most"), ROADS.values(), ids=ROADS.keys())
@pytest.mark.parametrize("lateral", ["left", "right"])
def test_a_camera_line_is_drawn_within_a_centimetre_of_its_cubic(
        c: tuple[float, float, float, float], most: int, lateral: str) -> None:
    sensor = Sensor("windscreen", SensorKind.CAMERA, Mount(x=2.1, y=0.2, z=1.4), lateral=lateral)

    line = camera_curve("left", sensor, c, LENGTH)

    # back in the sensor's frame: x = 0 … 99 m ahead of the camera, its lateral convention
    xs = [x - 2.1 for x, _ in line.points]
    ys = [(y - 0.2) * sensor.lateral_sign for _, y in line.points]
    assert xs[0] == 0.0 and xs[-1] == pytest.approx(LENGTH - 1)
    assert xs == sorted(xs)
    assert deviation(xs, ys, c) <= LANE_TOLERANCE_M
    assert len(line.points) <= most


def test_a_straight_line_is_two_points_and_a_bend_gets_more_where_it_bends() -> None:
    sensor = Sensor("cam", SensorKind.CAMERA)

    straight = camera_curve("left", sensor, ROADS["straight"][0], LENGTH)
    bend = camera_curve("left", sensor, (0.0, 0.0, 0.0, 2e-5), LENGTH)  # bends more far away

    assert straight.points == ((0.0, 1.8), (99.0, 1.8))
    gaps = [b[0] - a[0] for a, b in pairwise(bend.points)]
    assert gaps[0] > gaps[-1]
    assert len(bend.points) < 50  # half the 100 of old, even bending to a radius of 83 m


def test_a_yawed_camera_line_is_the_sensor_frame_polyline_turned() -> None:
    sensor = Sensor("cam", SensorKind.CAMERA, Mount(x=1.5, y=-0.3, yaw_deg=2.0))
    unturned = Sensor("cam", SensorKind.CAMERA, Mount())
    c = ROADS["tight bend"][0]

    turned = camera_curve("left", sensor, c, LENGTH)
    plain = camera_curve("left", unturned, c, LENGTH)

    cos, sin = math.cos(math.radians(2.0)), math.sin(math.radians(2.0))
    assert len(turned.points) == len(plain.points)
    for (x, y), (px, py) in zip(turned.points, plain.points, strict=True):
        assert (x, y) == pytest.approx((cos * px - sin * py + 1.5, sin * px + cos * py - 0.3))


@pytest.mark.parametrize("angle_deg", [0.0, 3.0, -20.0, 90.0])
def test_a_steering_line_is_drawn_within_a_centimetre_of_its_parabola(angle_deg: float) -> None:
    curvature = steering_curvature(math.radians(angle_deg), 2.7, 16.0)

    line = steering_curve("right", -1.75, curvature, LENGTH)

    xs, ys = [x for x, _ in line.points], [y for _, y in line.points]
    assert line.coefficients == (-1.75, 0.0, curvature / 2, 0.0)
    assert xs[0] == 0.0 and xs[-1] == LENGTH - 1
    assert deviation(xs, ys, line.coefficients) <= LANE_TOLERANCE_M
    assert len(line.points) <= (2 if angle_deg == 0 else 70)


def test_a_bend_tighter_than_the_tolerance_allows_is_drawn_every_metre_as_before() -> None:
    """A turn of radius < 12.5 m would need points closer than 1 m: it keeps the 1 m spacing."""
    curvature = steering_curvature(math.radians(-400.0), 2.7, 16.0)

    line = steering_curve("left", 1.75, curvature, LENGTH)

    assert [x for x, _ in line.points] == [float(x) for x in range(100)]
    assert line.points[50][1] == pytest.approx(polynomial(line.coefficients, 50.0))


def camera_world(tmp_path: Path) -> World:
    dbc, path, _ = car(tmp_path, WITH_CAMERA)
    return World(load(dbc, path))


def see(world: World, t_ns: int, left: tuple[float, float, float, float],
        right: tuple[float, float, float, float] = (-1.75, 0.0, 0.0, 0.0)) -> None:
    world.apply(LaneObservation("left", t_ns, left, True))
    world.apply(LaneObservation("right", t_ns, right, True))


def test_unchanged_camera_coefficients_reuse_the_line_and_a_change_makes_a_new_one(
        tmp_path: Path) -> None:
    world = camera_world(tmp_path)
    see(world, 0, (1.75, 0.0, 0.001, 0.0))
    first = world.lane_model(0)
    see(world, NS // 10, (1.75, 0.0, 0.001, 0.0))  # a new frame, the same line
    again = world.lane_model(NS // 5)
    see(world, NS // 5, (1.5, 0.0, 0.001, 0.0))  # the left line moved
    moved = world.lane_model(NS // 5)

    assert first.source == again.source == moved.source == "camera"
    assert again.lines[0] is first.lines[0] and again.lines[1] is first.lines[1]
    assert moved.lines[0] is not first.lines[0] and moved.lines[1] is first.lines[1]
    assert moved.lines[0].points[0][1] == pytest.approx(1.5)
    assert moved.lines[0].coefficients[0] == pytest.approx(1.5 + 0.001 * 1.9**2)  # at x = 0


def steering_world(tmp_path: Path, angle_rad: float) -> World:
    dbc, path, _ = car(tmp_path, NO_CAMERA)
    world = World(load(dbc, path))
    world.apply(EgoObservation(0, speed=15.0, steering_wheel_angle=angle_rad))
    return world


def test_steering_lines_follow_the_steering_angle_and_are_reused_while_it_holds(
        tmp_path: Path) -> None:
    world = steering_world(tmp_path, 0.5)
    first = world.lane_model(0)
    again = world.lane_model(NS // 50)
    world.apply(EgoObservation(NS // 25, steering_wheel_angle=-0.5))
    turned = world.lane_model(NS // 25)

    assert first.source == turned.source == "steering"
    assert again.lines == first.lines and again.lines[0] is first.lines[0]
    (left, _), (new_left, new_right) = first.lines, turned.lines
    assert new_left is not left
    curvature = steering_curvature(-0.5, 2.7, 16.0)
    assert new_left.coefficients == (1.75, 0.0, curvature / 2, 0.0)
    assert left.points[-1][1] > 1.75 > new_left.points[-1][1]  # left, then right
    xs, ys = [x for x, _ in new_right.points], [y for _, y in new_right.points]
    assert deviation(xs, ys, new_right.coefficients) <= LANE_TOLERANCE_M


def test_a_steering_only_car_draws_magenta_lines_of_the_curve_points(tmp_path: Path) -> None:
    world = steering_world(tmp_path, 0.3)
    model = world.lane_model(0)
    drawn_lines: list[WireEntity] = []

    lane_entities(drawn_lines, model, 7 * NS)

    update = scene_update(drawn_lines)

    assert [e.id for e in update.entities] == ["lane-left", "lane-right"]
    for e, line in zip(update.entities, model.lines, strict=True):
        (drawn,) = e.lines
        c = drawn.color
        assert (c.r, c.g, c.b, c.a) == STEERING_LANE_COLOR
        assert [(p.x, p.y) for p in drawn.points] == list(line.points)
        assert {p.z for p in drawn.points} == {0.05}
        assert drawn.thickness == 0.15
        assert e.timestamp.seconds == 7 and e.metadata[0].value == "steering"


def test_an_unchanged_line_keeps_its_drawn_entity_and_a_new_line_gets_its_own() -> None:
    sensor = Sensor("cam", SensorKind.CAMERA)
    line = camera_curve("left", sensor, ROADS["gentle bend"][0], LENGTH)
    moved = camera_curve("left", sensor, ROADS["tight bend"][0], LENGTH)

    def drawn(lines: tuple[LaneCurve, ...], source: str) -> bytes:
        """The bytes of the first line's entity, all but its timestamp."""
        into: list[WireEntity] = []
        lane_entities(into, LaneModel(source, lines, 0.0), 0)
        return into[0].parts[0]

    first = drawn((line,), "camera")

    assert drawn((line,), "camera") is first
    assert drawn((moved,), "camera") is not first
    assert drawn((line,), "steering") is not first
    (entity,) = scene_update([WireEntity("lane-left", [first])]).entities
    assert [(p.x, p.y) for p in entity.lines[0].points] == list(line.points)
    assert isinstance(line, LaneCurve)


@pytest.mark.parametrize("points", [
    [(0.0, 0.0), (1.0, -0.0)],
    [(2.1, -1.75), (45.5, 3.25e-7), (99.0, -1234.5678)],
    [(x * 0.7, math.sin(x) * 1e3) for x in range(40)],
])
def test_points_written_as_bytes_are_the_points_added_one_by_one(
        points: list[tuple[float, float]]) -> None:
    by_bytes, one_by_one = LinePrimitive(), LinePrimitive()

    by_bytes.MergeFromString(line_points(points, 0.05))
    for x, y in points:
        one_by_one.points.add(x=x, y=y, z=0.05)

    assert by_bytes == one_by_one
    assert by_bytes.SerializeToString() == one_by_one.SerializeToString()
    assert [(p.x, p.y, p.z) for p in by_bytes.points] == [(x, y, 0.05) for x, y in points]
