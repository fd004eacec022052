"""Raw frames in blocks: what a drive keeps of every frame, on ``/can/<bus>/frames``.

A drive's raw frames are archived as ``tankviz.CanFrameBlock`` messages (schemas/can_frame.proto):
the frames of one bus in one window of at most :data:`WINDOW_NS` (20 ms), one row each (id,
data, ``offset_ns`` after the block's first frame, flags, a DLC only where it is not the data's
length), in the order they were seen. ``/can/can0/frames.frames[:]{id==528}`` finds one id's
frames in Foxglove's Raw Messages panel.

How blocks are cut (:class:`BlockCutter`, fed every frame the pipeline sees, in its order): a bus's
block opens at its first frame that falls in no open block of the bus, whose time is the block's
log time, and holds the bus's frames stamped in ``[start, start + WINDOW_NS)``. The bus's first
frame outside it (later, or earlier: a clock that stepped back) closes it, and so does the
pipeline's time passing its end (any bus's frame; live, the clock: a quiet bus still has its
frames sent within a window), a clock step, a part of a drive that ends, the end of the drive.

Blocks are written in the order of their starts, and no frame is before its block's start
(until a clock steps back): a reader gets the pipeline's order back
(:class:`bridge.io.drives.BlockMerger`) by merging the frames of the blocks read so far by time,
up to the start of the block just read. Each bus's frames come back exactly in their order; across
buses the order is exact unless frames of two buses came out of time order or have the same stamp
(read back in the order their blocks were written). Rows are written straight in protobuf's wire
format (:func:`encode_block`), byte for byte what ``CanFrameBlock.SerializeToString`` gives.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, NamedTuple

from bridge.frame import END_NS, EXTENDED_KEY, Frame
from bridge.packed import BRS, ERROR, ESI, EXTENDED, FD, REMOTE, PackedFrames
from bridge.protowire import string, varint

#: The longest window of one block (20 ms: measured smallest with zstd, ``tools/bench_size.py``).
WINDOW_NS = 20_000_000


class RawBlock(NamedTuple):
    """One bus's frames in one window, as recorded: the serialized ``tankviz.CanFrameBlock``."""

    bus: str
    #: the block's first frame's time: its log time
    t_ns: int
    payload: bytes
    #: how many frames it holds
    frames: int


#: (arbitration id, is_extended, is_fd, is_error, is_remote, bitrate_switch,
#: error_state_indicator, dlc, data length)
_Kind = tuple[int, bool, bool, bool, bool, bool, bool, int, int]
#: kind of frame -> (the row's start for each length of its offset field: the row's tag and
#: length, its id field and its data field's tag and length; its flag and DLC fields)
_KINDS: dict[_Kind, tuple[tuple[bytes, ...], bytes]] = {}
#: offset -> its field (none for 0); the offsets of stamps in microseconds repeat
_OFFSETS: dict[int, bytes] = {0: b""}
#: a row in the block's ``frames`` (field 2, length-delimited)
_ROW_TAG = 2 << 3 | 2


def _kind(k: _Kind) -> tuple[tuple[bytes, ...], bytes]:
    """The fixed parts of the rows of a kind of frame."""
    arbitration_id, extended, fd, error, remote, brs, esi, dlc, n = k
    head = (b"\x08" + varint(arbitration_id) if arbitration_id else b"") + (
        b"\x12" + varint(n) if n else b"")
    tail = b"".join(bytes((number << 3, 1)) for number, flag in (
        (4, extended), (5, fd), (6, brs), (7, esi), (8, error), (9, remote)) if flag)
    if dlc != n:
        tail += b"\x50" + varint(dlc)
    starts = tuple(bytes((_ROW_TAG,)) + varint(len(head) + n + size + len(tail)) + head
                   for size in range(12))  # an offset field: a tag and up to 10 bytes
    if len(_KINDS) > 65536:  # ids x flags x lengths: only a babbling bus gets here
        _KINDS.clear()
    kind = _KINDS[k] = starts, tail
    return kind


def _offset(offset_ns: int) -> bytes:
    field = b"\x18" + varint(offset_ns)
    if len(_OFFSETS) > 65536:
        _OFFSETS.clear()
        _OFFSETS[0] = b""
    _OFFSETS[offset_ns] = field
    return field


def _name(bus: str) -> bytes:
    """A block's ``bus`` field."""
    return string(b"\x0a", bus) if bus else b""


def _row(frame: Frame, t_ns: int) -> bytes:
    """The row of ``frame`` in a block whose log time is ``t_ns``."""
    data = frame.data
    k = frame[2:3] + frame[4:] + (len(data),)
    starts, tail = _KINDS.get(k) or _kind(k)
    offset = _OFFSETS.get(frame.timestamp_ns - t_ns)
    if offset is None:
        offset = _offset(frame.timestamp_ns - t_ns)
    return starts[len(offset)] + data + offset + tail


#: (frame key, flags, DLC, data length) of a row of a PackedFrames -> its kind's fixed parts
_BLOCK_KINDS: dict[tuple[int, int, int, int], tuple[tuple[bytes, ...], bytes]] = {}


