"""Twins and a steady lead: one object seen in two slots is one object, and the lead changes
only when another object clearly is the lead.

:func:`twin_sets` groups the objects that lie within :data:`TWIN_DISTANCE_M` and
:data:`TWIN_SPEED_MPS` of each other (the scene draws a set as one); :class:`LeadKeeper` keeps its
lead until it clearly is not, and every change of its ``serial`` is a real lead change.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from bridge.frame import NS
from bridge.world.observe import ObjectObservation

#: Two objects of one group this close (m, ground plane) ...
TWIN_DISTANCE_M = 1.5
#: ... whose longitudinal velocities (where both have one) differ by at most this (m/s) are twins.
TWIN_SPEED_MPS = 1.0
#: The lead has left the ego lane when its centre is this far (m) outside a lane line.
LEAVE_MARGIN_M = 0.3
#: The lead vanished when neither it nor a twin of it was seen for longer than this (s).
GRACE_S = 0.5
#: Another in-lane object takes the lead when it is nearer by more than nearer_margin() ...
NEARER_MARGIN_M = 5.0
NEARER_SHARE = 0.1
#: ... for this long without a break (s).
NEARER_S = 0.5

Key = tuple[str, int]


def key(o: ObjectObservation) -> Key:
    return o.group, o.object_id


def are_twins(a: ObjectObservation, b: ObjectObservation) -> bool:
    """Whether ``a`` and ``b`` (of one group) look like one object seen twice."""
    if (a.x - b.x) ** 2 + (a.y - b.y) ** 2 > TWIN_DISTANCE_M ** 2:
        return False
    return a.vx is None or b.vx is None or abs(a.vx - b.vx) <= TWIN_SPEED_MPS


def _x(o: ObjectObservation) -> float:
    return o.x


def twin_sets(objects: Iterable[ObjectObservation]) -> dict[int, tuple[int, ...]]:
    """Object id -> the sorted ids of its set of twins (itself included), for every object of
    one group that has a twin (transitively: a chain of twins is one set)."""
    found = sorted(objects, key=_x)
    if len(found) < 2:
        return {}  # no twins without two objects
    parent = {o.object_id: o.object_id for o in found}

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    count = len(found)
    for n, a in enumerate(found):  # sorted by x: only neighbours within the distance compare
        ax = a.x
        for m in range(n + 1, count):
            b = found[m]
            if b.x - ax > TWIN_DISTANCE_M:
                break
            if are_twins(a, b):
                parent[root(a.object_id)] = root(b.object_id)
    if all(parent[i] == i for i in parent):
        return {}  # no twins (the common case)
    sets: dict[int, list[int]] = {}
    for i in parent:
        sets.setdefault(root(i), []).append(i)
    return {i: tuple(sorted(members)) for members in sets.values() if len(members) > 1
            for i in members}


def same_twins(a: Mapping[int, ObjectObservation], b: Mapping[int, ObjectObservation]) -> bool:
    """Whether two groups' objects (by id) make the same :func:`twin_sets`: the same ids, each
    at the same place with the same vx (what twins are judged by)."""
    if a.keys() != b.keys():
        return False
    for i, o in a.items():
        p = b[i]
        if o.x != p.x or o.y != p.y or o.vx != p.vx:
            return False
    return True


def nearer_margin(lead_x: float) -> float:
    """How much nearer (m) than a lead at ``lead_x`` another object must be to take the lead."""
    return max(NEARER_MARGIN_M, NEARER_SHARE * lead_x)


@dataclass(frozen=True)
class SteadyLead:
    """The lead of one tick: its latest observation (or None), and its serial number, which goes
    up by one at every real lead change (0 before the first lead)."""

    lead: ObjectObservation | None
    serial: int
    #: why it changed at this tick ("" when it did not)
    change: str = ""


class LeadKeeper:
    """The lead chosen from tracks, kept until another object clearly is the lead (see the module's
    rules). Call :meth:`update` once per tick, in log time order.

    The lead (``[lead] source = "tracks"``), followed through its twins, is kept until it leaves the
    ego lane (by :data:`LEAVE_MARGIN_M`), vanishes for more than :data:`GRACE_S`, or another in-lane
    object (not a twin) is nearer by :func:`nearer_margin` for :data:`NEARER_S`; the new lead is
    then the closest valid in-lane track, and ``serial`` goes up by one (``/perception/lead``'s
    ``lead_number``, the catalogue's ``lead_changes`` and cut-ins).
    """

    def __init__(self) -> None:
        self.lead: ObjectObservation | None = None
        self.serial = 0
        self._seen_ns = 0  # the last tick the lead (or a twin of it) was seen
        self._nearer: Key | None = None  # an in-lane object nearer than the lead ...
        self._nearer_since_ns = 0  # ... since this tick

    def shift(self, shift_ns: int) -> None:
        """The clock stepped: the times held move with it."""
        self._seen_ns += shift_ns
        self._nearer_since_ns += shift_ns

    def update(self, tracks: Mapping[Key, ObjectObservation], in_lane: Iterable[Key],
               outside_by: Mapping[Key, float], t_ns: int) -> SteadyLead:
        """The lead at log time ``t_ns``.

        - ``tracks``: every valid track now, by (group, id);
        - ``in_lane``: the tracks ahead inside the ego lane;
        - ``outside_by``: how far (m) each track's centre lies outside the ego lane (0 inside;
          a track with no lane there is missing).
        """
        candidates = sorted((tracks[k] for k in in_lane), key=lambda o: o.x)
        lead = self.lead
        if lead is None:
            return self._take(candidates[0] if candidates else None, t_ns, "appeared")
        now = self._follow(lead, tracks, t_ns)
        if now is None:
            if (t_ns - self._seen_ns) / NS > GRACE_S:
                return self._take(candidates[0] if candidates else None, t_ns,
                                  f"vanished for over {GRACE_S:g} s")
            return SteadyLead(lead, self.serial)
        self.lead, self._seen_ns = now, t_ns
        if outside_by.get(key(now), math.inf) > LEAVE_MARGIN_M:
            return self._take(candidates[0] if candidates else None, t_ns, "left the ego lane")
        nearer = next((o for o in candidates if o.x < now.x - nearer_margin(now.x)
                       and not (o.group == now.group and are_twins(o, now))), None)
        if nearer is None:
            self._nearer = None
        elif self._nearer != key(nearer):
            self._nearer, self._nearer_since_ns = key(nearer), t_ns
        elif (t_ns - self._nearer_since_ns) / NS >= NEARER_S:
            return self._take(nearer, t_ns, f"#{nearer.object_id} nearer by over "
                              f"{nearer_margin(now.x):.0f} m for {NEARER_S:g} s")
        return SteadyLead(now, self.serial)

    def _follow(self, lead: ObjectObservation, tracks: Mapping[Key, ObjectObservation],
                t_ns: int) -> ObjectObservation | None:
        """The lead's observation now: its own, else a twin where it would be by now."""
        own = tracks.get(key(lead))
        if own is not None:
            return own
        dt = (t_ns - lead.t_ns) / NS
        ahead = ObjectObservation(lead.group, lead.object_id, t_ns,
                                  lead.x + (lead.vx or 0.0) * dt,
                                  lead.y + (lead.vy or 0.0) * dt, True, lead.vx)
        twins = [o for k, o in tracks.items() if k[0] == lead.group and are_twins(o, ahead)]
        return min(twins, key=lambda o: (o.x - ahead.x) ** 2 + (o.y - ahead.y) ** 2,
                   default=None)

    def _take(self, lead: ObjectObservation | None, t_ns: int, why: str) -> SteadyLead:
        changed = lead is not None
        self.lead, self._nearer = lead, None
        if lead is not None:
            self.serial += 1
            self._seen_ns = t_ns
        return SteadyLead(lead, self.serial, why if changed else "")
