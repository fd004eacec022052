"""The ego's motion, from the messages of no family: speed, yaw rate, steering angle, lanes.

Each pick comes with the scale that converts it to SI (m/s, rad/s, rad) and says why; the lane
messages (:func:`lane_messages`) are named by the draft but not mapped.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from cantools.database.can.message import Message
from cantools.database.can.signal import Signal

from bridge.profile.guess import (
    ANG,
    ANGLE,
    LENGTH,
    RATE,
    SPEED,
    TODO_OPTIONAL,
    Candidate,
    guessed_from,
    tokens,
    unit_of,
)

#: The words of a wheel's signal: a speedometer's alternative names none of them.
WHEEL = {"wheel", "whl"}
_NOT_WHEEL_SPEED = {"fault", "valid", "validity", "vld", "qf", "status", "stat", "sts", "sign",
                    "dir", "direction", "cnt", "count", "counter"}


def pick_speed(signals: Sequence[tuple[str, Signal]]) -> tuple[Candidate, float, list[str]] | None:
    """The vehicle's speed, its scale to m/s, and optional TODO lines."""
    best: tuple[int, Candidate, float, list[str]] | None = None
    for name, s in signals:
        t = set(tokens(s.name))
        unit = unit_of(s)
        if t & {"set", "cruise", "limit", "target", "calc", "rate", "accel", "req", "max", "min",
                "lat", "ratio", "factor", "comp"}:
            continue
        notes: list[str] = []
        if t & {"speed", "spd", "velocity", "vel"} and unit in SPEED:
            score = 3 if t & {"veh", "vehicle", "ego", "car"} else (1 if t & {"wheel", "whl"}
                                                                   else 2)
            scale = SPEED[unit]
            why = guessed_from(s, " -> m/s" if scale != 1 else "")
            if t & {"wheel", "whl"}:
                notes.append(f"{TODO_OPTIONAL} one wheel's speed stands for the vehicle's: an "
                             "expression can average the four")
        elif t & {"wheel", "whl"} and unit in RATE and not t & {"yaw", "steer", "ste"}:
            score, scale = 0, 0.33 * RATE[unit]
            why = (f"guessed from the name {s.name} and unit {s.unit}: a wheel's angular speed "
                   "times a rolling radius of 0.33 m")
            per_deg = "" if RATE[unit] == 1 else "times 0.01745 for deg/s, "
            notes.append(f"{TODO_OPTIONAL} scale is the wheel's rolling radius in metres "
                         f"({per_deg}measure yours)")
        else:
            continue
        if best is None or score > best[0]:
            best = (score, Candidate(name, s, why), scale, notes)
    return None if best is None else (best[1], best[2], best[3])


def pick_yaw_rate(signals: Sequence[tuple[str, Signal]]) -> tuple[Candidate, float] | None:
    """The yaw rate and its scale to rad/s (one named calc, ack or tx last)."""
    best: tuple[int, Candidate, float] | None = None
    for name, s in signals:
        t = set(tokens(s.name))
        unit = unit_of(s)
        if "yaw" not in t or unit not in RATE:
            continue
        if t & {"bias", "shift", "accel", "validity", "valid", "vld", "high", "qf", "plsblity"}:
            continue
        score = 0 if t & {"calc", "ack", "tx"} else 1
        scale = RATE[unit]
        c = Candidate(name, s, guessed_from(s, " -> rad/s" if scale != 1 else ""))
        if best is None or score > best[0]:
            best = (score, c, scale)
    return None if best is None else (best[1], best[2])


def pick_steering(signals: Sequence[tuple[str, Signal]]) -> tuple[Candidate, float] | None:
    """The steering wheel angle and its scale to rad (not a rate, request or torque)."""
    best: tuple[int, Candidate, float] | None = None
    for name, s in signals:
        t = set(tokens(s.name))
        unit = unit_of(s)
        steer = t & {"steer", "steering", "ste", "stw", "str", "swa", "strg"}
        if not steer or unit not in ANGLE or not t & (ANG | {"an", "whl", "wheel", "swa"}):
            continue
        if t & {"rate", "req", "request", "cmd", "torque", "ack", "ratio", "gear", "offset",
                "limit", "max", "min", "des", "target", "spd", "speed"}:
            continue
        score = 2 if t & {"whl", "wheel"} else 1
        scale = ANGLE[unit]
        c = Candidate(name, s, guessed_from(s, " -> rad" if scale != 1 else ""))
        if best is None or score > best[0]:
            best = (score, c, scale)
    return None if best is None else (best[1], best[2])


def lane_messages(messages: Iterable[Message]) -> list[str]:
    """The names of the messages with a lane signal in a length unit (not a width)."""
    found = []
    for m in messages:
        for s in m.signals:
            t = set(tokens(s.name)) | set(tokens(m.name))
            if t & {"lane", "ln", "lanes"} and unit_of(s) in LENGTH and not t & {"width"}:
                found.append(m.name)
                break
    return found


def wheel_mean(signals: Sequence[tuple[str, Signal]]) -> tuple[str, float, str] | None:
    """Four wheel speeds of one message in one linear unit: their mean (an expression), the
    scale to m/s and the unit."""
    by_message: dict[str, list[tuple[str, Signal]]] = {}
    for name, s in signals:
        t = set(tokens(s.name))
        if t & WHEEL and t & {"speed", "spd", "velocity", "vel"} and unit_of(s) in SPEED \
                and not t & _NOT_WHEEL_SPEED:
            by_message.setdefault(name.rpartition(".")[0], []).append((name, s))
    for wheels in by_message.values():
        units = {unit_of(s) for _, s in wheels}
        if len(wheels) == 4 and len(units) == 1:
            names = sorted(n for n, _ in wheels)
            return f"({' + '.join(names)}) / 4", SPEED[units.pop()], wheels[0][1].unit or ""
    return None


def fraction(coarse: Candidate, messages: Sequence[Message]) -> Signal | None:
    """The fine part of a steering angle sent in two (``STEER_ANGLE`` + ``STEER_FRACTION``): a
    signal of the same message and unit named fraction (or fine)."""
    message = coarse.name.rpartition(".")[0]
    for m in messages:
        if m.name != message:
            continue
        for s in m.signals:
            if s is not coarse.signal and set(tokens(s.name)) & {"fraction", "frac", "fine"} \
                    and unit_of(s) == unit_of(coarse.signal):
                return s
    return None
