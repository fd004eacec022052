"""Observe: decoded DBC messages to observations in the vehicle frame, as the profile says.

:class:`Observer` routes each decoded message to what it means (an object, a lane line, the lead,
ego motion) and converts positions into the vehicle frame (x forward, y left, z up). A field not
mapped or not finite is ``None``, never 0; an object without a finite position makes no observation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from operator import itemgetter
from typing import Any, cast

from bridge.profile.model import (
    FamilyMember,
    Field,
    LaneLine,
    ObjectClass,
    ObjectGroup,
    Profile,
    Rule,
    Sensor,
    expand,
)
from bridge.world.pages import PageMerger, PageStats


def to_vehicle(sensor: Sensor, x: float, y: float) -> tuple[float, float]:
    """A position the sensor reports (its own lateral convention) in the vehicle frame."""
    y *= sensor.lateral_sign
    mount = sensor.mount
    if mount.yaw_deg:
        c, s = sensor.rotation
        x, y = c * x - s * y, s * x + c * y
    return x + mount.x, y + mount.y


def velocity_to_vehicle(sensor: Sensor, vx: float, vy: float) -> tuple[float, float]:
    """A velocity the sensor reports, rotated into the vehicle frame (no offset)."""
    vy *= sensor.lateral_sign
    if sensor.mount.yaw_deg:
        c, s = sensor.rotation
        vx, vy = c * vx - s * vy, s * vx + c * vy
    return vx, vy


def velocity(sensor: Sensor, vx: float | None, vy: float | None,
             scale: float = 1.0) -> tuple[float | None, float | None]:
    """The velocity components a sensor reports (each ``None`` when not mapped or not read), in
    the vehicle frame: a component is there when the sensor's own one is, and finite. Rotating
    through a mount yaw, a component the sensor does not report counts as 0 in the other's
    value, but is never made up itself: a radar's speed along its boresight gives a vx, no vy.
    """
    if vx is None and vy is None:
        return None, None
    rx, ry = velocity_to_vehicle(sensor, (vx or 0.0) * scale, (vy or 0.0) * scale)
    return (_finite(rx) if vx is not None else None), (_finite(ry) if vy is not None else None)


def polar_to_cartesian(distance: float, azimuth: float, angle_unit: str) -> tuple[float, float]:
    """Range and azimuth (in the sensor's unit) to the sensor's own x, y."""
    angle = math.radians(azimuth) if angle_unit == "deg" else azimuth
    return distance * math.cos(angle), distance * math.sin(angle)


# Observations are values: never changed once made. Not frozen=True only because a frozen
# dataclass is four times slower to create, and the radar makes thousands a second.


@dataclass(slots=True)
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
    #: why the validity rule could not be evaluated ("" when it could; then valid is False)
    rule_error: str = ""


@dataclass(slots=True)
class LaneObservation:
    """One lane line's coefficients in the sensor frame (sensor's lateral convention)."""

    name: str
    t_ns: int
    coefficients: tuple[float, float, float, float]
    valid: bool
    #: why the validity rule could not be evaluated ("" when it could; then valid is False)
    rule_error: str = ""


@dataclass(slots=True)
class EgoObservation:
    """Whatever ego signals one message carried, in m/s, rad/s and rad (left positive)."""

    t_ns: int
    speed: float | None = None
    yaw_rate: float | None = None
    steering_wheel_angle: float | None = None


Observation = ObjectObservation | LaneObservation | EgoObservation

#: What :meth:`Observer.watch` calls with each evaluation of an object: its group, what it made
#: (None: no position), its validity rule (None: none) and the values the rule read (by its
#: names; a missing one left out).
Watcher = Callable[[ObjectGroup, ObjectObservation | None, Rule | None, dict[str, Any]], None]

#: The group name under which the lead vehicle's own messages are observed.
LEAD_GROUP = "lead"


#: Object ids are uint32 on /perception.
_ID_LIMIT = 1 << 32


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _read(latest: Mapping[str, Mapping[str, Any]], ref: Field | None) -> float | None:
    """A field's value from the latest messages of an object, or None (also when not finite)."""
    return ref.value(latest) if ref is not None else None


#: In an object's key: a message of its family not come yet, or a signal not in a message.
_ABSENT = object()
_ABSENT_KEY = (_ABSENT,)


