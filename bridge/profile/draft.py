"""A starting profile drafted from the databases alone: what ``tankviz profile new`` writes.

:func:`draft_profile` is a pure function from databases to commented TOML text; every guess says
on its line why (``# guessed from the name LatDist and unit m``), and what could not be found is a
``# TODO: …`` line when the profile needs it (the loader then names that line) and ``# TODO
(optional): …`` otherwise.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from cantools.database.can.database import Database
from cantools.database.can.message import Message
from cantools.database.can.signal import Signal

from bridge.profile.ego import (
    WHEEL,
    fraction,
    lane_messages,
    pick_speed,
    pick_steering,
    pick_yaw_rate,
    wheel_mean,
)
from bridge.profile.families import expand, find_families, group_families
from bridge.profile.guess import (
    ANGLE,
    LAT,
    LENGTH,
    LONG,
    TODO,
    TODO_OPTIONAL,
    Candidate,
    classes_of,
    guessed_from,
    pick_class,
    pick_id,
    pick_probability,
    pick_unaxed_velocity,
    pick_validity,
    pick_velocity,
    position,
    tokens,
    unit_of,
)
from bridge.profile.plan import Plan, object_groups, plan_sensors

__all__ = ["BITRATE", "CAR", "TODO", "TODO_OPTIONAL", "draft_profile", "find_families",
           "group_families"]

#: The car drafted where the databases cannot say: a typical passenger car's numbers, each line a
#: ``# TODO (optional)`` saying what it is used for. Origin on the rear axle.
CAR = {"length": 4.5, "width": 1.8, "height": 1.5, "rear_overhang": 1.0, "wheelbase": 2.7,
       "steering_ratio": 15.0}
#: The bitrate drafted for a bus whose databases give none: the usual one of a car's CAN bus.
BITRATE = 500_000


@dataclass
class _Writer:
    lines: list[str] = field(default_factory=list)

    def add(self, text: str = "") -> None:
        self.lines.append(text)

    def key(self, key: str, value: str, comment: str = "") -> None:
        self.lines.append(f"{key} = {value}" + (f"  # {comment}" if comment else ""))


def _q(text: str) -> str:
    return json.dumps(text)


def _names(signals: Sequence[tuple[str, Signal]]) -> str:
    names = [n for n, _ in signals]
    return ", ".join(names[:12]) + (f", … ({len(names)} in all)" if len(names) > 12 else "")


def _bare(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _q(key)


def draft_profile(databases: Sequence[tuple[str, Database]], *, name: str = "car",
                  buses: Mapping[str, Sequence[str]] | None = None) -> str:
    """A commented starting profile for the messages of ``databases`` ((path as written in the
    profile's ``databases``, database) pairs), as TOML text. ``buses`` gives the buses the databases
    are for (bus, or "*" for every bus -> paths): ``databases`` is then a table per bus and every
    bus gets a bitrate; without it, ``databases`` is one list for every bus.

    It has ``[sensors]`` and ``[objects]`` per group of companion families, ``[lead]`` from the
    tracks, the sensors' placement and lateral sign (from the DBC's comment where it says, else
    ``lateral = "left"`` marked unknown), a typical car's ``[vehicle]``, the ego signals converted
    to SI, and steering-only ``[lanes]``.
    """
    messages = [(source, m) for source, db in databases for m in db.messages]
    families = find_families(messages)
    in_family = {expand(f.template, i) for f in families for i in range(f.first, f.last + 1)}
    ego_messages = [m for _, m in messages if m.name not in in_family]
    ego_signals = [(f"{m.name}.{s.name}", s) for m in ego_messages for s in m.signals]
    steering = pick_steering(ego_signals)
    w = _Writer()
    sources = [source for source, _ in databases]
    w.add(f"# Starting profile drafted by `tankviz profile new` from {', '.join(sources)}.")
    w.add("# Every mapping below is a guess from signal names and units: each says why. Lines")
    w.add("# '# TODO:' name what the profile needs and was not found (it does not load until they")
    w.add("# are done); '# TODO (optional):' what is missing or unsure. Check it with")
    w.add(f"#   tankviz profile check {name}.toml DRIVE   (docs/profiles.md)")
    w.add()
    w.add("[profile]")
    w.key("name", _q(name))
    w.key("description", _q(f"drafted from {', '.join(sources)}"))
    per_bus = {bus: list(paths) for bus, paths in (buses or {}).items() if paths}
    if per_bus and set(per_bus) != {"*"}:
        w.key("databases", "{ " + ", ".join(
            f"{_bare(bus)} = [{', '.join(_q(p) for p in paths)}]"
            for bus, paths in sorted(per_bus.items())) + " }",
              "used when no --dbc is given: per bus" + (
                  ' ("*": every bus)' if "*" in per_bus else ""))
    else:
        w.key("databases", "[" + ", ".join(_q(s) for s in sources) + "]",
              "used when no --dbc is given")
    w.add()
    for bus, paths in sorted(per_bus.items()):
        if bus != "*":
            _write_bus(w, bus, [db for source, db in databases if source in paths])
    _write_vehicle(w, steering is not None)

    object_like, others = object_groups(families)
    if not object_like:
        w.add(f"{TODO_OPTIONAL} no family of numbered messages with positions found: write "
              "[sensors.NAME] and [objects.GROUP] by hand (docs/profiles.md)")
        w.add()
    plans = plan_sensors(object_like)
    for plan in plans:
        _write_sensor(w, plan, name)
        for n, (gname, role) in enumerate(plan.names):
            _write_objects(w, plan, gname, role, notes=n == 0)
    if others:
        w.add("# Numbered message families that do not look like objects (no position signals):")
        for f in others:
            w.add(f"#   {f.template} [{f.first}..{f.last}]: {_names(f.signals)}")
        w.add()
    tracks = [gname for plan in plans for gname, role in plan.names if role == "tracks"]
    if tracks:
        w.add("# The lead vehicle: no message gives one, so it is chosen from the tracks "
              f"({', '.join(f'objects.{t}' for t in tracks)}):")
        w.add("# the closest valid one inside the ego lane.")
        w.add("[lead]")
        w.key("source", _q("tracks"))
        w.add()
    _write_ego(w, ego_signals, ego_messages, steering)
    return "\n".join(w.lines).rstrip() + "\n"


def _write_bus(w: _Writer, bus: str, dbs: Sequence[Database]) -> None:
    rates = sorted({b.baudrate for db in dbs for b in db.buses if b.baudrate})
    w.add(f"[buses.{_bare(bus)}]")
    if len(rates) == 1:
        w.key("bitrate", str(rates[0]), "bit/s, the database's own: for the bus load in /health")
    else:
        w.key("bitrate", str(BITRATE), "TODO (optional): bit/s, the usual rate of a car's CAN "
              "bus (the database gives none): for the bus load in /health")
    w.add()


def _write_vehicle(w: _Writer, steering: bool) -> None:
    w.add("# The car: a typical one's numbers, not yours (measure them). The ego box is drawn from")
    w.add("# its size and origin, and a forward radar is placed at its front from them.")
    w.add("[vehicle]")
    w.key("length", repr(CAR["length"]), "TODO (optional): m, the ego box; a forward radar sits "
          "at its front")
    w.key("width", repr(CAR["width"]), "TODO (optional): m, the ego box")
    w.key("height", repr(CAR["height"]), "TODO (optional): m, the ego box")
    why = ("the steering lanes start there, and the rear axle follows their bicycle model "
           "without slip" if steering else "the ego box and the sensors' mounts are placed from it")
    w.key("origin", _q("rear_axle"), f"TODO (optional): where the vehicle frame's (0, 0) is on "
          f"the car: {why} (else centre or front_bumper)")
    w.key("rear_overhang", repr(CAR["rear_overhang"]), "TODO (optional): m, how far the car's "
          "rear is behind the rear axle (the origin): the ego box and the radar's place")
    if steering:
        w.key("wheelbase", repr(CAR["wheelbase"]), "TODO (optional): m, for the steering lanes: "
              "their curvature is the road wheel angle / wheelbase")
        w.key("steering_ratio", repr(CAR["steering_ratio"]), "TODO (optional): steering wheel "
              "angle / road wheel angle: the steering lanes turn by the road wheel angle")
    w.add()


_SIDE = re.compile(r"positive\s+(?:to\s+(?:the\s+)?|is\s+|=\s*)?(left|right)|(left|right)\s+"
                   r"(?:is\s+)?positive", re.IGNORECASE)


def _never_negative(signal: Signal) -> bool:
    """Whether the DBC says the signal cannot be negative: its minimum, else its raw value."""
    if signal.minimum is not None:
        return bool(signal.minimum >= 0)
    return not signal.is_signed and not signal.is_float and signal.offset >= 0 \
        and signal.scale > 0


def _write_sensor(w: _Writer, plan: Plan, profile: str) -> None:
    """``[sensors.NAME]`` of the plan (``profile``: the profile's name, for the commands)."""
    fams, signals = plan.group.families, plan.group.signals
    pos = position(signals)
    w.add(f"# {' + '.join(f.template for f in fams)} [{fams[0].first}..{fams[0].last}] "
          f"(from {fams[0].source})" + (": the messages of one index are one object"
                                        if len(fams) > 1 else ""))
    w.add(f"[sensors.{plan.sensor}]")
    w.key("kind", _q(plan.kind), plan.kind_why)
    distance = pos.distance
    forward = plan.kind == "radar" and distance is not None and _never_negative(distance[1])
    if forward:
        assert distance is not None
        length, overhang = CAR["length"], CAR["rear_overhang"]
        w.key("mount", f"{{ x = {length - overhang!r}, y = 0.0, z = 0.5, yaw = 0.0 }}",
              f"TODO (optional): a forward radar (its {distance[1].name} cannot be negative), at "
              "the front of the car: [vehicle] length - rear_overhang ahead of the rear axle "
              f"({length!r} - {overhang!r} m); move it with them, and measure y, z (m) and yaw "
              "(deg)")
    else:
        w.key("mount", "{ x = 0.0, y = 0.0, z = 0.5, yaw = 0.0 }",
              "TODO (optional): where it sits in the vehicle frame (m, deg)")
    side = pos.lateral
    said = _SIDE.search(side[1].comment or "") if side is not None else None
    if side is not None and said is not None:
        w.key("lateral", _q((said.group(1) or said.group(2)).lower()),
              f"the DBC's comment on {side[1].name}: {' '.join((side[1].comment or '').split())}")
    else:
        what = f"positive {side[1].name}" if side is not None else "its positive lateral values"
        w.add(f"{TODO_OPTIONAL} lateral is UNKNOWN: the DBC does not say which way {what}")
        w.add("# points; \"left\" below is only the default, not a finding. `tankviz profile check "
              f"{profile}.toml DRIVE`")
        w.add("# judges it on a drive that turns past stationary objects (posts, parked cars): "
              "write what it says.")
        w.key("lateral", _q("left"))
    w.key("coordinates", _q("polar" if pos.polar else "cartesian"),
          "range and angle" if pos.polar else "x and y" if pos.x and pos.y else "")
    if distance is not None:
        unit = unit_of(distance[1])
        if unit in LENGTH and LENGTH[unit] != 1:
            w.key("distance_scale", repr(LENGTH[unit]), f"{distance[1].name} is in {unit}")
    if pos.polar and pos.angle is not None:
        unit = unit_of(pos.angle[1])
        if unit in ANGLE:
            w.key("angle_unit", _q("rad" if ANGLE[unit] == 1 else "deg"),
                  f"the unit of {pos.angle[1].name}")
        else:
            w.key("angle_unit", _q("deg"), f"TODO (optional): the DBC gives no unit for "
                  f"{pos.angle[1].name}: deg or rad?")
    w.add()


def _write_objects(w: _Writer, plan: Plan, name: str, role: str | None, *,
                   notes: bool) -> None:
    """One ``[objects.NAME]`` of the plan's group; ``notes``: its optional TODO lines too (once
    per sensor: a second group of the same messages would repeat them)."""
    g = plan.group
    fams, signals = g.families, g.signals
    pos = position(signals)
    ident = pick_id(signals)
    first = fams[0]
    w.add(f"[objects.{name}]")
    w.key("sensor", _q(plan.sensor))
    if role == "detections":
        w.key("role", _q("detections"), "every valid slot as the radar reports it (its colour); "
              "the same slots as tracks follow")
    elif role == "tracks":
        w.key("role", _q("tracks"), "the names say track (or an object id): slots that keep "
              "their object")
    w.key("messages", "[" + ", ".join(_q(f.template) for f in fams) + "]",
          "messages whose names differ only by the index" if len(fams) == 1 else
          "companions: the same indices; the first carries the position")
    w.key("index", f"[{first.first}, {first.last}]")
    if ident is not None:
        w.key("id", _q(ident[0]), f"guessed from the name {ident[1].name}: a stable object id "
              "(else the index is the id)")
    key = f"objects.{name}"
    x, y, rng, angle = pos.x, pos.y, pos.rng, pos.angle
    dist_candidate: Candidate | None
    if pos.polar:
        assert angle is not None
        d = rng if rng is not None else x
        assert d is not None
        why = guessed_from(d[1])
        if rng is None:
            why += ": no lateral position, but an angle, so it is taken as the range"
        w.key("range", _q(d[0]), why)
        w.key("azimuth", _q(angle[0]), guessed_from(angle[1]))
        dist_candidate = Candidate(d[0], d[1], why)
    else:
        dist_candidate = Candidate(x[0], x[1], "") if x else None
        if x is not None:
            w.key("x", _q(x[0]), guessed_from(x[1]))
        else:
            w.add(f"{TODO} no longitudinal position found for {key} (signals: {_names(signals)})")
        if y is not None:
            w.key("y", _q(y[0]), guessed_from(y[1]))
        else:
            w.add(f"{TODO} no lateral position found for {key} (signals: {_names(signals)})")
    for field_name, axis in (("vx", LONG), ("vy", LAT)):
        v = pick_velocity(signals, axis)
        if v is not None:
            w.key(field_name, _q(v[0]), guessed_from(v[1]) + ", relative")
        elif field_name == "vx" and not pos.polar:
            v = pick_unaxed_velocity(signals)
            if v is not None:
                w.key("vx", _q(v[0]), guessed_from(v[1]) + ": no axis in the name, so the "
                      "closing speed along x, relative")
    p = pick_probability(signals)
    if p is not None:
        range_note = "" if unit_of(p[1]) else f" and its range {p[1].minimum:g}..{p[1].maximum:g}"
        w.key("probability", _q(p[0]), guessed_from(p[1]).replace(" (the DBC gives no unit)", "")
              + range_note if range_note else guessed_from(p[1]))
    c = pick_class(signals)
    if c is not None:
        w.key("class", _q(c[0]), guessed_from(c[1]))
        classes = classes_of(c[1])
        if classes:
            w.add("# from the value table: " + "; ".join(
                f"{raw} {c[1].choices[raw]}" for raw in sorted(classes)) if c[1].choices else "")
            w.key("classes", "{ " + ", ".join(f"{raw} = {_q(v)}" for raw, v
                                               in sorted(classes.items())) + " }",
                  "guessed from the labels")
        elif notes:
            w.add(f"{TODO_OPTIONAL} {c[1].name} has no value table: say what its values mean "
                  "with classes = { 1 = \"car\", … }")
    if notes:
        for found in (x, y, rng, angle):
            if found is not None and not unit_of(found[1]) and (found is not angle
                                                                or not pos.polar):
                w.add(f"{TODO_OPTIONAL} the DBC gives no unit for {found[1].name}: check that it "
                      "is in metres (the sensor's distance_scale converts)")
    rule, why, todos = pick_validity(signals, dist_candidate)
    if rule:
        w.key("valid", _q(rule), why)
    if notes:
        for line in todos:
            w.add(line)
    tracks = role == "tracks" or (role is None and plan.tracks)
    w.key("lifetime", "0.3" if tracks else "0.1", "s an object lingers without a new frame")
    w.add()


def _write_ego(w: _Writer, signals: Sequence[tuple[str, Signal]],
               messages: Sequence[Message],
               steering: tuple[Candidate, float] | None) -> None:
    yaw = pick_yaw_rate(signals)
    w.add("# Ego motion, converted to SI by scale (m/s, rad/s, rad), left positive.")
    w.add("[ego]")
    mean = wheel_mean(signals)
    if mean is not None:
        text, scale, unit = mean
        others = pick_speed([(n, s) for n, s in signals if not set(tokens(s.name)) & WHEEL])
        w.add(f"# The mean of the four wheel speeds ({unit}{' -> m/s' if scale != 1 else ''}): "
              "one wheel runs faster or slower in a turn,")
        w.add("# and a speedometer reads high by design; "
              + (f"the alternative is {others[0].name} ({others[0].signal.unit or 'no unit'})."
                 if others is not None else "no other speed signal was found."))
        w.key("speed", _value(text, scale), "the four wheels' mean (above)")
    else:
        speed = pick_speed(signals)
        if speed is not None:
            c, scale, notes = speed
            w.key("speed", _ref(c.name, scale), c.why)
            for line in notes:
                w.add(line)
        else:
            w.add(f"{TODO_OPTIONAL} no vehicle speed found (a speed signal with a unit: m/s, "
                  "km/h or mph)")
    if yaw is not None:
        c, scale = yaw
        w.key("yaw_rate", _ref(c.name, scale), c.why)
        w.add(f"{TODO_OPTIONAL} check that {c.signal.name} is positive turning left")
    else:
        w.add(f"{TODO_OPTIONAL} no yaw rate found (a yaw signal in deg/s or rad/s)")
    if steering is not None:
        c, scale = steering
        fine = fraction(c, messages)
        if fine is not None:
            message = c.name.rpartition(".")[0]
            w.add(f"# The steering wheel angle in two parts: {c.signal.name} in steps of "
                  f"{c.signal.scale:g} {c.signal.unit}, {fine.name} the rest")
            w.add(f"# (in steps of {fine.scale:g} {fine.unit}); {c.why}.")
            w.key("steering_wheel_angle", _value(f"{c.name} + {message}.{fine.name}", scale),
                  "both parts (above)")
        else:
            w.key("steering_wheel_angle", _ref(c.name, scale), c.why)
        message = c.name.rpartition(".")[0]
        own = set(tokens(c.signal.name))
        sign = [s.name for m in messages if m.name == message for s in m.signals
                if s.name != c.signal.name and set(tokens(s.name)) - own == {"sign"}]
        unsigned = c.signal.minimum is not None and c.signal.minimum >= 0 and not \
            c.signal.is_signed and c.signal.offset >= 0
        if unsigned:
            w.add(f"{TODO_OPTIONAL} {c.signal.name} cannot be negative in the DBC: its sign "
                  f"may be in {', '.join(sign) or 'another signal'} (an expression can combine "
                  "them)")
        w.add(f"{TODO_OPTIONAL} check that {c.signal.name} is positive turning left (else "
              "scale it by -1)")
    else:
        w.add(f"{TODO_OPTIONAL} no steering wheel angle found (a steering signal in deg or rad)")
    w.add()
    lanes = lane_messages(messages)
    if steering is not None:
        w.add("# Lanes from the steering angle (a bicycle model): no camera lines mapped.")
        w.add("[lanes]")
        w.key("length", "100.0", "m drawn ahead")
        if lanes:
            w.add(f"{TODO_OPTIONAL} lane signals found in {', '.join(sorted(set(lanes)))}: map "
                  "[lanes.left] and [lanes.right] (docs/profiles.md, Lanes)")
    elif lanes:
        w.add(f"{TODO_OPTIONAL} lane signals found in {', '.join(sorted(set(lanes)))}: map "
              "[lanes] with [lanes.left] and [lanes.right] (docs/profiles.md, Lanes)")
    else:
        w.add(f"{TODO_OPTIONAL} no lanes: no camera lane signals and no steering angle found")


def _ref(name: str, scale: float) -> str:
    if scale == 1:
        return _q(name)
    return f"{{ signal = {_q(name)}, scale = {scale:.7g} }}"


def _value(expression: str, scale: float) -> str:
    if scale == 1:
        return _q(expression)
    return f"{{ value = {_q(expression)}, scale = {scale:.7g} }}"
