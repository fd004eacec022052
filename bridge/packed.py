"""A pack of frames as columns: how offline work hands frames over and decodes them in bulk.

A :class:`PackedFrames` holds N frames of any buses, in their order, as one column per field
(row ``i`` is the ``i``-th frame):

- ``buses``: the bus names, in the order they first come in the pack (the bus table);
- ``t``: ``array('q')``, log time in ns;
- ``bus``: one byte per frame, its index in ``buses``;
- ``key``: ``array('I')``, the frame key (:func:`bridge.frame.frame_key`: the arbitration id,
  with :data:`~bridge.frame.EXTENDED_KEY` set for a 29-bit id);
- ``flags``: one byte per frame, the bits :data:`FD`, :data:`BRS`, :data:`ESI`, :data:`ERROR`,
  :data:`REMOTE` and :data:`EXTENDED` (the last repeats ``key``'s, so the id comes back exactly);
- ``dlc``: one byte per frame (an ``array('q')`` instead in the rare pack with a DLC outside
  0-255, which a damaged text log can give);
- ``data``: every payload, one after the other, in one ``bytes``; ``ends``: ``array('I')``, the
  end offset of each frame's payload in it.

:meth:`~PackedFrames.to_bytes` and :meth:`PackedFrames.from_bytes` carry a pack between processes
as one buffer: a header, the bus names, then each column's raw bytes, in this machine's byte order
(a hand-over, not a file format). :meth:`PackedFrames.from_frames` packs
:class:`~bridge.frame.Frame` tuples; :meth:`~PackedFrames.frame` and iterating give back exactly
the same tuples. :meth:`~PackedFrames.groups` gives the rows of each ``(bus index, key)`` in order,
for :meth:`bridge.decode.decoder.Decoder.decode_packed` and
:meth:`bridge.health.traffic.TrafficCounting.count_packed`. A pack never changes once made. Bounds:
a time fits 64 signed bits, an id 32 bits (31 for an extended one), flags are taken as true or
false, and a pack has at most :data:`MAX_BUSES` buses; :meth:`PackedFrames.from_frames` raises
:class:`ValueError` naming the first frame beyond them, and :func:`packs` cuts frames into as many
packs as the bus limit takes.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Iterator, Sequence
from itertools import accumulate, chain, compress, repeat
from operator import or_, xor

from bridge.frame import EXTENDED_KEY, Frame

#: The flag bits of a frame (one byte per frame in :attr:`PackedFrames.flags`), in this order.
FD, BRS, ESI, ERROR, REMOTE, EXTENDED = 1, 2, 4, 8, 16, 32
#: Buses one pack can hold (its bus column has one byte per frame).
MAX_BUSES = 255

#: bytes.translate tables: one byte per flags value, 1 where the flag is set
_BIT_TABLES = {bit: bytes(1 if value & bit else 0 for value in range(256))
               for bit in (FD, BRS, ESI, ERROR, REMOTE, EXTENDED)}
#: the header of :meth:`PackedFrames.to_bytes`: magic, frames, buses, the DLC column's typecode,
#: payload bytes
_HEADER = struct.Struct("<4sIHcI")
_MAGIC = b"TVB1"
_NAME_LENGTH = struct.Struct("<H")


class PackedFrames:
    """N frames of any buses as columns, in their order (see the module's description)."""

    __slots__ = ("_all_flags", "_groups", "_payloads", "bus", "buses", "data", "dlc", "ends",
                 "flags", "key", "t")

    def __init__(self, buses: tuple[str, ...], t: array[int], bus: bytes, key: array[int],
                 flags: bytes, dlc: bytes | array[int], data: bytes, ends: array[int]) -> None:
        n = len(t)
        if not (len(bus) == len(key) == len(flags) == len(dlc) == len(ends) == n):
            raise ValueError("the columns of a frame pack must have one entry per frame")
        if len(buses) > MAX_BUSES:
            raise ValueError(f"a frame pack holds at most {MAX_BUSES} buses, not {len(buses)}")
        if (ends[-1] if n else 0) != len(data):
            raise ValueError("a frame pack's payload ends must end at its data's length")
        self.buses = buses
        self.t = t
        self.bus = bus
        self.key = key
        self.flags = flags
        self.dlc = dlc
        self.data = data
        self.ends = ends
        self._all_flags: int | None = None
        self._payloads: list[bytes] | None = None
        self._groups: dict[tuple[int, int], array[int]] | None = None

    @classmethod
    def from_frames(cls, frames: Sequence[Frame]) -> PackedFrames:
        """The pack of ``frames``, in their order; :class:`ValueError` for a frame beyond the
        module's bounds or more than :data:`MAX_BUSES` buses."""
        n = len(frames)
        if not n:
            return cls((), array("q"), b"", array("I"), b"", b"", b"", array("I"))
        (t_col, bus_col, id_col, data_col, ext_col, fd_col, error_col, remote_col, brs_col,
         esi_col, dlc_col) = zip(*frames, strict=True)
        buses = tuple(dict.fromkeys(bus_col))
        if len(buses) > MAX_BUSES:
            raise ValueError(f"a frame pack holds at most {MAX_BUSES} buses, these frames have "
                             f"{len(buses)} (bridge.packed.packs cuts them into packs)")
        if len(buses) == 1:
            bus = bytes(n)
        else:
            bus = bytes(map({name: i for i, name in enumerate(buses)}.__getitem__, bus_col))
        try:
            t = array("q", t_col)
        except (OverflowError, TypeError):
            raise ValueError(_first_beyond(frames)) from None
        extended = any(ext_col)
        try:
            if extended:
                ext_bits = list(map(EXTENDED_KEY.__mul__, map(bool, ext_col)))
                if max(compress(id_col, ext_col)) >= EXTENDED_KEY:
                    raise OverflowError
                key = array("I", map(or_, id_col, ext_bits))
            else:
                key = array("I", id_col)
        except (OverflowError, TypeError):
            raise ValueError(_first_beyond(frames)) from None
        # Each flag column as one int of a 0 or 1 byte per frame, shifted to its bit: the flags
        # are their sum, made and taken apart in C.
        flags_int = 0
        for shift, column in enumerate((fd_col, brs_col, esi_col, error_col, remote_col,
                                        ext_col)):
            if any(column):
                try:
                    ones = bytes(column)  # bools: 0 and 1
                except (TypeError, ValueError):
                    ones = bytes(map(bool, column))
                if max(ones) > 1:  # a true value other than True
                    ones = bytes(map(bool, column))
                flags_int |= int.from_bytes(ones, "little") << shift
        flags = flags_int.to_bytes(n, "little") if flags_int else None
        dlc: bytes | array[int]
        try:
            dlc = bytes(dlc_col)
        except (ValueError, TypeError):
            try:
                dlc = array("q", dlc_col)
            except (OverflowError, TypeError):
                raise ValueError(_first_beyond(frames)) from None
        data = b"".join(data_col)
        return cls(buses, t, bus, key, bytes(n) if flags is None else flags, dlc, data,
                   array("I", accumulate(map(len, data_col))))

    def __len__(self) -> int:
        return len(self.t)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PackedFrames):
            return NotImplemented
        return (self.buses == other.buses and self.t == other.t and self.bus == other.bus
                and self.key == other.key and self.flags == other.flags
                and list(self.dlc) == list(other.dlc) and self.data == other.data
                and self.ends == other.ends)

    __hash__ = None  # type: ignore[assignment]  # mutable columns

    def __repr__(self) -> str:
        return f"PackedFrames({len(self)} frames, buses={self.buses!r})"

    def all_flags(self) -> int:
        """Every flag bit set on at least one frame of the pack."""
        if self._all_flags is None:
            value = 0
            for f in set(self.flags):
                value |= f
            self._all_flags = value
        return self._all_flags

    def frame(self, i: int) -> Frame:
        """Row ``i`` as the frame it was made of."""
        n = len(self.t)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError("packed frames' row out of range")
        flags = self.flags[i]
        key = self.key[i]
        extended = bool(flags & EXTENDED)
        return Frame(self.t[i], self.buses[self.bus[i]], key ^ EXTENDED_KEY if extended else key,
                     self.data[self.ends[i - 1] if i else 0:self.ends[i]], extended,
                     bool(flags & FD), bool(flags & ERROR), bool(flags & REMOTE),
                     bool(flags & BRS), bool(flags & ESI), self.dlc[i])

    def payloads(self) -> list[bytes]:
        """Every frame's payload, in row order (made once: do not change the list)."""
        if self._payloads is None:
            data, ends = self.data, self.ends
            starts = chain((0,), ends)  # one longer than ends: zip stops at the last end
            self._payloads = [data[start:end] for start, end in zip(starts, ends)]  # noqa: B905
        return self._payloads

    def flag(self, bit: int) -> Iterator[bool]:
        """Whether each frame has flag ``bit`` (one of :data:`FD` ... :data:`EXTENDED`)."""
        if not self.all_flags() & bit:
            return repeat(False, len(self.t))
        return map(bool, self.flags.translate(_BIT_TABLES[bit]))

    def __iter__(self) -> Iterator[Frame]:
        n = len(self.t)
        buses = self.buses
        names: Iterator[str] | Sequence[str]
        names = repeat(buses[0], n) if len(buses) == 1 else map(buses.__getitem__, self.bus)
        ids: Iterator[int] | Sequence[int] = self.key
        extended = self.flag(EXTENDED)
        if self.all_flags() & EXTENDED:
            ids = map(xor, self.key, map(EXTENDED_KEY.__mul__, self.flag(EXTENDED)))
        return map(tuple.__new__, repeat(Frame), zip(
            self.t, names, ids, self.payloads(), extended, self.flag(FD), self.flag(ERROR),
            self.flag(REMOTE), self.flag(BRS), self.flag(ESI), self.dlc, strict=True))

    def slice(self, i: int, j: int) -> PackedFrames:
        """Rows ``i`` to ``j`` (excluded) as a pack, with the same bus table."""
        i, j, _ = slice(i, j).indices(len(self.t))
        j = max(i, j)
        start = self.ends[i - 1] if i else 0
        stop = self.ends[j - 1] if j > i else start
        ends = array("I", map((-start).__add__, self.ends[i:j])) if start else self.ends[i:j]
        dlc = self.dlc[i:j]
        return PackedFrames(self.buses, self.t[i:j], self.bus[i:j], self.key[i:j],
                          self.flags[i:j], dlc, self.data[start:stop], ends)

    def groups(self) -> dict[tuple[int, int], array[int]]:
        """The rows of each ``(bus index, key)``, in row order; the groups in the order of their
        first row (made once: do not change them)."""
        if self._groups is None:
            self._groups = self._make_groups()
        return self._groups

    def _make_groups(self) -> dict[tuple[int, int], array[int]]:
        rows: dict[int, array[int]] = {}
        get = rows.get
        if len(self.buses) <= 1:
            combined: Sequence[int] = self.key
            shift = 0
        else:
            shift = 32
            combined = list(map(or_, self.key, map((1 << 32).__mul__, self.bus)))
        for i, k in enumerate(combined):
            these = get(k)
            if these is None:
                rows[k] = these = array("I")
            these.append(i)
        mask = (1 << 32) - 1
        return {(k >> 32 if shift else 0, k & mask): r for k, r in rows.items()}

    def to_bytes(self) -> bytes:
        """The pack as one buffer (:meth:`from_bytes` makes it again)."""
        dlc = self.dlc
        typecode = b"q" if isinstance(dlc, array) else b"B"
        names = b"".join(_NAME_LENGTH.pack(len(b)) + b
                         for b in (name.encode() for name in self.buses))
        return b"".join((
            _HEADER.pack(_MAGIC, len(self.t), len(self.buses), typecode, len(self.data)),
            names, self.t.tobytes(), self.key.tobytes(), self.ends.tobytes(),
            dlc.tobytes() if isinstance(dlc, array) else dlc, self.bus, self.flags, self.data))

    @classmethod
    def from_bytes(cls, buffer: bytes | bytearray | memoryview) -> PackedFrames:
        """The pack :meth:`to_bytes` made ``buffer`` of."""
        view = memoryview(buffer)
        magic, n, bus_count, typecode, data_length = _HEADER.unpack_from(view)
        if magic != _MAGIC:
            raise ValueError("not a frame pack")
        at = _HEADER.size
        names = []
        for _ in range(bus_count):
            (length,) = _NAME_LENGTH.unpack_from(view, at)
            at += _NAME_LENGTH.size
            names.append(bytes(view[at:at + length]).decode())
            at += length

        def column(typecode: str) -> array[int]:
            nonlocal at
            values = array(typecode)
            size = values.itemsize * n
            values.frombytes(view[at:at + size])
            at += size
            return values

        t, key, ends = column("q"), column("I"), column("I")
        dlc: bytes | array[int]
        if typecode == b"q":
            dlc = column("q")
        else:
            dlc = bytes(view[at:at + n])
            at += n
        bus = bytes(view[at:at + n])
        flags = bytes(view[at + n:at + 2 * n])
        at += 2 * n
        data = bytes(view[at:at + data_length])
        if len(data) != data_length or at + data_length != len(view):
            raise ValueError("a frame pack's buffer is cut or too long")
        return cls(tuple(names), t, bus, key, flags, dlc, data, ends)


