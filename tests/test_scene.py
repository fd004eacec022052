"""The scene: hand-made frame sequences to exact SceneUpdates (goldens), and its properties.

Goldens live in tests/golden/*.json (SceneUpdate as protobuf JSON). After a deliberate change of
the look, regenerate them with  TANKVIZ_REGENERATE_GOLDENS=1 python -m pytest tests/test_scene.py
and review the diff before committing it.
"""

from __future__ import annotations

import itertools
import json
import math
from typing import Any

import cantools
import pytest
from conftest import ECOCAR_DBC, GOLDEN, check_golden
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import json_format
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.pipeline.perception import Perception
from bridge.profile.loader import load_profile
from bridge.profile.model import Mount, Profile, Sensor, SensorKind
from bridge.topics import TopicMessage
from bridge.world.observe import polar_to_cartesian, to_vehicle

T0 = 1_767_268_800_000_000_000
MS = 1_000_000


@pytest.fixture(scope="module")
def db() -> cantools.database.can.Database:
    return cantools.database.load_file(ECOCAR_DBC)


@pytest.fixture(scope="module")
def profile(db: cantools.database.can.Database) -> Profile:
    return load_profile("ecocar", [db])


class Drive:
    """Feeds encoded-then-decoded ecocar messages through Perception, like convert does."""

    def __init__(self, db: cantools.database.can.Database, profile: Profile,
                 rate: float = 20.0) -> None:
        self.db = db
        self.perception = Perception(profile, scene_rate=rate)
        self.outputs: list[TopicMessage] = []
        self.perception.advance(T0)  # the drive starts at T0: first scene at T0 + 50 ms

    def send(self, t_ms: float, name: str, **values: float) -> None:
        t = T0 + round(t_ms * MS)
        self.outputs += self.perception.advance(t)
        message = self.db.get_message_by_name(name)
        signals: dict[str, Any] = {s.name: 0 for s in message.signals}
        signals.update(values)
        data = message.encode(signals, strict=False)
        self.perception.feed(name, message.decode(data, decode_choices=False), t)

    def scene(self, category: str) -> list[SceneUpdate]:
        return [o.message for o in self.outputs if o.topic == f"/scene/{category}"]

    def topic(self, topic: str) -> list[Any]:
        return [o.message for o in self.outputs if o.topic == topic]

    def labels(self, view: str = "range") -> dict[str, list[str]]:
        """The texts of one view's labels at the latest scene, by the entity each names."""
        update = self.scene(f"labels/{view}")[-1]
        return {e.id: [t.text for t in e.texts] for e in update.entities}


def lanes(drive: Drive, t_ms: float, *, valid: bool = True) -> None:
    for name, c0 in (("CamLaneLeft", -1.8), ("CamLaneRight", 1.8)):  # camera: y positive right
        drive.send(t_ms, name, C0_Offset=c0, C2_Curvature=0.0005, Source=1 if valid else 0,
                   Quality=3 if valid else 0)


def street(drive: Drive) -> None:
    """Ego at 90 km/h on a gentle left curve; a pedestrian, a car, two tracks; the lead wrong."""
    drive.send(0, "EgoMotion", VehicleSpeed=90.0, YawRate=2.0)
    drive.send(1, "Steering", SteeringWheelAngle=30.0)
    lanes(drive, 2)
    drive.send(3, "RadarObj0_B", Class=3)
    drive.send(4, "RadarObj0_A", LongDist=12.5, LatDist=-4.0, ProbExist=93.75, Valid=1)
    drive.send(5, "RadarObj1_A", LongDist=60.0, LatDist=0.5, ProbExist=25.0, Valid=1)
    drive.send(6, "CamObstacle0_A", ObstacleID=4, PosX=30.0, PosY=-0.5, Type=0, Valid=1)
    drive.send(7, "FusionTrack0", TrackID=7, PosX=30.0, PosY=0.5, Class=1, Status=2)
    drive.send(8, "FusionTrack1", TrackID=9, PosX=20.0, PosY=0.25, Class=1, Status=2)
    drive.send(9, "LeadVehicle", Valid=1, TrackID=7, PosX=30.0, PosY=0.5)
    drive.send(50, "EgoMotion", VehicleSpeed=90.0, YawRate=2.0)  # time passes: the scene is due