class _Part:
    """How one message of an object's family enters the object's key: a tuple of the values
    of the signals the object reads from it, read at C speed by an :func:`operator.itemgetter`
    of the names the first message had; a message that lacks one of them or has one of the
    others (``absent``: a multiplexed or truncated message) is keyed name by name."""

    __slots__ = ("absent", "getter", "names", "single")

    def __init__(self, names: tuple[str, ...], first: Mapping[str, Any]) -> None:
        self.names = names
        present = [n for n in names if n in first]
        self.absent = frozenset(names) - frozenset(present)
        self.single = len(present) == 1  # then the getter gives the value, not a tuple
        self.getter: Callable[[Mapping[str, Any]], Any] = (
            itemgetter(*present) if present else _nothing)

    def key(self, values: Mapping[str, Any]) -> tuple[Any, ...]:
        if not self.absent or self.absent.isdisjoint(values):
            try:
                found = self.getter(values)
            except KeyError:
                pass
            else:
                return (found,) if self.single else found
        return (_ABSENT, *[values.get(n, _ABSENT) for n in self.names])


def _nothing(values: Mapping[str, Any]) -> tuple[()]:
    return ()


def _part_getter(part: _Part) -> Callable[[Mapping[str, Any]], tuple[Any, ...]]:
    """:meth:`_Part.key` where its getter reads the message: raises KeyError where it does not
    (a signal of the first message missing, one of the others there)."""
    getter, absent, single = part.getter, part.absent, part.single
    if 0 < len(absent) <= 2:  # one or two names looked up, not the message's names walked
        lacked = sorted(absent)
        first, second = lacked[0], lacked[-1]  # the same when one
        if single:
            def checked_single(values: Mapping[str, Any]) -> tuple[Any, ...]:
                if first in values or second in values:
                    raise KeyError("a signal the first message lacked")
                return (getter(values),)

            return checked_single

        def checked_few(values: Mapping[str, Any]) -> tuple[Any, ...]:
            if first in values or second in values:
                raise KeyError("a signal the first message lacked")
            found: tuple[Any, ...] = getter(values)
            return found

        return checked_few
    if absent:
        def checked(values: Mapping[str, Any]) -> tuple[Any, ...]:
            if not absent.isdisjoint(values):
                raise KeyError("a signal the first message lacked")
            found = getter(values)
            return (found,) if single else found

        return checked
    if single:
        return lambda values: (getter(values),)
    return getter


def _key_function(parts: list[tuple[str, _Part]]
                  ) -> Callable[[Mapping[str, Mapping[str, Any]]], tuple[tuple[Any, ...], ...]]:
    """:meth:`_Object.read_key` where every message of the family is there and each getter
    reads it (KeyError where not): one call per message, no loop for one or two."""
    getters = [(message, _part_getter(part)) for message, part in parts]
    if len(getters) == 1:
        (m1, g1), = getters
        return lambda latest: (g1(latest[m1]),)
    if len(getters) == 2:
        (m1, g1), (m2, g2) = getters
        return lambda latest: (g1(latest[m1]), g2(latest[m2]))
    return lambda latest: tuple([get(latest[message]) for message, get in getters])


