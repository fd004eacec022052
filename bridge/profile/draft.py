"""A starting profile drafted from the databases alone: what ``tankviz profile new`` writes.

:func:`draft_profile` is a pure function, databases (as cantools loaded them, and the buses they
are for) -> TOML text. It guesses, by name and unit, what a profile would map, and says on every
line why:

- **Databases**: ``[profile] databases`` as one list, or a table per bus when buses are given
  (``{ can0 = [...], can1 = [...] }``), and then ``[buses.BUS] bitrate`` for each (the
  database's own, else :data:`BITRATE`, a ``TODO (optional)``).
- **Object families**: messages whose names differ only by one number and whose signals have the
  same names (``RadarPoint{i}_A``, ``Target{i}``, ``Object_{i:02d}``, ``RADAR_TRACK_{i}`` with
  361..366; at least :data:`MIN_FAMILY` of them, the longest run of consecutive numbers; a number
  repeated inside signal names, ``FwdVsnRngTrk{i}Rev``, is part of the template). Families with
  the same numbers whose names differ only after the number (``Obj{i}_A`` and ``Obj{i}_B``) or in
  a one-letter part before it (``TRACK_A_{i}`` and ``TRACK_B_{i}``: :func:`stem`) are one object
  group, one object per index, the family with the position first. A family with no
  position-like signal (battery cells, say) is only listed in a comment.
- **Per group**: position as x/y (``LongDist``/``LatDist``, ``X_Rel``) or range + angle (polar;
  an x-like distance with an angle and no lateral signal is taken as the range), velocity
  ``vx``/``vy`` (in a cartesian group, a relative speed with no axis in its name, ``REL_SPEED``,
  is ``vx``), existence probability (``%``, or a score of 0..100), class (with ``classes`` from
  the value table), id, and a validity rule (a valid flag, a status with a value table, else the
  distance > 0). One sensor per group, its kind from the names (vision/camera, fusion, else
  radar), named ``radar`` when the names say only "objects" (``TRACK``, ``Target``, ``Object``).
  Where the names say track or an object id signal is found, the group's ``role = "tracks"``;
  a radar's track slots are then also a detections group beside it, and ``[lead] source =
  "tracks"`` chooses the lead among them (no message of the databases gives one).
- **Sensor placement and sign**: a radar whose distance cannot be negative (by its minimum, else
  its raw value and scale) looks forward: it is mounted at the front of the drafted car
  (``length - rear_overhang`` ahead of its rear-axle origin, :data:`CAR`), and the comment says
  to move it with them; other sensors at the origin. Which way positive lateral values point is
  taken from the DBC's comment on the signal where it says (``positive to the right``); else the
  draft says plainly that it is unknown, and that ``tankviz profile check PROFILE DRIVE`` judges
  it, above ``lateral = "left"`` (the default, not a guess).
- **Vehicle**: a typical car's length, width, height, origin (the rear axle) and rear overhang,
  and with a steering angle its wheelbase and steering ratio (:data:`CAR`), each a ``TODO
  (optional)`` saying what it is used for.
- **Ego**: speed as the mean of four wheel speeds of one message in a speed unit (the other
  speed signal found, a speedometer say, named as the alternative), else a speed signal (m/s,
  km/h, mph; else a wheel's angular speed times a rolling radius to measure); yaw rate; steering
  wheel angle, with its fine part where it comes in two (``STEER_ANGLE + STEER_FRACTION``); all
  converted to SI by ``scale``; ``[lanes]`` steering-only when there is a steering angle (camera
  lane signals, where some are found, are a TODO).

Every guess carries a comment (``# guessed from the name LatDist and unit m``). What could not be
found is a comment line ``# TODO: …`` when the profile needs it (an object group without a full
position: the profile then does not load, and :func:`bridge.profile.loader.load_profile` names
that line instead of a confusing error) and ``# TODO (optional): …`` otherwise.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from cantools.database.can.database import Database
from cantools.database.can.message import Message
from cantools.database.can.signal import Signal

#: The smallest number of messages that make a family.
MIN_FAMILY = 3
#: The comment that marks something a profile needs and the draft could not find.
TODO = "# TODO:"
#: The comment that marks something optional the draft could not find or is unsure of.
TODO_OPTIONAL = "# TODO (optional):"

_DEG = 0.017453292519943295
_RESERVED = {"ego", "health", "lanes", "lead", "mio"}

# Units by kind: the factor to metres, metres per second, radians, radians per second.
_LENGTH = {"m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0, "cm": 0.01,
           "mm": 0.001}
_SPEED = {"m/s": 1.0, "meters/sec": 1.0, "m/sec": 1.0, "mps": 1.0, "meter/s": 1.0,
          "km/h": 1 / 3.6, "kph": 1 / 3.6, "kmh": 1 / 3.6, "kmph": 1 / 3.6, "mph": 0.44704}
_ANGLE = {"deg": _DEG, "degree": _DEG, "degrees": _DEG, "°": _DEG, "rad": 1.0, "radian": 1.0,
          "radians": 1.0}
_RATE = {"deg/s": _DEG, "deg/sec": _DEG, "degree/s": _DEG, "degrees/s": _DEG, "°/s": _DEG,
         "rad/s": 1.0, "rad/sec": 1.0}
_PERCENT = {"%", "percent"}

_LONG = {"long", "lon", "longitudinal", "x", "dx"}
_LAT = {"lat", "lateral", "y", "dy"}
_DIST = {"dist", "distance", "dst", "pos", "position", "rel", "d"}
_RANGE = {"range", "rng", "dist", "distance", "dst", "r"}
_ANG = {"angle", "ang", "azimuth", "azmth", "azi", "az", "phi", "theta"}
_VEL = {"speed", "spd", "vel", "velocity", "v", "vx", "vy"}
_NOT_POSITION = {"sigma", "std", "var", "accel", "acc", "a", "rate", "width", "length",
                 "height", "loss", "vert", "ax", "ay", "dz", "z", "rear", "end", "offset",
                 "ofst", "misalignment", "mounting", "fov", "beamwidth"}
_OBJECT_WORDS = {"obj", "object", "objects", "track", "tracks", "trk", "target", "tgt",
                 "point", "radar", "detection", "det", "cluster"}


def tokens(name: str) -> list[str]:
    """The words of a signal or message name, lower case: ``LongDist`` -> long, dist."""
    name = re.sub(r"\{i[^}]*\}", "_", name)
    return [p.lower() for p in
            re.findall(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+", name)]


def _unit(signal: Signal) -> str:
    return (signal.unit or "").strip().lower().replace(" ", "")


@dataclass(frozen=True)
class Family:
    """Messages whose names differ only by one number, with the same signal names."""

    template: str
    prefix: str
    first: int
    last: int
    #: the first member's message, and its signal names as templates
    message: Message
    signals: tuple[tuple[str, Signal], ...]
    source: str


@dataclass(frozen=True)
class Candidate:
    """A guessed signal: the name to write (plain or Message.Signal) and why."""

    name: str
    signal: Signal
    why: str


def _index_text(index: int, width: int) -> str:
    return f"{index:0{width}d}" if width else str(index)


def find_families(messages: Iterable[tuple[str, Message]]) -> list[Family]:
    """The message families among ``messages`` (source name, message), biggest first."""
    by_key: dict[tuple[str, str, int], dict[int, tuple[str, Message]]] = {}
    for source, m in messages:
        for match in re.finditer(r"\d+", m.name):
            text = match.group()
            width = len(text) if text.startswith("0") and len(text) > 1 else 0
            key = (m.name[:match.start()], m.name[match.end():], width)
            by_key.setdefault(key, {})[int(text)] = (source, m)
    candidates: list[Family] = []
    for (prefix, suffix, width), members in by_key.items():
        if len(members) < MIN_FAMILY:
            continue
        padded_width = width
        if width:
            # a zero-padded family also holds its unpadded members of the same width (10, 11)
            extra = by_key.get((prefix, suffix, 0), {})
            members = {**{i: sm for i, sm in extra.items() if len(str(i)) == width}, **members}
        # Signal names as they are, or with the index in them as {i} (FwdVsnRngTrk1Rev):
        # whichever makes more members alike (as they are, on a tie: Index2 is no index).
        best: tuple[int, bool, list[int]] = (0, False, [])
        for numbered in (False, True):
            templates: dict[int, tuple[str, ...]] = {}
            for i, (_, m) in members.items():
                text = _index_text(i, padded_width)
                templates[i] = tuple(sorted(_signal_template(s.name, text, padded_width)
                                            if numbered else s.name for s in m.signals))
            counts: dict[tuple[str, ...], int] = {}
            for names in templates.values():
                counts[names] = counts.get(names, 0) + 1
            signature = max(counts, key=lambda k: counts[k])
            alike = sorted(i for i, names in templates.items() if names == signature)
            if signature and len(alike) > best[0]:
                best = (len(alike), numbered, alike)
        _, numbered, same = best
        run = _longest_run(same)
        if len(run) < MIN_FAMILY:
            continue
        source, first = members[run[0]]
        placeholder = f"{{i:0{padded_width}d}}" if padded_width else "{i}"
        text = _index_text(run[0], padded_width)
        signals = tuple((_signal_template(s.name, text, padded_width) if numbered else s.name, s)
                        for s in first.signals)
        candidates.append(Family(f"{prefix}{placeholder}{suffix}", prefix, run[0], run[-1],
                                 first, signals, source))
    candidates.sort(key=lambda f: (-(f.last - f.first), f.template))
    taken: set[str] = set()
    families = []
    for f in candidates:
        expanded = {_expand(f.template, i) for i in range(f.first, f.last + 1)}
        if expanded & taken:
            continue
        taken |= expanded
        families.append(f)
    families.sort(key=lambda f: f.template)
    return families


def _expand(template: str, index: int) -> str:
    return re.sub(r"\{i(?::0(\d)d)?\}",
                  lambda m: _index_text(index, int(m.group(1) or 0)), template)


def _signal_template(name: str, text: str, width: int) -> str:
    placeholder = f"{{i:0{width}d}}" if width else "{i}"
    return re.sub(r"\d+", lambda m: placeholder if m.group() == text else m.group(), name)


def _longest_run(numbers: Sequence[int]) -> list[int]:
    best: list[int] = []
    run: list[int] = []
    for n in numbers:
        run = [*run, n] if run and n == run[-1] + 1 else [n]
        if len(run) > len(best):
            best = run
    return best


def stem(prefix: str) -> str:
    """The name before the index without a one-letter part that only tells companions apart:
    ``TRACK_A_`` and ``TRACK_B_`` -> ``TRACK_`` (``RadarPoint`` stays)."""
    return re.sub(r"(?:(?<=_)|^)[A-Z]_$", "", prefix)


def group_families(families: Sequence[Family]) -> list[list[Family]]:
    """Companion families as one group each: the same numbers, and names that differ only after
    the index (``Obj{i}_A``, ``Obj{i}_B``) or in a one-letter part before it (``TRACK_A_{i}``,
    ``TRACK_B_{i}``, :func:`stem`): the messages of one index are one object."""
    groups: dict[tuple[str, int, int], list[Family]] = {}
    for f in families:
        groups.setdefault((stem(f.prefix), f.first, f.last), []).append(f)
    return list(groups.values())


# --- guessing signals ---------------------------------------------------------------------------


def _why(signal: Signal, unit_note: str = "") -> str:
    unit = signal.unit.strip() if signal.unit else ""
    if unit:
        return f"guessed from the name {signal.name} and unit {unit}{unit_note}"
    return f"guessed from the name {signal.name} (the DBC gives no unit{unit_note})"


def _best(signals: Iterable[tuple[str, Signal]], score: dict[str, int]
          ) -> tuple[str, Signal] | None:
    ranked = sorted(((score[name], n, name, s) for n, (name, s) in enumerate(signals)
                     if name in score), key=lambda t: (-t[0], t[1]))
    return (ranked[0][2], ranked[0][3]) if ranked else None


def _score_position(signals: Sequence[tuple[str, Signal]], axis: set[str],
                    units: dict[str, float], words: set[str], exclude: set[str]) -> dict[str, int]:
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        unit = _unit(s)
        if not t & axis or t & exclude or t & _NOT_POSITION or t & _VEL:
            continue
        if unit and unit not in units:
            continue
        scores[name] = (2 if unit else 0) + (1 if t & words else 0)
    return scores


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


def _snake(text: str) -> str:
    words = tokens(text)
    return "_".join(words) or "objects"


@dataclass(frozen=True)
class _Group:
    name: str
    families: tuple[Family, ...]
    #: (name to write, signal) of every signal of the group's messages
    signals: tuple[tuple[str, Signal], ...]


def _group(name: str, families: Sequence[Family]) -> _Group:
    counts: dict[str, int] = {}
    for f in families:
        for n, _ in f.signals:
            counts[n] = counts.get(n, 0) + 1
    signals = tuple((n if counts[n] == 1 else f"{f.template}.{n}", s)
                    for f in families for n, s in f.signals)
    return _Group(name, tuple(families), signals)


def _has_position(signals: Sequence[tuple[str, Signal]]) -> bool:
    return any(pick(signals) is not None
               for pick in (_pick_x, _pick_y, _pick_range, _pick_angle))


def _pick_x(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, _LONG, _LENGTH, _DIST, _LAT))


def _pick_y(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, _LAT, _LENGTH, _DIST, _LONG))


def _pick_range(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, _RANGE, _LENGTH, set(), _LONG | _LAT))


def _pick_angle(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, _ANG, _ANGLE, set(), set()))


def _pick_velocity(signals: Sequence[tuple[str, Signal]], axis: set[str]
                   ) -> tuple[str, Signal] | None:
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        unit = _unit(s)
        if not t & axis or not t & _VEL or t & {"sigma", "std", "accel", "acc", "a"}:
            continue
        if unit and unit not in _SPEED:
            continue
        scores[name] = 2 if unit else 0
    return _best(signals, scores)


def _pick_unaxed_velocity(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    """A relative speed whose name gives no axis (``REL_SPEED``): the closing speed along x."""
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        if not t & {"speed", "spd", "vel", "velocity"} or t & (_LONG | _LAT | {
                "sigma", "std", "accel", "acc", "a", "range", "rng", "rate", "lane", "ego"}):
            continue
        if _unit(s) in _SPEED:
            scores[name] = 1 if t & {"rel", "relative"} else 0
    return _best(signals, scores)


def _percent_like(signal: Signal) -> bool:
    """A unit of % or, without a unit, a range of 0..100."""
    unit = _unit(signal)
    if unit:
        return unit in _PERCENT
    return signal.minimum is not None and signal.minimum >= 0 and signal.maximum == 100


def _pick_probability(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        exist = bool(t & {"exist", "existence", "existance"})
        percent = _unit(s) in _PERCENT
        if t & {"score"} and _percent_like(s) and not t & {"obstacle", "non", "class", "cls"}:
            scores[name] = 1
            continue
        if not t & {"prob", "probability", "exist", "existence", "conf", "confidence"}:
            continue
        if t & {"obstacle", "non", "class", "cls"} or not (exist or percent):
            continue
        scores[name] = (3 if exist else 0) + (2 if percent else 0)
    return _best(signals, scores)


def _pick_class(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        if not t & {"class", "cls", "classification", "type", "typ"}:
            continue
        if t & {"prob", "probability", "conf"} or _unit(s) in _PERCENT:
            continue
        scores[name] = 1 if s.choices else 0
    return _best(signals, scores)


def _pick_id(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    scores = {}
    for name, _ in signals:
        t = set(tokens(name))
        if "id" in t and not t & {"burst", "brst", "msg", "sn", "sgu"}:
            scores[name] = 1 if t & _OBJECT_WORDS else 0
    return _best(signals, scores)


_INVALID_WORDS = ("invalid", "no_", "none", "empty", "not", "unused", "no target", "notarget",
                  "coast", "merged", "off", "error", "fault")


def _valid_values(signal: Signal) -> list[int]:
    values = []
    for raw, label in (signal.choices or {}).items():
        text = str(label).lower()
        if text in ("no", "false", "0") or any(w in text for w in _INVALID_WORDS):
            continue
        values.append(int(raw))
    return sorted(values)


def _pick_validity(signals: Sequence[tuple[str, Signal]], distance: Candidate | None
                   ) -> tuple[str, str, list[str]]:
    """(rule, why, optional TODO lines) of a group."""
    flags = [(n, s) for n, s in signals if set(tokens(n)) & {"valid", "vld", "validity"}]
    for n, s in flags:
        if s.choices:
            values = _valid_values(s)
            if values:
                return (_in_rule(n, values), f"guessed from the name {s.name} and its value "
                        f"table ({_labels(s, values)})", [])
        if s.length == 1:
            return f"{n} == 1", f"guessed from the name {s.name} (one bit)", []
    todos = []
    statuses = []
    for n, s in signals:
        t = set(tokens(n))
        if t & {"status", "stat", "sts"} and not t & {"move", "moving", "trn", "turn", "sig",
                                                      "brk", "brake", "lt", "light"}:
            values = _valid_values(s)
            if values and s.choices:
                return (_in_rule(n, values), f"guessed from the name {s.name} and its value "
                        f"table ({_labels(s, values)})", [])
            statuses.append(s.name)
    if statuses:
        todos.append(f"{TODO_OPTIONAL} {' or '.join(statuses)} may say which slots hold an "
                     "object (no value table in the DBC): write the rule with its valid values")
    if distance is not None and (distance.signal.minimum is None
                                 or distance.signal.minimum >= 0):
        return (f"{distance.name} > 0", f"guessed: no validity signal found; an empty slot is "
                f"taken to read {distance.signal.name} = 0", todos)
    todos.append(f"{TODO_OPTIONAL} no validity signal found: every slot is drawn, empty ones too")
    return "", "", todos


def _in_rule(name: str, values: list[int]) -> str:
    if len(values) == 1:
        return f"{name} == {values[0]}"
    return f"{name} in ({', '.join(str(v) for v in values)})"


def _labels(signal: Signal, values: list[int]) -> str:
    return ", ".join(f"{v} {signal.choices[v]}" for v in values) if signal.choices else ""


_CLASS_WORDS = (("pedestrian", "pedestrian"), ("ped", "pedestrian"), ("two_wheel", "two_wheeler"),
                ("twowheel", "two_wheeler"), ("bike", "two_wheeler"), ("cycl", "two_wheeler"),
                ("motorcycle", "two_wheeler"), ("stationary", "stationary"),
                ("static", "stationary"), ("construction", "stationary"),
                ("guard", "stationary"), ("car", "car"), ("vehicle", "car"), ("truck", "car"),
                ("four_wheel", "car"), ("passenger", "car"))


def _classes(signal: Signal) -> dict[int, str]:
    out = {}
    for raw, label in (signal.choices or {}).items():
        text = str(label).lower()
        out[int(raw)] = next((cls for word, cls in _CLASS_WORDS if word in text), "unknown")
    return out


# --- ego ----------------------------------------------------------------------------------------


def _pick_speed(signals: Sequence[tuple[str, Signal]]) -> tuple[Candidate, float, list[str]] | None:
    best: tuple[int, Candidate, float, list[str]] | None = None
    for name, s in signals:
        t = set(tokens(s.name))
        unit = _unit(s)
        if t & {"set", "cruise", "limit", "target", "calc", "rate", "accel", "req", "max", "min",
                "lat", "ratio", "factor", "comp"}:
            continue
        notes: list[str] = []
        if t & {"speed", "spd", "velocity", "vel"} and unit in _SPEED:
            score = 3 if t & {"veh", "vehicle", "ego", "car"} else (1 if t & {"wheel", "whl"}
                                                                   else 2)
            scale = _SPEED[unit]
            why = _why(s, " -> m/s" if scale != 1 else "")
            if t & {"wheel", "whl"}:
                notes.append(f"{TODO_OPTIONAL} one wheel's speed stands for the vehicle's: an "
                             "expression can average the four")
        elif t & {"wheel", "whl"} and unit in _RATE and not t & {"yaw", "steer", "ste"}:
            score, scale = 0, 0.33 * _RATE[unit]
            why = (f"guessed from the name {s.name} and unit {s.unit}: a wheel's angular speed "
                   "times a rolling radius of 0.33 m")
            per_deg = "" if _RATE[unit] == 1 else "times 0.01745 for deg/s, "
            notes.append(f"{TODO_OPTIONAL} scale is the wheel's rolling radius in metres "
                         f"({per_deg}measure yours)")
        else:
            continue
        if best is None or score > best[0]:
            best = (score, Candidate(name, s, why), scale, notes)
    return None if best is None else (best[1], best[2], best[3])


def _pick_yaw_rate(signals: Sequence[tuple[str, Signal]]) -> tuple[Candidate, float] | None:
    best: tuple[int, Candidate, float] | None = None
    for name, s in signals:
        t = set(tokens(s.name))
        unit = _unit(s)
        if "yaw" not in t or unit not in _RATE:
            continue
        if t & {"bias", "shift", "accel", "validity", "valid", "vld", "high", "qf", "plsblity"}:
            continue
        score = 0 if t & {"calc", "ack", "tx"} else 1
        scale = _RATE[unit]
        c = Candidate(name, s, _why(s, " -> rad/s" if scale != 1 else ""))
        if best is None or score > best[0]:
            best = (score, c, scale)
    return None if best is None else (best[1], best[2])


def _pick_steering(signals: Sequence[tuple[str, Signal]]) -> tuple[Candidate, float] | None:
    best: tuple[int, Candidate, float] | None = None
    for name, s in signals:
        t = set(tokens(s.name))
        unit = _unit(s)
        steer = t & {"steer", "steering", "ste", "stw", "str", "swa", "strg"}
        if not steer or unit not in _ANGLE or not t & (_ANG | {"an", "whl", "wheel", "swa"}):
            continue
        if t & {"rate", "req", "request", "cmd", "torque", "ack", "ratio", "gear", "offset",
                "limit", "max", "min", "des", "target", "spd", "speed"}:
            continue
        score = 2 if t & {"whl", "wheel"} else 1
        scale = _ANGLE[unit]
        c = Candidate(name, s, _why(s, " -> rad" if scale != 1 else ""))
        if best is None or score > best[0]:
            best = (score, c, scale)
    return None if best is None else (best[1], best[2])


def _lane_messages(messages: Iterable[Message]) -> list[str]:
    found = []
    for m in messages:
        for s in m.signals:
            t = set(tokens(s.name)) | set(tokens(m.name))
            if t & {"lane", "ln", "lanes"} and _unit(s) in _LENGTH and not t & {"width"}:
                found.append(m.name)
                break
    return found


# --- the profile --------------------------------------------------------------------------------

#: The car drafted where the databases cannot say: a typical passenger car's numbers, each line a
#: ``# TODO (optional)`` saying what it is used for. Origin on the rear axle.
CAR = {"length": 4.5, "width": 1.8, "height": 1.5, "rear_overhang": 1.0, "wheelbase": 2.7,
       "steering_ratio": 15.0}
#: The bitrate drafted for a bus whose databases give none: the usual one of a car's CAN bus.
BITRATE = 500_000
#: Words of a family's name that say only "objects": such a radar's sensor is called "radar".
_GENERIC = {"track", "tracks", "trk", "obj", "object", "objects", "target", "targets", "tgt"}


@dataclass(frozen=True)
class _Plan:
    """One sensor and what its family group becomes: (object group name, role or None) each,
    a radar's track slots both detections and tracks."""

    sensor: str
    group: _Group
    kind: str
    kind_why: str
    tracks: bool
    names: tuple[tuple[str, str | None], ...]


