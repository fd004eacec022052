"""The BLF container walk's short step (a header found intact before, known at one look-up) finds
what the careful walk finds, in intact and damaged containers alike (issue #36)."""

from __future__ import annotations

import io
import random
import struct
import zlib

import can
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.io import blf
from bridge.io.blf import _FILE_HEADER_SIZE, _MAX_OBJECT, _OBJ, _object_size, intact_objects

T0 = 1_700_000_000.0


def careful_walk(data: bytes, lost: bool = False,
                 ) -> tuple[list[tuple[int, int]], int, int, bool]:
    """The walk as it was before the short step (bridge/io/blf.py at 9e0da15): every object's
    header looked at, one after the other. The reference."""
    runs: list[tuple[int, int]] = []
    damaged = 0
    n = len(data)
    pos = 0
    start = 0
    if lost:
        first = data.find(b"LOBJ")
        if first < 0:
            return [], max(0, n - 3), 0, True
        pos = start = first
        lost = False
    while pos + _OBJ.size <= n:
        at = data.find(b"LOBJ", pos, pos + 8)
        if 0 <= at <= n - _OBJ.size:
            size = _object_size(data, at, _MAX_OBJECT)
            if size is not None:
                if at + size > n:
                    break
                pos = at + size
                continue
        elif at >= 0:
            break
        if pos > start:
            runs.append((start, pos))
        after = data.find(b"LOBJ", (pos if at < 0 else at) + 1)
        if after < 0:
            damaged += max(0, n - 3 - pos)
            return runs, max(pos, n - 3), damaged, True
        damaged += after - pos
        pos = start = after
    if pos > start:
        runs.append((start, pos))
    return runs, pos, damaged, lost


def _messages(n: int) -> list[can.Message]:
    """Classic, extended, remote, error and CAN FD frames of every length, mixed."""
    pick = random.Random(3)
    out = []
    for i in range(n):
        kind = pick.choice(["classic", "classic", "classic", "fd", "error", "remote"])
        fd = kind == "fd"
        length = pick.choice([0, 1, 8, 12, 24, 64]) if fd else pick.randint(0, 8)
        out.append(can.Message(
            timestamp=T0 + i * 0.001, arbitration_id=pick.randrange(0x800),
            is_extended_id=pick.random() < 0.2, is_fd=fd, bitrate_switch=fd and i % 2 == 0,
            is_error_frame=kind == "error", is_remote_frame=kind == "remote",
            data=b"" if kind == "remote" else pick.randbytes(length), channel=i % 3))
    return out


class _Kept(io.BytesIO):
    """A file python-can's writer writes to, kept when it closes it."""

    def close(self) -> None:
        self.flush()


def _container_data() -> list[bytes]:
    """The uncompressed data of each log container of a BLF python-can writes, joined as the
    reader joins them (an object may go on in the next container)."""
    out = _Kept()
    writer = can.BLFWriter(out)
    writer.max_container_size = 4096
    for message in _messages(600):
        writer.on_message_received(message)
    writer.stop()
    whole = out.getvalue()
    datas = []
    pos = _FILE_HEADER_SIZE
    while pos + _OBJ.size <= len(whole):
        _, _, _, size, _ = _OBJ.unpack_from(whole, pos)
        datas.append(zlib.decompress(whole[pos + 32:pos + size]))
        pos += size + size % 4
    return datas


CONTAINERS = _container_data()
JOINED = b"".join(CONTAINERS)


def both(data: bytes, lost: bool) -> None:
    blf._INTACT.clear()
    blf._KINDS.clear()
    cold = intact_objects(data, lost)
    warm = intact_objects(data, lost)  # every intact header known now
    assert cold == warm == careful_walk(data, lost)


def test_an_intact_log_is_one_run_as_the_careful_walk_finds_it() -> None:
    assert len(CONTAINERS) > 5
    for data in CONTAINERS:
        both(data, lost=False)
    runs, rest, damaged, lost = intact_objects(JOINED)
    assert (runs, rest, damaged, lost) == ([(0, len(JOINED))], len(JOINED), 0, False)


damage = st.lists(st.tuples(st.floats(0.0, 1.0), st.binary(min_size=1, max_size=24)),
                  max_size=4)


@settings(max_examples=300, deadline=None)
@given(index=st.integers(0, len(CONTAINERS) - 1), joined=st.booleans(), changes=damage,
       cut=st.floats(0.0, 1.0), lost=st.booleans(), sizes=st.lists(
           st.tuples(st.floats(0.0, 1.0), st.sampled_from([0, 1, 15, 16, 31, 40, 47, 1 << 21])),
           max_size=2),
       padding=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(1, 6), st.booleans()),
                        max_size=30))
def test_a_damaged_container_gives_what_the_careful_walk_gives(
        index: int, joined: bool, changes: list[tuple[float, bytes]], cut: float, lost: bool,
        sizes: list[tuple[float, int]], padding: list[tuple[float, int, bool]]) -> None:
    data = bytearray(JOINED if joined else CONTAINERS[index])
    for where, count, zeros in padding:  # bytes between objects (up to 4 are padding python-can
        at = data.find(b"LOBJ", int(where * (len(data) - 1)))  # steps over, more are damage)
        if at >= 0:
            data[at:at] = bytes(count) if zeros else b"LOBJ"[:count % 4] + bytes(count)
    for where, junk in changes:  # bytes overwritten anywhere
        at = int(where * (len(data) - 1))
        data[at:at + len(junk)] = junk[:len(data) - at]
    for where, size in sizes:  # an object's size field made impossible (or merely wrong)
        at = data.find(b"LOBJ", int(where * (len(data) - 1)))
        if at >= 0 and at + 12 <= len(data):
            struct.pack_into("<L", data, at + 8, size)
    data = data[:max(1, int(cut * len(data)))] if cut < 0.9 else data  # cut short
    both(bytes(data), lost)


def test_an_object_size_zero_among_known_headers_is_damage() -> None:
    data = bytearray(CONTAINERS[1])
    intact_objects(bytes(data))  # every header known
    first = data.find(b"LOBJ", 200)
    struct.pack_into("<L", data, first + 8, 0)
    runs, _, damaged, _ = intact_objects(bytes(data))
    assert damaged > 0 and runs[0][1] <= first
    assert intact_objects(bytes(data)) == careful_walk(bytes(data))
