"""Groups observed together: one radar's slots as detections and as tracks (the highway car's
profile) are observed once and their /perception made once; the scene is byte for byte the one
observing each group apart makes.

Also the scene tick's other shortcuts, each checked against the long way on a whole drive: an
unchanged invalid object's observation given again (its time counts nowhere), a rule of plain
names judged once per set of values, numbers written with two decimals held by value.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from typing import Any, cast
from unittest import mock

import pytest

from bridge.frame import NS
from bridge.pipeline import perception as perception_module
from bridge.pipeline.drive import load_stages
from bridge.pipeline.perception import Perception
from bridge.profile.model import Profile
from bridge.scene import entities, wire
from bridge.sim.highway import CAR_BUS, highway_database, simulate_highway
from bridge.sim.highway_body import UNKNOWN_IDS
from bridge.world import observe
from bridge.world.observe import ObjectObservation, _Object


def _decoded(seconds: float) -> Iterator[tuple[int, str, dict[str, Any]]]:
    """The simulated highway drive's frames decoded: (time, message name, signals); the ids no
    database defines are not decoded."""
    databases = {CAR_BUS: highway_database("car")}
    radar = highway_database("radar")
    for frame in simulate_highway(duration_s=seconds):
        if frame.arbitration_id in UNKNOWN_IDS:
            continue
        db = databases.get(frame.bus, radar)
        message = db.get_message_by_frame_id(frame.arbitration_id)
        yield frame.timestamp_ns, message.name, cast(dict[str, Any], db.decode_message(
            frame.arbitration_id, frame.data))


@pytest.fixture(scope="module")
def drive() -> list[tuple[int, str, dict[str, Any]]]:
    return list(_decoded(20.0))


@pytest.fixture(scope="module")
def highway() -> Profile:
    profile = load_stages([], "highway").profile
    assert profile is not None
    return profile


def _scenes(profile: Profile, drive: list[tuple[int, str, dict[str, Any]]]) -> list[str]:
    """A digest of each tick's messages (topic, time, bytes)."""
    perception = Perception(profile)
    out = []
    for t, name, values in drive:
        for message in perception.advance(t):
            out.append(hashlib.sha256(b"%s %d %s" % (
                message.topic.encode(), message.t_ns,
                message.message.SerializeToString())).hexdigest())
        perception.feed(name, values, t)
    return out


@pytest.mark.slow
def test_groups_observed_together_make_the_scene_observing_them_apart_makes(
        highway: Profile, drive: list[tuple[int, str, dict[str, Any]]]) -> None:
    together = Perception(highway)
    assert together.observer.aliases == {"tracks": "radar"}  # observed once
    shared = _scenes(highway, drive)
    with mock.patch.object(observe, "_reading", lambda group: group), \
            mock.patch.object(perception_module, "copies", lambda a, b: False), \
            mock.patch.object(perception_module, "same_twins", lambda a, b: False):
        assert Perception(highway).observer.aliases == {}
        apart = _scenes(highway, drive)
    assert len(shared) > 20 * 20 * 5
    assert shared == apart


@pytest.mark.slow
def test_the_scene_tick_s_shortcuts_make_the_scene_the_long_way_makes(
        highway: Profile, drive: list[tuple[int, str, dict[str, Any]]]) -> None:
    """Every object evaluated anew (a fresh observation each tick, its rule judged), no number
    held: the same bytes."""
    short = _scenes(highway, drive)

    def hundredths(value: float) -> str:
        entities._HUNDREDTHS.clear()
        return f"{value:.2f}"

    def speed(vx: float) -> bytes:
        entities._SPEEDS.clear()
        return wire.metadata(entities._VX_KEY, f"{vx:.2f} m/s")

    with mock.patch.object(_Object, "read_key", lambda self: object()), \
            mock.patch.object(entities, "_hundredths", hundredths), \
            mock.patch.object(entities, "_speed", speed):
        entities._HUNDREDTHS.clear()
        entities._SPEEDS.clear()
        long = _scenes(highway, drive)
    assert short == long


@pytest.mark.slow
def test_an_unchanged_invalid_observation_is_given_again_a_valid_one_at_its_new_time(
        highway: Profile, drive: list[tuple[int, str, dict[str, Any]]]) -> None:
    observer = observe.Observer(highway)
    pending: dict[str, tuple[dict[str, Any], int]] = {}
    before: dict[tuple[str, int], ObjectObservation] = {}
    again = renewed = 0
    end = drive[0][0] + 10 * NS
    for t, name, values in drive:
        if t > end:
            break
        if name.startswith("TRACK_A_") and name in pending:  # one radar cycle: observe it
            for o in observer.observe_latest(pending):
                if not isinstance(o, ObjectObservation):
                    continue  # ego
                last = before.get((o.group, o.object_id))
                if last is not None and not o.valid and not last.valid and (
                        o.x, o.y) == (last.x, last.y):
                    again += o is last
                if o.valid:
                    assert o.t_ns == pending[f"TRACK_A_{o.object_id}"][1]
                    renewed += 1
                before[o.group, o.object_id] = o
            pending = {}
        pending.pop(name, None)
        pending[name] = (values, t)
    assert again > 100 and renewed > 100
