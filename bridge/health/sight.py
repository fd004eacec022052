"""Who sees what: a sensor's field of view (:func:`in_fov`; :class:`FieldOfView` asks it of many
points), and the objects two sensors both see (:func:`associate`), the evidence of the health
monitor's misalignment and blindness checks (:mod:`bridge.health.monitor`). Points are in the
vehicle frame (x forward, y left, metres)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from functools import lru_cache
from typing import TYPE_CHECKING

from bridge.frame import NS

if TYPE_CHECKING:
    from bridge.profile.model import Sensor
    from bridge.world.observe import ObjectObservation


class FieldOfView:
    """A sensor's field of view, its mount's turn worked out once: :meth:`contains` is
    :func:`in_fov` (the same arithmetic, so the same answer to the last bit) for the many points
    a scene tick asks about."""

    __slots__ = ("azimuth_deg", "c", "mx", "my", "range", "s", "turned")

    def __init__(self, sensor: Sensor) -> None:
        self.mx, self.my = sensor.mount.x, sensor.mount.y
        self.turned = bool(sensor.mount.yaw_deg)
        yaw = math.radians(sensor.mount.yaw_deg) if self.turned else 0.0
        self.c, self.s = math.cos(yaw), math.sin(yaw)
        self.range = sensor.fov_range
        self.azimuth_deg = sensor.fov_azimuth_deg

    def contains(self, x: float, y: float) -> bool:
        """Whether a vehicle-frame point is inside the field of view (True if unknown)."""
        dx, dy = x - self.mx, y - self.my
        if self.turned:
            c, s = self.c, self.s
            dx, dy = c * dx + s * dy, -s * dx + c * dy
        if self.range is not None and math.hypot(dx, dy) > self.range:
            return False
        return not (self.azimuth_deg is not None
                    and abs(math.degrees(math.atan2(dy, dx))) > self.azimuth_deg)


@lru_cache(maxsize=64)
def _view(sensor: Sensor) -> FieldOfView:
    """The field of view of ``sensor``, worked out once (:func:`associate` asks every tick)."""
    return FieldOfView(sensor)


def in_fov(sensor: Sensor, x: float, y: float) -> bool:
    """Whether a vehicle-frame point is inside the sensor's field of view (True if unknown)."""
    return FieldOfView(sensor).contains(x, y)


def has_fov(sensor: Sensor) -> bool:
    """Whether the profile gives the sensor a range or an azimuth (a field of view to check)."""
    return sensor.fov_range is not None or sensor.fov_azimuth_deg is not None


def associate(a_objects: Iterable[ObjectObservation], b_objects: Iterable[ObjectObservation],
              a_sensor: Sensor | None, b_sensor: Sensor | None, t_ns: int, *, gate_m: float,
              min_range_m: float) -> list[tuple[float, float]]:
    """Objects two sensors both see, as ``(lateral offset m, angular offset deg)`` of a minus b.

    Each object is predicted to ``t_ns`` with its velocity (where the sensor reports one); only
    objects inside both fields of view and at least ``min_range_m`` from sensor a count. Pairs
    are matched greedily, nearest first, at most ``gate_m`` apart. Angles are seen from sensor
    a's mount, left positive.
    """

    a_view = _view(a_sensor) if a_sensor is not None else None
    b_view = _view(b_sensor) if b_sensor is not None else None

    def usable(objects: Iterable[ObjectObservation]) -> list[tuple[float, float]]:
        out = []
        for o in objects:
            dt = (t_ns - o.t_ns) / NS
            x, y = o.x + (o.vx or 0.0) * dt, o.y + (o.vy or 0.0) * dt
            if ((a_view is None or a_view.contains(x, y))
                    and (b_view is None or b_view.contains(x, y))
                    and math.hypot(x - mx, y - my) >= min_range_m):
                out.append((x, y))
        return out

    mx = a_sensor.mount.x if a_sensor is not None else 0.0
    my = a_sensor.mount.y if a_sensor is not None else 0.0
    a_points, b_points = usable(a_objects), usable(b_objects)
    gate = gate_m * gate_m
    candidates = sorted(
        ((ax - bx) ** 2 + (ay - by) ** 2, i, j)
        for i, (ax, ay) in enumerate(a_points) for j, (bx, by) in enumerate(b_points)
        if (ax - bx) ** 2 + (ay - by) ** 2 <= gate)
    used_a: set[int] = set()
    used_b: set[int] = set()
    out = []
    for _, i, j in candidates:
        if i in used_a or j in used_b:
            continue
        used_a.add(i)
        used_b.add(j)
        (ax, ay), (bx, by) = a_points[i], b_points[j]
        angle = math.degrees(math.atan2(ay - my, ax - mx) - math.atan2(by - my, bx - mx))
        out.append((ay - by, (angle + 180.0) % 360.0 - 180.0))
    return out
