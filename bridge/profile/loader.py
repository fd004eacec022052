"""Reading and checking a vehicle profile: a TOML file that declares what the DBC signals of one
car mean, read into a :class:`~bridge.profile.model.Profile` and checked on load.

The format is documented in docs/profiles.md. Whatever is wrong raises
:class:`~bridge.profile.model.ProfileError` naming the file, the key, the bad name and the closest
existing names; a draft that fails while it still has ``# TODO:`` lines names the first of them.
"""

from __future__ import annotations

import codecs
import dataclasses
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from cantools.database.can.database import Database
from cantools.database.can.message import Message as DbcMessage

from bridge.profile.expr import Expression, ExpressionError, parse
from bridge.profile.model import (
    INDEX_PLACEHOLDER,
    Computed,
    EgoSpec,
    FamilyMember,
    Field,
    LaneLine,
    LaneSpec,
    LeadSpec,
    MarkRule,
    Mount,
    ObjectClass,
    ObjectGroup,
    Pages,
    Profile,
    ProfileError,
    Rule,
    Sensor,
    SensorKind,
    SignalRef,
    Vehicle,
    expand,
)
from bridge.profile.values import (
    BITRATE,
    DISTANCE,
    SECONDS,
    VEHICLE,
    ValueReader,
    closest,
    type_name,
)
from bridge.resources import data_dir
from bridge.topics import VEHICLE_FRAME

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib


#: Scene categories that are not object groups (a group gets /scene/<name>).
_RESERVED_GROUPS = {"ego", "health", "lanes", "lead", "marks", "mio"}
#: What an object group is (``[objects.GROUP] role``).
_ROLES = ("detections", "tracks")
_TOP_KEYS = {"profile", "vehicle", "buses", "sensors", "objects", "lead", "lanes", "ego",
             "marks"}
_CLASS_NAMES = {c.value: c for c in ObjectClass}
#: The mapped fields of an object (``[objects.GROUP] x = ...``), in the order they are read.
_GROUP_FIELDS = ("x", "y", "range", "azimuth", "vx", "vy", "probability", "class", "id")
#: ``{i:0Nd}`` with a width of 3 digits or more (at most 2: :data:`INDEX_PLACEHOLDER`).
_WIDE_INDEX = re.compile(r"\{i:0?(\d{3,})d\}")
_LANE_NAMES = ("left", "right", "next_left", "next_right")

#: A mapped field written as one name ("Signal", "Message.Signal", "Obj{i}_A.X"): no operator, space
#: or parenthesis. Anything else is an expression.
#: An object group's name: one segment of its topics' paths.
_GROUP_NAME = re.compile(r"[A-Za-z0-9_]+")
_ONE_NAME = re.compile(r"[^\s()+\-*/,<>=!&|]*")


def bundled_profile(name: str) -> Path | None:
    """The bundled profile called ``name`` (``ecocar``), if there is one."""
    candidate = data_dir() / f"{name}.toml"
    return candidate if "/" not in name and candidate.is_file() else None