def check_scene_golden(name: str, message: SceneUpdate) -> None:
    got = json.loads(json_format.MessageToJson(message))
    check_golden(GOLDEN / f"{name}.json", json.dumps(got, indent=1, sort_keys=True) + "\n", name)


@pytest.mark.parametrize("category", ["ego", "lanes", "radar", "camera", "tracks", "lead", "mio",
                                      "labels/chase", "labels/range"])
def test_the_street_scene_matches_its_golden(db: cantools.database.can.Database,
                                             profile: Profile, category: str) -> None:
    drive = Drive(db, profile)
    street(drive)
    (update,) = drive.scene(category)
    check_scene_golden(f"street_{category.replace('/', '-')}", update)


def test_the_street_scene_in_words(db: cantools.database.can.Database, profile: Profile) -> None:
    """What the goldens pin down, spelled out."""
    drive = Drive(db, profile)
    street(drive)
    (ego,) = drive.scene("ego")
    cube = ego.entities[0].cubes[0]
    assert (cube.size.x, cube.size.y, cube.size.z) == (2.5, 1.5, 1.0)
    assert cube.color.r > cube.color.g > cube.color.b  # orange-brown

    (radar,) = drive.scene("radar")
    assert [e.id for e in radar.entities] == ["radar-0"]  # the 25 % detection is not valid
    pedestrian = radar.entities[0]
    assert pedestrian.spheres[0].color.b == 1.0  # blue sphere
    assert (pedestrian.spheres[0].pose.position.x, pedestrian.spheres[0].pose.position.y) == (
        12.5, -4.0)
    assert pedestrian.cylinders[0].size.z == 1.8  # and a tall yellow cylinder
    assert not pedestrian.texts  # its label is each view's
    assert pedestrian.lifetime.nanos == 100 * MS

    (camera,) = drive.scene("camera")
    position = camera.entities[0].spheres[0].pose.position
    assert (position.x, position.y) == (30.0, 0.5)  # the camera's y points right: flipped
    assert camera.entities[0].spheres[0].color.r == 1.0 == camera.entities[0].spheres[0].color.b

    # One block per place: track 7 stands where the (wrong) lead is, track 9 is where the MIO
    # check points: each track's label is a line of that block.
    (tracks,) = drive.scene("tracks")
    assert [e.id for e in tracks.entities] == ["tracks-7", "tracks-9"]
    assert tracks.entities[0].lifetime.nanos == 300 * MS

    # Each view's labels: an entity per block, with the id and lifetime of what it names; the
    # MIO check's reason in lines a laptop's panel holds, first; in the chase view's smaller
    # panel the lead's label is compact beside it.
    mio_words = ("MIO CHECK: lead #7 at 30.0 m is not the\nclosest in-lane track #9 at 20.0 m\n"
                 "TrackID: 9 · 20 m")
    assert drive.labels("range") == {
        "mio-check": [mio_words], "lead": ["Lead Vehicle\nx: 30.00\ny: 0.50\nTrackID: 7 · 30 m"],
        "radar-0": ["PEDESTRIAN"]}
    assert drive.labels("chase") == {
        "mio-check": [mio_words], "lead": ["Lead · 30 m"], "radar-0": ["PEDESTRIAN"]}
    for view in ("chase", "range"):
        (labels,) = drive.scene(f"labels/{view}")
        lifetimes = {e.id: e.lifetime.ToNanoseconds() for e in labels.entities}
        assert lifetimes["radar-0"] == pedestrian.lifetime.ToNanoseconds()

    (lane_update,) = drive.scene("lanes")
    left = lane_update.entities[0].lines[0]
    assert lane_update.entities[0].id == "lane-left"
    assert left.color.g > 0.8 and left.color.r == 0  # green
    assert left.points[0].x == 0 and left.points[-1].x == 99  # 0…99 m, in few points
    assert len(left.points) < 20
    assert left.points[0].y == pytest.approx(1.8)  # camera right-positive -1.8 is left +1.8
    assert left.points[-1].y == pytest.approx(1.8 - 0.0005 * 99**2)


