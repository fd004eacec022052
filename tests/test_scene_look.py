"""The look of objects where they meet: a track and the detections it was fused from.

One object gets one label block (the seed's "TrackID: n / x: … / y: …", then its class), never two
texts stacked on the same spot; and a track's red marker never hides the blue radar or white
camera detection at its place: the detection stands out of the track's flat red disc.

Cars here are not ecocar: a small made-up DBC and profile written to tmp_path (a radar with its
detections and track slots, a camera, classes on their own raw values), and GM's object bus from
the public DBCs (tests/profiles/gm_object.toml); ecocar is checked to keep its format.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import cantools
import pytest
from conftest import ECOCAR_DBC
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bridge.pipeline.perception import Perception
from bridge.profile.loader import load_profile
from bridge.profile.model import Profile
from bridge.scene.entities import CAMERA_COLOR, RADAR_COLOR, TRACK_COLOR
from bridge.topics import scene_topic

T0 = 1_767_268_800_000_000_000
MS = 1_000_000
PROFILES = Path(__file__).resolve().parent / "profiles"

DBC = """VERSION ""

BU_: FRONT CAM

BO_ 1792 DET_0: 8 FRONT
 SG_ DET_X : 0|16@1+ (0.02,0) [0|1300] "m" Vector__XXX
 SG_ DET_Y : 16|16@1- (0.02,0) [-650|650] "m" Vector__XXX
 SG_ DET_KIND : 32|4@1+ (1,0) [0|15] "" Vector__XXX
 SG_ DET_OK : 36|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 1793 DET_1: 8 FRONT
 SG_ DET_X : 0|16@1+ (0.02,0) [0|1300] "m" Vector__XXX
 SG_ DET_Y : 16|16@1- (0.02,0) [-650|650] "m" Vector__XXX
 SG_ DET_KIND : 32|4@1+ (1,0) [0|15] "" Vector__XXX
 SG_ DET_OK : 36|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 1808 TRK_0: 8 FRONT
 SG_ TRK_NO : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ TRK_X : 8|16@1+ (0.02,0) [0|1300] "m" Vector__XXX
 SG_ TRK_Y : 24|16@1- (0.02,0) [-650|650] "m" Vector__XXX
 SG_ TRK_KIND : 40|4@1+ (1,0) [0|15] "" Vector__XXX
 SG_ TRK_OK : 44|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 1824 VIS_0: 8 CAM
 SG_ VIS_X : 0|16@1+ (0.02,0) [0|1300] "m" Vector__XXX
 SG_ VIS_Y : 16|16@1- (0.02,0) [-650|650] "m" Vector__XXX
 SG_ VIS_KIND : 32|4@1+ (1,0) [0|15] "" Vector__XXX
 SG_ VIS_OK : 36|1@1+ (1,0) [0|1] "" Vector__XXX
"""

# Raw class values unlike ecocar's; the radar serves detections and track slots.
PROFILE = """
[sensors.front]
kind = "radar"
mount = { x = 3.5, z = 0.6 }
lateral = "left"

[sensors.cam]
kind = "camera"
mount = { x = 1.5, z = 1.2 }
lateral = "left"

[objects.hits]
sensor = "front"
messages = ["DET_{i}"]
index = [0, 1]
x = "DET_X"
y = "DET_Y"
class = "DET_KIND"
classes = { 6 = "car", 9 = "pedestrian", 12 = "stationary" }
valid = "DET_OK == 1"

[objects.slots]
sensor = "front"
role = "tracks"
messages = ["TRK_{i}"]
index = [0, 0]
id = "TRK_NO"
x = "TRK_X"
y = "TRK_Y"
class = "TRK_KIND"
classes = { 6 = "car", 9 = "pedestrian", 12 = "stationary" }
valid = "TRK_OK == 1"
lifetime = 0.3