def _unique(base: str, used: set[str]) -> str:
    name, n = base, 2
    while name in used:
        name, n = f"{base}_{n}", n + 1
    used.add(name)
    return name


def _plan(object_like: Sequence[tuple[str, list[Family]]]) -> list[_Plan]:
    plans = []
    sensors: set[str] = set()
    groups = {name for name, _ in object_like}
    for gname, fams in object_like:
        g = _group(gname, fams)
        kind, kind_why = _kind(fams)
        words = {t for f in fams for t in tokens(stem(f.prefix))}
        tracks = bool(words & {"track", "tracks", "trk", "tracked"}) or _pick_id(
            g.signals) is not None
        sensor = _unique("radar" if kind == "radar" and words and words <= _GENERIC else gname,
                         sensors)
        names: tuple[tuple[str, str | None], ...] = ((gname, "tracks" if tracks else None),)
        if tracks and kind == "radar":
            detections = sensor if sensor not in groups else f"{gname}_detections"
            groups.add(_unique(detections, groups))
            names = ((detections, "detections"), (gname, "tracks"))
        plans.append(_Plan(sensor, g, kind, kind_why, tracks, names))
    return plans


def _bare(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _q(key)


def draft_profile(databases: Sequence[tuple[str, Database]], *, name: str = "car",
                  buses: Mapping[str, Sequence[str]] | None = None) -> str:
    """A commented starting profile for the messages of ``databases`` ((path as written in the
    profile's ``databases``, database) pairs), as TOML text. ``buses`` gives the buses the
    databases are for (bus, or "*" for every bus -> paths): ``databases`` is then a table per bus
    and every bus gets a bitrate; without it, ``databases`` is one list for every bus."""
    messages = [(source, m) for source, db in databases for m in db.messages]
    families = find_families(messages)
    in_family = {_expand(f.template, i) for f in families for i in range(f.first, f.last + 1)}
    ego_messages = [m for _, m in messages if m.name not in in_family]
    ego_signals = [(f"{m.name}.{s.name}", s) for m in ego_messages for s in m.signals]
    steering = _pick_steering(ego_signals)
    w = _Writer()
    sources = [source for source, _ in databases]
    w.add(f"# Starting profile drafted by `tankviz profile new` from {', '.join(sources)}.")
    w.add("# Every mapping below is a guess from signal names and units: each says why. Lines")
    w.add("# '# TODO:' name what the profile needs and was not found (it does not load until they")
    w.add("# are done); '# TODO (optional):' what is missing or unsure. Check it with")
    w.add(f"#   tankviz profile check {name}.toml DRIVE   (README \"Vehicle profiles\")")
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

    object_like: list[tuple[str, list[Family]]] = []
    others: list[Family] = []
    used_names: set[str] = set()
    for fams in group_families(families):
        signals = [sig for f in fams for sig in f.signals]
        words = set(tokens(stem(fams[0].prefix)))
        if not _has_position(signals) and not words & _OBJECT_WORDS:
            others.extend(fams)
            continue
        base = _snake(stem(fams[0].prefix))
        if base in _RESERVED:
            base = f"{base}_objects"
        # the family with the position first
        fams = sorted(fams, key=lambda f: (not _has_position(f.signals), f.template))
        object_like.append((_unique(base, used_names), fams))

    if not object_like:
        w.add(f"{TODO_OPTIONAL} no family of numbered messages with positions found: write "
              "[sensors.NAME] and [objects.GROUP] by hand (README \"Vehicle profiles\")")
        w.add()
    plans = _plan(object_like)
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


def _kind(fams: Sequence[Family]) -> tuple[str, str]:
    words = {t for f in fams for t in tokens(f.template) + tokens(f.message.name)}
    if words & {"vision", "vsn", "vis", "camera", "cam", "mobileye", "video", "mono", "stereo"}:
        return "camera", "the message names say vision/camera"
    if words & {"fusion", "fus", "fused", "fusd"}:
        return "fusion", "the message names say fusion"
    return "radar", "guessed: the names say neither camera nor fusion"


@dataclass(frozen=True)
class _Position:
    """How a group's position was found: x/y, or range and azimuth (polar)."""

    x: tuple[str, Signal] | None
    y: tuple[str, Signal] | None
    rng: tuple[str, Signal] | None
    angle: tuple[str, Signal] | None

    @property
    def polar(self) -> bool:
        return not (self.x and self.y) and bool(self.angle) and bool(self.rng or self.x)

    @property
    def distance(self) -> tuple[str, Signal] | None:
        """The distance along the boresight: the range of a polar group, else x."""
        return self.rng if self.polar and self.rng else self.x

    @property
    def lateral(self) -> tuple[str, Signal] | None:
        """What says left or right: the azimuth of a polar group, else y."""
        return self.angle if self.polar else self.y


def _position(signals: Sequence[tuple[str, Signal]]) -> _Position:
    return _Position(_pick_x(signals), _pick_y(signals), _pick_range(signals),
                     _pick_angle(signals))


_SIDE = re.compile(r"positive\s+(?:to\s+(?:the\s+)?|is\s+|=\s*)?(left|right)|(left|right)\s+"
                   r"(?:is\s+)?positive", re.IGNORECASE)


def _never_negative(signal: Signal) -> bool:
    """Whether the DBC says the signal cannot be negative: its minimum, else its raw value."""
    if signal.minimum is not None:
        return bool(signal.minimum >= 0)
    return not signal.is_signed and not signal.is_float and signal.offset >= 0 \
        and signal.scale > 0


def _write_sensor(w: _Writer, plan: _Plan, profile: str) -> None:
    """``[sensors.NAME]`` of the plan (``profile``: the profile's name, for the commands)."""
    fams, signals = plan.group.families, plan.group.signals
    pos = _position(signals)
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
        unit = _unit(distance[1])
        if unit in _LENGTH and _LENGTH[unit] != 1:
            w.key("distance_scale", repr(_LENGTH[unit]), f"{distance[1].name} is in {unit}")
    if pos.polar and pos.angle is not None:
        unit = _unit(pos.angle[1])
        if unit in _ANGLE:
            w.key("angle_unit", _q("rad" if _ANGLE[unit] == 1 else "deg"),
                  f"the unit of {pos.angle[1].name}")
        else:
            w.key("angle_unit", _q("deg"), f"TODO (optional): the DBC gives no unit for "
                  f"{pos.angle[1].name}: deg or rad?")
    w.add()


def _write_objects(w: _Writer, plan: _Plan, name: str, role: str | None, *,
                   notes: bool) -> None:
    """One ``[objects.NAME]`` of the plan's group; ``notes``: its optional TODO lines too (once
    per sensor: a second group of the same messages would repeat them)."""
    g = plan.group
    fams, signals = g.families, g.signals
    pos = _position(signals)
    ident = _pick_id(signals)
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
        why = _why(d[1])
        if rng is None:
            why += ": no lateral position, but an angle, so it is taken as the range"
        w.key("range", _q(d[0]), why)
        w.key("azimuth", _q(angle[0]), _why(angle[1]))
        dist_candidate = Candidate(d[0], d[1], why)
    else:
        dist_candidate = Candidate(x[0], x[1], "") if x else None
        if x is not None:
            w.key("x", _q(x[0]), _why(x[1]))
        else:
            w.add(f"{TODO} no longitudinal position found for {key} (signals: {_names(signals)})")
        if y is not None:
            w.key("y", _q(y[0]), _why(y[1]))
        else:
            w.add(f"{TODO} no lateral position found for {key} (signals: {_names(signals)})")
    for field_name, axis in (("vx", _LONG), ("vy", _LAT)):
        v = _pick_velocity(signals, axis)
        if v is not None:
            w.key(field_name, _q(v[0]), _why(v[1]) + ", relative")
        elif field_name == "vx" and not pos.polar:
            v = _pick_unaxed_velocity(signals)
            if v is not None:
                w.key("vx", _q(v[0]), _why(v[1]) + ": no axis in the name, so the closing speed "
                      "along x, relative")
    p = _pick_probability(signals)
    if p is not None:
        range_note = "" if _unit(p[1]) else f" and its range {p[1].minimum:g}..{p[1].maximum:g}"
        w.key("probability", _q(p[0]), _why(p[1]).replace(" (the DBC gives no unit)", "")
              + range_note if range_note else _why(p[1]))
    c = _pick_class(signals)
    if c is not None:
        w.key("class", _q(c[0]), _why(c[1]))
        classes = _classes(c[1])
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
            if found is not None and not _unit(found[1]) and (found is not angle
                                                              or not pos.polar):
                w.add(f"{TODO_OPTIONAL} the DBC gives no unit for {found[1].name}: check that it "
                      "is in metres (the sensor's distance_scale converts)")
    rule, why, todos = _pick_validity(signals, dist_candidate)
    if rule:
        w.key("valid", _q(rule), why)
    if notes:
        for line in todos:
            w.add(line)
    tracks = role == "tracks" or (role is None and plan.tracks)
    w.key("lifetime", "0.3" if tracks else "0.1", "s an object lingers without a new frame")
    w.add()


# --- ego ------------------------------------------------------------------------------------------

_WHEEL = {"wheel", "whl"}
_NOT_WHEEL_SPEED = {"fault", "valid", "validity", "vld", "qf", "status", "stat", "sts", "sign",
                    "dir", "direction", "cnt", "count", "counter"}


def _wheel_mean(signals: Sequence[tuple[str, Signal]]) -> tuple[str, float, str] | None:
    """Four wheel speeds of one message in one linear unit: their mean (an expression), the
    scale to m/s and the unit."""
    by_message: dict[str, list[tuple[str, Signal]]] = {}
    for name, s in signals:
        t = set(tokens(s.name))
        if t & _WHEEL and t & {"speed", "spd", "velocity", "vel"} and _unit(s) in _SPEED \
                and not t & _NOT_WHEEL_SPEED:
            by_message.setdefault(name.rpartition(".")[0], []).append((name, s))
    for wheels in by_message.values():
        units = {_unit(s) for _, s in wheels}
        if len(wheels) == 4 and len(units) == 1:
            names = sorted(n for n, _ in wheels)
            return f"({' + '.join(names)}) / 4", _SPEED[units.pop()], wheels[0][1].unit or ""
    return None


def _fraction(coarse: Candidate, messages: Sequence[Message]) -> Signal | None:
    """The fine part of a steering angle sent in two (``STEER_ANGLE`` + ``STEER_FRACTION``): a
    signal of the same message and unit named fraction (or fine)."""
    message = coarse.name.rpartition(".")[0]
    for m in messages:
        if m.name != message:
            continue
        for s in m.signals:
            if s is not coarse.signal and set(tokens(s.name)) & {"fraction", "frac", "fine"} \
                    and _unit(s) == _unit(coarse.signal):
                return s
    return None


def _write_ego(w: _Writer, signals: Sequence[tuple[str, Signal]],
               messages: Sequence[Message],
               steering: tuple[Candidate, float] | None) -> None:
    yaw = _pick_yaw_rate(signals)
    w.add("# Ego motion, converted to SI by scale (m/s, rad/s, rad), left positive.")
    w.add("[ego]")
    mean = _wheel_mean(signals)
    if mean is not None:
        text, scale, unit = mean
        others = _pick_speed([(n, s) for n, s in signals if not set(tokens(s.name)) & _WHEEL])
        w.add(f"# The mean of the four wheel speeds ({unit}{' -> m/s' if scale != 1 else ''}): "
              "one wheel runs faster or slower in a turn,")
        w.add("# and a speedometer reads high by design; "
              + (f"the alternative is {others[0].name} ({others[0].signal.unit or 'no unit'})."
                 if others is not None else "no other speed signal was found."))
        w.key("speed", _value(text, scale), "the four wheels' mean (above)")
    else:
        speed = _pick_speed(signals)
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
        fine = _fraction(c, messages)
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
    lanes = _lane_messages(messages)
    if steering is not None:
        w.add("# Lanes from the steering angle (a bicycle model): no camera lines mapped.")
        w.add("[lanes]")
        w.key("length", "100.0", "m drawn ahead")
        if lanes:
            w.add(f"{TODO_OPTIONAL} lane signals found in {', '.join(sorted(set(lanes)))}: map "
                  "[lanes.left] and [lanes.right] (README \"Vehicle profiles\", Lanes)")
    elif lanes:
        w.add(f"{TODO_OPTIONAL} lane signals found in {', '.join(sorted(set(lanes)))}: map "
              "[lanes] with [lanes.left] and [lanes.right] (README \"Vehicle profiles\", Lanes)")
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
