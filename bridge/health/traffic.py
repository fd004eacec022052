"""What the health monitor counts of every frame, per bus and per family.

Frames are counted one by one (:meth:`TrafficCounting.on_frame`, the hot path) or a pack at a
time, count for count the same; either way each frame is counted by the outcome the decoder gave
it, never sorted again. :mod:`bridge.health.counts` holds the counts.
"""

from __future__ import annotations

from array import array
from bisect import bisect_left
from collections import deque
from collections.abc import Sequence
from functools import reduce
from itertools import chain
from operator import add, itemgetter
from typing import NamedTuple

from bridge.decode.codec import Decoded, MessageCodec
from bridge.decode.decoder import Decoder
from bridge.decode.outcome import Outcome, Undecoded
from bridge.frame import EXTENDED_KEY, NS, Frame, frame_key
from bridge.health.alarms import HealthSettings
from bridge.health.bus_bits import MAX_KINDS, FrameKind, KindKey
from bridge.health.counts import NEVER, BusCounts, FamilyCounts
from bridge.packed import BRS, ERROR, ESI, EXTENDED, FD, REMOTE, PackedFrames

# why a frame did not decode (module globals: the per-frame path)
_ERROR_FRAME, _UNKNOWN_ID, _DECODE_ERROR, _REMOTE = (
    Undecoded.ERROR_FRAME, Undecoded.UNKNOWN_ID, Undecoded.DECODE_ERROR, Undecoded.REMOTE)


class BusRows(NamedTuple):
    """One bus's rows of a pack, in row order, with their times, keys and bits."""

    rows: Sequence[int]
    times: Sequence[int]
    keys: Sequence[int]
    arbitration: list[float]
    #: None: no frame of the pack switches its bit rate
    data_phase: list[float] | None


class PackedCount(NamedTuple):
    """A pack's frames made ready to count (:meth:`TrafficCounting.count_packed`)."""

    pack: PackedFrames
    #: what the decoder made of each row
    decoded: Sequence[Outcome]
    #: the kinds of frame of each bus, the pack's counted in
    kinds: dict[str, dict[KindKey, FrameKind]]
    #: each bus index's rows, in the order of their first row
    buses: dict[int, BusRows]
    #: (row, bus index, why) of every row that did not decode and is counted, in row order
    undecoded: list[tuple[int, int, Undecoded]]
    #: rows with non-finite values
    bad: list[int]
    #: each family's rows and their times, in row order
    families: dict[FamilyCounts, tuple[Sequence[int], list[int]]]
    #: (row, codec) of the first row of each message the monitor had not seen, in row order
    firsts: list[tuple[int, MessageCodec]]

    @property
    def cuts(self) -> list[int]:
        """Where a run of rows must end for :meth:`TrafficCounting.count_rows` to count them as
        frame by frame: right after the first row of each message not seen before (its
        database's cycle time may shorten its bus's gap time)."""
        return [r + 1 for r, _ in self.firsts]