class _Object:
    """One object of a group: where each of its fields is, and its latest messages."""

    __slots__ = ("azimuth", "class_signal", "fast_key", "id", "index", "judged", "key", "latest",
                 "made", "names", "parts", "position_ns", "probability", "range", "reads",
                 "rule", "rule_sources", "vx", "vy", "x", "y")

    def __init__(self, group: ObjectGroup, index: int | None) -> None:
        def ref(found: Field | None) -> Field | None:
            return found.at(index) if found is not None else None

        self.x, self.y = ref(group.x), ref(group.y)
        self.range, self.azimuth = ref(group.range), ref(group.azimuth)
        self.vx, self.vy = ref(group.vx), ref(group.vy)
        self.probability, self.class_signal = ref(group.probability), ref(group.class_signal)
        self.id = ref(group.id)
        self.index = index
        #: the messages of this object, in the family's order
        self.names = [t if index is None else expand(t, index) for t in group.templates]
        self.rule = group.valid.get(index)
        #: the plain names the rule reads (each from the first message of the family having it)
        self.rule_sources = sorted(self.rule.names) if self.rule is not None else []
        #: latest values per message name
        self.latest: dict[str, Mapping[str, Any]] = {}
        #: time of the latest position; -1 until the first
        self.position_ns = -1
        #: every signal the observation reads, per message of the family
        reads: dict[str, dict[str, None]] = {message: {} for message in self.names}
        for found in (self.x, self.y, self.range, self.azimuth, self.vx, self.vy,
                      self.probability, self.class_signal, self.id):
            if found is not None:
                for message, signal in found.signals:
                    if message in reads:  # a field of another message never reads anything
                        reads[message][signal] = None
        if self.rule is not None:
            for message in self.names:
                for name in self.rule_sources:
                    if "." not in name:
                        reads[message][name] = None
            for _, message, signal in self.rule.qualified:
                if message in reads:
                    reads[message][signal] = None
        self.reads = [(message, tuple(signals)) for message, signals in reads.items()
                      if signals]
        self.parts: dict[str, _Part] = {}
        #: the key of the latest observation (the values it read), and what it made
        self.key: tuple[tuple[Any, ...], ...] | None = None
        self.made: ObjectObservation | None = None
        #: the values the rule last judged (name, value) and its verdict (:meth:`valid`)
        self.judged: tuple[tuple[tuple[str, Any], ...], tuple[bool, str]] | None = None
        #: read_key's common case (every message of the family there, each with the signals
        #: its first had), once each message has its _Part: raises KeyError where it is not
        self.fast_key: Callable[[Mapping[str, Mapping[str, Any]]],
                                tuple[tuple[Any, ...], ...]] | None = None

    def read_key(self) -> tuple[tuple[Any, ...], ...]:
        """The values of every signal the observation reads, from the latest messages."""
        latest, parts = self.latest, self.parts
        fast = self.fast_key
        if fast is not None:
            try:
                return fast(latest)
            except KeyError:
                pass  # a message not come yet, or not as its first: read as below
        elif len(parts) == len(self.reads) and self.reads:
            self.fast_key = _key_function([(message, parts[message])
                                           for message, _ in self.reads])
        key: list[tuple[Any, ...]] = []
        for message, names in self.reads:
            values = latest.get(message)
            if values is None:
                key.append(_ABSENT_KEY)
                continue
            part = parts.get(message)
            if part is None:
                part = parts[message] = _Part(names, values)
            if part.absent:
                key.append(part.key(values))
                continue
            try:  # _Part.key's common case, inline
                found = part.getter(values)
            except KeyError:
                key.append(part.key(values))
            else:
                key.append((found,) if part.single else found)
        return tuple(key)

    def rule_values(self) -> dict[str, Any]:
        """The values the validity rule reads (by its names; a missing one left out)."""
        rule = self.rule
        if rule is None:
            return {}
        latest = self.latest
        values: dict[str, Any] = {}
        for name in self.rule_sources:
            found = next((v for v in map(latest.get, self.names)
                          if v is not None and name in v), None)
            if found is not None:
                values[name] = found[name]
        for name, message, signal in rule.qualified:
            found = latest.get(message)
            if found is not None and signal in found:
                values[name] = found[signal]
        return values

    def valid(self) -> tuple[bool, str]:
        """Whether the object is valid, and why its rule could not be evaluated ("" if it
        could)."""
        rule = self.rule
        if rule is None:
            return True, ""
        latest = self.latest  # this object's messages only: what qualified names read
        merged: dict[str, Any] = {}
        for name in self.rule_sources:
            for message in self.names:
                found = latest.get(message)
                if found is not None and name in found:
                    merged[name] = found[name]
                    break
        if rule.qualified:
            return rule.judge(merged, latest)
        # a rule of plain names alone judges the same values (by ==) the same: judged once
        inputs = tuple(merged.items())
        judged = self.judged
        if judged is not None and judged[0] == inputs:
            return judged[1]
        verdict = rule.judge(merged)
        self.judged = (inputs, verdict)
        return verdict


