"""Bits that switch between two moments: steady in one window of time, steady at the other
value in another ("always 0 while I did not press the brake, always 1 while I did").

An id needs :data:`MIN_FRAMES` frames in each window, and a bit that flips at a steady rhythm
over the whole source is a counter's, never a switch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from bridge.bringup.columns import Bytes, Columns, by_id

#: Frames an id needs in a window for its bits to be called steady there.
MIN_FRAMES = 2
#: A bit with this many flips at least ...
RHYTHM_FLIPS = 5
#: ... whose gaps (frames of its id between flips) spread less than this share of their mean
#: flips at a rhythm: a counter's bit.
RHYTHM_SPREAD = 0.1


@dataclass(frozen=True)
class Switch:
    """A bit steady at ``before`` in the first window and at ``after`` in the second."""

    bus: str
    key: int
    bit: int
    before: int
    after: int


@dataclass
class _Window:
    frames: int
    all_of: Bytes  # AND of the payloads
    any_of: Bytes  # OR of the payloads


def _merge(window: _Window | None, payload: Bytes) -> _Window:
    all_of = np.bitwise_and.reduce(payload, axis=0)
    any_of = np.bitwise_or.reduce(payload, axis=0)
    if window is None:
        return _Window(len(payload), all_of, any_of)
    width = max(len(all_of), len(window.all_of))

    def wide(a: Bytes) -> Bytes:
        return np.pad(a, (0, width - len(a)))

    return _Window(window.frames + len(payload), wide(window.all_of) & wide(all_of),
                   wide(window.any_of) | wide(any_of))


@dataclass
class _Rhythm:
    """Per bit of one id: flips, and the sum and sum of squares of the gaps between them
    (frames of the id)."""

    frames: int = 0
    last: Bytes | None = None
    last_flip: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    flips: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    s1: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    s2: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def add(self, payload: Bytes) -> None:
        bits = payload.shape[1] * 8
        if len(self.flips) < bits:
            grow = bits - len(self.flips)
            self.last_flip = np.concatenate((self.last_flip, np.full(grow, -1, np.int64)))
            self.flips = np.pad(self.flips, (0, grow))
            self.s1, self.s2 = np.pad(self.s1, (0, grow)), np.pad(self.s2, (0, grow))
        bits = len(self.flips)
        rows = payload if payload.shape[1] * 8 == bits else np.pad(
            payload, ((0, 0), (0, bits // 8 - payload.shape[1])))
        if self.last is not None:
            rows = np.vstack((self.last[None, :], rows))
            first = self.frames - 1
        else:
            first = 0
        self.frames += len(payload)
        self.last = rows[-1].copy()
        if len(rows) < 2:
            return
        changed = np.unpackbits(rows[1:] ^ rows[:-1], axis=1, bitorder="little")
        which, row = np.nonzero(changed.T)  # by bit, then by frame
        if not len(which):
            return
        frame = row.astype(np.int64) + first + 1
        same = np.concatenate(([False], which[1:] == which[:-1]))
        previous = np.where(same, np.concatenate(([0], frame[:-1])), self.last_flip[which])
        counted = previous >= 0
        gaps = (frame - previous)[counted].astype(np.float64)
        np.add.at(self.s1, which[counted], gaps)
        np.add.at(self.s2, which[counted], gaps * gaps)
        np.add.at(self.flips, which, 1)
        latest = np.concatenate((which[1:] != which[:-1], [True]))
        self.last_flip[which[latest]] = frame[latest]

    def rhythmic(self) -> npt.NDArray[np.bool_]:
        """Per bit: whether it flips at a steady rhythm (a counter's bit)."""
        n = np.maximum(self.flips - 1, 1)
        mean = self.s1 / n
        spread = np.sqrt(np.maximum(self.s2 / n - mean * mean, 0.0))
        return (self.flips >= RHYTHM_FLIPS) & (spread <= RHYTHM_SPREAD * mean)


class Steadiness:
    """Per id, the AND and OR of its payloads in each of two windows (log times, ns), and the
    rhythm of its bits over the whole source; a bit is steady in a window where they agree.
    """

    def __init__(self, first: tuple[int, int], second: tuple[int, int]) -> None:
        self.windows = (first, second)
        self._seen: tuple[dict[tuple[str, int], _Window], ...] = ({}, {})
        self._rhythms: dict[tuple[str, int], _Rhythm] = {}

    def add(self, columns: Columns) -> None:
        t = columns.t
        for bus, key, rows in by_id(columns):
            rhythm = self._rhythms.get((bus, key))
            if rhythm is None:
                rhythm = self._rhythms[(bus, key)] = _Rhythm()
            rhythm.add(columns.payload[rows, :int(columns.length[rows].max())])
        for w, (start, end) in enumerate(self.windows):
            inside = (t >= start) & (t < end)
            if not inside.any():
                continue
            seen = self._seen[w]
            for bus, key, rows in by_id(columns):
                rows = rows[inside[rows]]
                if len(rows):
                    seen[(bus, key)] = _merge(seen.get((bus, key)), columns.payload[rows])

    def switches(self) -> list[Switch]:
        """Every bit steady in both windows at different values, by bus, id and bit."""
        out = []
        first, second = self._seen
        for ident in sorted(first.keys() & second.keys()):
            a, b = first[ident], second[ident]
            if a.frames < MIN_FRAMES or b.frames < MIN_FRAMES:
                continue
            width = min(len(a.all_of), len(b.all_of))
            bits = [np.unpackbits(x[:width], bitorder="little")
                    for x in (a.all_of, a.any_of, b.all_of, b.any_of)]
            a_and, a_or, b_and, b_or = bits
            steady = (a_and == a_or) & (b_and == b_or) & (a_and != b_and)
            rhythm = self._rhythms[ident].rhythmic()
            steady &= ~np.pad(rhythm, (0, max(0, len(steady) - len(rhythm))))[:len(steady)]
            out += [Switch(ident[0], ident[1], int(bit), int(a_and[bit]), int(b_and[bit]))
                    for bit in np.flatnonzero(steady)]
        return out

    def frames(self, window: int) -> int:
        """Frames of every id seen in window 0 or 1."""
        return sum(w.frames for w in self._seen[window].values())
