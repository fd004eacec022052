"""Where a group's objects are drawn, and which share a place.

- Twins (one object seen in two slots, :func:`bridge.world.lead.twin_sets`) are drawn as one
  object at the mean of their places (:class:`Drawn`, :func:`drawn_objects`).
- A labelled detection within :data:`SHARED_PLACE_M` of a track is at the track's place
  (:func:`shared_places`): its label would be drawn over the track's, so the track's one label
  block speaks for it, and adds "group: class" for a class other than its own
  (:func:`place_notes`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import NamedTuple

from bridge.profile.model import ObjectClass
from bridge.world.observe import ObjectObservation

# A detection this close to a track (m, in the ground plane) is at the track's place: its label
# would be drawn over the track's, so the track's one label block speaks for it.
SHARED_PLACE_M = 2.0

#: What a label calls each class (a class without one has no class line).
CLASS_LABELS = {
    ObjectClass.CAR: "car",
    ObjectClass.TWO_WHEELER: "two-wheeler",
    ObjectClass.PEDESTRIAN: "PEDESTRIAN",
    ObjectClass.STATIONARY: "stationary",
}
#: CLASS_LABELS by the class's value (a str hashes faster than an Enum member)
LABEL_OF_VALUE = {kind._value_: label for kind, label in CLASS_LABELS.items()}


@dataclass(frozen=True)
class SharedPlaces:
    """Detections at a track's place (within SHARED_PLACE_M): one label block for the place."""

    #: (group, id) of the detections whose label the track's block carries
    covered: frozenset[tuple[str, int]] = frozenset()
    #: (group, id) of a track -> lines its block adds: the other classes seen at its place
    notes: Mapping[tuple[str, int], tuple[str, ...]] = field(default_factory=dict)


def shared_places(tracks: Sequence[ObjectObservation],
                  detections: Iterable[ObjectObservation]) -> SharedPlaces:
    """Which labelled detections sit at a track's place (the nearest track within
    SHARED_PLACE_M): their label is left to the track's block, which adds "group: class" for
    a class other than its own."""
    covered: set[tuple[str, int]] = set()
    notes: dict[tuple[str, int], set[str]] = {}
    if not tracks:
        return NO_SHARED_PLACES
    limit = SHARED_PLACE_M ** 2
    places = [(t.x, t.y, t) for t in tracks]
    for d in detections:
        if d.object_class._value_ not in LABEL_OF_VALUE:
            continue
        dx, dy = d.x, d.y
        nearest = tracks[0]  # the first of the nearest, as min() picks it
        best = math.inf
        for tx, ty, t in places:
            across = (tx - dx) ** 2
            if across >= limit:
                continue  # its gap is no less: beyond the place, whether nearest or not
            gap = across + (ty - dy) ** 2
            if gap < best:
                best, nearest = gap, t
        if best >= limit:
            continue
        covered.add((d.group, d.object_id))
        if d.object_class is not nearest.object_class:
            notes.setdefault((nearest.group, nearest.object_id), set()).add(
                f"{d.group}: {CLASS_LABELS[d.object_class]}")
    return SharedPlaces(frozenset(covered), {k: tuple(sorted(v)) for k, v in notes.items()})


NO_SHARED_PLACES = SharedPlaces()


class Drawn(NamedTuple):
    """One object as drawn: a set of twins (or one object alone) at its mean place."""

    group: str
    ids: tuple[int, ...]
    x: float
    y: float
    first: ObjectObservation  # the member with the lowest id: class, velocity

    @property
    def id_text(self) -> str:
        """The ids, as a label names them: ``2/8`` for twins."""
        ids = self.ids
        return str(ids[0]) if len(ids) == 1 else "/".join(str(i) for i in ids)


#: ``Drawn`` of a tuple of its fields: the very object ``Drawn(*fields)`` makes, without its
#: Python-level ``__new__``
_drawn = partial(tuple.__new__, Drawn)


def drawn_objects(objects: Mapping[int, ObjectObservation],
                  twins: Mapping[int, tuple[int, ...]]) -> list[Drawn]:
    """The objects of one group as drawn: each set of ``twins`` (id -> the ids of its set) as
    one object at the mean of its members' places, by lowest id."""
    out = []
    for i in sorted(objects):
        o = objects[i]
        ids = twins.get(i)
        if ids is None:  # alone: the mean of one place (0 + x, so -0.0 is 0.0 as in a sum)
            out.append(_drawn((o.group, (i,), o.x + 0.0, o.y + 0.0, o)))
            continue
        if ids[0] != i:
            continue  # drawn with the set's lowest id
        members = [objects[m] for m in ids if m in objects]
        out.append(Drawn(o.group, ids, sum(m.x for m in members) / len(members),
                         sum(m.y for m in members) / len(members), o))
    return out


def place_notes(places: SharedPlaces, o: Drawn) -> tuple[str, ...]:
    """The notes of the places of every twin of ``o``, each once."""
    return tuple(sorted({n for i in o.ids for n in places.notes.get((o.group, i), ())}))
