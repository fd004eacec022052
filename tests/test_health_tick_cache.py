"""What the health monitor and its overlay keep from one scene tick to the next changes nothing:
fields of view asked once per object (:class:`bridge.health.sight.FieldOfView`, and the
monitor's witnesses), the active alarms made once per check, and the field-of-view entities made
once per set of alarmed sensors, each tick a copy stamped with its time.

References here are the straightforward ways (the field of view worked out at every call, every
object asked at every tick, the entities built at every tick), written out in the tests.
"""

from __future__ import annotations

import math
import random

import pytest
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity

from bridge.decode.codec import Decoded
from bridge.frame import NS, Frame
from bridge.health.alarms import AlarmInfo, AlarmKind
from bridge.health.monitor import HealthMonitor
from bridge.health.overlay import (
    ALARM_COLOR,
    _fov_outline,
    alarm_entities,
    fov_entities,
)
from bridge.health.sight import FieldOfView, has_fov, in_fov
from bridge.pipeline.drive import load_stages
from bridge.pipeline.perception import Perception
from bridge.profile.model import ObjectClass, Profile, Sensor
from bridge.scene.entities import color, entity, text
from bridge.sim.ecocar import simulate
from bridge.sim.scenario import SCENARIOS

T0 = 1_700_000_000 * NS


def reference_in_fov(sensor: Sensor, x: float, y: float) -> bool:
    dx, dy = x - sensor.mount.x, y - sensor.mount.y
    if sensor.mount.yaw_deg:
        yaw = math.radians(sensor.mount.yaw_deg)
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = c * dx + s * dy, -s * dx + c * dy
    if sensor.fov_range is not None and math.hypot(dx, dy) > sensor.fov_range:
        return False
    return not (sensor.fov_azimuth_deg is not None
                and abs(math.degrees(math.atan2(dy, dx))) > sensor.fov_azimuth_deg)


def reference_fov_entities(profile: Profile, alarms: list[AlarmInfo],
                           t_ns: int) -> list[SceneEntity]:
    alarmed: dict[str, list[str]] = {}
    for a in alarms:
        for name in a.sensors:
            alarmed.setdefault(name, []).append(a.id)
    out = []
    for sensor in profile.sensors.values():
        if sensor.fov_range is None or sensor.fov_azimuth_deg is None:
            continue
        ids = alarmed.get(sensor.name)
        e = entity(t_ns, f"fov-{sensor.name}", 0.0)
        e.lines.add().CopyFrom(_fov_outline(sensor, bool(ids), 24))
        if ids:
            yaw = math.radians(sensor.mount.yaw_deg)
            mx, my, far = sensor.mount.x, sensor.mount.y, min(sensor.fov_range, 30.0)
            label = text(mx + far * math.cos(yaw), my + far * math.sin(yaw), 1.5,
                         f"{sensor.name}: {', '.join(ids)}")
            label.color.CopyFrom(color(ALARM_COLOR))
            e.texts.append(label)
        e.metadata.add(key="state", value="alarm" if ids else "ok")
        out.append(e)
    return out


def ecocar() -> Profile:
    _, profile = load_stages([], "ecocar")
    assert profile is not None
    return profile


def test_a_field_of_view_worked_out_once_answers_as_in_fov_does() -> None:
    rng = random.Random(3)
    sensors = list(ecocar().sensors.values())
    turned = [s for s in sensors if s.mount.yaw_deg]
    for sensor in [*sensors, *(s.__class__(**{**s.__dict__, "mount": s.mount.__class__(
            **{**s.mount.__dict__, "yaw_deg": 7.5})}) for s in sensors if not turned)]:
        view = FieldOfView(sensor)
        for _ in range(3000):
            x, y = rng.uniform(-100, 250), rng.uniform(-80, 80)
            assert view.contains(x, y) == in_fov(sensor, x, y) == reference_in_fov(sensor, x, y)
        # on the edge of the range and of the azimuth
        if sensor.fov_range is not None and sensor.fov_azimuth_deg is not None:
            yaw = math.radians(sensor.mount.yaw_deg)
            for angle in (yaw + math.radians(sensor.fov_azimuth_deg), yaw,
                          yaw - math.radians(sensor.fov_azimuth_deg)):
                x = sensor.mount.x + sensor.fov_range * math.cos(angle)
                y = sensor.mount.y + sensor.fov_range * math.sin(angle)
                assert view.contains(x, y) == reference_in_fov(sensor, x, y)


