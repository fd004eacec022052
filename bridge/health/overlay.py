"""The health alarms in the scene, drawn in the vehicle frame from the active alarms
(:class:`~bridge.health.alarms.AlarmInfo`), not the monitor.

A red text above the ego names the active alarms (entity ``health-alarms``); each sensor's field
of view is an outline on the ground (entity ``fov-<sensor>``), red and labelled while an alarm
concerns it.
"""

from __future__ import annotations

import functools
import math
import textwrap
from collections.abc import Mapping, Sequence

from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Point3_pb2 import Point3
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity

from bridge.frame import timestamp
from bridge.health.alarms import AlarmInfo
from bridge.profile.model import Profile, Sensor
from bridge.scene.entities import RGBA, color, entity, pose, text

ALARM_COLOR: RGBA = (1.0, 0.15, 0.1, 1.0)  # signal red
FOV_COLOR: RGBA = (0.75, 0.75, 0.75, 0.25)  # dim grey
FOV_ALARM_COLOR: RGBA = (1.0, 0.1, 0.1, 0.9)
ALARM_FONT_SIZE = 18.0
#: The alarm ids are drawn in lines of at most this many characters: a laptop's narrowest 3D
#: panel holds them (what each alarm says is in /log, /health and the engineer layout).
ALARM_LINE_CHARS = 34
FOV_THICKNESS = 0.05  # m
FOV_ALARM_THICKNESS = 0.15


def alarm_entities(alarms: Sequence[AlarmInfo], t_ns: int, *, x: float = 0.0, y: float = 0.0,
                   z: float = 3.0, lifetime_s: float = 0.0) -> list[SceneEntity]:
    """A red text above the ego listing the active alarms (nothing when there are none)."""
    if not alarms:
        return []
    e = entity(t_ns, "health-alarms", lifetime_s)
    lines = [f"HEALTH: {len(alarms)} ALARM{'S' if len(alarms) > 1 else ''}"]
    lines += textwrap.wrap(", ".join(a.id for a in alarms), ALARM_LINE_CHARS,
                           break_on_hyphens=False)
    label = text(x, y, z, "\n".join(lines))
    label.font_size = ALARM_FONT_SIZE
    label.color.CopyFrom(color(ALARM_COLOR))
    e.texts.append(label)
    e.metadata.add(key="alarms", value=",".join(a.id for a in alarms))
    return [e]


@functools.lru_cache(maxsize=64)
def _fov_outline(sensor: Sensor, alarmed: bool, arc_points: int) -> LinePrimitive:
    """A sensor's field of view on the ground (made once: the scene draws it at every tick)."""
    assert sensor.fov_range is not None and sensor.fov_azimuth_deg is not None
    half = math.radians(sensor.fov_azimuth_deg)
    yaw = math.radians(sensor.mount.yaw_deg)
    mx, my, r = sensor.mount.x, sensor.mount.y, sensor.fov_range
    points = [(mx, my)]
    for k in range(arc_points + 1):
        angle = yaw - half + 2 * half * k / arc_points
        points.append((mx + r * math.cos(angle), my + r * math.sin(angle)))
    points.append((mx, my))
    return LinePrimitive(
        type=LinePrimitive.LINE_STRIP, pose=pose(0, 0, 0),
        thickness=FOV_ALARM_THICKNESS if alarmed else FOV_THICKNESS, scale_invariant=False,
        color=color(FOV_ALARM_COLOR if alarmed else FOV_COLOR),
        points=[Point3(x=px, y=py, z=0.03) for px, py in points])


def fov_entities(profile: Profile, alarms: Sequence[AlarmInfo], t_ns: int, *,
                 lifetime_s: float = 0.0, arc_points: int = 24) -> list[SceneEntity]:
    """Each sensor's field of view (from the profile) as an outline on the ground: dim when
    healthy, red and labelled when an active alarm concerns the sensor."""
    alarmed: dict[str, list[str]] = {}
    for a in alarms:
        for name in a.sensors:
            alarmed.setdefault(name, []).append(a.id)
    key = (id(profile), tuple((name, tuple(ids)) for name, ids in alarmed.items()), lifetime_s,
           arc_points)
    made = _outlines.get(key)
    if made is None or made[0] is not profile:
        if len(_outlines) >= _OUTLINE_SETS:
            _outlines.clear()
        made = _outlines[key] = (profile, _fov_templates(profile, alarmed, lifetime_s,
                                                         arc_points))
    stamp = timestamp(t_ns)
    out = []
    for template in made[1]:
        e = SceneEntity()
        e.CopyFrom(template)
        e.timestamp.CopyFrom(stamp)
        out.append(e)
    return out


#: the outlines of every profile and state seen lately: (the profile, its entities without a
#: time) by (the profile's id, the alarm ids of each alarmed sensor, lifetime, arc points)
_outlines: dict[tuple[object, ...], tuple[Profile, list[SceneEntity]]] = {}
_OUTLINE_SETS = 64  # then all are forgotten at once


def _fov_templates(profile: Profile, alarmed: Mapping[str, Sequence[str]], lifetime_s: float,
                   arc_points: int) -> list[SceneEntity]:
    """The entities of :func:`fov_entities` at time 0 (the timestamp set, empty)."""
    out = []
    for sensor in profile.sensors.values():
        if sensor.fov_range is None or sensor.fov_azimuth_deg is None:
            continue
        ids = alarmed.get(sensor.name)
        e = entity(0, f"fov-{sensor.name}", lifetime_s)
        e.lines.add().CopyFrom(_fov_outline(sensor, bool(ids), arc_points))
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
