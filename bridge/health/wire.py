"""Bits on the wire: how long each CAN frame takes on the bus, the measure of the bus load.

:func:`frame_bits` counts a frame's bits from the frame alone (its id and format, its flags and
its payload), every field from SOF to the end of the interframe space, stuff bits included:

- exact for everything up to the end of the data field, and the expected 0.5 stuff bits for the
  15-bit CRC of a classic frame (CAN FD's CRC field has fixed stuff bits: exact);
- split into the arbitration phase, sent at the nominal bitrate, and the data phase, sent at the
  data bitrate: from the bit rate switch (BRS) to the CRC delimiter of a CAN FD frame with BRS,
  and 0 for every other frame;
- a CAN FD payload between two lengths is padded to the next (with 0xCC); a remote frame has no
  data field; an error frame counts :data:`ERROR_FRAME_BITS` (all in the arbitration phase).

:func:`estimate_frame_bits` is one number in nominal bit times: given both bitrates, each
data-phase bit counts ``bitrate / data_bitrate``; otherwise every bit counts 1. The bus load is
these bits over the bitrate (:mod:`bridge.health.monitor` works it out per window; no bitrate,
no load).

:func:`frame_bits` runs for every frame (the monitor's per-frame hook), so it is cheap: what
comes before the data is worked out once per kind of frame (id, format, flags and length;
beyond 65536 kinds, all are forgotten), the data field is stuffed a byte at a time
from a table, and the bits of up to 256 recent payloads of each kind are remembered (counters
and signals repeat), then forgotten all at once. A remembered count is the same as a new one.
"""

from __future__ import annotations

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
