"""What the drafted profile's sensors and object groups are, from the groups of companion families.

A group is objects when it has a position-like signal or its name says so, named after its
messages in snake case; each gets one sensor, its kind (camera, fusion, else radar) and role
(tracks or detections) from the names.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cantools.database.can.signal import Signal

from bridge.profile.families import Family, group_families, stem
from bridge.profile.guess import OBJECT_WORDS, has_position, pick_id, tokens

#: Words of a family's name that say only "objects": such a radar's sensor is called "radar".
_GENERIC = {"track", "tracks", "trk", "obj", "object", "objects", "target", "targets", "tgt"}
#: The profile's own tables: an object group of that name is NAME_objects.
_RESERVED = {"ego", "health", "lanes", "lead", "mio"}


def _snake(text: str) -> str:
    words = tokens(text)
    return "_".join(words) or "objects"


@dataclass(frozen=True)
class Group:
    """A group of companion families, one object per index, and their signals."""

    name: str
    families: tuple[Family, ...]
    #: (name to write, signal) of every signal of the group's messages
    signals: tuple[tuple[str, Signal], ...]


def _group(name: str, families: Sequence[Family]) -> Group:
    counts: dict[str, int] = {}
    for f in families:
        for n, _ in f.signals:
            counts[n] = counts.get(n, 0) + 1
    signals = tuple((n if counts[n] == 1 else f"{f.template}.{n}", s)
                    for f in families for n, s in f.signals)
    return Group(name, tuple(families), signals)


def object_groups(families: Sequence[Family]
                  ) -> tuple[list[tuple[str, list[Family]]], list[Family]]:
    """The groups of companion ``families`` that are objects, (name, families) each, and the
    families that are not."""
    object_like: list[tuple[str, list[Family]]] = []
    others: list[Family] = []
    used_names: set[str] = set()
    for fams in group_families(families):
        signals = [sig for f in fams for sig in f.signals]
        words = set(tokens(stem(fams[0].prefix)))
        if not has_position(signals) and not words & OBJECT_WORDS:
            others.extend(fams)
            continue
        base = _snake(stem(fams[0].prefix))
        if base in _RESERVED:
            base = f"{base}_objects"
        # the family with the position first
        fams = sorted(fams, key=lambda f: (not has_position(f.signals), f.template))
        object_like.append((_unique(base, used_names), fams))
    return object_like, others


@dataclass(frozen=True)
class Plan:
    """One sensor and what its family group becomes: (object group name, role or None) each,
    a radar's track slots both detections and tracks."""

    sensor: str
    group: Group
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


def plan_sensors(object_like: Sequence[tuple[str, list[Family]]]) -> list[Plan]:
    """The sensor and object groups of each of :func:`object_groups`' groups."""
    plans = []
    sensors: set[str] = set()
    groups = {name for name, _ in object_like}
    for gname, fams in object_like:
        g = _group(gname, fams)
        kind, kind_why = _kind(fams)
        words = {t for f in fams for t in tokens(stem(f.prefix))}
        tracks = bool(words & {"track", "tracks", "trk", "tracked"}) or pick_id(
            g.signals) is not None
        sensor = _unique("radar" if kind == "radar" and words and words <= _GENERIC else gname,
                         sensors)
        names: tuple[tuple[str, str | None], ...] = ((gname, "tracks" if tracks else None),)
        if tracks and kind == "radar":
            detections = sensor if sensor not in groups else f"{gname}_detections"
            groups.add(_unique(detections, groups))
            names = ((detections, "detections"), (gname, "tracks"))
        plans.append(Plan(sensor, g, kind, kind_why, tracks, names))
    return plans


def _kind(fams: Sequence[Family]) -> tuple[str, str]:
    words = {t for f in fams for t in tokens(f.template) + tokens(f.message.name)}
    if words & {"vision", "vsn", "vis", "camera", "cam", "mobileye", "video", "mono", "stereo"}:
        return "camera", "the message names say vision/camera"
    if words & {"fusion", "fus", "fused", "fusd"}:
        return "fusion", "the message names say fusion"
    return "radar", "guessed: the names say neither camera nor fusion"