def test_the_lead_track_is_labelled_once_on_the_lead_box(
        db: cantools.database.can.Database, profile: Profile) -> None:
    """Two labels at one place are unreadable: the lead's track gives its id to the lead label."""
    drive = Drive(db, profile)
    drive.send(0, "EgoMotion", VehicleSpeed=90.0)
    lanes(drive, 1)
    drive.send(2, "FusionTrack0", TrackID=7, PosX=30.0, PosY=0.5, Class=1, Status=2)
    drive.send(3, "FusionTrack1", TrackID=9, PosX=60.0, PosY=5.0, Class=1, Status=2)
    drive.send(4, "LeadVehicle", Valid=1, TrackID=7, PosX=30.5, PosY=0.5)
    drive.send(50, "EgoMotion", VehicleSpeed=90.0)

    (mio,) = drive.scene("mio")
    assert mio.entities == []  # the lead is the closest in-lane track
    (tracks,) = drive.scene("tracks")
    assert [(e.id, len(e.spheres)) for e in tracks.entities] == [("tracks-7", 1), ("tracks-9", 1)]
    assert drive.labels() == {"tracks-9": ["TrackID: 9\nx: 60.00\ny: 5.00\ncar"],
                              "lead": ["Lead Vehicle · TrackID: 7\nx: 30.50\ny: 0.50\ncar"]}


def test_every_visible_field_is_set(db: cantools.database.can.Database, profile: Profile) -> None:
    """Foxglove draws protobuf defaults as nothing: alpha, sizes, font, thickness must be set."""
    drive = Drive(db, profile)
    street(drive)
    for output in drive.outputs:
        if not output.topic.startswith("/scene/"):
            continue
        for e in output.message.entities:
            assert e.frame_id == "vehicle" and e.frame_locked
            for primitive in [*e.cubes, *e.spheres, *e.cylinders, *e.lines]:
                assert primitive.color.a > 0
                assert primitive.pose.orientation.w == 1.0
            for p in [*e.cubes, *e.spheres, *e.cylinders]:
                assert min(p.size.x, p.size.y, p.size.z) > 0
            for c in e.cylinders:
                assert c.bottom_scale == 1.0 == c.top_scale
            for t in e.texts:
                assert t.font_size > 0 and t.color.a > 0 and t.billboard and t.text
            for line in e.lines:
                assert line.thickness > 0


def test_objects_expire_after_their_lifetime_and_are_deleted(
        db: cantools.database.can.Database, profile: Profile) -> None:
    drive = Drive(db, profile)
    drive.send(0, "RadarObj0_A", LongDist=12.5, LatDist=-4.0, ProbExist=90, Valid=1)
    drive.send(0, "FusionTrack0", TrackID=7, PosX=30.0, PosY=0.5, Status=2)
    for t in range(10, 500, 10):  # ego keeps the clock going; nothing else is heard of again
        drive.send(t, "EgoMotion", VehicleSpeed=50)
    radar = drive.scene("radar")
    tracks = drive.scene("tracks")
    # scenes at 50, 100, ...: radar lives 0.1 s, tracks 0.3 s
    assert [len(u.entities) for u in radar[:3]] == [1, 1, 0]
    assert [d.id for d in radar[2].deletions] == ["radar-0"]
    assert [len(u.entities) for u in tracks[:7]] == [1, 1, 1, 1, 1, 1, 0]
    assert [d.id for d in tracks[6].deletions] == ["tracks-7"]
    assert all(not u.deletions for u in radar[3:])  # deleted once


