"""A Mazda front radar (opendbc's mazda_radar.dbc) with tests/profiles/mazda_radar.toml.

Six track slots, each its own message named after its CAN id (``RADAR_TRACK_361`` ..
``RADAR_TRACK_366``), a distance and an angle without unit or scale in the DBC: the profile
scales them (1/16 m, 1/64 deg, the angle positive to the right) and declares the slots
``role = "tracks"`` with ``index = [361, 366]``. A log written here with python-can (frames
encoded with cantools) is converted through the real pipeline; the drawn tracks are checked
against the positions the frames carry, with their labels, and healthy data raises no alarm.
The DBC is read where it is, in ../shared/data/dbc (conftest's ``shared_dbc``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
from conftest import T0, WriteLog, message
from foxglove_schemas_protobuf.Log_pb2 import Log
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.apps.inspect import summarize_file
from bridge.pipeline.convert import convert
from bridge.pipeline.drive import load_stages
from bridge.scene.entities import TRACK_COLOR
from bridge.sinks.mcap import METADATA_NAME
from bridge.topics import LOG_TOPIC, objects_topic, scene_topic

PROFILE = Path(__file__).resolve().parent / "profiles" / "mazda_radar.toml"
MOUNT_X = 3.6  # the radar's mount in the profile
EMPTY = {"DIST_OBJ": 4095, "ANG_OBJ": 2046, "RELV_OBJ": -16}  # raw values of an empty slot


def where(distance: float, angle_deg: float) -> tuple[float, float]:
    """Vehicle-frame x, y of a track at ``distance`` m and ``angle_deg`` to the RIGHT."""
    a = math.radians(angle_deg)
    return MOUNT_X + distance * math.cos(a), -distance * math.sin(a)


#: slot -> (distance m, angle deg to the right); slots 363..366 are empty
TRACKS = {361: (40.0, 5.0), 362: (70.0, -3.0)}


def cycle(db: cantools.database.can.Database, t: float) -> list[can.Message]:
    frames = []
    for slot in range(361, 367):
        if slot in TRACKS:
            distance, angle = TRACKS[slot]
            raw = {"DIST_OBJ": round(distance / 0.0625), "ANG_OBJ": round(angle / 0.015625),
                   "RELV_OBJ": 0}
        else:
            raw = EMPTY
        frames.append(message(db, f"RADAR_TRACK_{slot}", t + (slot - 361) * 0.001, **raw))
    return frames


@pytest.fixture
def mazda_drive(shared_dbc: Path, write_log: WriteLog, tmp_path: Path) -> Path:
    dbc = shared_dbc / "mazda_radar.dbc"
    db = cantools.database.load_file(dbc)
    log = write_log("mazda.blf", [m for i in range(60) for m in cycle(db, T0 + i * 0.1)])
    out = tmp_path / "mazda.mcap"
    convert([log], out, [str(dbc)], profile=PROFILE)
    return out


def last_message(path: Path, topic: str) -> Any:
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        *_, (_, _, _, last) = reader.iter_decoded_messages(topics=[topic])
    return last


def test_the_profile_loads_six_numbered_track_slots(shared_dbc: Path) -> None:
    _, profile = load_stages([str(shared_dbc / "mazda_radar.dbc")], PROFILE)

    assert profile is not None
    group = profile.groups["radar_tracks"]
    assert group.is_tracks
    assert sorted(group.members) == [f"RADAR_TRACK_{i}" for i in range(361, 367)]
    assert group.sensor.lateral == "right" and group.sensor.coordinates == "polar"


def test_tracks_are_drawn_where_distance_and_angle_point_labelled_by_slot(
        mazda_drive: Path) -> None:
    perceived = {o.id: o for o in last_message(
        mazda_drive, objects_topic("radar_tracks")).objects}

    assert set(perceived) == {361, 362}  # the empty slots are not objects
    for slot, (distance, angle) in TRACKS.items():
        assert (perceived[slot].x, perceived[slot].y) == pytest.approx(
            where(distance, angle), abs=0.02)
    assert perceived[361].y < 0 < perceived[362].y  # 5 deg to the right, 3 deg to the left

    scene = last_message(mazda_drive, scene_topic("radar_tracks"))
    drawn = {e.id: e for e in scene.entities}
    blocks = {e.id: e for e in last_message(mazda_drive, scene_topic("labels/range")).entities}
    assert set(drawn) == {"radar_tracks-361", "radar_tracks-362"}
    for slot, (distance, angle) in TRACKS.items():
        entity = drawn[f"radar_tracks-{slot}"]
        (sphere,) = entity.spheres
        color = (sphere.color.r, sphere.color.g, sphere.color.b)
        assert color == pytest.approx(TRACK_COLOR[:3])  # red: tracks
        position = sphere.pose.position
        assert (position.x, position.y) == pytest.approx(where(distance, angle), abs=0.02)
        assert any(f"TrackID: {slot}" in text.text for text in blocks[entity.id].texts)


def test_healthy_mazda_data_raises_no_alarm(mazda_drive: Path) -> None:
    metadata = summarize_file(mazda_drive).metadata[METADATA_NAME]

    assert json.loads(metadata["alarms"]) == []
    with mazda_drive.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        warnings = [m.message for *_, m in reader.iter_decoded_messages(topics=[LOG_TOPIC])
                    if m.level >= Log.WARNING]
    assert warnings == []
    health = last_message(mazda_drive, "/health")
    assert not any(alarm.active for alarm in health.alarms)
