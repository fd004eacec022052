"""A field the profile does not map is absent from /perception, never a made-up zero.

A radar that reports its relative speed along its boresight only (the highway car's REL_SPEED:
``vx`` mapped, no ``vy``) gives objects with a vx and no vy; one without a speed or a score
gives neither vx nor probability. ``tankviz.PerceivedObject`` declares them ``optional``, so a
reader can tell "not reported" from 0 (``HasField``); a lateral sign of "right" once turned the
missing vy into -0.0. Through a mount yaw, a component not reported counts as 0 in the other's
value and is itself left out (:func:`bridge.world.observe.velocity`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from bridge.cli import main
from bridge.pb import perception_pb2
from bridge.pipeline.convert import convert
from bridge.profile.model import Mount, Sensor, SensorKind
from bridge.resources import data_dir
from bridge.topics import LEAD_TOPIC, objects_topic
from bridge.world.observe import velocity


def perceived(path: Path) -> dict[str, list[Any]]:
    """Every object on /perception/radar, /perception/tracks and /perception/lead, by topic."""
    found: dict[str, list[Any]] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(
                topics=[objects_topic("radar"), objects_topic("tracks"), LEAD_TOPIC]):
            if channel.topic == LEAD_TOPIC:
                lead = perception_pb2.LeadVehicle.FromString(message.data)
                objects = [lead.object] if lead.present else []
            else:
                objects = list(perception_pb2.PerceivedObjects.FromString(message.data).objects)
            found.setdefault(channel.topic, []).extend(objects)
    return found


def test_a_radar_without_vy_gives_objects_without_vy(tmp_path: Path) -> None:
    drive = tmp_path / "highway.mcap"  # the profile maps vx and probability, not vy
    assert main(["simulate", "--car", "highway", "-o", str(drive), "--duration", "3"]) == 0

    found = perceived(drive)

    assert found.keys() == {"/perception/radar", "/perception/tracks", "/perception/lead"}
    for topic, objects in found.items():
        assert len(objects) > 50, topic
        assert all(o.HasField("vx") and o.HasField("probability") for o in objects), topic
        assert not any(o.HasField("vy") for o in objects), topic


def test_a_radar_without_speed_or_score_gives_objects_without_them(tmp_path: Path) -> None:
    text = (data_dir() / "highway.toml").read_text()
    lines = text.splitlines()
    kept = [line for line in lines if not line.startswith(("vx = ", "probability = "))]
    assert len(kept) == len(lines) - 4  # two fields of two groups
    bare = "\n".join(kept) + "\n"
    profile = tmp_path / "bare.toml"
    profile.write_text(bare)
    log = tmp_path / "highway.blf"
    assert main(["simulate", "--car", "highway", "-o", str(log), "--duration", "3"]) == 0
    drive = tmp_path / "bare.mcap"

    convert([log], drive, [], profile=profile)

    found = perceived(drive)
    assert found.keys() == {"/perception/radar", "/perception/tracks", "/perception/lead"}
    for topic, objects in found.items():
        assert len(objects) > 50, topic
        assert not any(o.HasField("vx") or o.HasField("vy") or o.HasField("probability")
                       for o in objects), topic


@pytest.mark.parametrize("lateral", ["left", "right"])
def test_a_velocity_component_not_reported_is_never_made_up(lateral: str) -> None:
    ahead = Sensor("radar", SensorKind.RADAR, lateral=lateral)
    corner = Sensor("corner", SensorKind.RADAR, Mount(yaw_deg=30.0), lateral=lateral)
    sign = 1.0 if lateral == "left" else -1.0

    assert velocity(ahead, -20.0, None) == (-20.0, None)
    assert velocity(ahead, None, 1.5) == (None, sign * 1.5)
    assert velocity(ahead, None, None) == (None, None)
    # turned 30 deg: the speed along the boresight is most of vx; vy is not reported
    vx, vy = velocity(corner, -20.0, None)
    assert vx == pytest.approx(-20.0 * math.cos(math.radians(30.0))) and vy is None
    assert velocity(corner, -20.0, 2.0, scale=0.5)[1] == pytest.approx(
        0.5 * (-20.0 * math.sin(math.radians(30.0)) + sign * 2.0 * math.cos(math.radians(30.0))))