class _GroupReader:
    """Turns the messages of one object group into object observations.

    Any message of an object's family makes a new observation of it, from the latest values of
    every message of the family, at the time of the newest position (the first message).
    """

    def __init__(self, group: ObjectGroup) -> None:
        self.group = group
        self.primary = group.templates[0]
        self.objects: dict[int | None, _Object] = {}
        sensor = group.sensor
        self.polar = group.range is not None
        self.angle_unit = sensor.angle_unit
        self.scale = sensor.distance_scale
        #: a sensor mounted without yaw: its lateral sign and mount (to_vehicle and velocity
        #: spelled out in evaluate); (0.0, mount) for one with a yaw
        self.unturned = (0.0 if sensor.mount.yaw_deg else sensor.lateral_sign, sensor.mount)
        #: the other groups that read the same fields of the same messages as this one (e.g.
        #: one radar's slots as detections and as tracks): each of its observations is theirs
        #: too, under their name (:func:`_reading`)
        self.aliases: list[str] = []
        #: what merging the pages of its multiplexed messages made (:mod:`bridge.world.pages`)
        self.page_stats = PageStats()

    def note(self, member: FamilyMember, message: str, values: Mapping[str, Any],
             t_ns: int) -> _Object:
        """Take one message of an object's family; returns the object."""
        obj = self.object(member.index)
        obj.latest[message] = values
        if member.template == self.primary:
            obj.position_ns = t_ns
        return obj

    def object(self, index: int | None) -> _Object:
        """Object ``index`` (made when first asked for)."""
        obj = self.objects.get(index)
        if obj is None:
            obj = self.objects[index] = _Object(self.group, index)
        return obj

    def observe(self, member: FamilyMember, message: str, values: Mapping[str, Any],
                t_ns: int) -> ObjectObservation | None:
        return self.observation(member.index, self.note(member, message, values, t_ns))

    def also(self, made: ObjectObservation, out: list[Observation]) -> None:
        """``made`` as each alias group's observation too (:attr:`aliases`), into ``out``."""
        for alias in self.aliases:
            out.append(ObjectObservation(alias, made.object_id, made.t_ns, made.x, made.y,
                                         made.valid, made.vx, made.vy, made.probability,
                                         made.object_class, made.rule_error))

    def observation(self, index: int | None, obj: _Object) -> ObjectObservation | None:
        """Object ``index`` as its latest messages describe it.

        When none of the signals it reads changed since its last observation (a standing
        target, an empty slot, a message re-sent with only its counter changed), the fields and
        the validity are those of the last observation: only the time is new."""
        t_ns = obj.position_ns
        if t_ns < 0:
            return None  # no position of this object yet
        # Values equal by == make the same observation: a field is read as value·scale + offset
        # (so -0.0 reads as 0.0), a class or id as an int, a rule compares.
        key = obj.read_key()
        if key == obj.key:
            made = obj.made
            if made is None:
                return None
            return ObjectObservation(made.group, made.object_id, t_ns, made.x, made.y,
                                     made.valid, made.vx, made.vy, made.probability,
                                     made.object_class, made.rule_error)
        obj.key = key
        made = obj.made = self.evaluate(index, obj, t_ns)
        return made

    def evaluate(self, index: int | None, obj: _Object, t_ns: int) -> ObjectObservation | None:
        """Object ``index`` at ``t_ns``, every field read and the validity rule judged."""
        latest = obj.latest
        scale = self.scale
        if self.polar:
            distance, azimuth = _read(latest, obj.range), _read(latest, obj.azimuth)
            if distance is None or azimuth is None:
                return None
            xs, ys = polar_to_cartesian(distance * scale, azimuth, self.angle_unit)
        else:
            ref = obj.x  # _read of each field, inline
            xr = ref.value(latest) if ref is not None else None
            if xr is None:
                return None
            ref = obj.y
            yr = ref.value(latest) if ref is not None else None
            if yr is None:
                return None
            xs, ys = xr * scale, yr * scale
        g = self.group
        sensor = g.sensor
        sign, mount = self.unturned
        if sign:  # to_vehicle of a sensor mounted without yaw, inline
            x, y = xs + mount.x, ys * sign + mount.y
        else:
            x, y = to_vehicle(sensor, xs, ys)
        isfinite = math.isfinite
        if not (isfinite(x) and isfinite(y)):
            return None
        ref = obj.vx
        vx_raw = ref.value(latest) if ref is not None else None
        ref = obj.vy
        vy_raw = ref.value(latest) if ref is not None else None
        if vx_raw is None and vy_raw is None:
            vx = vy = None
        elif sign:  # velocity() of a sensor mounted without yaw, inline
            vx = (vx_raw or 0.0) * scale
            vy = (vy_raw or 0.0) * scale * sign
            if vx_raw is None or not isfinite(vx):
                vx = None
            if vy_raw is None or not isfinite(vy):
                vy = None
        else:
            vx, vy = velocity(sensor, vx_raw, vy_raw, scale)
        ref = obj.id
        ident = ref.value(latest) if ref is not None else None
        ref = obj.class_signal
        raw_class = ref.value(latest) if ref is not None else None
        object_class = (g.classes.get(int(raw_class), ObjectClass.UNKNOWN)
                        if raw_class is not None else ObjectClass.UNKNOWN)
        object_id = (int(ident) if ident is not None and 0 <= ident < _ID_LIMIT
                     else (index or 0))  # an id /perception cannot carry: the slot
        valid, rule_error = obj.valid()
        ref = obj.probability
        probability = ref.value(latest) if ref is not None else None
        return ObjectObservation(g.name, object_id, t_ns, x, y, valid, vx, vy, probability,
                                 object_class, rule_error)