def test_an_invalid_observation_removes_the_object_at_once(
        db: cantools.database.can.Database, profile: Profile) -> None:
    drive = Drive(db, profile)
    drive.send(0, "RadarObj3_A", LongDist=40, ProbExist=90, Valid=1)
    drive.send(60, "RadarObj3_A", LongDist=40, ProbExist=90, Valid=0)
    drive.send(110, "EgoMotion")
    assert [[e.id for e in u.entities] for u in drive.scene("radar")] == [["radar-3"], []]


def test_camera_lanes_fall_back_to_steering_and_come_back(
        db: cantools.database.can.Database, profile: Profile) -> None:
    drive = Drive(db, profile)
    drive.send(0, "Steering", SteeringWheelAngle=-45.0)  # turning right
    lanes(drive, 0)
    lanes(drive, 60, valid=False)  # the camera says: no lanes
    lanes(drive, 110, valid=False)
    lanes(drive, 160)  # lanes again
    drive.send(210, "EgoMotion")
    sources = [u.entities[0].metadata[0].value for u in drive.scene("lanes")]
    assert sources == ["camera", "steering", "steering", "camera"]
    steering = drive.scene("lanes")[1]
    left, right = (e.lines[0] for e in steering.entities)
    assert (left.color.r, left.color.g, left.color.b) == (1.0, 0.0, 1.0)  # magenta
    assert left.points[0].y == pytest.approx(1.8) and right.points[0].y == pytest.approx(-1.8)
    curvature = math.tan(math.radians(-45.0) / 15.0) / 2.8
    far = left.points[-1]
    assert far.x == 99 and far.y == pytest.approx(1.8 + curvature / 2 * 99**2, abs=1e-3)
    assert far.y < 1.8  # bends right
    semantic = [m.source for m in drive.topic("/perception/lanes")]
    assert semantic == sources


def test_stale_camera_lanes_fall_back_too(db: cantools.database.can.Database,
                                         profile: Profile) -> None:
    drive = Drive(db, profile)
    drive.send(0, "Steering", SteeringWheelAngle=0.0)
    lanes(drive, 0)
    for t in range(10, 700, 10):
        drive.send(t, "EgoMotion")  # the camera goes silent
    sources = [m.source for m in drive.topic("/perception/lanes")]
    assert sources[:10] == ["camera"] * 10  # fresh for stale_after = 0.5 s
    assert set(sources[10:]) == {"steering"}


def test_the_mio_check_agrees_when_the_lead_is_the_closest_in_lane_track(
        db: cantools.database.can.Database, profile: Profile) -> None:
    drive = Drive(db, profile)
    lanes(drive, 0)
    drive.send(1, "FusionTrack0", TrackID=7, PosX=30.0, PosY=0.5, Status=2)
    drive.send(2, "FusionTrack1", TrackID=9, PosX=15.0, PosY=3.6, Status=2)  # left lane
    drive.send(3, "LeadVehicle", Valid=1, TrackID=7, PosX=30.0, PosY=0.5)
    drive.send(60, "EgoMotion")
    (lead,) = drive.topic("/perception/lead")
    assert lead.mio_ok and lead.object.id == 7 and lead.expected.id == 7
    assert drive.scene("mio")[0].entities == []


def test_the_mio_check_flags_a_missing_lead(db: cantools.database.can.Database,
                                           profile: Profile) -> None:
    drive = Drive(db, profile)
    lanes(drive, 0)
    drive.send(1, "FusionTrack0", TrackID=7, PosX=30.0, PosY=0.5, Status=2)
    drive.send(2, "LeadVehicle", Valid=0)
    drive.send(60, "EgoMotion")
    (lead,) = drive.topic("/perception/lead")
    assert not lead.present and not lead.mio_ok
    assert lead.mio_reason == "no lead vehicle reported, but track #7 is in the ego lane at 30.0 m"