class TrafficCounting:
    """The frame-counting part of :class:`~bridge.health.monitor.HealthMonitor` (which sets
    these up and makes a bus's alarms when its first frame comes: :meth:`_add_bus`)."""

    decoder: Decoder
    settings: HealthSettings
    _buses: dict[str, BusCounts]
    _families_of: dict[MessageCodec, tuple[FamilyCounts, ...]]
    _by_message: dict[str, list[FamilyCounts]]
    #: (count, latest value) of every signal that had a non-finite value, by bus/Message.Signal
    _bad_values: dict[str, tuple[int, str]]

    def _add_bus(self, name: str, t_ns: int) -> BusCounts:
        """A bus's counts, at its first frame."""
        raise NotImplementedError

    def _resolve(self, bus: BusCounts, codec: MessageCodec) -> tuple[FamilyCounts, ...]:
        """First frame of a message on a bus: its families, cycle time and the bus's gap."""
        message = codec.message
        families = tuple(self._by_message.get(message.name, ()))
        self._families_of[codec] = families
        for family in families:
            family.seen_messages.add(message.name)
            family.buses.add(bus.name)
            bus.families.add(family.name)
        if message.cycle_time:
            bus.cycles[frame_key(message.frame_id, message.is_extended_frame)] = (
                message.cycle_time / 1000.0)
            gap = round(self.settings.gap_factor * message.cycle_time / 1000.0 * NS)
            bus.gap_ns = min(bus.gap_ns, gap)
        return families

    def on_frame(self, frame: Frame, decoded: Outcome) -> None:
        """Count one frame, given what the monitor's decoder made of it."""
        # By position (the eleven fields by name cost ~100 ns more a frame): timestamp_ns, bus,
        # arbitration_id, data, is_extended, is_fd, is_error, is_remote, bitrate_switch, esi, dlc.
        t, name, ident, data, extended, fd, error, remote, brs, esi, dlc = frame
        bus = self._buses.get(name)
        if bus is None:
            bus = self._add_bus(name, t)
        if t - bus.last_ns > bus.gap_ns:
            bus.gaps += 1  # a gap just ended
        bus.last_ns = t
        bus.frames += 1
        # the bits on the wire: exact for a sample of each kind, else its mean (FrameKind.bits)
        kind_key = (ident, extended, fd, error, remote, brs, esi, dlc if remote else len(data))
        kind = bus.kinds.get(kind_key)
        if kind is None:
            if len(bus.kinds) >= MAX_KINDS:
                bus.kinds.clear()
            kind = bus.kinds[kind_key] = FrameKind(frame)
        kind.frames += 1
        estimate = (kind.estimates.get(data.count(0)) if kind.frames < kind.next_exact
                    else None)
        arbitration, data_phase = kind.count(frame) if estimate is None else estimate
        bus.bits += arbitration
        if data_phase:
            bus.brs_bits += data_phase
        bus.ids[ident | EXTENDED_KEY if extended else ident] += 1  # frame_key, inlined
        if type(decoded) is not Decoded:
            if decoded is _UNKNOWN_ID:
                bus.unknown += 1
            elif decoded is _DECODE_ERROR:
                bus.decode_errors += 1
            elif decoded is _ERROR_FRAME:
                bus.error_frames += 1
            return
        if decoded.non_finite:
            self._non_finite(bus, decoded)
        families = self._families_of.get(decoded.codec)
        if families is None:
            families = self._resolve(bus, decoded.codec)
        for family in families:
            if t - family.last_ns > family.gap_ns:
                family.resumed_ns = t
                if family.first_ns == NEVER:
                    family.first_ns = t
            family.last_ns = t
            family.frames += 1

    def count_packed(self, pack: PackedFrames,
                    decoded: Sequence[Outcome]) -> PackedCount | None:
        """Get a pack's frames ready to be counted, a run of rows at a time
        (:meth:`count_rows`), as :meth:`on_frame` of each in order counts them; ``decoded``:
        what the decoder made of each row. None where the pack must be counted frame by frame
        (a bus with so many kinds of frame that the pack could make it forget them).

        The bits of every frame are counted here, a ``(bus, key)`` column at a time (a kind's
        exact counts and estimates follow its own frames only, whatever comes between them:
        :meth:`FrameKind.bits_of`), and each bus's and family's rows are gathered; the rest is
        counted at :meth:`count_rows`, in row order where order matters (gaps, the sum of the
        bits, ids and non-finite values first seen, families). A pack is counted exactly as
        frame by frame if every run ends right after each row of a message the monitor had not
        seen (:attr:`PackedCount.cuts`: the bus's gap time may change there)."""
        n = len(pack)
        names = pack.buses
        for name in names:
            bus = self._buses.get(name)
            if (len(bus.kinds) if bus is not None else 0) + n > MAX_KINDS:
                return None
        payloads, flags, dlcs, ts = pack.payloads(), pack.flags, pack.dlc, pack.t
        plain = not pack.all_flags()
        groups = pack.groups()
        bits: list[tuple[float, float]] = [(0.0, 0.0)] * n
        kinds = {name: (self._buses[name].kinds if name in self._buses else {})
                 for name in names}
        undecoded: list[tuple[int, int, Undecoded]] = []
        bad: list[int] = []
        family_rows: dict[FamilyCounts, list[Sequence[int]]] = {}
        firsts: list[tuple[int, MessageCodec]] = []
        for (k, key), rows in groups.items():
            whole = len(rows) == n
            datas = payloads if whole else list(map(payloads.__getitem__, rows))
            # runs of rows of one kind of frame: (flags, length or a remote frame's DLC)
            lengths = set(map(len, datas))
            these = {0} if plain else set(map(flags.__getitem__, rows))
            if len(lengths) == 1 and len(these) == 1 and not min(these) & REMOTE:
                runs = [(min(these), len(datas[0]), 0, len(datas))]
            else:
                runs = []
                for at, (r, data) in enumerate(zip(rows, datas, strict=True)):
                    f = flags[r]
                    m = dlcs[r] if f & REMOTE else len(data)
                    if not runs or runs[-1][:2] != (f, m):
                        runs.append((f, m, at, at + 1))
                    else:
                        runs[-1] = (f, m, runs[-1][2], at + 1)
            bus_kinds = kinds[names[k]]
            ident = key ^ EXTENDED_KEY if key & EXTENDED_KEY else key
            column: list[tuple[float, float]] = []
            for f, m, start, end in runs:
                kind_key = (ident, bool(f & EXTENDED), bool(f & FD), bool(f & ERROR),
                            bool(f & REMOTE), bool(f & BRS), bool(f & ESI), m)
                kind = bus_kinds.get(kind_key)
                if kind is None:
                    kind = bus_kinds[kind_key] = FrameKind(kind_key)
                column += kind.bits_of(datas[start:end])
            if whole:
                bits = column
            else:
                deque(map(bits.__setitem__, rows, column), 0)  # bits[rows] = column, in C
            results = decoded if whole else list(map(decoded.__getitem__, rows))
            fed: Sequence[int] = rows
            if Undecoded in set(map(type, results)):
                fed = []
                for r, d in zip(rows, results, strict=True):
                    if not isinstance(d, Undecoded):
                        fed.append(r)
                    elif d is not _REMOTE:  # (a remote frame is counted as no other)
                        undecoded.append((r, k, d))
                if not fed:
                    continue
            # a (bus, key)'s frames are of one message (the decoder's table)
            first = decoded[fed[0]]
            assert type(first) is Decoded
            codec = first.codec
            if codec.floats:  # (only a float signal can be non-finite)
                bad += [r for r, d in zip(rows, results, strict=True)
                        if type(d) is Decoded and d.non_finite]
            families = self._families_of.get(codec)
            if families is None:
                families = tuple(self._by_message.get(codec.message.name, ()))
                firsts.append((fed[0], codec))
            for family in families:
                family_rows.setdefault(family, []).append(fed)
        by_row = itemgetter(0)
        undecoded.sort(key=by_row)
        bad.sort()
        firsts.sort(key=by_row)
        arbitration = list(map(itemgetter(0), bits))
        data_phase = list(map(itemgetter(1), bits)) if pack.all_flags() & BRS else None
        buses: dict[int, BusRows] = {}
        if len(names) == 1:
            buses[0] = BusRows(range(n), ts, pack.key, arbitration, data_phase)
        else:
            of_bus: dict[int, list[array[int]]] = {}
            for (k, _), rows in groups.items():
                of_bus.setdefault(k, []).append(rows)
            for k, columns in of_bus.items():
                merged = sorted(chain.from_iterable(columns))
                buses[k] = BusRows(
                    merged, list(map(ts.__getitem__, merged)),
                    list(map(pack.key.__getitem__, merged)),
                    list(map(arbitration.__getitem__, merged)),
                    None if data_phase is None else list(map(data_phase.__getitem__, merged)))
        families_of: dict[FamilyCounts, tuple[Sequence[int], list[int]]] = {}
        for family, fed_columns in family_rows.items():
            fed_rows = (fed_columns[0] if len(fed_columns) == 1
                        else sorted(chain.from_iterable(fed_columns)))
            families_of[family] = (fed_rows, list(map(ts.__getitem__, fed_rows)))
        return PackedCount(pack, decoded, kinds, buses, undecoded, bad, families_of, firsts)

    def count_rows(self, c: PackedCount, i: int, j: int) -> None:
        """Count rows ``i`` to ``j`` (excluded) of a pack made ready by :meth:`count_packed`,
        which no run counted yet, as :meth:`on_frame` of each in turn (a run that holds a row
        of :attr:`PackedCount.cuts` but its last is counted as if that row came last)."""
        pack = c.pack
        names = pack.buses
        for k, (rows, times, keys, arbitration, data_phase) in c.buses.items():
            a, b = (i, j) if isinstance(rows, range) else (bisect_left(rows, i),
                                                         bisect_left(rows, j))
            if a == b:
                continue
            name = names[k]
            bus = self._buses.get(name)
            if bus is None:
                bus = self._add_bus(name, times[a])
                bus.kinds = c.kinds[name]
            last, gap, gaps = bus.last_ns, bus.gap_ns, 0
            for t in times[a:b]:
                if t - last > gap:
                    gaps += 1  # a gap just ended
                last = t
            bus.gaps += gaps
            bus.last_ns = last
            bus.frames += b - a
            bus.ids.update(keys[a:b])
            bus.bits = reduce(add, arbitration[a:b], bus.bits)
            if data_phase is not None:
                bus.brs_bits = reduce(add, data_phase[a:b], bus.brs_bits)
        undecoded = c.undecoded
        for _, k, why in undecoded[bisect_left(undecoded, (i,)):bisect_left(undecoded, (j,))]:
            bus = self._buses[names[k]]
            if why is _UNKNOWN_ID:
                bus.unknown += 1
            elif why is _DECODE_ERROR:
                bus.decode_errors += 1
            else:
                bus.error_frames += 1
        decoded = c.decoded
        for r in c.bad[bisect_left(c.bad, i):bisect_left(c.bad, j)]:
            d = decoded[r]
            assert type(d) is Decoded
            self._non_finite(self._buses[names[pack.bus[r]]], d)
        for r, codec in c.firsts[bisect_left(c.firsts, (i,)):bisect_left(c.firsts, (j,))]:
            if codec not in self._families_of:
                self._resolve(self._buses[names[pack.bus[r]]], codec)
        for family, (rows, times) in c.families.items():
            a, b = bisect_left(rows, i), bisect_left(rows, j)
            if a == b:
                continue
            last, gap, resumed, first = (family.last_ns, family.gap_ns, family.resumed_ns,
                                         family.first_ns)
            for t in times[a:b]:
                if t - last > gap:
                    resumed = t
                    if first == NEVER:
                        first = t
                last = t
            family.last_ns, family.resumed_ns, family.first_ns = last, resumed, first
            family.frames += b - a

    def _non_finite(self, bus: BusCounts, decoded: Decoded) -> None:
        """Count a frame's non-finite values (per signal, for the warnings on /log)."""
        bus.non_finite += len(decoded.non_finite)
        message = decoded.codec.message.name
        for name in decoded.non_finite:
            key = f"{bus.name}/{message}.{name}"
            count, _ = self._bad_values.get(key, (0, ""))
            self._bad_values[key] = (count + 1, str(decoded.signals.get(name)))
