"""Bits on the wire: how long each CAN frame takes on the bus, the measure of the bus load.

:func:`frame_bits` counts a frame's bits from SOF to the end of the interframe space, stuff bits
included, split into arbitration and data phase; the load is these bits over the bitrate (no
bitrate, no load). :class:`FrameKind` counts from a sample: the same frames always count the
same, and every one-second window's load is within 1 % of the exact one.
"""

from __future__ import annotations

from collections.abc import Iterable

from bridge.frame import Frame

#: An error frame: error flag (6), the other nodes' error flags (up to 6), delimiter (8), IFS (3).
ERROR_FRAME_BITS = 23
#: After the CRC, at the nominal bitrate: CRC delimiter, ACK slot, ACK delimiter, EOF (7), IFS (3).
_TAIL_BITS = 13
#: Expected stuff bits in the 15 CRC bits of a classic frame: random bits get one stuff bit in
#: about 30 (a Markov chain over the run length: P(run of 4 continues) = (1/8) / 1.875 / 2).
_CRC15_STUFF = 15 / 30
#: CAN FD payload lengths; a payload between two is padded up to the next with this byte.
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
_FD_PADDING = 0xCC


def _fd_length(n: int) -> tuple[int, int]:
    """The DLC code and the length on the wire of an ``n``-byte CAN FD payload."""
    for code, length in enumerate(_FD_LENGTHS):
        if n <= length:
            return code, length
    return 15, 64


def _stuff(value: int, nbits: int, state: int) -> tuple[int, int]:
    """Stuff bits inserted into ``nbits`` bits of ``value`` (MSB first), and the state after.

    The state is ``polarity * 4 + (run - 1)``: the wire's last bit and how many equal bits end
    the wire (1-4; at 5 a complementary stuff bit is inserted, which starts a run of 1 itself).
    """
    polarity, run = state >> 2, (state & 3) + 1
    stuffed = 0
    for i in range(nbits - 1, -1, -1):
        bit = (value >> i) & 1
        if bit == polarity:
            run += 1
        else:
            polarity, run = bit, 1
        if run == 5:
            stuffed += 1
            polarity, run = polarity ^ 1, 1
    return stuffed, polarity * 4 + run - 1


#: The state before SOF: any run of recessive bits (SOF, dominant, always starts a new run).
_IDLE = 4
#: Per (state, byte): stuff bits << 3 | state after, for the data field.
_STUFF_TABLE = [0] * (8 * 256)
for _state in range(8):
    for _byte in range(256):
        _n, _after = _stuff(_byte, 8, _state)
        _STUFF_TABLE[_byte << 3 | _state] = _n << 3 | _after


class _Header:
    """What comes before the data of one kind of frame: its bits (stuff bits included) in the
    arbitration phase and in the data phase (CAN FD with bit rate switch), the stuffing state
    after it, and the bits after the data in both phases."""

    __slots__ = ("arbitration", "data_phase", "length", "padding", "recent", "state",
                 "tail_arbitration", "tail_data")

    def __init__(self, arbitration_id: int, extended: bool, fd: bool, remote: bool,
                 brs: bool, esi: bool, n: int) -> None:
        fields_: list[tuple[int, int]] = [(0, 1)]  # SOF
        if extended:  # base id, SRR, IDE, id extension
            fields_ += [(arbitration_id >> 18 & 0x7FF, 11), (1, 1), (1, 1),
                        (arbitration_id & 0x3FFFF, 18)]
        else:
            fields_.append((arbitration_id & 0x7FF, 11))
        data_fields: list[tuple[int, int]] = []
        if fd:
            code, self.length = _fd_length(n)
            fields_.append((0, 1))  # RRS
            if not extended:
                fields_.append((0, 1))  # IDE
            fields_ += [(1, 1), (0, 1)]  # FDF, res
            tail = [(esi, 1), (code, 4)]
            if brs:
                fields_.append((1, 1))
                data_fields = tail
            else:
                fields_ += [(0, 1), *tail]
            crc = 17 if self.length <= 16 else 21
            # stuff count (3 bits + parity), CRC, a fixed stuff bit before and every 4 bits
            crc_bits = 4 + crc + (4 + crc + 3) // 4
        else:
            self.length = 0 if remote else min(n, 8)
            code = min(n, 15) if remote else self.length
            fields_.append((int(remote), 1))  # RTR
            fields_ += [(0, 1), (0, 1)]  # IDE and r0, or r1 and r0 (extended)
            fields_.append((code, 4))
            crc_bits = 0
        state = _IDLE
        self.arbitration = 0.0
        for value, nbits in fields_:
            stuffed, state = _stuff(value, nbits, state)
            self.arbitration += nbits + stuffed
        self.data_phase = 0.0
        for value, nbits in data_fields:
            stuffed, state = _stuff(value, nbits, state)
            self.data_phase += nbits + stuffed
        self.state = state
        self.padding = max(0, self.length - n)
        #: the bits of recent payloads (counters and signals repeat: most payloads come back)
        self.recent: dict[bytes, tuple[float, float]] = {}
        if fd:
            self.tail_data, self.tail_arbitration = float(crc_bits), float(_TAIL_BITS)
        else:
            self.tail_data, self.tail_arbitration = 0.0, 15 + _CRC15_STUFF + _TAIL_BITS
        if fd and not brs:  # everything at the nominal bitrate
            self.arbitration += self.data_phase
            self.data_phase = 0.0
            self.tail_arbitration += self.tail_data
            self.tail_data = 0.0


