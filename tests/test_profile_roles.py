"""The role of an object group: ``role = "detections" | "tracks"`` on ``[objects.GROUP]``.

A radar's track slots (stable ids while an object is tracked) are tracks, though the radar is no
fusion sensor: one physical radar serves a detections group and a tracks group. Without ``role``
a group's role follows its sensor's kind (fusion: tracks, else detections).

The car here is radar-only and looks nothing like ecocar: a small DBC and profile written to
tmp_path, frames encoded with cantools and fed through perception as the converter does.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cantools
import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bridge.pipeline.perception import Perception
from bridge.profile.loader import load_profile
from bridge.profile.model import Profile, ProfileError
from bridge.scene.entities import RADAR_COLOR, TRACK_COLOR
from bridge.topics import LEAD_TOPIC, scene_topic

T0 = 1_767_268_800_000_000_000
MS = 1_000_000

DBC = """VERSION ""

BU_: RADAR

BO_ 1280 RDR_POINT_0: 8 RADAR
 SG_ PT_LONG : 0|16@1+ (0.01,0) [0|600] "m" Vector__XXX
 SG_ PT_LAT : 16|16@1- (0.01,0) [-300|300] "m" Vector__XXX
 SG_ PT_OK : 32|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 1281 RDR_POINT_1: 8 RADAR
 SG_ PT_LONG : 0|16@1+ (0.01,0) [0|600] "m" Vector__XXX
 SG_ PT_LAT : 16|16@1- (0.01,0) [-300|300] "m" Vector__XXX
 SG_ PT_OK : 32|1@1+ (1,0) [0|1] "" Vector__XXX

BO_ 1296 RDR_SLOT_0: 8 RADAR
 SG_ SLOT_ID : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ SLOT_LONG : 8|16@1+ (0.01,0) [0|600] "m" Vector__XXX
 SG_ SLOT_LAT : 24|16@1- (0.01,0) [-300|300] "m" Vector__XXX
 SG_ SLOT_STATE : 40|2@1+ (1,0) [0|3] "" Vector__XXX

BO_ 1297 RDR_SLOT_1: 8 RADAR
 SG_ SLOT_ID : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ SLOT_LONG : 8|16@1+ (0.01,0) [0|600] "m" Vector__XXX
 SG_ SLOT_LAT : 24|16@1- (0.01,0) [-300|300] "m" Vector__XXX
 SG_ SLOT_STATE : 40|2@1+ (1,0) [0|3] "" Vector__XXX

BO_ 1536 STEER: 8 RADAR
 SG_ WHEEL_ANGLE : 0|16@1- (0.1,0) [-800|800] "deg" Vector__XXX

BO_ 1537 LANE_LEFT: 8 RADAR
 SG_ OFFSET : 0|16@1- (0.01,0) [-300|300] "m" Vector__XXX

BO_ 1538 LANE_RIGHT: 8 RADAR
 SG_ OFFSET : 0|16@1- (0.01,0) [-300|300] "m" Vector__XXX
"""

PROFILE = """
[sensors.front]
kind = "radar"
mount = { x = 3.0 }
lateral = "right"

[objects.points]                    # raw detections: role from the sensor kind (detections)
sensor = "front"
messages = ["RDR_POINT_{i}"]
index = [0, 1]
x = "PT_LONG"
y = "PT_LAT"
valid = "PT_OK == 1"

[objects.slots]                     # the same radar's track slots
sensor = "front"
role = "tracks"
messages = ["RDR_SLOT_{i}"]
index = [0, 1]
id = "SLOT_ID"
x = "SLOT_LONG"
y = "SLOT_LAT"
valid = "SLOT_STATE == 2"
lifetime = 0.3

[lead]
source = "tracks"

[lanes]                             # never sent: the steering fallback draws the ego lane
sensor = "front"
left = { message = "LANE_LEFT", c0 = "OFFSET" }
right = { message = "LANE_RIGHT", c0 = "OFFSET" }