def packs(frames: Sequence[Frame]) -> list[PackedFrames]:
    """``frames`` as packs, in order: one, or, where they have more than :data:`MAX_BUSES`
    buses, as many as it takes (each cut where one more bus would not fit)."""
    try:
        return [PackedFrames.from_frames(frames)]
    except ValueError:
        if len(set(map(_bus_of, frames))) <= MAX_BUSES:
            raise
    out = []
    start = 0
    seen: set[str] = set()
    for i, frame in enumerate(frames):
        if frame.bus not in seen:
            if len(seen) == MAX_BUSES:
                out.append(PackedFrames.from_frames(frames[start:i]))
                start, seen = i, set()
            seen.add(frame.bus)
    out.append(PackedFrames.from_frames(frames[start:]))
    return out


def _bus_of(frame: Frame) -> str:
    return frame.bus


def _first_beyond(frames: Sequence[Frame]) -> str:
    """Which frame a pack cannot hold, and why."""
    for i, f in enumerate(frames):
        why = _beyond(f)
        if why:
            return f"frame {i} of the pack ({f.bus}, time {f.timestamp_ns!r}): {why}"
    return "a frame beyond a frame pack's bounds"


def _beyond(f: Frame) -> str:
    if not isinstance(f.timestamp_ns, int) or not -(1 << 63) <= f.timestamp_ns < 1 << 63:
        return f"time {f.timestamp_ns!r} does not fit 64 signed bits"
    limit = EXTENDED_KEY if f.is_extended else 1 << 32
    if not isinstance(f.arbitration_id, int) or not 0 <= f.arbitration_id < limit:
        return f"id {f.arbitration_id!r} is beyond a frame key's {limit.bit_length() - 1} bits"
    if not isinstance(f.dlc, int) or not -(1 << 63) <= f.dlc < 1 << 63:
        return f"DLC {f.dlc!r} does not fit 64 signed bits"
    return ""
