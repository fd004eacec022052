"""What each (bus, id) of a source sends: frames, periods, lengths and how often each bit flips.

A :class:`Census` is fed data frames as columns in as many pieces as come, and tells each id as
an :class:`IdRow`, with its database message (or none) and the changing bits no signal covers.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bridge.bringup.columns import Array, Bytes, Columns, id_text
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


def _zero_padded(counts: Array, size: int) -> Array:
    """``counts`` followed by zeros up to ``size`` (``np.pad``'s result, for a tenth of its
    time: an id's first piece makes two of them)."""
    out = np.zeros(size, dtype=counts.dtype)
    out[:len(counts)] = counts
    return out


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
    #: the time of each piece's last frame
    ends: deque[int] = field(default_factory=deque)
    #: payload length (bytes) → frames
    lengths: dict[int, int] = field(default_factory=dict)
    #: per bit, the frames that flipped it
    flips: Array = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: flips since :meth:`Census.take_recent`
    recent: Array = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: the latest payload (zero-padded to the widest)
    last: Bytes | None = None

    def add(self, t: Array, payload: Bytes, length: Array, history: int | None,
            window_ns: int | None = None) -> None:
        """The id's next frames, in order; gaps kept: of the latest ``history`` pieces, or
        those ending within ``window_ns`` of the last frame."""
        width = max(payload.shape[1], len(self.flips) // 8)
        payload = _widen(payload, width)
        if len(self.flips) < width * 8:
            self.flips = _zero_padded(self.flips, width * 8)
            self.recent = _zero_padded(self.recent, width * 8)
        before = None if self.last is None else _widen(self.last[None, :], width)
        flips = flips_of(payload, before)
        self.flips += flips
        self.recent += flips
        gaps = np.diff(t if not self.frames else np.concatenate(([self.last_ns], t)))
        if window_ns is not None:  # (only those that end within the window of the last frame)
            gaps = gaps[(gaps >= 0) & (t[len(t) - len(gaps):] >= t[-1] - window_ns)]
        else:
            gaps = gaps[gaps >= 0]
        if not self.frames:
            self.first_ns = int(t[0])
        self.frames += len(t)
        self.last_ns = int(t[-1])
        self.keep_gaps(gaps, history, window_ns)
        self.last = payload[-1].copy()
        values, counts = np.unique(length, return_counts=True)
        for value, count in zip(values.tolist(), counts.tolist(), strict=True):
            self.lengths[value] = self.lengths.get(value, 0) + count

    def keep_gaps(self, gaps: Array, history: int | None, window_ns: int | None) -> None:
        """The gaps of the frames just added (up to :attr:`last_ns`): kept, then only those of
        the latest ``history`` pieces, or within ``window_ns`` of the last frame."""
        if len(gaps):
            self.gaps.append(gaps)
            self.ends.append(self.last_ns)
            if history is not None:
                while len(self.gaps) > history:
                    self.gaps.popleft()
                    self.ends.popleft()
        if window_ns is not None:
            _trim(self, window_ns)

    def all_gaps(self) -> Array:
        """Every gap kept, in order."""
        return np.concatenate(self.gaps) if self.gaps else np.zeros(0, dtype=np.int64)


def _trim(tally: Tally, window_ns: int) -> None:
    """Keep the pieces of gaps that end within ``window_ns`` of the tally's last frame."""
    since = tally.last_ns - window_ns
    gaps, ends = tally.gaps, tally.ends
    while ends and ends[0] < since:
        gaps.popleft()
        ends.popleft()


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
    """Median, 5th and 95th percentile of gaps in ns, as ms (None where there are none): what
    ``np.percentile(gaps, (50, 5, 95)) / 1e6`` gives, to the bit, in a tenth of its time (the
    linear interpolation between the two gaps around each, as numpy makes it)."""
    n = len(gaps)
    if not n:
        return None, None, None
    around = []
    for q in (0.5, 0.05, 0.95):
        at = (n - 1) * q
        below = math.floor(at)
        around.append((below, min(below + 1, n - 1), at - below))
    ordered = np.partition(gaps, sorted({i for a, b, _ in around for i in (a, b)}))
    out = []
    for below, above, share in around:
        a, b = int(ordered[below]), int(ordered[above])
        step = b - a
        out.append((a + step * share if share < 0.5 else b - step * (1 - share)) / 1e6)
    return out[0], out[1], out[2]


class Census:
    """Every id's :class:`Tally` of the frames fed so far.

    Gaps are kept whole, or those of the latest ``history`` pieces or ``window_ns``; a short payload
    counts its missing bytes as zeros; a clock stepping back gives no gap.
    """

    def __init__(self, *, history: int | None = None, window_ns: int | None = None) -> None:
        #: how many pieces of gaps an id keeps (None: all), and of how long before its latest
        #: frame (None: any)
        self.history = history
        self.window_ns = window_ns
        self.tallies: dict[tuple[str, int], Tally] = {}
        #: the bits each message's signals cover, by the message's id() (a census asked again
        #: and again, live, makes them once)
        self._covered: dict[int, tuple[Any, set[int]]] = {}

    def add(self, columns: Columns) -> None:
        """The next data frames, in order: as :meth:`Tally.add` of each id's rows, every id at
        once (a few numpy steps for the whole piece, a few Python ones per id)."""
        n = len(columns.t)
        if not n:
            return
        code = (columns.bus << 32) | columns.key
        order = np.argsort(code, kind="stable")
        ordered = code[order]
        starts = np.flatnonzero(np.concatenate(([True], ordered[1:] != ordered[:-1])))
        ends = np.append(starts[1:], n)
        tallies = []
        for c in ordered[starts].tolist():
            k = (columns.buses[c >> 32], c & 0xFFFFFFFF)
            tally = self.tallies.get(k)
            if tally is None:
                tally = self.tallies[k] = Tally(*k)
            tallies.append(tally)
        length = columns.length[order]
        # (each id's payloads are as wide as its widest so far: its last frame's bytes past
        # this piece's widest flip against zeros)
        width = max(columns.payload.shape[1], *(len(t.flips) // 8 for t in tallies))
        payload = _widen(columns.payload[order], width)
        before = np.empty_like(payload)
        before[1:] = payload[:-1]
        before[starts] = payload[starts]  # (an id's first frame: no flip)
        for s, tally in zip(starts.tolist(), tallies, strict=True):
            if tally.last is not None:
                before[s] = 0
                before[s, :len(tally.last)] = tally.last
        changed = payload ^ before
        # each id's rows unpacked and summed: a third of the time of eight add.reduceat calls
        # over every row, which accumulating uint8 into int64 along the rows makes slow
        flips = np.zeros((len(starts), width * 8), dtype=np.int64)
        for i, (s, e) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
            flips[i] = np.unpackbits(changed[s:e], axis=1, bitorder="little").sum(
                axis=0, dtype=np.int64)
        t = columns.t[order]
        since = np.empty_like(t)
        since[1:] = t[:-1]
        since[starts] = [tally.last_ns if tally.frames else t[s]
                         for s, tally in zip(starts.tolist(), tallies, strict=True)]
        gaps = t - since
        kept = gaps >= 0
        kept[[s for s, tally in zip(starts.tolist(), tallies, strict=True)
              if not tally.frames]] = False  # (a new id's first frame: no gap)
        segment = np.repeat(np.arange(len(starts)), ends - starts)
        if self.window_ns is not None:  # (only those that end within the window of the last)
            kept &= t >= (t[ends - 1] - self.window_ns)[segment]
        chosen = gaps[kept]
        splits = np.cumsum(kept)[ends - 1].tolist()
        widest = np.maximum.reduceat(length, starts).tolist()
        longest = int(length.max()) + 1
        pairs, counts = np.unique(segment * longest + length, return_counts=True)
        lengths = [divmod(p, longest) for p in pairs.tolist()]
        lasts = payload[ends - 1]
        firsts_ns, lasts_ns = t[starts].tolist(), t[ends - 1].tolist()
        history, window = self.history, self.window_ns
        done = 0
        for i, (tally, s, e) in enumerate(zip(tallies, starts.tolist(), ends.tolist(),
                                              strict=True)):
            w = max(widest[i], len(tally.flips) // 8)
            if len(tally.flips) < w * 8:
                tally.flips = _zero_padded(tally.flips, w * 8)
                tally.recent = _zero_padded(tally.recent, w * 8)
            these_flips = flips[i, :w * 8]
            tally.flips += these_flips
            tally.recent += these_flips
            if not tally.frames:
                tally.first_ns = firsts_ns[i]
            tally.frames += e - s
            tally.last_ns = lasts_ns[i]
            these = chosen[done:splits[i]]
            done = splits[i]
            tally.keep_gaps(these, history, window)
            tally.last = lasts[i, :w].copy()
        for (i, value), count in zip(lengths, counts.tolist(), strict=True):
            known = tallies[i].lengths
            known[value] = known.get(value, 0) + count

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
