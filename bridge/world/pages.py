"""Pages: the frames of a multiplexed object message merged into one message per object and cycle.

A cycle that ends short is observed with what it has only if it has the position and every signal
the validity rule reads, else not judged at all, so the world keeps the object's last observation
rather than mixing cycles.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from operator import itemgetter
from typing import Any

from bridge.frame import NS

#: Pages of one object further apart than this are never one cycle (a radar's cycle is far
#: shorter); an object's pages older than this are forgotten.
CYCLE_LIMIT_NS = NS
#: The page after the longest pause opens the cycles once each page has this many pauses ...
_SAMPLES = 2
#: ... and its pause is this many times the next longest (else no page is known to open them).
_CLEAR = 1.5
#: A page's pause is the lower median of its latest pauses, so many: a lost page lengthens the
#: pause before the next, and one such does not move it.
_KEPT = 15


@dataclass
class PageStats:
    """What the merging of one group's multiplexed messages made, over a drive."""

    #: the messages merged (their names, or templates in an indexed family), multiplexors
    messages: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: cycles ended, complete or not
    cycles: int = 0
    #: cycles that ended without every signal the group reads
    incomplete: int = 0
    #: of those, cycles not observed: without the position or a signal the rule reads
    unjudged: int = 0
    #: each signal the group reads: in how many cycles it was missing
    missing: Counter[str] = field(default_factory=Counter)
    #: the signals the validity rule reads from pages
    rule: set[str] = field(default_factory=set)


class _Cycle:
    """One object's pages so far in one cycle."""

    __slots__ = ("first_ns", "pages", "position_ns", "values")

    def __init__(self, t_ns: int) -> None:
        self.first_ns = t_ns
        self.position_ns = t_ns
        self.pages: set[Hashable] = set()
        self.values: dict[str, Any] = {}


class PageMerger:
    """The pages of one multiplexed message merged per object (``key``) and cycle.

    ``multiplexors``: the signals whose values say which page a frame is; ``needed``: the signals
    the group reads that only some pages carry; ``position`` and ``rule``: those of them the
    position and the validity rule read.

    Pages of one object (by its id, or its slot) within one radar cycle become one message, timed by
    the page that carried the position; pages the group does not read are left out; a cycle is
    observed at once when complete. A cycle ends short when a page repeats, the cycle's opening page
    comes, or after :data:`CYCLE_LIMIT_NS`.
    """

    def __init__(self, multiplexors: tuple[str, ...], needed: frozenset[str],
                 position: frozenset[str], rule: frozenset[str], stats: PageStats) -> None:
        self.multiplexors = multiplexors
        self.needed = needed
        self.position = position
        self.judged = position | rule
        self.stats = stats
        stats.rule |= rule
        #: each object's open cycle
        self._open: dict[Hashable, _Cycle] = {}
        #: each object's latest page (time), for the pauses before each page
        self._last: dict[Hashable, int] = {}
        #: per page: the latest pauses before it (ns)
        self._pauses: dict[Hashable, deque[int]] = {}
        self._swept_ns: int | None = None
        self._opening: tuple[Hashable, float] | None = None

    def page(self, values: Mapping[str, Any]) -> Hashable:
        return tuple([values.get(m) for m in self.multiplexors])

    def opening(self) -> tuple[Hashable, float] | None:
        """The page that opens the radar's cycles, and a pause that ends one (midway between
        the pause before it and the next longest), once the pauses say so clearly; while they
        do not (many pages lost at once lengthen the pauses of the others), what they said
        last."""
        pauses = self._pauses
        if len(pauses) < 2 or any(len(kept) < _SAMPLES for kept in pauses.values()):
            return self._opening
        ranked = sorted(((sorted(kept)[(len(kept) - 1) // 2], page)
                         for page, kept in pauses.items()), key=itemgetter(0), reverse=True)
        (longest, first), (second, _) = ranked[0], ranked[1]
        if longest > _CLEAR * second:
            self._opening = (first, (longest + second) / 2)
        return self._opening

    def take(self, key: Hashable, values: Mapping[str, Any], t_ns: int
             ) -> list[tuple[dict[str, Any], int]]:
        """One page of object ``key``: the merged messages to observe (and their times), none
        while its cycle is incomplete, one most of the time, a cycle it ended first."""
        if self.needed.isdisjoint(values):
            return []  # a page of nothing the group reads
        page = self.page(values)
        last = self._last.get(key)
        self._last[key] = t_ns
        if last is not None and 0 <= t_ns - last < CYCLE_LIMIT_NS:
            kept = self._pauses.get(page)
            if kept is None:
                kept = self._pauses[page] = deque(maxlen=_KEPT)
            kept.append(t_ns - last)
        out: list[tuple[dict[str, Any], int]] = []
        cycle = self._open.get(key)
        if cycle is not None:
            timed_out = not 0 <= t_ns - cycle.first_ns < CYCLE_LIMIT_NS
            opening = self.opening()
            # the page that opens cycles, or another after as long a pause
            opens = opening is not None and (page == opening[0] or (
                last is not None and t_ns - last > opening[1]))
            if timed_out or opens or page in cycle.pages:
                del self._open[key]
                self._ended(cycle, out, observe=not timed_out)
                cycle = None
        if cycle is None:
            cycle = self._open[key] = _Cycle(t_ns)
        cycle.pages.add(page)
        cycle.values.update(values)
        if not self.position or not self.position.isdisjoint(values):
            cycle.position_ns = t_ns
        if self.needed.issubset(cycle.values):
            del self._open[key]
            self.stats.cycles += 1
            out.append((cycle.values, cycle.position_ns))
        if self._swept_ns is None:
            self._swept_ns = t_ns
        elif not 0 <= t_ns - self._swept_ns < CYCLE_LIMIT_NS:
            self._sweep(t_ns)
        return out

    def _ended(self, cycle: _Cycle, out: list[tuple[dict[str, Any], int]], *,
               observe: bool) -> None:
        """A cycle that ended without a page: counted, and observed if it can be judged."""
        stats = self.stats
        stats.cycles += 1
        stats.incomplete += 1
        missing = self.needed.difference(cycle.values)
        stats.missing.update(missing)
        if observe and self.judged.isdisjoint(missing):
            out.append((cycle.values, cycle.position_ns))
        else:
            stats.unjudged += 1

    def _sweep(self, t_ns: int) -> None:
        """Forget the objects not seen for :data:`CYCLE_LIMIT_NS` (their open cycles end)."""
        self._swept_ns = t_ns
        for key, cycle in list(self._open.items()):
            if not 0 <= t_ns - cycle.first_ns < CYCLE_LIMIT_NS:
                del self._open[key]
                self._ended(cycle, [], observe=False)
        self._last = {key: t for key, t in self._last.items()
                      if 0 <= t_ns - t < CYCLE_LIMIT_NS}

    def close(self) -> None:
        """The input ended: every open cycle ends, counted, not observed."""
        for cycle in self._open.values():
            self._ended(cycle, [], observe=False)
        self._open.clear()

    def shift(self, shift_ns: int) -> None:
        """The clock stepped: every time held moves with it."""
        for cycle in self._open.values():
            cycle.first_ns += shift_ns
            cycle.position_ns += shift_ns
        self._last = {key: t + shift_ns for key, t in self._last.items()}
        if self._swept_ns is not None:
            self._swept_ns += shift_ns
