"""Which signal of an object group means what, guessed from its name and unit.

Each pick scores the signals whose lower-case words and unit fit and takes the best, the first on
a tie; every pick says why (:func:`guessed_from`), and what could not be found is a :data:`TODO`
line when the profile needs it, :data:`TODO_OPTIONAL` otherwise.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from cantools.database.can.signal import Signal

#: The comment that marks something a profile needs and the draft could not find.
TODO = "# TODO:"
#: The comment that marks something optional the draft could not find or is unsure of.
TODO_OPTIONAL = "# TODO (optional):"

_DEG = 0.017453292519943295

# Units by kind: the factor to metres, metres per second, radians, radians per second.
LENGTH = {"m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0, "cm": 0.01,
          "mm": 0.001}
SPEED = {"m/s": 1.0, "meters/sec": 1.0, "m/sec": 1.0, "mps": 1.0, "meter/s": 1.0,
         "km/h": 1 / 3.6, "kph": 1 / 3.6, "kmh": 1 / 3.6, "kmph": 1 / 3.6, "mph": 0.44704}
ANGLE = {"deg": _DEG, "degree": _DEG, "degrees": _DEG, "°": _DEG, "rad": 1.0, "radian": 1.0,
         "radians": 1.0}
RATE = {"deg/s": _DEG, "deg/sec": _DEG, "degree/s": _DEG, "degrees/s": _DEG, "°/s": _DEG,
        "rad/s": 1.0, "rad/sec": 1.0}
_PERCENT = {"%", "percent"}

LONG = {"long", "lon", "longitudinal", "x", "dx"}
LAT = {"lat", "lateral", "y", "dy"}
_DIST = {"dist", "distance", "dst", "pos", "position", "rel", "d"}
_RANGE = {"range", "rng", "dist", "distance", "dst", "r"}
ANG = {"angle", "ang", "azimuth", "azmth", "azi", "az", "phi", "theta"}
_VEL = {"speed", "spd", "vel", "velocity", "v", "vx", "vy"}
_NOT_POSITION = {"sigma", "std", "var", "accel", "acc", "a", "rate", "width", "length",
                 "height", "loss", "vert", "ax", "ay", "dz", "z", "rear", "end", "offset",
                 "ofst", "misalignment", "mounting", "fov", "beamwidth"}
OBJECT_WORDS = {"obj", "object", "objects", "track", "tracks", "trk", "target", "tgt",
                "point", "radar", "detection", "det", "cluster"}


def tokens(name: str) -> list[str]:
    """The words of a signal or message name, lower case: ``LongDist`` -> long, dist."""
    name = re.sub(r"\{i[^}]*\}", "_", name)
    return [p.lower() for p in
            re.findall(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+", name)]


def unit_of(signal: Signal) -> str:
    """The signal's unit as the tables above spell it: lower case, no spaces."""
    return (signal.unit or "").strip().lower().replace(" ", "")


@dataclass(frozen=True)
class Candidate:
    """A guessed signal: the name to write (plain or Message.Signal) and why."""

    name: str
    signal: Signal
    why: str


def guessed_from(signal: Signal, unit_note: str = "") -> str:
    """Why a signal was picked: its name and unit (``unit_note`` after the unit, ``-> m/s``)."""
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
        unit = unit_of(s)
        if not t & axis or t & exclude or t & _NOT_POSITION or t & _VEL:
            continue
        if unit and unit not in units:
            continue
        scores[name] = (2 if unit else 0) + (1 if t & words else 0)
    return scores


def has_position(signals: Sequence[tuple[str, Signal]]) -> bool:
    """Whether any of ``signals`` looks like a position: x, y, range or angle."""
    return any(pick(signals) is not None
               for pick in (_pick_x, _pick_y, _pick_range, _pick_angle))


def _pick_x(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, LONG, LENGTH, _DIST, LAT))


def _pick_y(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, LAT, LENGTH, _DIST, LONG))


def _pick_range(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, _RANGE, LENGTH, set(), LONG | LAT))


def _pick_angle(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    return _best(signals, _score_position(signals, ANG, ANGLE, set(), set()))


@dataclass(frozen=True)
class Position:
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


def position(signals: Sequence[tuple[str, Signal]]) -> Position:
    """The position signals of a group's ``signals`` (name to write, signal)."""
    return Position(_pick_x(signals), _pick_y(signals), _pick_range(signals),
                    _pick_angle(signals))


def pick_velocity(signals: Sequence[tuple[str, Signal]], axis: set[str]
                  ) -> tuple[str, Signal] | None:
    """A speed along ``axis`` (:data:`LONG` or :data:`LAT`): relative, as a radar reports it."""
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        unit = unit_of(s)
        if not t & axis or not t & _VEL or t & {"sigma", "std", "accel", "acc", "a"}:
            continue
        if unit and unit not in SPEED:
            continue
        scores[name] = 2 if unit else 0
    return _best(signals, scores)


def pick_unaxed_velocity(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    """A relative speed whose name gives no axis (``REL_SPEED``): the closing speed along x."""
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        if not t & {"speed", "spd", "vel", "velocity"} or t & (LONG | LAT | {
                "sigma", "std", "accel", "acc", "a", "range", "rng", "rate", "lane", "ego"}):
            continue
        if unit_of(s) in SPEED:
            scores[name] = 1 if t & {"rel", "relative"} else 0
    return _best(signals, scores)


def _percent_like(signal: Signal) -> bool:
    """A unit of % or, without a unit, a range of 0..100."""
    unit = unit_of(signal)
    if unit:
        return unit in _PERCENT
    return signal.minimum is not None and signal.minimum >= 0 and signal.maximum == 100


def pick_probability(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    """An existence probability (or confidence) in %, or a score of 0..100."""
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        exist = bool(t & {"exist", "existence", "existance"})
        percent = unit_of(s) in _PERCENT
        if t & {"score"} and _percent_like(s) and not t & {"obstacle", "non", "class", "cls"}:
            scores[name] = 1
            continue
        if not t & {"prob", "probability", "exist", "existence", "conf", "confidence"}:
            continue
        if t & {"obstacle", "non", "class", "cls"} or not (exist or percent):
            continue
        scores[name] = (3 if exist else 0) + (2 if percent else 0)
    return _best(signals, scores)


def pick_class(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    """The object's class or type, one with a value table first."""
    scores = {}
    for name, s in signals:
        t = set(tokens(name))
        if not t & {"class", "cls", "classification", "type", "typ"}:
            continue
        if t & {"prob", "probability", "conf"} or unit_of(s) in _PERCENT:
            continue
        scores[name] = 1 if s.choices else 0
    return _best(signals, scores)


def pick_id(signals: Sequence[tuple[str, Signal]]) -> tuple[str, Signal] | None:
    """A stable object id (not a message's or a burst's), one named after objects first."""
    scores = {}
    for name, _ in signals:
        t = set(tokens(name))
        if "id" in t and not t & {"burst", "brst", "msg", "sn", "sgu"}:
            scores[name] = 1 if t & OBJECT_WORDS else 0
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


def pick_validity(signals: Sequence[tuple[str, Signal]], distance: Candidate | None
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


def classes_of(signal: Signal) -> dict[int, str]:
    """The class of each value of the signal's value table, from the words of its label."""
    out = {}
    for raw, label in (signal.choices or {}).items():
        text = str(label).lower()
        out[int(raw)] = next((cls for word, cls in _CLASS_WORDS if word in text), "unknown")
    return out