def test_field_of_view_entities_are_the_built_ones_whatever_the_alarms_and_time() -> None:
    profile = ecocar()
    named = [s.name for s in profile.sensors.values() if s.fov_range is not None]
    radar = AlarmInfo("radar.silent", AlarmKind.SENSOR_SILENT, "radar", "no frame", T0,
                      (named[0],))
    both = AlarmInfo("radar-camera.misaligned", AlarmKind.MISALIGNED, "radar-camera", "off",
                     T0, tuple(named))
    for k, alarms in enumerate([[], [radar], [radar, both], [both], [], [radar]] * 2):
        t = T0 + k * 50_000_000 + k
        got = fov_entities(profile, alarms, t)
        want = reference_fov_entities(profile, alarms, t)
        assert [e.SerializeToString() for e in got] == [e.SerializeToString() for e in want]
        got[0].id = "changed"  # a copy: the next tick's entities are made afresh
        got[0].lines[0].points[0].x = 1e9


@pytest.mark.slow
def test_active_alarms_follow_every_check_and_clock_step() -> None:
    decoder, _ = load_stages([], "ecocar")
    monitor = HealthMonitor(None, decoder)
    frames = [(T0 + k * 10_000_000, k) for k in range(300)]
    for t, _ in frames:
        monitor.advance(t)
        frame = Frame(t, "can0", 0x7E5, bytes(8))
        monitor.on_frame(frame, decoder.decode(frame))
    assert monitor.active_alarms() == []
    seen = []
    t = frames[-1][0]
    for k in range(1, 60):  # the bus goes silent: its alarm is raised, in log time
        monitor.advance(t + k * 100_000_000)
        seen.append(monitor.active_alarms())
        assert seen[-1] == reference_active(monitor)
    assert seen[-1] and seen[-1][0].id == "bus.can0.silent"
    alarms = monitor.active_alarms()
    alarms.clear()  # the caller's own list
    assert monitor.active_alarms() == seen[-1]
    monitor.rebase(3600 * NS, t + 70 * 100_000_000)
    assert monitor.active_alarms() == reference_active(monitor)
    assert monitor.active_alarms()[0].since_ns == seen[-1][0].since_ns + 3600 * NS


def reference_active(monitor: HealthMonitor) -> list[AlarmInfo]:
    active = [a for a in monitor._alarms.values() if a.active]
    return [a.info() for a in sorted(active, key=lambda a: (a.since_ns or 0, a.id))]


@pytest.mark.slow
def test_who_sees_what_is_asked_of_each_object_once_with_the_same_verdict() -> None:
    """A simulated drive of a blind radar: at every tick each family's witnessed time is the
    one every object asked afresh gives, and so are the overlay's entities."""
    profile = ecocar()
    decoder, _ = load_stages([], "ecocar")
    monitor = HealthMonitor(profile, decoder)
    perception = Perception(profile)
    seers = [f for f in monitor.families if monitor._detections(f)]
    checked = [f for f in seers if f.sensor is not None and has_fov(f.sensor)]
    assert checked
    witnessed = {f.name: f.witnessed_ns for f in seers}
    ticks = 0
    answers: set[bool] = set()  # whether a family was witnessed at a tick: both happen
    for frame in simulate(duration_s=min(SCENARIOS["radar_blind"].duration_s, 30.0),
                          scenario="radar_blind"):
        t = frame.timestamp_ns
        for tick in perception.due_ticks(t):
            lanes = perception.update_world(tick)
            monitor.on_world(tick, perception.world, lanes)
            ticks += 1
            for family in checked:
                sensor = family.sensor
                assert sensor is not None
                if any(other.sensor is not None and other.sensor.name != sensor.name
                       and any(o.object_class is not ObjectClass.STATIONARY
                               and reference_in_fov(sensor, o.x, o.y)
                               for o in perception.world.objects.get(other.group or "",
                                                                     {}).values())
                       for other in seers):
                    witnessed[family.name] = tick
                answers.add(witnessed[family.name] == tick)
                assert family.witnessed_ns == witnessed[family.name], (family.name, tick)
            alarms = monitor.active_alarms()
            assert ([e.SerializeToString() for e in alarm_entities(alarms, tick)
                     + fov_entities(profile, alarms, tick)]
                    == [e.SerializeToString() for e in alarm_entities(alarms, tick)
                        + reference_fov_entities(profile, alarms, tick)])
        monitor.advance(t)
        decoded = decoder.decode(frame)
        if type(decoded) is Decoded:
            perception.feed(decoded.codec.message.name, decoded.signals, t)
        monitor.on_frame(frame, decoded)
    assert ticks > 100
    assert answers == {True, False}