def test_scene_rate_sets_the_number_of_scenes(db: cantools.database.can.Database,
                                             profile: Profile) -> None:
    drive = Drive(db, profile, rate=50.0)
    for t in range(0, 1001, 5):
        drive.send(t, "EgoMotion")
    assert len(drive.scene("ego")) == 50
    times = [o.t_ns for o in drive.outputs if o.topic == "/scene/ego"]
    assert {b - a for a, b in itertools.pairwise(times)} == {20 * MS}


def test_sensor_mounts_are_frame_transforms(db: cantools.database.can.Database,
                                           profile: Profile) -> None:
    drive = Drive(db, profile)
    drive.send(60, "EgoMotion")
    (tf,) = drive.topic("/tf")
    frames = {t.child_frame_id: t for t in tf.transforms}
    assert set(frames) == {"radar", "camera", "fusion"}
    assert {t.parent_frame_id for t in tf.transforms} == {"vehicle"}
    assert frames["camera"].translation.z == 1.3 and frames["camera"].rotation.w == 1.0


# --- properties -----------------------------------------------------------------------------

finite = st.floats(min_value=-500, max_value=500, allow_nan=False)


@given(x=finite, y=finite, mx=finite, my=finite, yaw=st.floats(-180, 180),
       lateral=st.sampled_from(["left", "right"]))
def test_mounting_is_a_rotation_then_a_translation(x: float, y: float, mx: float, my: float,
                                                   yaw: float, lateral: str) -> None:
    sensor = Sensor("s", SensorKind.RADAR, Mount(mx, my, 0.0, yaw), lateral)
    vx, vy = to_vehicle(sensor, x, y)
    # distance from the mount is kept, and a point on the sensor's axis lies along its yaw
    assert math.hypot(vx - mx, vy - my) == pytest.approx(math.hypot(x, y), abs=1e-6)
    ax, ay = to_vehicle(sensor, 10.0, 0.0)
    assert (ax - mx, ay - my) == pytest.approx(
        (10 * math.cos(math.radians(yaw)), 10 * math.sin(math.radians(yaw))), abs=1e-9)
    if yaw == 0 and lateral == "right":
        assert (vx, vy) == pytest.approx((x + mx, -y + my))


@given(r=st.floats(0, 300), az=st.floats(-90, 90))
def test_polar_to_cartesian_in_degrees_and_radians(r: float, az: float) -> None:
    x, y = polar_to_cartesian(r, az, "deg")
    assert math.hypot(x, y) == pytest.approx(r, abs=1e-9)
    assert (x, y) == pytest.approx(polar_to_cartesian(r, math.radians(az), "rad"), abs=1e-9)
    if r > 1e-3 and az > 1e-3:
        assert y > 0  # positive azimuth to the left, as positive y


signal_values = st.dictionaries(
    st.sampled_from(["LongDist", "LatDist", "ProbExist", "Valid", "LongSpeed"]),
    st.floats(min_value=-1e6, max_value=1e6, allow_nan=False), min_size=0, max_size=5)


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(frames=st.lists(st.tuples(st.integers(0, 31), signal_values, st.integers(0, 400)),
                       max_size=40))
def test_any_decoded_values_give_finite_unique_entities(
        db: cantools.database.can.Database, profile: Profile,
        frames: list[tuple[int, dict[str, float], int]]) -> None:
    """Whatever the radar says, entities are finite, unique at once, and expire."""
    perception = Perception(profile)
    perception.advance(T0)
    t = T0
    outputs: list[TopicMessage] = []
    for index, values, dt_ms in frames:
        t += dt_ms * MS
        outputs += perception.advance(t)
        perception.feed(f"RadarObj{index}_A", values, t)
    outputs += perception.advance(t + 10**9)  # a second later: everything expired
    radar = [o.message for o in outputs if o.topic == "/scene/radar"]
    for update in radar:
        ids = [e.id for e in update.entities]
        assert len(ids) == len(set(ids))
        for e in update.entities:
            p = e.spheres[0].pose.position
            assert math.isfinite(p.x) and math.isfinite(p.y)
    if radar:
        assert radar[-1].entities == []