[ego]
steering_wheel_angle = { signal = "STEER.WHEEL_ANGLE", scale = 0.01745329 }
"""


@pytest.fixture
def db(tmp_path: Path) -> cantools.database.can.Database:
    path = tmp_path / "radar.dbc"
    path.write_text(DBC)
    return cantools.database.load_file(path)


def load(tmp_path: Path, db: cantools.database.can.Database, text: str = PROFILE) -> Profile:
    path = tmp_path / "car.toml"
    path.write_text(text)
    return load_profile(path, [db])


def drive(db: cantools.database.can.Database, profile: Profile,
          frames: list[tuple[str, dict[str, float]]]) -> dict[str, Any]:
    """Feed the frames 10 ms apart, as convert does; what perception says 50 ms after."""
    perception = Perception(profile, scene_rate=20.0)
    perception.advance(T0)
    t = T0
    for name, values in frames:
        t += 10 * MS
        perception.advance(t)
        m = db.get_message_by_name(name)
        signals: dict[str, float] = {s.name: 0 for s in m.signals}
        signals.update(values)
        perception.feed(name, m.decode(m.encode(signals), decode_choices=False), t)
    outputs = perception.advance(t + 50 * MS)
    return {o.topic: o.message for o in outputs}


def rgba(sphere: Any) -> tuple[float, ...]:
    c = sphere.color
    return tuple(round(v, 2) for v in (c.r, c.g, c.b, c.a))


def test_role_defaults_to_the_sensor_kind_and_can_be_set(
        tmp_path: Path, db: cantools.database.can.Database) -> None:
    profile = load(tmp_path, db)
    assert profile.groups["points"].role == "detections"
    assert profile.groups["slots"].role == "tracks"
    assert profile.groups["slots"].is_tracks
    assert profile.groups["points"].sensor is profile.groups["slots"].sensor


def test_a_radars_track_slots_are_drawn_as_labelled_tracks_and_feed_the_lead(
        tmp_path: Path, db: cantools.database.can.Database) -> None:
    profile = load(tmp_path, db)
    out = drive(db, profile, [
        ("STEER", {"WHEEL_ANGLE": 0.0}),
        ("RDR_POINT_0", {"PT_LONG": 20.0, "PT_LAT": 0.5, "PT_OK": 1}),
        ("RDR_SLOT_0", {"SLOT_ID": 7, "SLOT_LONG": 40.0, "SLOT_LAT": -0.5, "SLOT_STATE": 2}),
        ("RDR_SLOT_1", {"SLOT_ID": 9, "SLOT_LONG": 25.0, "SLOT_LAT": 6.0, "SLOT_STATE": 2}),
    ])
    points: SceneUpdate = out[scene_topic("points")]
    slots: SceneUpdate = out[scene_topic("slots")]
    # the detection: a small blue radar sphere, unlabelled (no class)
    (point,) = points.entities
    assert rgba(point.spheres[0]) == RADAR_COLOR
    blocks = {e.id: [t.text for t in e.texts] for e in out[scene_topic("labels/range")].entities}
    assert point.id not in blocks
    # the track slots: red spheres labelled with their TrackID and position (lateral = right,
    # mount x = 3); slot 7 is the lead, labelled once, on the lead box
    by_id = {e.id: e for e in slots.entities}
    assert set(by_id) == {"slots-7", "slots-9"}
    for e in by_id.values():
        assert rgba(e.spheres[0]) == TRACK_COLOR
        assert e.spheres[0].size.x > point.spheres[0].size.x
    assert blocks["slots-9"] == ["TrackID: 9\nx: 28.00\ny: -6.00"]
    assert "slots-7" not in blocks
    lead = out[LEAD_TOPIC]
    assert lead.present and lead.mio_ok
    assert (lead.object.id, round(lead.object.x, 2), round(lead.object.y, 2)) == (7, 43.0, 0.5)


def test_without_role_a_radar_group_is_detections_and_feeds_no_lead(
        tmp_path: Path, db: cantools.database.can.Database) -> None:
    text = PROFILE.replace('role = "tracks"\n', "")
    with pytest.raises(ProfileError) as info:  # a lead from tracks, and no group of tracks
        load(tmp_path, db, text)
    assert str(info.value) == (
        f"{tmp_path / 'car.toml'}: lead.source: 'tracks' but no object group has role = "
        '"tracks" (a fusion sensor\'s groups, or role = "tracks" on a group): there would '
        "never be a lead")
    profile = load(tmp_path, db, text.replace('[lead]\nsource = "tracks"\n', ""))
    assert profile.groups["slots"].role == "detections"
    out = drive(db, profile, [
        ("STEER", {"WHEEL_ANGLE": 0.0}),
        ("RDR_SLOT_0", {"SLOT_ID": 7, "SLOT_LONG": 40.0, "SLOT_LAT": -0.5, "SLOT_STATE": 2}),
    ])
    (slot,) = out[scene_topic("slots")].entities
    assert rgba(slot.spheres[0]) == RADAR_COLOR
    assert out[scene_topic("labels/range")].entities == []
    assert LEAD_TOPIC not in out


def test_a_fusion_group_can_be_declared_detections(
        tmp_path: Path, db: cantools.database.can.Database) -> None:
    text = PROFILE.replace('kind = "radar"', 'kind = "fusion"').replace(
        'sensor = "front"\nmessages = ["RDR_POINT_{i}"]',
        'sensor = "front"\nrole = "detections"\nmessages = ["RDR_POINT_{i}"]')
    profile = load(tmp_path, db, text)
    assert profile.groups["points"].role == "detections"
    assert profile.groups["slots"].role == "tracks"


def test_a_bad_role_is_one_line_with_the_allowed_values(
        tmp_path: Path, db: cantools.database.can.Database) -> None:
    with pytest.raises(ProfileError) as info:
        load(tmp_path, db, PROFILE.replace('role = "tracks"', 'role = "track"'))
    assert str(info.value) == (f"{tmp_path / 'car.toml'}: objects.slots.role: must be one of "
                               "detections, tracks, got 'track'; closest: tracks")
    assert "\n" not in str(info.value)
