"""The bring-up stage: what every id of every bus sends, published while a drive goes on.

:class:`BringUpMonitor` is fed like the health monitor (every frame live, a pack's rows
offline: the same figures either way) and ticked on log time at whole seconds. It publishes
``/can/<bus>/ids`` (``tankviz.CanIds``: a row per id, sorted), ``/can/bits`` and
``/can/bits/labels`` (the bit-change map, :mod:`bridge.bringup.bitmap`), and on
``/can/<bus>/unknown`` (:mod:`bridge.bringup.payload`) the data frames of ids no database of
their bus defines. Sinks that record no file get all of it; sinks that record files
(:attr:`bridge.sinks.base.Sink.records`) get at most :data:`FILE_HZ` unknown frames a second per
id and the tables every :data:`FILE_PERIOD_S` and at the end. A clock step
(:meth:`~BringUpMonitor.rebase`) leaves no gap; :attr:`BringUpMonitor.on_unknown` is told each
unknown ``(bus, frame key)`` once.
"""

from __future__ import annotations

from bisect import bisect_left
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations

from bridge.bringup.bitmap import MapRow, bit_map
from bridge.bringup.census import Census, IdRow
from bridge.bringup.columns import Columns, concat, data_frames
from bridge.bringup.payload import PayloadWriter
from bridge.decode.codec import Decoded
from bridge.decode.decoder import Decoder
from bridge.decode.outcome import Outcome
from bridge.frame import EXTENDED_KEY, NEVER_NS, NS, Frame
from bridge.packed import ERROR, REMOTE, PackedFrames, packs
from bridge.pb.bringup_pb2 import CanIds, CanPayload
from bridge.topics import (
    BITS_LABELS_TOPIC,
    BITS_TOPIC,
    TopicMessage,
    ids_topic,
    unknown_topic,
)

#: Seconds of log time between two publications.
PERIOD_S = 1.0
#: Seconds of an id's latest gaps that make its period and jitter.
WINDOW_S = 10.0
#: Frames a second per unknown id that files get on ``/can/<bus>/unknown``.
FILE_HZ = 0.5
#: Seconds of log time between two publications that files get (the ids tables and the map).
FILE_PERIOD_S = 60.0
#: What a message of no database is called in ``/can/<bus>/ids`` and the map's labels.
UNKNOWN = "unknown"
#: Frames fed one by one kept as they are before they are packed into a pack.
_PACK = 16384
#: Rows of a pack counted as frames again, with their neighbours (columns of a few rows cost
#: more than their frames).
_FEW = 64


class Made(NamedTuple):
    """A ``/can/<bus>/unknown`` message: as :class:`bridge.sinks.base.Serialized` (the pipeline
    has the monitor make those: :attr:`BringUpMonitor.envelope`)."""

    topic: str
    message_class: Any
    payload: bytes
    t_ns: int


class Published(NamedTuple):
    """A tick's messages, and whether the sinks that record files get them."""

    messages: list[TopicMessage]
    files: bool


_NOTHING = Published([], False)


class _Unknown:
    """An id no database of its bus defines."""

    __slots__ = ("key", "slot", "told", "topic", "write")

    def __init__(self, bus: str, key: int) -> None:
        self.key = key
        self.topic = unknown_topic(bus)
        self.write = PayloadWriter(key)
        #: the 1/FILE_HZ s of log time of its latest frame that files got
        self.slot: int | None = None
        #: whether its first frame came (and its bus's first unknown id was told)
        self.told = False


_NOT_SEEN: Any = object()  # (an id not looked up yet)