class _Paged:
    """A multiplexed message of an object family, for one group: its pages merged per object
    (its id; in an indexed family, its message) and cycle (:class:`PageMerger`), each merged
    cycle observed as one message."""

    __slots__ = ("ident", "member", "merger", "message", "reader")

    def __init__(self, reader: _GroupReader, member: FamilyMember, message: str) -> None:
        self.reader, self.member, self.message = reader, member, message
        group = reader.group
        pages = group.pages[message]
        obj = reader.object(member.index)
        reads = frozenset(dict(obj.reads).get(message, ()))

        def paged(*refs: Field | None) -> frozenset[str]:
            return frozenset(signal for ref in refs if ref is not None
                             for m, signal in ref.signals if m == message) & pages.paged

        rule: frozenset[str] = frozenset()
        if obj.rule is not None:
            rule = (frozenset(obj.rule_sources) | frozenset(
                signal for _, m, signal in obj.rule.qualified if m == message)) & pages.paged
        self.merger = PageMerger(pages.multiplexors, reads & pages.paged,
                                 paged(obj.x, obj.y, obj.range, obj.azimuth), rule,
                                 reader.page_stats)
        reader.page_stats.messages[member.template] = pages.multiplexors
        #: the id that tells one object's pages from another's (without an index range)
        self.ident = group.id if member.index is None else None

    def observe(self, values: Mapping[str, Any], t_ns: int, out: list[Observation]) -> None:
        key: float | None = None
        if self.ident is not None:
            key = self.ident.value({self.message: values})
            if key is None:
                return  # no object to give the page to (an id that is not finite)
        reader = self.reader
        for merged, at_ns in self.merger.take(key, values, t_ns):
            made = reader.observe(self.member, self.message, merged, at_ns)
            if made is not None:
                out.append(made)
                if reader.aliases:
                    reader.also(made, out)


def copies(a: Mapping[int, ObjectObservation], b: Mapping[int, ObjectObservation]) -> bool:
    """Whether two groups' objects (by id) are the same observations under two names: each
    field the very same value (``is``: what :meth:`_GroupReader.also` makes, and nothing that
    only compares equal, such as -0.0 and 0.0), the same times and ids."""
    if a.keys() != b.keys():
        return False
    for i, o in a.items():
        p = b[i]
        if not (o.t_ns == p.t_ns and o.x is p.x and o.y is p.y and o.vx is p.vx
                and o.vy is p.vy and o.probability is p.probability
                and o.object_class is p.object_class and o.valid is p.valid
                and o.object_id == p.object_id):
            return False
    return True


def _reading(group: ObjectGroup) -> ObjectGroup:
    """What of ``group`` its observations depend on: all but its name, lifetime and role (two
    groups equal in this observe the same objects, e.g. a radar's slots as detections and as
    tracks)."""
    return replace(group, name="", lifetime_s=0.0, role=None)