_HEADERS: dict[tuple[int, bool, bool, bool, bool, bool, int], _Header] = {}


def frame_bits(frame: Frame) -> tuple[float, float]:
    """The frame's bits on the wire: ``(arbitration phase, data phase)``.

    Every field from SOF to the end of the interframe space counts, with the stuff bits: exact
    for everything up to the end of the data field, and the expected 0.5 stuff bits for the
    15-bit CRC of a classic frame (CAN FD's CRC field has fixed stuff bits: exact). The data
    phase, sent at the data bitrate, is from the bit rate switch (BRS) to the CRC delimiter of a
    CAN FD frame with BRS; it is 0 for every other frame. A CAN FD payload between two lengths is
    padded to the next (with 0xCC); an error frame counts :data:`ERROR_FRAME_BITS`.
    """
    # Unpacked by position (fields by name would cost ~100 ns more a frame): timestamp_ns, bus,
    # arbitration_id, data, is_extended, is_fd, is_error, is_remote, bitrate_switch,
    # error_state_indicator, dlc.
    _, _, arbitration_id, data, extended, fd, error, remote, brs, esi, dlc = frame
    if error:
        return float(ERROR_FRAME_BITS), 0.0
    n = len(data)
    key = (arbitration_id, extended, fd, remote, brs, esi, dlc if remote else n)
    header = _HEADERS.get(key)
    if header is None:
        if len(_HEADERS) > 65536:
            _HEADERS.clear()
        header = _HEADERS[key] = _Header(*key)
    bits = header.recent.get(data)
    if bits is None:
        bits = _bits(header, data, n)
        if len(header.recent) >= _RECENT_PAYLOADS:
            header.recent.clear()
        header.recent[data] = bits
    return bits


#: Payloads remembered per kind of frame by :func:`frame_bits`.
_RECENT_PAYLOADS = 256


def _bits(header: _Header, data: bytes, n: int) -> tuple[float, float]:
    state = header.state
    stuffed = 0
    table = _STUFF_TABLE
    for byte in data if n == header.length else data[:header.length]:
        entry = table[byte << 3 | state]
        stuffed += entry >> 3
        state = entry & 7
    for _ in range(header.padding):
        entry = table[_FD_PADDING << 3 | state]
        stuffed += entry >> 3
        state = entry & 7
    payload = 8 * header.length + stuffed
    if header.data_phase:
        return (header.arbitration + header.tail_arbitration,
                header.data_phase + payload + header.tail_data)
    return header.arbitration + payload + header.tail_arbitration, 0.0


def estimate_frame_bits(frame: Frame, *, bitrate: int | None = None,
                        data_bitrate: int | None = None) -> float:
    """Estimated bits one frame takes on the wire, stuff bits included (see :func:`frame_bits`).

    In nominal bit times: given both bitrates, each data-phase bit of a CAN FD frame with bit
    rate switch counts ``bitrate / data_bitrate``; otherwise every bit counts 1 (the plain
    number of bits on the wire).
    """
    arbitration, data_phase = frame_bits(frame)
    if data_phase and bitrate and data_bitrate:
        return arbitration + data_phase * bitrate / data_bitrate
    return arbitration + data_phase



#: Frames of each kind counted exactly before a sample of them is (a short drive, such as the
#: bundled sample with up to 1000 frames of an id, is counted exactly throughout).
EXACT_FIRST = 1024
#: After its first counts, the weight of each new exact count in an estimate is at least this (a
#: running mean that follows payloads that change their habits).
_MIN_WEIGHT = 1 / 8
#: The exact counts of the first frames that go into the estimates: the last 128 before the
#: sample starts (earlier ones would weigh (7/8)^16 < 12 % at most: not worth the bookkeeping).
_LEARN_FROM = EXACT_FIRST - 128
#: Kinds of frames the monitor keeps per bus (beyond, all are forgotten and start over).
MAX_KINDS = 65536

#: The key of a kind of frame: id, format, error, remote, BRS, ESI and length (a remote frame's
#: DLC).
KindKey = tuple[int, bool, bool, bool, bool, bool, bool, int]


def kind_key(frame: Frame) -> KindKey:
    """What makes frames of one kind (the monitor builds the same tuple inline)."""
    return (frame.arbitration_id, frame.is_extended, frame.is_fd, frame.is_error, frame.is_remote,
            frame.bitrate_switch, frame.error_state_indicator,
            frame.dlc if frame.is_remote else len(frame.data))