def _block_kind(key: int, flags: int, dlc: int, n: int) -> tuple[tuple[bytes, ...], bytes]:
    """The fixed parts of the rows of a kind of frame, from a PackedFrames's columns."""
    extended = bool(flags & EXTENDED)
    kind = _kind((key ^ EXTENDED_KEY if extended else key, extended, bool(flags & FD),
                  bool(flags & ERROR), bool(flags & REMOTE), bool(flags & BRS), bool(flags & ESI),
                  dlc, n))
    if len(_BLOCK_KINDS) > 65536:
        _BLOCK_KINDS.clear()
    _BLOCK_KINDS[key, flags, dlc, n] = kind
    return kind


def encode_block(bus: str, t_ns: int, frames: Iterable[Frame]) -> bytes:
    """A ``tankviz.CanFrameBlock`` of ``bus`` whose log time is ``t_ns``: a row per frame, in
    order (none stamped before ``t_ns``)."""
    return _name(bus) + b"".join(_row(frame, t_ns) for frame in frames)


class BlockCutter:
    """Cuts a drive's frames into blocks, and hands closed blocks to ``emit``.

    Feed every frame in the pipeline's order (:meth:`add`, or :meth:`add_rows` for rows of a
    :class:`~bridge.packed.PackedFrames`: the same blocks). A bus's block opens at its first
    frame that falls in no open block of the bus, and closes at the bus's first frame outside
    ``[start, start + window)``, or when the pipeline's time passes its end (checked at every
    frame, and by :meth:`due` / :meth:`flush_due` for live's clock), or at :meth:`flush` (a clock
    step, a part of a drive that ends, the end). Blocks closed together are emitted in the order
    of their starts. A frame's row is encoded as it comes (:func:`encode_block`'s rows)."""

    def __init__(self, emit: Callable[[list[RawBlock]], None], *,
                 window_ns: int = WINDOW_NS) -> None:
        self.emit = emit
        self.window_ns = window_ns
        #: bus -> [start, end, rows] of its open block
        self._open: dict[str, list[Any]] = {}
        #: the earliest end of an open block (none open: never)
        self._next_end = END_NS

    def _open_block(self, bus: str, t_ns: int) -> list[Any]:
        """A new block of ``bus`` from ``t_ns`` (its open one closed first)."""
        if bus in self._open:
            self._close([bus])
        end = t_ns + self.window_ns
        block = self._open[bus] = [t_ns, end, []]
        if end < self._next_end:
            self._next_end = end
        return block

    def add(self, frame: Frame) -> None:
        """One frame into its bus's open block (closing what it falls outside of first)."""
        t = frame.timestamp_ns
        if t >= self._next_end:
            self.flush_due(t)
        block = self._open.get(frame.bus)
        if block is None or not block[0] <= t < block[1]:
            block = self._open_block(frame.bus, t)
        # _row, inlined (live's per-frame path)
        data = frame.data
        k = frame[2:3] + frame[4:] + (len(data),)
        starts, tail = _KINDS.get(k) or _kind(k)
        offset = _OFFSETS.get(t - block[0])
        if offset is None:
            offset = _offset(t - block[0])
        block[2].append(starts[len(offset)] + data + offset + tail)

    def add_rows(self, frames: PackedFrames, i: int, j: int) -> None:
        """Rows ``i`` to ``j`` (excluded) of a block of frames, as :meth:`add` of each."""
        ts, bus_of, names = frames.t, frames.bus, frames.buses
        payloads, keys, flags, dlcs = frames.payloads(), frames.key, frames.flags, frames.dlc
        open_blocks, kinds, offsets = self._open, _BLOCK_KINDS, _OFFSETS
        next_end = self._next_end
        for r in range(i, j):
            t = ts[r]
            if t >= next_end:
                self.flush_due(t)
                next_end = self._next_end
            name = names[bus_of[r]]
            block = open_blocks.get(name)
            if block is None or not block[0] <= t < block[1]:
                block = self._open_block(name, t)
                next_end = self._next_end
            data = payloads[r]
            k = (keys[r], flags[r], dlcs[r], len(data))
            starts, tail = kinds.get(k) or _block_kind(*k)
            since = t - block[0]
            offset = offsets.get(since)
            if offset is None:
                offset = _offset(since)
            block[2].append(starts[len(offset)] + data + offset + tail)

    def due(self, t_ns: int) -> bool:
        """Whether log time ``t_ns`` is past the end of an open block."""
        return t_ns >= self._next_end

    def flush_due(self, t_ns: int) -> None:
        """Close every block whose window ends by log time ``t_ns``."""
        self._close([bus for bus, block in self._open.items() if block[1] <= t_ns])

    def flush(self) -> None:
        """Close every open block."""
        self._close(list(self._open))

    def _close(self, buses: list[str]) -> None:
        if not buses:
            return
        closed = sorted(((bus, self._open.pop(bus)) for bus in buses), key=lambda b: b[1][0])
        self._next_end = min((block[1] for block in self._open.values()), default=END_NS)
        self.emit([RawBlock(bus, start, _name(bus) + b"".join(rows), len(rows))
                   for bus, (start, _, rows) in closed])


def cut(frames: Iterable[Frame], *, window_ns: int = WINDOW_NS) -> list[RawBlock]:
    """The blocks of ``frames``, cut as the pipeline cuts them (every window closed)."""
    blocks: list[RawBlock] = []
    cutter = BlockCutter(blocks.extend, window_ns=window_ns)
    for frame in frames:
        cutter.add(frame)
    cutter.flush()
    return blocks
