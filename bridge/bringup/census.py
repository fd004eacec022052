"""What each (bus, id) of a source sends: frames, periods, lengths and how often each bit flips.

A :class:`Census` is fed data frames as columns (:mod:`bridge.bringup.columns`) in their order,
in as many pieces as come, and keeps per id a :class:`Tally`: how many frames, the gaps between
them, the payload lengths seen, and per bit how many frames differ in it from the id's frame
before (a flip). :meth:`Census.rows` tells each id as an :class:`IdRow`, with the message a
database names it (or none) and the changing bits its signals do not cover.

Gaps are kept whole (for a drive of an hour, 8 bytes a frame), or only those of the latest
``history`` pieces (live: the latest seconds). A payload shorter than the id's widest counts its
missing bytes as zeros. A clock stepping back gives no gap (the gap after a step forward is
kept).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bridge.bringup.columns import Array, Bytes, Columns, by_id, id_text
from bridge.bringup.layout import message_bits
from bridge.frame import NS


def flips_of(payload: Bytes, before: Bytes | None = None) -> Array:
    """Per bit, how many rows of ``payload`` differ in it from the row before (the first from
    ``before``, where given; else it has none)."""
    rows = payload if before is None else np.vstack((before, payload))
    if len(rows) < 2:
        return np.zeros(payload.shape[1] * 8, dtype=np.int64)
    changed = np.bitwise_xor(rows[1:], rows[:-1])
    flips: Array = np.unpackbits(changed, axis=1, bitorder="little").sum(axis=0, dtype=np.int64)
    return flips


def _widen(payload: Bytes, width: int) -> Bytes:
    if payload.shape[1] >= width:
        return payload
    return np.pad(payload, ((0, 0), (0, width - payload.shape[1])))


@dataclass
class Tally:
    """One id's counts (see the module's description)."""

    bus: str
    key: int
    frames: int = 0
    first_ns: int = 0
    last_ns: int = 0
    #: gaps between the id's frames, ns (in pieces as they came)
    gaps: deque[Array] = field(default_factory=deque)
    #: payload length (bytes) → frames
    lengths: dict[int, int] = field(default_factory=dict)
    #: per bit, the frames that flipped it
    flips: Array = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: flips since :meth:`Census.take_recent`
    recent: Array = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: the latest payload (zero-padded to the widest)
    last: Bytes | None = None

    def add(self, t: Array, payload: Bytes, length: Array, history: int | None) -> None:
        """The id's next frames, in order."""
        width = max(payload.shape[1], len(self.flips) // 8)
        payload = _widen(payload, width)
        if len(self.flips) < width * 8:
            self.flips = np.pad(self.flips, (0, width * 8 - len(self.flips)))
            self.recent = np.pad(self.recent, (0, width * 8 - len(self.recent)))
        before = None if self.last is None else _widen(self.last[None, :], width)
        flips = flips_of(payload, before)
        self.flips += flips
        self.recent += flips
        gaps = np.diff(t if not self.frames else np.concatenate(([self.last_ns], t)))
        gaps = gaps[gaps >= 0]
        if len(gaps):
            self.gaps.append(gaps)
            if history is not None:
                while len(self.gaps) > history:
                    self.gaps.popleft()
        if not self.frames:
            self.first_ns = int(t[0])
        self.frames += len(t)
        self.last_ns = int(t[-1])
        self.last = payload[-1].copy()
        values, counts = np.unique(length, return_counts=True)
        for value, count in zip(values.tolist(), counts.tolist(), strict=True):
            self.lengths[value] = self.lengths.get(value, 0) + count

    def all_gaps(self) -> Array:
        return np.concatenate(self.gaps) if self.gaps else np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class IdRow:
    """One id as ``tankviz ids`` and the ``/can/<bus>/ids`` table tell it."""

    bus: str
    key: int
    frames: int
    #: median gap, and the 5th and 95th percentiles of the gaps, ms (None: under two frames)
    period_ms: float | None
    gap_p5_ms: float | None
    gap_p95_ms: float | None
    #: payload lengths seen (bytes)
    dlcs: tuple[int, ...]
    #: the database's name of the message, or None
    message: str | None
    #: bits that ever flipped
    changing_bits: int
    #: of those, bits no signal of the message covers (None for an unknown id)
    unexplained_bits: int | None
    #: bits that flipped since the census was last asked (:meth:`Census.take_recent`)
    recent_bits: int

    @property
    def id(self) -> str:
        return id_text(self.key)

    def as_json(self) -> dict[str, Any]:
        return {"bus": self.bus, "id": self.id, "frames": self.frames,
                "period_ms": self.period_ms, "gap_p5_ms": self.gap_p5_ms,
                "gap_p95_ms": self.gap_p95_ms, "dlcs": list(self.dlcs),
                "message": self.message, "changing_bits": self.changing_bits,
                "unexplained_bits": self.unexplained_bits}


#: The database message of a (bus, key), or None: what the census asks of the decoder.
Lookup = Callable[[str, int], Any]


def gap_figures(gaps: Array) -> tuple[float | None, float | None, float | None]:
    """Median, 5th and 95th percentile of gaps in ns, as ms (None where there are none)."""
    if not len(gaps):
        return None, None, None
    median, p5, p95 = np.percentile(gaps, (50, 5, 95)) / 1e6
    return float(median), float(p5), float(p95)


class Census:
    """Every id's :class:`Tally` of the frames fed so far."""

    def __init__(self, *, history: int | None = None) -> None:
        #: how many pieces of gaps an id keeps (None: all)
        self.history = history
        self.tallies: dict[tuple[str, int], Tally] = {}
        #: the bits each message's signals cover, by the message's id() (a census asked again
        #: and again, live, makes them once)
        self._covered: dict[int, tuple[Any, set[int]]] = {}

    def add(self, columns: Columns) -> None:
        """The next data frames, in order."""
        tallies = self.tallies
        for bus, key, rows in by_id(columns):
            tally = tallies.get((bus, key))
            if tally is None:
                tally = tallies[(bus, key)] = Tally(bus, key)
            width = int(columns.length[rows].max()) if len(rows) else 0
            tally.add(columns.t[rows], columns.payload[rows, :width], columns.length[rows],
                      self.history)

    def take_recent(self) -> dict[tuple[str, int], Array]:
        """Each id's flips since the last call, and start counting anew."""
        out = {}
        for k, tally in self.tallies.items():
            out[k] = tally.recent
            tally.recent = np.zeros_like(tally.recent)
        return out

    def _covered_by(self, message: Any) -> set[int]:
        known = self._covered.get(id(message))
        if known is None or known[0] is not message:
            known = self._covered[id(message)] = (message, set(message_bits(message)))
        return known[1]

    def rows(self, lookup: Lookup, recent: dict[tuple[str, int], Array] | None = None,
             buses: Iterable[str] | None = None) -> list[IdRow]:
        """Every id (of ``buses``), sorted by bus and id; ``lookup`` names its message."""
        wanted = None if buses is None else set(buses)
        out = []
        for (bus, key), tally in sorted(self.tallies.items()):
            if wanted is not None and bus not in wanted:
                continue
            message = lookup(bus, key)
            changing = np.flatnonzero(tally.flips)
            unexplained = None
            if message is not None:
                covered = self._covered_by(message)
                unexplained = sum(1 for bit in changing.tolist() if bit not in covered)
            flips_now = recent.get((bus, key)) if recent is not None else None
            median, p5, p95 = gap_figures(tally.all_gaps())
            out.append(IdRow(bus, key, tally.frames, median, p5, p95,
                             tuple(sorted(tally.lengths)),
                             None if message is None else message.name, len(changing),
                             unexplained,
                             0 if flips_now is None else int(np.count_nonzero(flips_now))))
        return out


def census_of(pieces: Iterable[Columns], *, history: int | None = None) -> Census:
    """The census of columns fed in order."""
    census = Census(history=history)
    for columns in pieces:
        census.add(columns)
    return census


def seconds(ns: int | float) -> float:
    return ns / NS


def window_rows(t: Array, window: Sequence[int] | None) -> Array:
    """The rows of sorted-or-not times ``t`` inside ``[start, end)`` ns (all without one)."""
    if window is None:
        return np.arange(len(t))
    return np.flatnonzero((t >= window[0]) & (t < window[1]))