class FrameKind:
    """The bits of one kind of frame on one bus (:func:`kind_key`), counted from a sample.

    The first :data:`EXACT_FIRST` frames are counted exactly (as :func:`frame_bits` counts them);
    after them, one frame in about 16 is (at pseudo-random gaps of 9 to 24 frames, the same on
    every run, so that a rolling counter cannot alias with the sample), and so is a frame whose
    payload has a number of zero bytes that no exact count had yet. Every other frame counts the
    estimate of its payloads with that many zero bytes (:attr:`estimates`): the running mean of
    the exact counts from the 128th frame before the sample on, each new count weighing at
    least :data:`_MIN_WEIGHT`. Only the data field's stuff bits vary within a kind, and zero
    bytes are what stuffs them most: an empty radar slot (zeros but its counter) stuffs far more
    than a full one, and slots fill and empty as traffic comes and goes (one mean per kind was
    up to 1.8 % off the exact load of a one-second window of the simulated drive; one per zero
    count, 0.33 %).

    The monitor does what :meth:`bits` does inline.
    """

    __slots__ = ("_counts", "_gaps", "estimates", "exact", "frames", "header", "next_exact")

    def __init__(self, frame: Frame | KindKey) -> None:
        """The kind of ``frame`` (or of the frames with this :func:`kind_key`)."""
        arbitration_id, extended, fd, error, remote, brs, esi, n = (
            kind_key(frame) if isinstance(frame, Frame) else frame)
        #: how its frames are counted (None for an error frame: fixed bits)
        self.header = None if error else _Header(arbitration_id, extended, fd, remote, brs,
                                                 esi, n)
        self.frames = 0  # frames of this kind so far
        self.exact = 0  # of them counted exactly
        self.next_exact = 1  # the frame number of the next exact count of the sample
        #: the estimated bits per frame, ``(arbitration, data phase)``, by the payload's zero bytes
        self.estimates: dict[int, tuple[float, float]] = {}
        self._counts: dict[int, int] = {}  # exact counts by zero bytes
        self._gaps = (arbitration_id * 2654435761 + n) & 0x7FFFFFFF  # the gaps' generator

    def bits(self, frame: Frame) -> tuple[float, float]:
        """The bits counted for the next frame of this kind: ``(arbitration, data phase)``."""
        self.frames += 1
        if self.frames < self.next_exact:
            estimate = self.estimates.get(frame.data.count(0))
            if estimate is not None:
                return estimate
        return self.count(frame)

    def bits_of(self, payloads: Iterable[bytes]) -> list[tuple[float, float]]:
        """:meth:`bits` of frames of this kind with these payloads, in turn."""
        out: list[tuple[float, float]] = []
        append = out.append
        estimates = self.estimates
        recent = self.header.recent if self.header is not None else None
        for data in payloads:
            frames = self.frames = self.frames + 1
            if frames < self.next_exact:
                bits = estimates.get(data.count(0))
                if bits is not None:
                    append(bits)
                    continue
            elif frames < _LEARN_FROM and recent is not None:
                # (count_data's path for a payload it counted lately, before learning)
                bits = recent.get(data)
                if bits is not None:
                    self.exact += 1
                    self.next_exact = frames + 1
                    append(bits)
                    continue
            append(self.count_data(data))
        return out

    def count(self, frame: Frame) -> tuple[float, float]:
        """The exact bits of this frame (as :func:`frame_bits`), taken into the estimate; after
        a frame of the sample, the frame number of the next one."""
        return self.count_data(frame.data)

    def count_data(self, data: bytes) -> tuple[float, float]:
        """:meth:`count` of a frame of this kind with payload ``data``."""
        header = self.header
        bits: tuple[float, float] | None
        if header is None:
            bits = (float(ERROR_FRAME_BITS), 0.0)
        else:
            bits = header.recent.get(data)
            if bits is None:
                bits = _bits(header, data, len(data))
                if len(header.recent) >= _RECENT_PAYLOADS:
                    header.recent.clear()
                header.recent[data] = bits
        self.exact += 1
        if self.frames >= _LEARN_FROM:
            zeros = data.count(0)
            n = self._counts[zeros] = self._counts.get(zeros, 0) + 1
            weight = max(1.0 / n, _MIN_WEIGHT)
            arbitration, data_phase = self.estimates.get(zeros, bits)
            self.estimates[zeros] = (arbitration + (bits[0] - arbitration) * weight,
                                     data_phase + (bits[1] - data_phase) * weight)
        if self.frames >= self.next_exact:
            if self.frames < EXACT_FIRST:
                self.next_exact = self.frames + 1
            else:
                self._gaps = (self._gaps * 1103515245 + 12345) & 0x7FFFFFFF
                self.next_exact = self.frames + 9 + (self._gaps >> 16) % 16
        return bits