[objects.vision]
sensor = "cam"
messages = ["VIS_{i}"]
index = [0, 0]
x = "VIS_X"
y = "VIS_Y"
class = "VIS_KIND"
classes = { 6 = "car", 9 = "pedestrian" }
valid = "VIS_OK == 1"
"""

CAR, PEDESTRIAN = 6, 9


@pytest.fixture
def made_up(tmp_path: Path) -> tuple[cantools.database.can.Database, Profile]:
    (tmp_path / "front.dbc").write_text(DBC)
    db = cantools.database.load_file(tmp_path / "front.dbc")
    (tmp_path / "car.toml").write_text(PROFILE)
    return db, load_profile(tmp_path / "car.toml", [db])


def scene(db: cantools.database.can.Database, profile: Profile,
          frames: Iterable[tuple[str, dict[str, float]]]) -> dict[str, SceneUpdate]:
    """Feed the frames 5 ms apart, as convert does; the scene 50 ms after (topic -> update)."""
    perception = Perception(profile, scene_rate=20.0)
    perception.advance(T0)
    t = T0
    for name, values in frames:
        t += 5 * MS
        perception.advance(t)
        m = db.get_message_by_name(name)
        signals: dict[str, float] = {s.name: 0 for s in m.signals}
        signals.update(values)
        perception.feed(name, m.decode(m.encode(signals), decode_choices=False), t)
    out = {o.topic: o.message for o in perception.advance(t + 50 * MS)}
    return {topic: u for topic, u in out.items() if topic.startswith("/scene/")}


def entities(updates: dict[str, SceneUpdate]) -> Iterator[SceneEntity]:
    for u in updates.values():
        yield from u.entities


def labels(updates: dict[str, SceneUpdate], view: str = "range") -> dict[str, SceneEntity]:
    """One view's label blocks, by the id of the entity each names."""
    return {e.id: e for e in updates[scene_topic(f"labels/{view}")].entities}


def texts_at(updates: dict[str, SceneUpdate], x: float, y: float,
             within: float = 2.0, view: str = "range") -> list[str]:
    """Every label of one view anchored within ``within`` metres of (x, y)."""
    return [t.text for e in labels(updates, view).values() for t in e.texts
            if math.hypot(t.pose.position.x - x, t.pose.position.y - y) < within]


def rgba(primitive: Any) -> tuple[float, ...]:
    c = primitive.color
    return tuple(round(v, 2) for v in (c.r, c.g, c.b, c.a))


def inside(point: tuple[float, float, float], ellipsoid: Any) -> bool:
    """Whether a point lies inside a SpherePrimitive (an axis-aligned ellipsoid)."""
    centre, size = ellipsoid.pose.position, ellipsoid.size
    return ((point[0] - centre.x) / (size.x / 2)) ** 2 + (
        (point[1] - centre.y) / (size.y / 2)) ** 2 + (
        (point[2] - centre.z) / (size.z / 2)) ** 2 < 1.0


def check_detection_stands_out_of_its_track(detection: SceneEntity, track: SceneEntity) -> None:
    """The detection is drawn in the track's footprint (on screen, inside the track's region),
    and its top is outside every part of the track (seen from above, its colour shows)."""
    ball, marker = detection.spheres[0], track.spheres[0]
    position = ball.pose.position
    top = (position.x, position.y, position.z + ball.size.z / 2)
    assert not any(inside(top, part) for part in track.spheres), (ball, track.spheres)
    # the track's marker surrounds the detection in the ground plane
    assert marker.size.x > ball.size.x and marker.size.y > ball.size.y
    assert math.hypot(marker.pose.position.x - position.x,
                      marker.pose.position.y - position.y) < marker.size.x / 2


# --- one label block per object --------------------------------------------------------------