# The messages of the property below: (name, signal -> strategy), plain values (no encoding).
_MESSAGES = [
    (f"RadarObj{i}_{part}", part) for i in range(3) for part in "AB"
] + [("FusionTrack1", "T"), ("CamLaneLeft", "L"), ("CamLaneRight", "L"), ("EgoMotion", "E"),
     ("Steering", "S")]
_VALUES = {
    "A": st.fixed_dictionaries({"LongDist": st.floats(0, 200), "LatDist": st.floats(-20, 20),
                                "ProbExist": st.sampled_from([50.0, 90.0]),
                                "Valid": st.integers(0, 1), "LongSpeed": st.floats(-30, 30)}),
    "B": st.fixed_dictionaries({"LatSpeed": st.floats(-5, 5), "Class": st.integers(0, 7)}),
    "T": st.fixed_dictionaries({"TrackID": st.just(7), "PosX": st.floats(0, 200),
                                "PosY": st.floats(-20, 20), "Status": st.integers(0, 2)}),
    "L": st.fixed_dictionaries({"C0_Offset": st.floats(-3, 3), "C2_Curvature": st.just(0.001),
                                "Source": st.integers(0, 1), "Quality": st.integers(0, 3)}),
    "E": st.fixed_dictionaries({"VehicleSpeed": st.floats(0, 150), "YawRate": st.floats(-5, 5)}),
    "S": st.fixed_dictionaries({"SteeringWheelAngle": st.floats(-90, 90)}),
}


@st.composite
def message_sequences(draw: st.DrawFn) -> list[tuple[int, str, dict[str, float]]]:
    out = []
    t = T0
    for _ in range(draw(st.integers(1, 60))):
        t += draw(st.integers(0, 30)) * MS
        name, kind = draw(st.sampled_from(_MESSAGES))
        out.append((t, name, draw(_VALUES[kind])))
    return out


@pytest.mark.slow
@settings(max_examples=80, deadline=None)
@given(sequence=message_sequences())
def test_observing_at_the_tick_gives_the_world_observing_each_message_gives(
        profile: Profile, sequence: list[tuple[int, str, dict[str, float]]]) -> None:
    """Perception notes messages and observes them at the tick, one observation per object;
    the world it ticks with is the one observing every message on arrival makes."""
    from bridge.world.model import World
    from bridge.world.observe import Observer

    perception = Perception(profile, scene_rate=50)
    perception.advance(T0)
    eager_observer, eager_world = Observer(profile), World(profile)
    worlds: list[tuple[World, World]] = []  # (lazy, eager) at every tick

    def snapshot(world: World) -> Any:
        return ({g: dict(objects) for g, objects in world.objects.items()}, dict(world.lanes),
                (world.ego.speed, world.ego.yaw_rate, world.ego.steering_wheel_angle))

    def tick(t: int) -> None:
        outputs = perception.advance(t)
        if outputs:  # the ticks (every one of a gap) expired old objects: so does the eager world
            eager_world.expire(outputs[-1].t_ns)
            worlds.append((snapshot(perception.world), snapshot(eager_world)))

    for t, name, values in sequence:
        tick(t)
        perception.feed(name, values, t)
        for observation in eager_observer.observe(name, values, t):
            eager_world.apply(observation)
    tick(sequence[-1][0] + 20 * MS)  # a last tick after the last message
    assert worlds
    for lazy, eager in worlds:
        assert lazy == eager