def resolve_profile(name_or_path: str | Path) -> Path:
    """A profile path from a path or the name of a bundled profile."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    bundled = bundled_profile(str(name_or_path))
    if bundled is not None:
        return bundled
    known = sorted(p.stem for p in data_dir().glob("*.toml"))
    raise ProfileError(path, "", f"no such profile file, and no bundled profile of that name "
                       f"(bundled: {', '.join(known) or 'none'})")


def read_profile_databases(path: Path) -> dict[str, tuple[Path, ...]]:
    """The databases a profile names (``[profile] databases``), without loading anything else."""
    return _Loader(path, _read_toml(path), []).databases()


def load_profile(name_or_path: str | Path, databases: Iterable[Database], *,
                 own_databases: bool = True) -> Profile:
    """Load and check a profile against the databases its messages must come from.

    With ``own_databases=False`` its ``[profile] databases`` are set aside (not even checked to
    exist): the databases come from elsewhere (``--dbc``, or those attached to a recorded drive).
    """
    path = resolve_profile(name_or_path)
    doc = _read_toml(path)
    if not own_databases and isinstance(doc.get("profile"), dict):
        doc["profile"].pop("databases", None)
    try:
        return _Loader(path, doc, list(databases)).profile()
    except ProfileError as exc:
        raise _todo_error(path) or exc from None


def _todo_error(path: Path) -> ProfileError | None:
    """A drafted profile (``tankviz profile new``) that fails to load while ``# TODO:`` lines
    (what it needs and the draft did not find) are left: the error names the first of them."""
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return None
    todos = [(n, line.strip().lstrip("#").strip()) for n, line in enumerate(lines, 1)
             if re.match(r"\s*#\s*TODO:", line)]
    if not todos:
        return None
    (n, text), more = todos[0], [str(m) for m, _ in todos[1:]]
    return ProfileError(path, f"line {n}", text + (f" (more TODO lines: {', '.join(more)})"
                                                   if more else ""))


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        content = path.read_bytes()
        if content.startswith(codecs.BOM_UTF8):  # as editors on Windows save UTF-8
            content = content[len(codecs.BOM_UTF8):]
        doc: dict[str, Any] = tomllib.loads(content.decode("utf-8"))
        return doc
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(path, "", f"not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ProfileError(path, "", f"not valid TOML: not UTF-8 text (byte "
                           f"0x{exc.object[exc.start]:02x} at position {exc.start})") from None
    except OSError as exc:
        raise ProfileError(path, "", f"cannot read: {exc.strerror or exc}") from None


class _Unread(Exception):
    """A name an expression reads that is not a signal it can read: why, as the error of a
    validity rule says it (``rule '…' reads 'X', …``) and as that of a value."""

    def __init__(self, as_rule: str, as_value: str) -> None:
        super().__init__(as_value)
        self.as_rule = as_rule
        self.as_value = as_value


@dataclasses.dataclass(frozen=True)
class _Family:
    """The messages of an object group: its templates, the template and object index of each
    message, and the messages of each object (index), in template order."""

    templates: tuple[str, ...]
    members: dict[str, FamilyMember]
    instances: dict[int | None, list[DbcMessage]]


class _Loader(ValueReader):
    """Reads one parsed TOML document into a :class:`Profile`, checking as it goes."""

    def __init__(self, path: Path, doc: dict[str, Any], databases: list[Database]) -> None:
        super().__init__(path)
        self.doc = doc
        self.messages: dict[str, DbcMessage] = {}
        #: every expression parsed so far, by text
        self.parsed: dict[str, Expression] = {}
        for db in databases:
            for m in db.messages:
                self.messages.setdefault(m.name, m)

    def message(self, name: str, key: str) -> DbcMessage:
        m = self.messages.get(name)
        if m is None:
            raise self.fail(key, f"no message {name!r} in the databases"
                            f"{closest(name, self.messages)}")
        return m

    def rule(self, table: Mapping[str, Any], key: str, messages: Sequence[DbcMessage],
             index: int | None = None) -> Rule | None:
        """The validity rule, ``{i}`` in it replaced by ``index``; every name it reads checked
        against ``messages`` (plain names must be in exactly one of them)."""
        text = table.get("valid")
        if text is None:
            return None
        if not isinstance(text, str):
            raise self.fail(f"{key}.valid", f"expected a rule (string), got {type_name(text)}")
        if index is not None:
            text = expand(text, index)
        expression = self.parse(text, f"{key}.valid")
        reads = self.resolve(expression, f"{key}.valid", messages, rule=True)
        return Rule(expression, tuple(read for read in reads if "." in read[0]))

    def parse(self, text: str, key: str) -> Expression:
        """``text`` parsed (once per text: the objects of a family share it)."""
        expression = self.parsed.get(text)
        if expression is None:
            try:
                expression = self.parsed[text] = parse(text)
            except ExpressionError as exc:
                raise self.fail(key, str(exc)) from None
        return expression

    def resolve(self, expression: Expression, key: str, messages: Sequence[DbcMessage] | None,
                *, rule: bool = False,
                anywhere: bool = False) -> tuple[tuple[str, str, str], ...]:
        """(name, message, signal) for every name the expression reads: a plain name must be a
        signal of exactly one of ``messages``, ``Message.Signal`` name one of them; without
        ``messages`` (an ego value) every name is ``Message.Signal`` of any message (or, with
        ``anywhere``, a plain name a signal of exactly one message of the databases). The errors
        of a validity rule (``rule``) name what it reads; those of a value, the column."""
        text = expression.text
        columns = expression.columns
        reads = []
        names = sorted(expression.names) if rule else sorted(
            expression.names, key=lambda n: (columns.get(n, 0), n))
        for name in names:
            try:
                message, signal = self.read(name, messages, anywhere)
            except _Unread as why:
                if rule:
                    raise self.fail(key, f"rule {text!r} reads {name!r}, {why.as_rule}") from None
                raise self.fail(key, str(ExpressionError(text, columns.get(name, 1),
                                                         why.as_value))) from None
            reads.append((name, message, signal))
        return tuple(reads)

    def read(self, name: str, messages: Sequence[DbcMessage] | None,
             anywhere: bool = False) -> tuple[str, str]:
        """The message and signal a name of an expression reads (:meth:`resolve`)."""
        where = ", ".join(m.name for m in messages) if messages is not None else "the databases"
        message_name, _, signal_name = name.rpartition(".")
        if messages is None:
            if not message_name and not anywhere:
                raise _Unread("", f"write Message.Signal for {name!r}: ego values may come from "
                              "any message")
            if message_name and message_name not in self.messages:
                raise _Unread("", f"no message {message_name!r} in the databases"
                              f"{closest(message_name, self.messages)}")
            candidates = ([self.messages[message_name]] if message_name
                          else list(self.messages.values()))
        elif message_name:
            candidates = [m for m in messages if m.name == message_name]
            if not candidates:
                raise _Unread(f"but {message_name!r} is not one of {where}",
                              f"message {message_name!r} is not one of {where}"
                              f"{closest(message_name, [m.name for m in messages])}")
        else:
            candidates = list(messages)
        owners = [m for m in candidates if any(s.name == signal_name for s in m.signals)]
        if not owners:
            near = closest(signal_name, {s.name for m in candidates for s in m.signals})
            named = message_name or where
            raise _Unread(f"which is not a signal of {named}{near}",
                          f"no signal {signal_name!r} in {named}{near}")
        if len(owners) > 1:
            both = f"{owners[0].name} and {owners[1].name}: write Message.Signal"
            raise _Unread(f"which is in {both}", f"signal {signal_name!r} is in {both}")
        return owners[0].name, signal_name

    def is_computed(self, value: Any, key: str) -> bool:
        """Whether a mapped field is an expression: ``{ value = ... }``, or a string that is more
        than one name."""
        if isinstance(value, dict):
            if "value" in value and "signal" in value:
                raise self.fail(key, "give either signal or value, not both")
            return "value" in value
        return isinstance(value, str) and _ONE_NAME.fullmatch(value) is None

    def computed(self, value: Any, key: str, messages: Sequence[DbcMessage] | None,
                 index: int | None = None) -> Computed:
        """A value computed by an expression: "expr" or {value = "expr", scale =, offset =};
        ``{i}`` in it replaced by ``index``; its names checked against ``messages`` (any message,
        as Message.Signal, when None)."""
        value, key, scale, offset = self.converted(value, key, "value")
        if not isinstance(value, str):
            raise self.fail(key, f"expected an expression (string), got {type_name(value)}")
        expression = self.parse(value if index is None else expand(value, index), key)
        return Computed(expression, self.resolve(expression, key, messages), scale, offset)

    def converted(self, value: Any, key: str, name: str) -> tuple[Any, str, float, float]:
        """A mapped field's ``name`` (signal or value), its key, scale and offset: ``{name =
        ..., scale = .., offset = ..}``, or the field itself converting nothing."""
        if not isinstance(value, dict):
            return value, key, 1.0, 0.0
        spec = self.table(value, key, {name, "scale", "offset"}, required=[name])
        scale = self.number(spec, key, "scale", 1.0)
        offset = self.number(spec, key, "offset", 0.0)
        return spec[name], f"{key}.{name}", scale, offset

    def mapped(self, value: Any, key: str, messages: Sequence[DbcMessage]) -> Field:
        """A mapped field: one signal (:meth:`signal`) or a value :meth:`computed` by an
        expression over ``messages``."""
        if self.is_computed(value, key):
            return self.computed(value, key, messages)
        return self.signal(value, key, messages)

    def signal(self, value: Any, key: str, messages: Sequence[DbcMessage]) -> SignalRef:
        """A signal reference: "Signal", "Message.Signal" or {signal=..., scale=, offset=}."""
        value, key, scale, offset = self.converted(value, key, "signal")
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"expected a signal name, got {type_name(value)}")
        message_name, _, signal_name = value.rpartition(".")
        candidates = list(messages)
        if message_name:
            candidates = [m for m in messages if m.name == message_name]
            if not candidates:
                names = [m.name for m in messages]
                raise self.fail(key, f"message {message_name!r} is not one of "
                                f"{', '.join(names)}{closest(message_name, names)}")
        owners = [m for m in candidates if any(s.name == signal_name for s in m.signals)]
        if not owners:
            known = {s.name for m in candidates for s in m.signals}
            where = ", ".join(m.name for m in candidates)
            raise self.fail(key, f"no signal {signal_name!r} in {where}"
                            f"{closest(signal_name, known)}")
        if len(owners) > 1:
            raise self.fail(key, f"signal {signal_name!r} is in {owners[0].name} and "
                            f"{owners[1].name}: write Message.Signal")
        return SignalRef(owners[0].name, signal_name, scale, offset)

    # sections

    def databases(self) -> dict[str, tuple[Path, ...]]:
        section = self.table(self.doc.get("profile", {}), "profile",
                             {"name", "description", "databases"})
        value = section.get("databases", [])
        if value == [] or value == {}:
            return {}
        by_bus: dict[str, Any] = value if isinstance(value, dict) else {"*": value}
        out: dict[str, tuple[Path, ...]] = {}
        for bus, files in by_bus.items():
            key = "profile.databases" + (f".{bus}" if isinstance(value, dict) else "")
            if isinstance(files, str):
                files = [files]
            if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
                raise self.fail(key, f"expected a list of database files, got {type_name(files)}")
            paths = []
            for f in files:
                candidate = (self.path.parent / f)
                if not candidate.is_file():
                    candidate = data_dir() / f
                if not candidate.is_file():
                    raise self.fail(key, f"no database file {f!r} beside the profile or bundled")
                paths.append(candidate)
            out[bus] = tuple(paths)
        return out

    def profile(self) -> Profile:
        doc = self.table(self.doc, "", _TOP_KEYS)
        meta = self.table(doc.get("profile", {}), "profile", {"name", "description", "databases"})
        name = self.string(meta, "profile", "name", self.path.stem)
        self.string(meta, "profile", "description", "")
        vehicle = self.vehicle(doc.get("vehicle", {}))
        sensors_doc = self.section(doc.get("sensors", {}), "sensors")
        if VEHICLE_FRAME in sensors_doc:
            raise self.fail(f"sensors.{VEHICLE_FRAME}", f"'{VEHICLE_FRAME}' is the vehicle frame; "
                            "name the sensor otherwise")
        sensors = {n: self.sensor(n, v) for n, v in sensors_doc.items()}
        objects_doc = self.section(doc.get("objects", {}), "objects")
        for n in objects_doc:
            if not _GROUP_NAME.fullmatch(n):
                raise self.fail(f"objects.{n}", f"{n!r} is not a name for its topics "
                                "(/scene/<name>, /perception/<name>): letters, digits and _ "
                                "only")
            if n in _RESERVED_GROUPS:
                raise self.fail(f"objects.{n}", f"'{n}' is taken by /scene/{n}; not one of "
                                f"{', '.join(sorted(_RESERVED_GROUPS))}")
        groups = {n: self.group(f"objects.{n}", n, v, sensors) for n, v in objects_doc.items()}
        lead = self.lead(doc["lead"], sensors) if "lead" in doc else None
        if lead is not None and lead.source == "tracks" and not any(
                g.role == "tracks" for g in groups.values()):
            raise self.fail("lead.source", "'tracks' but no object group has role = \"tracks\" "
                            "(a fusion sensor's groups, or role = \"tracks\" on a group): "
                            "there would never be a lead")
        lanes = self.lanes(doc["lanes"], sensors) if "lanes" in doc else None
        ego = self.ego(doc.get("ego", {}))
        if lanes is not None and not lanes.lines and ego.steering_wheel_angle is None:
            raise self.fail("lanes", "no camera lines and no ego.steering_wheel_angle: nothing "
                            "to draw the lanes from")
        bitrates, data_bitrates = self.buses(doc.get("buses", {}))
        return Profile(name=name, path=self.path, vehicle=vehicle, sensors=sensors,
                       groups=groups, lead=lead, lanes=lanes, ego=ego,
                       databases=self.databases(), bitrates=bitrates,
                       data_bitrates=data_bitrates, marks=self.marks(doc.get("marks", [])))

    def marks(self, value: Any) -> tuple[MarkRule, ...]:
        """``[marks]``, one rule, or ``[[marks]]``, several (keys ``marks[1]``, ``marks[2]``…)."""
        if isinstance(value, list):
            return tuple(self.mark(v, f"marks[{n}]") for n, v in enumerate(value, 1))
        return (self.mark(value, "marks"),)

    def mark(self, value: Any, key: str) -> MarkRule:
        """A rule over signals of any message (plain names of one message only), that marks the
        drive each time it becomes true; its text (default: the rule) and category."""
        t = self.table(value, key, {"when", "text", "category"}, required=["when"])
        when = self.string(t, key, "when")
        expression = self.parse(when, f"{key}.when")
        if not expression.names:
            raise self.fail(f"{key}.when", f"rule {when!r} reads no signal: it would never mark")
        return MarkRule(expression, self.resolve(expression, f"{key}.when", None, anywhere=True),
                        self.string(t, key, "text", when), self.string(t, key, "category", ""))

    def buses(self, value: Any) -> tuple[dict[str, int], dict[str, int]]:
        """``[buses.NAME] bitrate = …, data_bitrate = …``: for the bus load in /health."""
        bitrates: dict[str, int] = {}
        data_bitrates: dict[str, int] = {}
        for bus, spec in self.section(value, "buses").items():
            key = f"buses.{bus}"
            t = self.table(spec, key, {"bitrate", "data_bitrate"}, required=["bitrate"])
            bitrates[bus] = round(self.number(t, key, "bitrate", positive=True, **BITRATE))
            if "data_bitrate" in t:
                data_bitrates[bus] = round(self.number(t, key, "data_bitrate", positive=True,
                                                          **BITRATE))
        return bitrates, data_bitrates

    def vehicle(self, value: Any) -> Vehicle:
        t = self.table(value, "vehicle", {"wheelbase", "steering_ratio", "length", "width",
                                          "height", "origin", "rear_overhang"})
        d = Vehicle()
        length = self.number(t, "vehicle", "length", d.length_m, positive=True, **VEHICLE)
        origin = self.string(t, "vehicle", "origin", d.origin, choices=Vehicle.ORIGINS)
        overhang = self.number(t, "vehicle", "rear_overhang", d.rear_overhang_m,
                               non_negative=True, **VEHICLE)
        if "rear_overhang" in t and origin != "rear_axle":
            raise self.fail("vehicle.rear_overhang",
                            f'only for origin = "rear_axle", the origin is {origin!r}')
        if origin == "rear_axle" and overhang >= length:
            raise self.fail("vehicle.rear_overhang",
                            f"must be less than the length {length}, got {overhang}")
        return Vehicle(
            wheelbase_m=self.number(t, "vehicle", "wheelbase", d.wheelbase_m, positive=True,
                                    **VEHICLE),
            steering_ratio=self.number(t, "vehicle", "steering_ratio", d.steering_ratio,
                                       positive=True),
            length_m=length,
            width_m=self.number(t, "vehicle", "width", d.width_m, positive=True, **VEHICLE),
            height_m=self.number(t, "vehicle", "height", d.height_m, positive=True, **VEHICLE),
            origin=origin,
            rear_overhang_m=overhang,
        )

    def sensor(self, name: str, value: Any) -> Sensor:
        key = f"sensors.{name}"
        t = self.table(value, key, {"kind", "mount", "lateral", "coordinates", "angle_unit",
                                    "distance_scale", "fov"}, required=["kind"])
        kind = SensorKind(self.string(t, key, "kind", choices=[k.value for k in SensorKind]))
        mount_doc = self.table(t.get("mount", {}), f"{key}.mount", {"x", "y", "z", "yaw"})
        mount = Mount(*(self.number(mount_doc, f"{key}.mount", axis, 0.0,
                                    **(VEHICLE if axis != "yaw" else {}))
                        for axis in ("x", "y", "z", "yaw")))
        fov_doc = self.table(t.get("fov", {}), f"{key}.fov", {"range", "azimuth"})
        fov_range = (self.number(fov_doc, f"{key}.fov", "range", positive=True, **DISTANCE)
                     if "range" in fov_doc else None)
        fov_azimuth = (self.number(fov_doc, f"{key}.fov", "azimuth", positive=True)
                       if "azimuth" in fov_doc else None)
        if fov_azimuth is not None and fov_azimuth > 180:
            raise self.fail(f"{key}.fov.azimuth",
                            f"is a half angle: at most 180, got {fov_azimuth}")
        return Sensor(
            name=name, kind=kind, mount=mount,
            lateral=self.string(t, key, "lateral", "left", ["left", "right"]),
            coordinates=self.string(t, key, "coordinates", "cartesian", ["cartesian", "polar"]),
            angle_unit=self.string(t, key, "angle_unit", "deg", ["deg", "rad"]),
            distance_scale=self.number(t, key, "distance_scale", 1.0, positive=True),
            fov_range=fov_range, fov_azimuth_deg=fov_azimuth,
        )

    def sensor_of(self, t: Mapping[str, Any], key: str, sensors: Mapping[str, Sensor]) -> Sensor:
        name = self.string(t, key, "sensor")
        if name not in sensors:
            raise self.fail(f"{key}.sensor", f"no sensor {name!r} in [sensors]"
                            f"{closest(name, sensors, or_all=True)}")
        return sensors[name]

    def group(self, key: str, name: str, value: Any, sensors: Mapping[str, Sensor],
              *, lifetime: float = 0.1) -> ObjectGroup:
        """An object group (``[objects.NAME]``, or ``[lead]`` without a role) and its family."""
        roles = {"role"} if key.startswith("objects.") else set()  # not on [lead]
        t = self.table(value, key, {"sensor", "messages", "index", "classes", "valid",
                                    "lifetime", *_GROUP_FIELDS} | roles,
                       required=["sensor", "messages"])
        sensor = self.sensor_of(t, key, sensors)
        role = self.role(t, key, sensor) if roles else None
        family = self.family(t, key, self.templates(t, key))
        self.coordinates(t, key, sensor)
        classes = self.classes(t, key)
        rules = self.rules(t, key, family)
        f = {field: self.family_field(t, key, field, family) for field in _GROUP_FIELDS}
        pages = self.pages(key, family, f["id"])
        return ObjectGroup(
            name=name, sensor=sensor, templates=family.templates, members=family.members,
            x=f["x"], y=f["y"], range=f["range"], azimuth=f["azimuth"], vx=f["vx"], vy=f["vy"],
            probability=f["probability"], class_signal=f["class"], classes=classes, id=f["id"],
            valid=rules,
            lifetime_s=self.number(t, key, "lifetime", lifetime, non_negative=True, **SECONDS),
            role=role, pages=pages,
        )

    def pages(self, key: str, family: _Family, ident: Field | None) -> dict[str, Pages]:
        """The multiplexed messages of the family and their pages. Without an index range the
        id tells the pages of one object from another's: it must be in every page."""
        pages: dict[str, Pages] = {}
        for messages in family.instances.values():
            for m in messages:
                if not m.is_multiplexed():
                    continue
                pages[m.name] = Pages(
                    tuple(s.name for s in m.signals if s.is_multiplexer),
                    frozenset(s.name for s in m.signals if s.multiplexer_ids is not None))
                if ident is None or None not in family.instances:
                    continue
                for message, name in ident.signals:
                    s = m.get_signal_by_name(name) if message == m.name else None
                    if s is not None and s.multiplexer_ids is not None:
                        which = ", ".join(map(str, s.multiplexer_ids))
                        raise self.fail(f"{key}.id", f"{name} is only in page {which} of "
                                        f"{m.name} (multiplexor {s.multiplexer_signal}): a "
                                        "page without it cannot be told which object it is; "
                                        "the id must be in every page")
        return pages

    def templates(self, t: Mapping[str, Any], key: str) -> tuple[str, ...]:
        """``messages``: one message name or several, each once (templates with {i})."""
        templates = t["messages"]
        if isinstance(templates, str):
            templates = [templates]
        if (not isinstance(templates, list) or not templates
                or not all(isinstance(m, str) and m for m in templates)):
            raise self.fail(f"{key}.messages", "expected a non-empty list of message names "
                            "(templates with {i} for an indexed family)")
        for n, template in enumerate(templates):
            if template in templates[:n]:
                raise self.fail(f"{key}.messages", f"{template!r} is named twice")
        return tuple(templates)

    def family(self, t: Mapping[str, Any], key: str, templates: tuple[str, ...]) -> _Family:
        """The messages of every object: each template's for every index of ``index``."""
        if "index" not in t:
            return self.single(t, key, templates)
        first, last = self.index(t, key)
        family = _Family(templates, {}, {})
        for template in templates:
            wide = _WIDE_INDEX.search(template)
            if wide:
                raise self.fail(f"{key}.messages", f"{template!r}: the width of {{i:0Nd}} is "
                                f"at most 2 digits, got {wide.group(1)}")
            if not INDEX_PLACEHOLDER.search(template):
                raise self.fail(f"{key}.messages", f"{template!r} has no {{i}} for the index")
            for i in range(first, last + 1):
                m = self.message(expand(template, i), f"{key}.messages")
                family.members[m.name] = FamilyMember(template, i)
                family.instances.setdefault(i, []).append(m)
        return family

    def index(self, t: Mapping[str, Any], key: str) -> tuple[int, int]:
        """``index``: the first and last object indices of a family."""
        index = t["index"]
        if (not isinstance(index, list) or len(index) != 2
                or not all(isinstance(i, int) and not isinstance(i, bool) for i in index)):
            raise self.fail(f"{key}.index", "expected [first, last] object indices, e.g. "
                            "[0, 31]")
        first, last = index
        if first < 0:
            raise self.fail(f"{key}.index", f"indices cannot be negative, got "
                            f"[{first}, {last}]")
        if last < first:
            raise self.fail(f"{key}.index", f"empty family: [{first}, {last}]")
        return first, last

    def single(self, t: Mapping[str, Any], key: str, templates: tuple[str, ...]) -> _Family:
        """Without ``index``: one message carrying one object per frame, ``id`` says which."""
        if "id" not in t:
            raise self.fail(key, "without 'index' each frame carries one object: name the "
                            "signal that says which with 'id'")
        if len(templates) != 1:
            raise self.fail(f"{key}.messages", "without 'index' the family is one message "
                            "carrying one object per frame")
        if INDEX_PLACEHOLDER.search(templates[0]):
            raise self.fail(f"{key}.messages", f"{templates[0]!r} has {{i}} but there is no "
                            "'index' range")
        m = self.message(templates[0], f"{key}.messages")
        return _Family(templates, {m.name: FamilyMember(templates[0], None)}, {None: [m]})

    def coordinates(self, t: Mapping[str, Any], key: str, sensor: Sensor) -> None:
        """The position fields are those of the sensor's coordinates: x and y, or polar."""
        if sensor.coordinates == "polar":
            if "x" in t or "y" in t:
                raise self.fail(key, f"sensor {sensor.name!r} is polar: use range and azimuth, "
                                "not x and y")
            if "range" not in t or "azimuth" not in t:
                raise self.fail(key, f"sensor {sensor.name!r} is polar: name 'range' and "
                                "'azimuth'")
        else:
            if "range" in t or "azimuth" in t:
                raise self.fail(key, f"sensor {sensor.name!r} is cartesian: use x and y (or set "
                                "coordinates = \"polar\" on the sensor)")
            if "x" not in t or "y" not in t:
                raise self.fail(key, f"sensor {sensor.name!r} is cartesian: name 'x' and 'y'")

    def classes(self, t: Mapping[str, Any], key: str) -> dict[int, ObjectClass]:
        """``classes``: the object class of each raw value of the ``class`` signal."""
        classes: dict[int, ObjectClass] = {}
        if "classes" not in t:
            return classes
        if "class" not in t:
            raise self.fail(f"{key}.classes", "given without a 'class' signal")
        for raw, label in self.section(t["classes"], f"{key}.classes").items():
            if not isinstance(label, str):
                raise self.fail(f"{key}.classes.{raw}", f"expected a class name (string), "
                                f"got {type_name(label)}")
            if not re.fullmatch(r"-?\d+", raw):
                raise self.fail(f"{key}.classes.{raw}", "keys are the signal's raw values "
                                "(integers)")
            if label not in _CLASS_NAMES:
                raise self.fail(f"{key}.classes.{raw}", f"unknown class {label!r}; one of "
                                f"{', '.join(_CLASS_NAMES)}")
            classes[int(raw)] = _CLASS_NAMES[label]
        return classes

    def rules(self, t: Mapping[str, Any], key: str, family: _Family) -> dict[int | None, Rule]:
        """The validity rule of each object: a rule may name signals with {i}."""
        rules: dict[int | None, Rule] = {}
        for index, messages in family.instances.items():
            rule = self.rule(t, key, messages, index)
            if rule is not None:
                rules[index] = rule
        return rules

    def family_field(self, t: Mapping[str, Any], key: str, name: str,
                     family: _Family) -> Field | None:
        """Field ``name`` of every object of the family ({i} in names is each object's index)."""
        if name not in t:
            return None
        value, key = t[name], f"{key}.{name}"
        if self.is_computed(value, key):
            each = {i: self.computed(value, key, messages, i)
                    for i, messages in family.instances.items()}
            first = next(iter(each.values()))
            return dataclasses.replace(
                first, objects={i: c for i, c in each.items() if i is not None})
        text = value.get("signal") if isinstance(value, dict) else value
        found: SignalRef | None = None
        for i, messages in family.instances.items():
            filled = value
            if i is not None and isinstance(value, str):
                filled = expand(value, i)
            elif i is not None and isinstance(value, dict) and isinstance(text, str):
                filled = {**value, "signal": expand(text, i)}
            r = self.signal(filled, key, messages)
            found = found or r
        assert found is not None and isinstance(text, str)
        # Kept as templates: each object reads its own message and signal.
        return SignalRef(family.members[found.message].template, text.rpartition(".")[2],
                         found.scale, found.offset)

    def role(self, t: Mapping[str, Any], key: str, sensor: Sensor) -> str:
        """``role``: detections or tracks; by default tracks on a fusion sensor."""
        default = "tracks" if sensor.kind is SensorKind.FUSION else "detections"
        role = self.string(t, key, "role", default)
        if role not in _ROLES:
            raise self.fail(f"{key}.role", f"must be one of {', '.join(_ROLES)}, got {role!r}"
                            f"{closest(role, _ROLES)}")
        return role

    def lead(self, value: Any, sensors: Mapping[str, Sensor]) -> LeadSpec:
        key = "lead"
        if isinstance(value, dict) and "source" in value:
            self.string(value, key, "source", choices=["message", "tracks"])
        if isinstance(value, dict) and value.get("source") == "tracks":
            t = self.table(value, key, {"source", "lifetime"})
            return LeadSpec(source="tracks", lifetime_s=self.number(
                t, key, "lifetime", 0.3, **SECONDS, non_negative=True))
        if isinstance(value, dict):
            value = {k: v for k, v in value.items() if k != "source"}
        group = self.group(key, "lead", value, sensors, lifetime=0.3)
        return LeadSpec(source="message", group=group, lifetime_s=group.lifetime_s)

    def lanes(self, value: Any, sensors: Mapping[str, Sensor]) -> LaneSpec:
        key = "lanes"
        # No camera lines at all: a car without a lane camera, lanes from the steering angle only.
        camera = isinstance(value, dict) and any(name in value for name in _LANE_NAMES)
        t = self.table(value, key, {"sensor", "stale_after", "length", "fallback", *_LANE_NAMES},
                       required=["sensor"] if camera else [])
        if not camera and "sensor" in t:
            raise self.fail(f"{key}.sensor", f"{t['sensor']!r} but there are no camera lines "
                            "([lanes.left], [lanes.right]): lanes from the steering angle need "
                            "no sensor")
        sensor = self.sensor_of(t, key, sensors) if camera else None
        lines = {name: self.lane_line(name, t[name]) for name in _LANE_NAMES if name in t}
        if lines and ("left" not in lines or "right" not in lines):
            named: list[str] = [n for n in ("left", "right") if n in lines] or list(lines)
            given = ", ".join(f"[lanes.{n}]" for n in named)
            missing = " and ".join(f"[lanes.{n}]" for n in ("left", "right") if n not in lines)
            raise self.fail(key, f"{given} need{'s' if len(named) == 1 else ''} {missing} too; "
                            "or no camera lines at all for lanes from the steering angle only")
        fallback = self.table(t.get("fallback", {}), f"{key}.fallback", {"left", "right"})
        return LaneSpec(
            sensor=sensor, lines=lines,
            stale_after_s=self.number(t, key, "stale_after", 0.5, positive=True, **SECONDS),
            length_m=self.number(t, key, "length", 100.0, positive=True, **DISTANCE),
            fallback_left_m=self.number(fallback, f"{key}.fallback", "left", 1.8, **VEHICLE),
            fallback_right_m=self.number(fallback, f"{key}.fallback", "right", -1.8, **VEHICLE),
        )

    def lane_line(self, name: str, value: Any) -> LaneLine:
        """``[lanes.NAME]``: a camera line's coefficients, read from one message."""
        key = f"lanes.{name}"
        t = self.table(value, key, {"message", "c0", "c1", "c2", "c3", "valid"},
                       required=["message", "c0"])
        message = self.message(self.string(t, key, "message"), f"{key}.message")
        c0, c1, c2, c3 = (self.mapped(t[c], f"{key}.{c}", [message]) if c in t else None
                          for c in ("c0", "c1", "c2", "c3"))
        assert c0 is not None
        return LaneLine(name=name, message=message.name, c0=c0, c1=c1, c2=c2, c3=c3,
                        valid=self.rule(t, key, [message]))

    def ego(self, value: Any) -> EgoSpec:
        t = self.table(value, "ego", {"speed", "yaw_rate", "steering_wheel_angle"})
        return EgoSpec(speed=self.ego_field(t, "speed"), yaw_rate=self.ego_field(t, "yaw_rate"),
                       steering_wheel_angle=self.ego_field(t, "steering_wheel_angle"))

    def ego_field(self, t: Mapping[str, Any], name: str) -> Field | None:
        """An ego value: ``Message.Signal`` of any message, or computed from several."""
        if name not in t:
            return None
        raw, key = t[name], f"ego.{name}"
        if self.is_computed(raw, key):
            return self.computed(raw, key, None)
        text = raw
        if isinstance(raw, dict):
            text = self.table(raw, key, {"signal", "scale", "offset"},
                              required=["signal"])["signal"]
            key = f"{key}.signal"
        if not isinstance(text, str):
            raise self.fail(key, f"expected Message.Signal, got {type_name(text)}")
        message_name, _, signal_name = text.rpartition(".")
        if not message_name or not signal_name:
            raise self.fail(key, f"write Message.Signal, got {text!r}")
        return self.signal(raw, f"ego.{name}", [self.message(message_name, key)])