def test_a_track_and_the_detections_at_its_place_show_one_label_block(made_up: Any) -> None:
    db, profile = made_up
    updates = scene(db, profile, [
        ("TRK_0", {"TRK_NO": 42, "TRK_X": 21.5, "TRK_Y": -2.0, "TRK_KIND": CAR, "TRK_OK": 1}),
        ("DET_0", {"DET_X": 21.5, "DET_Y": -2.0, "DET_KIND": CAR, "DET_OK": 1}),
        ("VIS_0", {"VIS_X": 23.5, "VIS_Y": -2.0, "VIS_KIND": CAR, "VIS_OK": 1}),
    ])
    # every one is at x = 25 m, y = -2 m in the vehicle frame (mounts: radar 3.5, camera 1.5)
    for view in ("chase", "range"):
        assert texts_at(updates, 25.0, -2.0, view=view) == [
            "TrackID: 42\nx: 25.00\ny: -2.00\ncar"]
    (track,) = updates[scene_topic("slots")].entities
    assert list(labels(updates)) == [track.id]


def test_a_detection_of_another_class_is_named_in_the_tracks_block(made_up: Any) -> None:
    db, profile = made_up
    updates = scene(db, profile, [
        ("TRK_0", {"TRK_NO": 3, "TRK_X": 11.5, "TRK_Y": 1.0, "TRK_KIND": CAR, "TRK_OK": 1}),
        ("DET_0", {"DET_X": 11.0, "DET_Y": 1.5, "DET_KIND": PEDESTRIAN, "DET_OK": 1}),
    ])
    assert texts_at(updates, 15.0, 1.0) == [
        "TrackID: 3\nx: 15.00\ny: 1.00\ncar\nhits: PEDESTRIAN"]
    # the pedestrian still stands out: its tall cylinder is drawn
    (hit,) = updates[scene_topic("hits")].entities
    assert hit.cylinders and hit.id not in labels(updates)


def test_a_detection_away_from_every_track_keeps_its_class_label(made_up: Any) -> None:
    db, profile = made_up
    updates = scene(db, profile, [
        ("TRK_0", {"TRK_NO": 3, "TRK_X": 36.5, "TRK_Y": 4.0, "TRK_KIND": CAR, "TRK_OK": 1}),
        ("DET_0", {"DET_X": 11.5, "DET_Y": 1.0, "DET_KIND": CAR, "DET_OK": 1}),
        ("DET_1", {"DET_X": 36.5, "DET_Y": 8.0, "DET_KIND": 12, "DET_OK": 1}),
    ])
    assert texts_at(updates, 15.0, 1.0) == ["car"]
    assert texts_at(updates, 40.0, 4.0) == ["TrackID: 3\nx: 40.00\ny: 4.00\ncar"]
    # 4 m from the track, 40 m ahead: on screen its label would cover the track's block, so it
    # is moved aside, with a leader line from where it would have stood
    (far,) = [e for e in labels(updates).values() if e.lines]
    assert [t.text for t in far.texts] == ["stationary"]
    (leader,) = far.lines
    assert (leader.points[0].x, leader.points[0].y) == (40.0, 8.0)
    # it ends at the block's edge, on the way to the block: never across its text
    text_y = far.texts[0].pose.position.y
    assert min(8.0, text_y) < leader.points[1].y < max(8.0, text_y)