class BringUpMonitor:
    """Every id's census, ``/can/<bus>/unknown``, and the ids tables and bit map once a second
    (see the module's description). ``decoder``: the pipeline's, which says which ids are known
    and names their messages."""

    def __init__(self, decoder: Decoder, *, period_s: float = PERIOD_S,
                 window_s: float = WINDOW_S, file_hz: float = FILE_HZ,
                 file_period_s: float = FILE_PERIOD_S,
                 on_unknown: Callable[[str, int], None] | None = None) -> None:
        self.decoder = decoder
        self.period_ns = round(period_s * NS)
        self.window_ns = round(window_s * NS)
        self.file_period_ns = round(file_period_s * NS)
        self.slot_ns = round(NS / file_hz)
        self.census = Census(window_ns=self.window_ns)
        #: log time of the next tick; frames at or after it make it happen
        self.next_tick_ns = NEVER_NS  # (no frame yet)
        #: told ``(bus, frame key)`` of the first unknown id of each bus, as it comes
        self.on_unknown = on_unknown
        #: bus -> the frame key of its first unknown id (:func:`bridge.frame.frame_key`)
        self.first_unknown: dict[str, int] = {}
        #: whether a sink that records no file takes what is made (a viewer: every publication,
        #: every ``/unknown`` frame); else only what files get is made. Set by the pipeline
        #: before the first frame.
        self.everyone = True
        #: makes a ``/unknown`` message of (topic, message class, payload, log time)
        self.envelope: Callable[[str, Any, bytes, int], Any] = Made
        #: the ``/unknown`` messages made since the pipeline took them, and whether files keep
        #: each
        self.made: list[Any] = []
        self.kept: list[bool] = []
        #: frames fed one by one since the last count (the pipeline appends them itself)
        self.pending: list[Frame] = []
        #: what came before them since the last count: rows of packs, in order
        self._pieces: list[list[Any]] = []
        #: (bus, key) -> the unknown id, or None for a known one
        self._ids: dict[tuple[str, int], _Unknown | None] = {}
        #: each id's frames when its share of flips started to be counted
        self._frames_then: dict[tuple[str, int], int] = {}
        #: the pack whose unknown rows are found (:meth:`on_rows`), and they: the rows files
        #: keep and all of them, each with its id, in row order
        self._last_pack: PackedFrames | None = None
        self._rows: tuple[list[int], list[_Unknown], list[int], list[_Unknown]] = (
            [], [], [], [])

    # --- frames ----------------------------------------------------------------------------

    def on_frame(self, frame: Frame, decoded: Outcome) -> None:
        """One frame, as the decoder made it (the pipeline inlines this)."""
        self.pending.append(frame)
        if type(decoded) is not Decoded:
            self.on_undecoded(frame)

    def on_undecoded(self, frame: Frame) -> None:
        """A frame the decoder did not decode: its ``/unknown`` message if it is a data frame
        of an unknown id (and a sink takes it)."""
        t, bus, ident, data, extended, _, error, remote = frame[:8]
        if error or remote:
            return
        key = ident | EXTENDED_KEY if extended else ident  # frame_key, inlined
        unknown = self._ids.get((bus, key), _NOT_SEEN)
        if unknown is _NOT_SEEN:
            unknown = self._learn(bus, key)
        if unknown is None:
            return
        if not unknown.told:
            self._tell(bus, unknown)
        slot = t // self.slot_ns
        keep = slot != unknown.slot
        if keep:
            unknown.slot = slot
        elif not self.everyone:
            return
        self.made.append(self.envelope(unknown.topic, CanPayload, unknown.write(data), t))
        self.kept.append(keep)

    def on_rows(self, pack: PackedFrames, i: int, j: int) -> None:
        """Rows ``i`` to ``j`` (excluded) of a pack, after those before them, as
        :meth:`on_frame` of each."""
        if self.pending:
            self._pack()
        pieces = self._pieces
        if pieces and pieces[-1][0] is pack and pieces[-1][2] == i:
            pieces[-1][2] = j
        else:
            pieces.append([pack, i, j])
        if pack is not self._last_pack:
            self._find_unknown(pack)
        kept_rows, kept_ids, all_rows, all_ids = self._rows
        rows, ids = (all_rows, all_ids) if self.everyone else (kept_rows, kept_ids)
        a, b = bisect_left(rows, i), bisect_left(rows, j)
        if a == b:
            return
        kept = (set(kept_rows[bisect_left(kept_rows, i):bisect_left(kept_rows, j)])
                if self.everyone else None)
        ts, payloads, names, buses = pack.t, pack.payloads(), pack.buses, pack.bus
        envelope, made, keeps = self.envelope, self.made, self.kept
        for r, unknown in zip(rows[a:b], ids[a:b], strict=True):
            if not unknown.told:
                self._tell(names[buses[r]], unknown)
            made.append(envelope(unknown.topic, CanPayload, unknown.write(payloads[r]), ts[r]))
            keeps.append(kept is None or r in kept)

    def bound(self) -> None:
        """Pack the frames fed one by one once there are many (call it now and then: packed,
        they take far less memory)."""
        if len(self.pending) >= _PACK:
            self._pack()

    def _pack(self) -> None:
        """The frames fed one by one, packed (rows to count)."""
        self._pieces += [[pack, 0, len(pack)] for pack in packs(self.pending)]
        self.pending.clear()

    def _find_unknown(self, pack: PackedFrames) -> None:
        """A new pack's data rows of unknown ids, and which of them files keep (the first of
        their id in each slot of log time: decided here for the whole pack, in row order)."""
        self._last_pack = pack
        names = pack.buses
        n = len(pack)
        times = np.frombuffer(pack.t, dtype=np.int64, count=n)
        flags = (np.frombuffer(pack.flags, dtype=np.uint8, count=n)
                 if pack.all_flags() & (ERROR | REMOTE) else None)
        ids: list[_Unknown] = []
        rows_of: list[npt.NDArray[np.int64]] = []
        keep_of: list[npt.NDArray[np.bool_]] = []
        for (k, key), group in pack.groups().items():
            bus = names[k]
            unknown = self._ids.get((bus, key), _NOT_SEEN)
            if unknown is _NOT_SEEN:
                unknown = self._learn(bus, key)
            if unknown is None:
                continue
            rows = np.frombuffer(group, dtype=np.uint32).astype(np.int64)
            if flags is not None:
                rows = rows[(flags[rows] & (ERROR | REMOTE)) == 0]
            if not len(rows):
                continue
            slots = times[rows] // self.slot_ns
            keep = np.empty(len(rows), dtype=np.bool_)
            keep[1:] = slots[1:] != slots[:-1]
            keep[0] = unknown.slot is None or int(slots[0]) != unknown.slot
            unknown.slot = int(slots[-1])
            ids.append(unknown)
            rows_of.append(rows)
            keep_of.append(keep)
        if not ids:
            self._rows = ([], [], [], [])
            return
        rows = np.concatenate(rows_of)
        which = np.repeat(np.arange(len(ids)), [len(r) for r in rows_of])
        keep = np.concatenate(keep_of)
        kept_rows, kept_which = rows[keep], which[keep]
        first = np.argsort(kept_rows, kind="stable")
        self._rows = (kept_rows[first].tolist(), [ids[i] for i in kept_which[first].tolist()],
                      [], [])
        if self.everyone:
            first = np.argsort(rows, kind="stable")
            self._rows = (self._rows[0], self._rows[1], rows[first].tolist(),
                          [ids[i] for i in which[first].tolist()])

    def _learn(self, bus: str, key: int) -> _Unknown | None:
        """Whether a database of ``bus`` defines ``key``: None if one does, else the id."""
        unknown = None if self.decoder.knows(bus, key) else _Unknown(bus, key)
        self._ids[(bus, key)] = unknown
        return unknown

    def _tell(self, bus: str, unknown: _Unknown) -> None:
        unknown.told = True
        if bus not in self.first_unknown:
            self.first_unknown[bus] = unknown.key
            if self.on_unknown is not None:
                self.on_unknown(bus, unknown.key)

    def take_made(self) -> tuple[list[Any], list[bool]]:
        """The ``/unknown`` messages made since the last call, and whether files keep each."""
        made, kept = self.made, self.kept
        self.made, self.kept = [], []
        return made, kept

    # --- ticks -----------------------------------------------------------------------------

    def _period(self) -> int:
        """Between two ticks: a second for viewers, else the files' period."""
        return self.period_ns if self.everyone else self.file_period_ns

    def advance(self, t_ns: int) -> Published:
        """The publication due before log time ``t_ns``, if one is (call it before the frame
        at ``t_ns``, and with the clock when no frame comes)."""
        if t_ns < self.next_tick_ns:
            return _NOTHING
        period = self._period()
        if self.next_tick_ns == NEVER_NS:
            self.next_tick_ns = (t_ns // period + 1) * period
            return _NOTHING
        tick = self.next_tick_ns
        self.next_tick_ns = (t_ns // period + 1) * period
        return Published(self.publish(tick), tick % self.file_period_ns == 0)

    def finish(self, last_ns: int) -> Published:
        """At the end of the drive: a last publication, for files too, at the time of its last
        frame (``last_ns``: the drive's length stays the frames'), if frames came since the
        one before."""
        if self.next_tick_ns == NEVER_NS or not (self.pending or self._pieces):
            return _NOTHING
        return Published(self.publish(last_ns), True)

    def rebase(self, shift_ns: int, t_ns: int) -> None:
        """The clock stepped by ``shift_ns`` to log time ``t_ns``: the frames before the step are
        counted, every id's times move with the clock (no gap across the step), and the next
        tick is the one of the grid after ``t_ns``: nothing is drawn at the step itself, where
        live's health and scene catch up on the new clock."""
        self._count()
        for tally in self.census.tallies.values():
            tally.first_ns += shift_ns
            tally.last_ns += shift_ns
            tally.ends = deque(end + shift_ns for end in tally.ends)
        if self.next_tick_ns != NEVER_NS:
            period = self._period()
            self.next_tick_ns = (t_ns // period + 1) * period

    def _count(self, cuts: Sequence[int] = ()) -> None:
        """The frames since the last count into the census: the frames before each of
        ``cuts`` (log times) a piece, the shares of flips counted from the last cut on."""
        if self.pending:
            self._pack()
        if not self._pieces:
            return
        columns = concat(self._columns())
        self._pieces.clear()
        for cut in cuts:
            before = columns.t < cut
            if before.any():
                self.census.add(_rows(columns, before))
                columns = _rows(columns, ~before)
            self._start_shares()
        if len(columns.t):
            self.census.add(columns)

    def _columns(self) -> list[Columns]:
        """The rows to count as columns; runs of a few rows (packs of a few frames) made one
        pack again first."""
        out: list[Columns] = []
        few: list[Frame] = []
        for pack, i, j in self._pieces:
            if j - i < _FEW:
                few += map(pack.frame, range(i, j))
                continue
            if few:
                out += [data_frames(b) for b in packs(few)]
                few = []
            out.append(data_frames(pack, i, j))
        if few:
            out += [data_frames(b) for b in packs(few)]
        return out

    def _start_shares(self) -> None:
        """The shares of flips count from here."""
        self.census.take_recent()
        self._frames_then = {k: tally.frames for k, tally in self.census.tallies.items()}

    def publish(self, t_ns: int) -> list[TopicMessage]:
        """Count what came, and the ids tables and the bit map at log time ``t_ns`` (the shares
        of flips: of the last second)."""
        self._count([] if self.everyone else [t_ns - self.period_ns])
        census = self.census
        recent = census.take_recent()
        rows = census.rows(self.message, recent)
        out = []
        bus_rows: dict[str, list[IdRow]] = {}
        for row in rows:
            bus_rows.setdefault(row.bus, []).append(row)
        for bus, these in bus_rows.items():
            out.append(TopicMessage(ids_topic(bus), ids_message(bus, these), t_ns))
        drawn = []
        then = self._frames_then
        for row in rows:
            k = (row.bus, row.key)
            tally = census.tallies[k]
            frames = tally.frames - then.get(k, 0)
            flips = recent[k]
            share = flips / frames if frames else np.zeros(len(flips))
            drawn.append(MapRow(row.bus, row.key, row.message, len(tally.flips) // 8,
                                tally.flips > 0, share))
        self._frames_then = {k: tally.frames for k, tally in census.tallies.items()}
        image, labels = bit_map(drawn, t_ns)
        out += [TopicMessage(BITS_TOPIC, image, t_ns),
                TopicMessage(BITS_LABELS_TOPIC, labels, t_ns)]
        return out

    def message(self, bus: str, key: int) -> Any:
        """The database message of (bus, frame key), or None: the decoder's (a J1939 message's
        for every source address of its PGN)."""
        return self.decoder.message_of(bus, key)

    def topics(self, buses: Iterable[str]) -> list[tuple[str, Any]]:
        """Every topic it publishes on these buses, with its message class."""
        out: list[tuple[str, Any]] = []
        for bus in buses:
            out += [(ids_topic(bus), CanIds), (unknown_topic(bus), CanPayload)]
        return [*out, (BITS_TOPIC, CompressedImage), (BITS_LABELS_TOPIC, ImageAnnotations)]


def _rows(columns: Columns, chosen: npt.NDArray[np.bool_]) -> Columns:
    """The rows of ``columns`` where ``chosen``."""
    return Columns(columns.t[chosen], columns.buses, columns.bus[chosen], columns.key[chosen],
                   columns.payload[chosen], columns.length[chosen])


def ids_message(bus: str, rows: Iterable[IdRow]) -> CanIds:
    """The ``/can/<bus>/ids`` table of a bus's rows (times rounded to 0.1 us: the
    table shows them as they are)."""
    out = CanIds(bus=bus)
    for r in rows:
        jitter = (r.gap_p95_ms - r.gap_p5_ms
                  if r.gap_p95_ms is not None and r.gap_p5_ms is not None else 0.0)
        row = out.rows.add(id=r.id, message=r.message or UNKNOWN, frames=r.frames,
                           period_ms=round(r.period_ms or 0.0, 4), jitter_ms=round(jitter, 4),
                           dlc=",".join(map(str, r.dlcs)), changing_bits=r.changing_bits,
                           changed_last_s=r.recent_bits)
        # an unknown id's changing bits are all unexplained (and the Table has a number there)
        row.unexplained_bits = (r.changing_bits if r.unexplained_bits is None
                                else r.unexplained_bits)
    return out
