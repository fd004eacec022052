"""Observe: decoded DBC messages to observations in the vehicle frame, as the profile says.

The profile stage of the data path. :class:`Observer` routes each decoded message to what it
means (an object of a group, a lane line, the lead vehicle, ego motion) and converts positions
from the sensor's conventions (polar or cartesian, lateral sign, units, mounting pose) into the
one vehicle frame: x forward, y left, z up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bridge.profile import (
    FamilyMember,
    LaneLine,
    ObjectClass,
    ObjectGroup,
    Profile,
    Sensor,
    SignalRef,
    expand,
)


def to_vehicle(sensor: Sensor, x: float, y: float) -> tuple[float, float]:
    """A position the sensor reports (its own lateral convention) in the vehicle frame."""
    y *= sensor.lateral_sign
    mount = sensor.mount
    if mount.yaw_deg:
        yaw = math.radians(mount.yaw_deg)
        c, s = math.cos(yaw), math.sin(yaw)
        x, y = c * x - s * y, s * x + c * y
    return x + mount.x, y + mount.y


def velocity_to_vehicle(sensor: Sensor, vx: float, vy: float) -> tuple[float, float]:
    """A velocity the sensor reports, rotated into the vehicle frame (no offset)."""
    vy *= sensor.lateral_sign
    if sensor.mount.yaw_deg:
        yaw = math.radians(sensor.mount.yaw_deg)
        c, s = math.cos(yaw), math.sin(yaw)
        vx, vy = c * vx - s * vy, s * vx + c * vy
    return vx, vy


def polar_to_cartesian(distance: float, azimuth: float, angle_unit: str) -> tuple[float, float]:
    """Range and azimuth (in the sensor's unit) to the sensor's own x, y."""
    angle = math.radians(azimuth) if angle_unit == "deg" else azimuth
    return distance * math.cos(angle), distance * math.sin(angle)


@dataclass(frozen=True, slots=True)
class ObjectObservation:
    """One object as one sensor (or the fusion) saw it at ``t_ns``, in the vehicle frame."""

    group: str
    object_id: int
    t_ns: int
    x: float
    y: float
    valid: bool
    vx: float | None = None
    vy: float | None = None
    probability: float | None = None
    object_class: ObjectClass = ObjectClass.UNKNOWN


@dataclass(frozen=True, slots=True)
class LaneObservation:
    """One lane line's coefficients in the sensor frame (sensor's lateral convention)."""

    name: str
    t_ns: int
    coefficients: tuple[float, float, float, float]
    valid: bool


@dataclass(frozen=True, slots=True)
class EgoObservation:
    """Whatever ego signals one message carried, in m/s, rad/s and rad (left positive)."""

    t_ns: int
    speed: float | None = None
    yaw_rate: float | None = None
    steering_wheel_angle: float | None = None


Observation = ObjectObservation | LaneObservation | EgoObservation

#: The group name under which the lead vehicle's own messages are observed.
LEAD_GROUP = "lead"


_FIELDS = ("x", "y", "range", "azimuth", "vx", "vy", "probability", "class_signal", "id")


class _GroupReader:
    """Turns the messages of one object group into object observations.

    Any message of an object's family makes a new observation of it, from the latest values of
    every message of the family, at the time of the newest position (the first message).
    """

    def __init__(self, group: ObjectGroup) -> None:
        self.group = group
        self.primary = group.templates[0]
        #: latest values per (object index, message name)
        self.latest: dict[tuple[int | None, str], Mapping[str, Any]] = {}
        #: time of the latest position per object index
        self.position_ns: dict[int | None, int] = {}
        self._refs: dict[int | None, dict[str, tuple[str, str, float, float] | None]] = {}
        self._names: dict[int | None, list[str]] = {}

    def message_names(self, index: int | None) -> list[str]:
        """The messages of object ``index``, in the family's order."""
        names = self._names.get(index)
        if names is None:
            names = self._names[index] = [t if index is None else expand(t, index)
                                          for t in self.group.templates]
        return names

    def refs(self, index: int | None) -> dict[str, tuple[str, str, float, float] | None]:
        """Per field of object ``index``: (message, signal, scale, offset), or None."""
        refs = self._refs.get(index)
        if refs is None:
            refs = self._refs[index] = {}
            for name in _FIELDS:
                ref: SignalRef | None = getattr(self.group, name)
                if ref is not None:
                    ref = ref.at(index)
                refs[name] = (ref.message, ref.signal, ref.scale, ref.offset) if ref else None
        return refs

    def observe(self, member: FamilyMember, message: str, values: Mapping[str, Any],
                t_ns: int) -> ObjectObservation | None:
        index = member.index
        self.latest[(index, message)] = values
        if member.template == self.primary:
            self.position_ns[index] = t_ns
        t_ns = self.position_ns.get(index, -1)
        if t_ns < 0:
            return None  # no position of this object yet
        g = self.group
        refs = self.refs(index)
        latest = self.latest

        def read(name: str) -> float | None:
            ref = refs[name]
            if ref is None:
                return None
            found = latest.get((index, ref[0]))
            raw = found.get(ref[1]) if found is not None else None
            return None if raw is None else float(raw) * ref[2] + ref[3]

        sensor = g.sensor
        if g.range is not None:
            distance, azimuth = read("range"), read("azimuth")
            if distance is None or azimuth is None:
                return None
            xs, ys = polar_to_cartesian(distance * sensor.distance_scale, azimuth,
                                        sensor.angle_unit)
        else:
            xr, yr = read("x"), read("y")
            if xr is None or yr is None:
                return None
            xs, ys = xr * sensor.distance_scale, yr * sensor.distance_scale
        x, y = to_vehicle(sensor, xs, ys)
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        vx, vy = read("vx"), read("vy")
        if vx is not None or vy is not None:
            vx, vy = velocity_to_vehicle(sensor, (vx or 0.0) * sensor.distance_scale,
                                         (vy or 0.0) * sensor.distance_scale)
        ident = read("id")
        raw_class = read("class_signal")
        object_class = (g.classes.get(int(raw_class), ObjectClass.UNKNOWN)
                        if raw_class is not None and math.isfinite(raw_class)
                        else ObjectClass.UNKNOWN)
        valid = True
        rule = g.valid.get(index)
        if rule is not None:
            by_message = {name: found for name in self.message_names(index)
                          if (found := latest.get((index, name))) is not None}
            merged: dict[str, Any] = {}
            for name in rule.names:  # only what the rule reads; the first message has it
                for found in by_message.values():
                    if name in found:
                        merged[name] = found[name]
                        break
            valid = rule.test(merged, by_message)
        object_id = (int(ident) if ident is not None and math.isfinite(ident)
                     else (index or 0))
        return ObjectObservation(g.name, object_id, t_ns, x, y, valid, vx, vy,
                                 read("probability"), object_class)