def test_gm_object_tracks_and_camera_objects_at_one_place(shared_dbc: Path) -> None:
    db = cantools.database.load_file(shared_dbc / "gm_global_a_object.dbc")
    profile = load_profile(PROFILES / "gm_object.toml", [db])
    # the long-range radar (mount x = 3.6) and the camera (x = 1.9) both see an object 23.6 m
    # ahead, 4 m to the left: range 20 m and 21.7 m (rounded to their signals' steps)
    azimuth_lrr = math.degrees(math.atan2(4.0, 20.0))
    updates = scene(db, profile, [
        ("LRRObject01", {"TrkObjectID": 12, "TrkRange": math.hypot(20.0, 4.0),
                         "TrkAzimuth": azimuth_lrr}),
        ("F_Vision_Obj_Track_1", {"FwdVsnRngTrk1Rev": math.hypot(21.7, 4.0),
                                  "FwdVsnAzmthTrk1Rev": math.degrees(math.atan2(4.0, 21.7))}),
    ])
    (track,) = updates[scene_topic("tracks")].entities
    (seen,) = updates[scene_topic("camera")].entities
    x, y = track.spheres[0].pose.position.x, track.spheres[0].pose.position.y
    assert math.hypot(seen.spheres[0].pose.position.x - x,
                      seen.spheres[0].pose.position.y - y) < 0.3
    (label,) = texts_at(updates, x, y)
    assert label.startswith("TrackID: 12\n") and f"x: {x:.2f}" in label
    assert f"y: {y:.2f}" in label
    assert rgba(seen.spheres[0]) == CAMERA_COLOR and rgba(track.spheres[0]) == TRACK_COLOR
    check_detection_stands_out_of_its_track(seen, track)


# --- the ecocar keeps its format ----------------------------------------------------------------


@pytest.fixture(scope="module")
def ecocar() -> tuple[cantools.database.can.Database, Profile]:
    db = cantools.database.load_file(ECOCAR_DBC)
    return db, load_profile("ecocar", [db])


def test_ecocar_track_with_its_radar_and_camera_detections(ecocar: Any) -> None:
    db, profile = ecocar
    updates = scene(db, profile, [
        ("EgoMotion", {"VehicleSpeed": 60.0}),
        ("FusionTrack0", {"TrackID": 31, "PosX": 45.0, "PosY": 6.0, "Class": 1, "Status": 2}),
        ("RadarObj0_B", {"Class": 1}),
        ("RadarObj0_A", {"LongDist": 45.0, "LatDist": 6.0, "ProbExist": 93.75, "Valid": 1}),
        ("CamObstacle0_A", {"ObstacleID": 2, "PosX": 45.0, "PosY": -6.0, "Type": 1, "Valid": 1}),
        ("RadarObj1_B", {"Class": 3}),
        ("RadarObj1_A", {"LongDist": 15.0, "LatDist": -5.0, "ProbExist": 93.75, "Valid": 1}),
    ])
    assert texts_at(updates, 45.0, 6.0) == ["TrackID: 31\nx: 45.00\ny: 6.00\ncar"]
    assert texts_at(updates, 15.0, -5.0) == ["PEDESTRIAN"]  # alone: it keeps its own label
    (track,) = updates[scene_topic("tracks")].entities
    radar = {e.id: e for e in updates[scene_topic("radar")].entities}
    (camera,) = updates[scene_topic("camera")].entities
    assert rgba(radar["radar-0"].spheres[0]) == RADAR_COLOR
    check_detection_stands_out_of_its_track(radar["radar-0"], track)
    check_detection_stands_out_of_its_track(camera, track)


def test_ecocar_lead_track_and_its_detection_show_the_lead_block_only(ecocar: Any) -> None:
    db, profile = ecocar
    updates = scene(db, profile, [
        ("EgoMotion", {"VehicleSpeed": 60.0}),
        ("CamLaneLeft", {"C0_Offset": -1.8, "Source": 1, "Quality": 3}),
        ("CamLaneRight", {"C0_Offset": 1.8, "Source": 1, "Quality": 3}),
        ("FusionTrack0", {"TrackID": 8, "PosX": 30.0, "PosY": 0.5, "Class": 1, "Status": 2}),
        ("RadarObj0_B", {"Class": 1}),
        ("RadarObj0_A", {"LongDist": 30.0, "LatDist": 0.5, "ProbExist": 93.75, "Valid": 1}),
        ("LeadVehicle", {"Valid": 1, "TrackID": 8, "PosX": 30.0, "PosY": 0.5}),
    ])
    assert texts_at(updates, 30.0, 0.5) == [
        "Lead Vehicle · TrackID: 8\nx: 30.00\ny: 0.50\ncar"]