class Observer:
    """Routes decoded messages (by DBC message name) to observations, as the profile says.

    Groups that read the same fields of the same messages (:func:`_reading`) are observed once: each
    observation of the first is made again under the other's name, just after it (the order in which
    observing them apart would make them).

    An object whose computed value reads ``none`` makes no observation. An object is evaluated again
    only when a signal it reads changed (equal by ``==``); otherwise it repeats its last observation
    at the newest time. Multiplexed pages are merged per object and cycle first
    (:mod:`bridge.world.pages`). A validity rule that cannot be evaluated leaves the object out, as
    a rule that does not hold does, and says why in ``rule_error``.
    """

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self._objects: dict[str, list[tuple[_GroupReader, FamilyMember]]] = {}
        readers: list[_GroupReader] = []
        for group in profile.groups.values():
            same = next((r for r in readers if _reading(r.group) == _reading(group)), None)
            if same is not None:  # its observations are the other's, under its own name
                same.aliases.append(group.name)
            else:
                readers.append(_GroupReader(group))
        if profile.lead is not None and profile.lead.group is not None:
            readers.append(_GroupReader(replace(profile.lead.group, name=LEAD_GROUP)))
        self._readers = readers
        #: each multiplexed message of an object family: its pages merged, for each group
        self._paged: dict[str, list[_Paged]] = {}
        for reader in readers:
            for name, member in reader.group.members.items():
                if name in reader.group.pages:
                    self._paged.setdefault(name, []).append(_Paged(reader, member, name))
                else:
                    self._objects.setdefault(name, []).append((reader, member))
        #: per message: each object it is for (made here, once), the object's reader and
        #: whether it is the family's first message (its time is the object's position's)
        #: each group observed with another (:func:`_reading`) -> that group
        self.aliases = {alias: reader.group.name for reader in readers
                        for alias in reader.aliases}
        self._routes = {name: [(reader.object(member.index), reader,
                                member.template == reader.primary) for reader, member in pairs]
                        for name, pairs in self._objects.items()}
        self._lanes: dict[str, list[LaneLine]] = {}
        if profile.lanes is not None:
            for line in profile.lanes.lines.values():
                self._lanes.setdefault(line.message, []).append(line)
        #: the ego values each message is read by
        self._ego: dict[str, list[tuple[str, Field]]] = {}
        for field_name in ("speed", "yaw_rate", "steering_wheel_angle"):
            ref = getattr(profile.ego, field_name)
            if ref is not None:
                for name in ref.messages:
                    self._ego.setdefault(name, []).append((field_name, ref))
        #: the latest values of each message an ego value reads
        self._ego_latest: dict[str, Mapping[str, Any]] = {}
        #: every message name this observer uses, to skip the rest cheaply
        self._lanes_and_ego = frozenset(self._lanes) | frozenset(self._ego)
        self.messages = frozenset(self._objects) | frozenset(self._paged) | self._lanes_and_ego
        #: whether a message of objects is read by a lane line or an ego value too
        self._objects_and_more = not self._lanes_and_ego.isdisjoint(self._objects)
        #: messages of object groups without an index range: each frame may be another object
        #: (its id signal says which), so every frame counts, not only the newest of its name;
        #: and multiplexed messages of objects: each frame is another page
        self.every_frame = frozenset(
            name for reader in readers if reader.group.name != LEAD_GROUP
            for name, member in reader.group.members.items()
            if member.index is None) | frozenset(self._paged)

    def shift(self, shift_ns: int) -> None:
        """The clock stepped: the time of each object's latest position moves by ``shift_ns``,
        so an observation its companion message makes after the step is in the new timeline."""
        for reader in self._readers:
            for obj in reader.objects.values():
                if obj.position_ns >= 0:
                    obj.position_ns += shift_ns
        for paged in self._paged.values():
            for one in paged:
                one.merger.shift(shift_ns)

    def close(self) -> None:
        """The input ended: the cycles of pages still open end (counted in
        :meth:`page_stats`; not observed)."""
        for paged in self._paged.values():
            for one in paged:
                one.merger.close()

    def page_stats(self) -> dict[str, PageStats]:
        """Per group with multiplexed messages: what merging their pages made."""
        return {name: reader.page_stats for reader in self._readers
                if reader.page_stats.messages for name in (reader.group.name, *reader.aliases)}

    def watch(self, watcher: Watcher) -> None:
        """Call ``watcher`` each time an object is evaluated (its signals changed), e.g. to
        say why a group's objects never hold their rule (``tankviz profile check``). Costs
        nothing unwatched."""
        for reader in self._readers:
            evaluate = reader.evaluate

            def watched(index: int | None, obj: _Object, t_ns: int, *,
                        evaluate: Callable[..., ObjectObservation | None] = evaluate,
                        group: ObjectGroup = reader.group) -> ObjectObservation | None:
                made = evaluate(index, obj, t_ns)
                watcher(group, made, obj.rule, obj.rule_values())
                return made

            reader.evaluate = watched  # type: ignore[method-assign]

    def observe(self, message: str, values: Mapping[str, Any], t_ns: int) -> list[Observation]:
        """The observations one decoded message makes (often none, e.g. for a companion)."""
        out: list[Observation] = []
        for reader, member in self._objects.get(message, ()):
            obs = reader.observe(member, message, values, t_ns)
            if obs is not None:
                out.append(obs)
                if reader.aliases:
                    reader.also(obs, out)
        paged = self._paged.get(message)
        if paged is not None:
            for one in paged:
                one.observe(values, t_ns, out)
        self._observe_lanes_and_ego(message, values, t_ns, out)
        return out

    def observe_latest(self, latest: Mapping[str, tuple[Mapping[str, Any], int]]
                       ) -> list[Observation]:
        """The observations of several messages at once (message -> (values, time), each the
        newest of its name, in the order they came): one per object however many of its
        family's messages came, from the newest of them all. What the last of them would
        observe one by one, but for the time of an unchanged invalid observation: it is the
        last one again, whose time counts nowhere (the world only drops its object)."""
        out: list[Observation] = []
        touched: dict[_Object, _GroupReader] = {}
        routes, others, both = self._routes, self._lanes_and_ego, self._objects_and_more
        for message, (values, t_ns) in latest.items():
            found = routes.get(message)
            if found is not None:
                for obj, reader, primary in found:  # _GroupReader.note, inline
                    obj.latest[message] = values
                    if primary:
                        obj.position_ns = t_ns
                    touched[obj] = reader
                if both and message in others:
                    self._observe_lanes_and_ego(message, values, t_ns, out)
            elif message in self._paged:  # in every_frame: here only when called with it
                out += self.observe(message, values, t_ns)
            elif message in others:
                self._observe_lanes_and_ego(message, values, t_ns, out)
        for obj, reader in touched.items():  # _GroupReader.observation, inline
            t_ns = obj.position_ns
            if t_ns < 0:
                continue  # no position of this object yet
            key = obj.read_key()
            if key == obj.key:
                made = obj.made
                if made is None:
                    continue
                if made.valid:  # an invalid one is the last again: its time counts nowhere
                    made = ObjectObservation(
                        made.group, made.object_id, t_ns, made.x, made.y, True, made.vx,
                        made.vy, made.probability, made.object_class, made.rule_error)
            else:
                obj.key = key
                made = obj.made = reader.evaluate(obj.index, obj, t_ns)
                if made is None:
                    continue
            out.append(made)
            if reader.aliases:
                reader.also(made, out)
        return out

    def _observe_lanes_and_ego(self, message: str, values: Mapping[str, Any], t_ns: int,
                               out: list[Observation]) -> None:
        lines = self._lanes.get(message, ())
        latest = {message: values} if lines else {}
        for line in lines:
            c = [ref.value(latest) if ref is not None else 0.0
                 for ref in (line.c0, line.c1, line.c2, line.c3)]
            if None in c or not all(map(math.isfinite, cast("list[float]", c))):
                continue  # not observed: a non-finite value never reaches the world
            coefficients = (float(c[0] or 0.0), float(c[1] or 0.0), float(c[2] or 0.0),
                            float(c[3] or 0.0))
            valid, rule_error = (line.valid.judge(values, {message: values})
                                 if line.valid is not None else (True, ""))
            out.append(LaneObservation(line.name, t_ns, coefficients, valid, rule_error))
        refs = self._ego.get(message)
        if refs:
            ego_latest = self._ego_latest
            ego_latest[message] = values
            found = {name: ref.value(ego_latest) for name, ref in refs}
            out.append(EgoObservation(t_ns, found.get("speed"), found.get("yaw_rate"),
                                      found.get("steering_wheel_angle")))