class Observer:
    """Routes decoded messages (by DBC message name) to observations, as the profile says."""

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self._objects: dict[str, list[tuple[_GroupReader, FamilyMember]]] = {}
        readers = [_GroupReader(g) for g in profile.groups.values()]
        if profile.lead is not None and profile.lead.group is not None:
            lead = profile.lead.group
            readers.append(_GroupReader(ObjectGroup(
                LEAD_GROUP, lead.sensor, lead.templates, lead.members, lead.x, lead.y, lead.range,
                lead.azimuth, lead.vx, lead.vy, lead.probability, lead.class_signal,
                lead.classes, lead.id, lead.valid, lead.lifetime_s)))
        for reader in readers:
            for name, member in reader.group.members.items():
                self._objects.setdefault(name, []).append((reader, member))
        self._lanes: dict[str, list[LaneLine]] = {}
        if profile.lanes is not None:
            for line in profile.lanes.lines.values():
                self._lanes.setdefault(line.message, []).append(line)
        self._ego: dict[str, list[tuple[str, SignalRef]]] = {}
        for field_name in ("speed", "yaw_rate", "steering_wheel_angle"):
            ref = getattr(profile.ego, field_name)
            if ref is not None:
                self._ego.setdefault(ref.message, []).append((field_name, ref))
        #: every message name this observer uses, to skip the rest cheaply
        self.messages = frozenset(self._objects) | frozenset(self._lanes) | frozenset(self._ego)

    def observe(self, message: str, values: Mapping[str, Any], t_ns: int) -> list[Observation]:
        """The observations one decoded message makes (often none, e.g. for a companion)."""
        out: list[Observation] = []
        for reader, member in self._objects.get(message, ()):
            obs = reader.observe(member, message, values, t_ns)
            if obs is not None:
                out.append(obs)
        for line in self._lanes.get(message, ()):
            c = [ref.read(values) if ref is not None else 0.0
                 for ref in (line.c0, line.c1, line.c2, line.c3)]
            if any(v is None for v in c):
                continue
            coefficients = (float(c[0] or 0.0), float(c[1] or 0.0), float(c[2] or 0.0),
                            float(c[3] or 0.0))
            valid = (line.valid.test(values, {message: values}) if line.valid is not None
                     else True)
            out.append(LaneObservation(line.name, t_ns, coefficients,
                                       valid and all(math.isfinite(v) for v in coefficients)))
        refs = self._ego.get(message)
        if refs:
            found = {name: ref.read(values) for name, ref in refs}
            out.append(EgoObservation(t_ns, found.get("speed"), found.get("yaw_rate"),
                                      found.get("steering_wheel_angle")))
        return out
