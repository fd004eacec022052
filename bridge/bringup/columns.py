"""Data frames as numpy columns, grouped per (bus, id).

:func:`data_frames` gives the rows of a :class:`~bridge.packed.PackedFrames` that carry data as
:class:`Columns` (times, buses, frame keys, payloads as one zero-padded ``uint8`` matrix);
:func:`by_id` and :func:`concat` split and join them, in order.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from bridge.frame import EXTENDED_KEY, key_id
from bridge.packed import ERROR, REMOTE, PackedFrames

Array = npt.NDArray[np.int64]
Bytes = npt.NDArray[np.uint8]


class Columns(NamedTuple):
    """Data frames as columns: row ``i`` is one frame."""

    #: log time, ns
    t: Array
    #: the bus names; ``bus`` holds an index into them
    buses: tuple[str, ...]
    bus: Array
    #: frame keys (:func:`bridge.frame.frame_key`)
    key: Array
    #: payloads, a row per frame, zero-padded to the widest
    payload: Bytes
    #: each payload's length in bytes
    length: Array


def id_text(key: int) -> str:
    """A frame key as people write the id: ``0x1A0``, a 29-bit id with eight digits."""
    if key & EXTENDED_KEY:
        return f"0x{key_id(key):08X}"
    return f"0x{key:03X}"


def data_frames(pack: PackedFrames, i: int = 0, j: int | None = None) -> Columns:
    """Rows ``i`` to ``j`` of ``pack`` that carry data, as columns."""
    n = len(pack)
    i, j, _ = slice(i, j).indices(n)
    j = max(i, j)
    t = np.frombuffer(pack.t, dtype=np.int64, count=n)[i:j]
    bus = np.frombuffer(pack.bus, dtype=np.uint8, count=n)[i:j].astype(np.int64)
    key = np.frombuffer(pack.key, dtype=np.uint32, count=n)[i:j].astype(np.int64)
    # (the ends of rows i - 1 to j only: a run of a few rows of a large pack costs a few)
    ends = np.frombuffer(pack.ends, dtype=np.uint32, count=n)[max(i - 1, 0):j].astype(np.int64)
    starts = ends[:-1] if i else np.concatenate(([0], ends[:-1]))
    length = (ends[1:] if i else ends) - starts
    if pack.all_flags() & (ERROR | REMOTE):
        flags = np.frombuffer(pack.flags, dtype=np.uint8, count=n)[i:j]
        keep = (flags & (ERROR | REMOTE)) == 0
        t, bus, key, starts, length = t[keep], bus[keep], key[keep], starts[keep], length[keep]
    data = np.frombuffer(pack.data, dtype=np.uint8)
    width = int(length.max()) if len(length) else 0
    payload = np.zeros((len(t), width), dtype=np.uint8)
    # the rows of each length at once: their own bytes, not the widest row's for every row (a
    # few 64-byte FD frames among 8-byte ones made it 8 times the work)
    # (the lengths present by a count of each: np.unique imports numpy.ma, 7 ms of a start)
    for size in np.flatnonzero(np.bincount(length)).tolist():
        if size:
            rows = np.flatnonzero(length == size)
            payload[rows, :size] = data[starts[rows, None] + np.arange(size)]
    return Columns(t, pack.buses, bus, key, payload, length)


def by_id(columns: Columns) -> Iterator[tuple[str, int, Array]]:
    """``(bus, key, rows)`` of each id in ``columns``, its rows in their order."""
    if not len(columns.t):
        return
    code = (columns.bus << 32) | columns.key
    order = np.argsort(code, kind="stable")
    ordered = code[order]
    cuts = np.flatnonzero(np.diff(ordered)) + 1
    for rows in np.split(order, cuts):
        c = int(code[rows[0]])
        yield columns.buses[c >> 32], c & 0xFFFFFFFF, rows


def concat(pieces: Sequence[Columns]) -> Columns:
    """Several pieces of columns as one, their rows in order (one bus table, the payloads
    padded to the widest)."""
    if len(pieces) == 1:
        return pieces[0]
    names = tuple(dict.fromkeys(name for p in pieces for name in p.buses))
    index = {name: i for i, name in enumerate(names)}
    width = max((p.payload.shape[1] for p in pieces), default=0)
    empty = np.zeros(0, dtype=np.int64)
    return Columns(
        np.concatenate([p.t for p in pieces]) if pieces else empty, names,
        np.concatenate([np.array([index[name] for name in p.buses], dtype=np.int64)[p.bus]
                        if len(p.bus) else empty for p in pieces]) if pieces else empty,
        np.concatenate([p.key for p in pieces]) if pieces else empty,
        np.vstack([np.pad(p.payload, ((0, 0), (0, width - p.payload.shape[1])))
                   for p in pieces]) if pieces else np.zeros((0, 0), dtype=np.uint8),
        np.concatenate([p.length for p in pieces]) if pieces else empty)
