"""A frame pack gives back exactly the frames it was made of (every flag, extended ids, empty
and 64-byte CAN FD payloads), through its buffer too; its slices and its groups by (bus, key)
are those of the frames."""

from __future__ import annotations

import pickle
from array import array
from collections import defaultdict

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bridge.frame import Frame, frame_key
from bridge.packed import MAX_BUSES, PackedFrames, packs


def every_kind() -> list[Frame]:
    return [
        Frame(1, "can0", 0x100, bytes(range(8)), dlc=8),
        Frame(2, "can1", 0x1ABCDEF, b"\x01\x02", is_extended=True, dlc=2),
        Frame(3, "can0", 0x100, b"", is_remote=True, dlc=8),
        Frame(4, "can2", 0, b"", is_error=True),
        Frame(5, "can1", 0x7FF, bytes(range(64)), is_fd=True, bitrate_switch=True, dlc=15),
        Frame(6, "can1", 0x1FFFFFFF, bytes(48), is_extended=True, is_fd=True,
              error_state_indicator=True, dlc=14),
        Frame(7, "can0", 0x100, b"\xff" * 8, dlc=8),
        Frame(-5, "can0", 0x100, b"", dlc=0),  # a time before the log's start, no payload
        Frame(9, "x.y-z", 0xFFFF_FFFF, b"a", dlc=1),  # a standard id beyond 29 bits
    ]


def check_round_trip(frames: list[Frame]) -> PackedFrames:
    pack = PackedFrames.from_frames(frames)
    again = PackedFrames.from_bytes(pack.to_bytes())
    for made in (pack, again):
        assert len(made) == len(frames)
        got = list(made)
        assert got == frames
        assert [made.frame(i) for i in range(len(frames))] == frames
        for g, f in zip(got, frames, strict=True):  # the same types, not only equal values
            assert type(g) is Frame
            assert [type(v) for v in g] == [type(v) for v in f]
    assert again == pack
    return pack


def test_every_kind_of_frame_comes_back_the_same() -> None:
    pack = check_round_trip(every_kind())

    assert pack.buses == ("can0", "can1", "can2", "x.y-z")
    assert pack.key[1] == frame_key(0x1ABCDEF, True)
    assert pack.frame(-1) == every_kind()[-1]
    with pytest.raises(IndexError):
        pack.frame(len(pack))


def test_an_empty_block() -> None:
    pack = check_round_trip([])

    assert pack.groups() == {} and pack.payloads() == [] and len(pack.slice(0, 5)) == 0


frame_strategy = st.builds(
    Frame,
    timestamp_ns=st.integers(-(1 << 63), (1 << 63) - 1),
    bus=st.sampled_from(["can0", "can1", "radar", "ü"]),
    arbitration_id=st.integers(0, (1 << 29) - 1),
    data=st.binary(max_size=64),
    is_extended=st.booleans(), is_fd=st.booleans(), is_error=st.booleans(),
    is_remote=st.booleans(), bitrate_switch=st.booleans(), error_state_indicator=st.booleans(),
    dlc=st.integers(0, 64),
)


@given(st.lists(frame_strategy, max_size=60))
def test_any_frames_come_back_the_same(frames: list[Frame]) -> None:
    check_round_trip(frames)


@given(st.lists(frame_strategy, max_size=40), st.integers(-50, 50), st.integers(-50, 50))
def test_a_slice_is_the_block_of_those_frames(frames: list[Frame], i: int, j: int) -> None:
    part = PackedFrames.from_frames(frames).slice(i, j)

    assert list(part) == frames[i:j]
    assert list(PackedFrames.from_bytes(part.to_bytes())) == frames[i:j]


@given(st.lists(frame_strategy, max_size=80))
def test_the_groups_are_the_rows_of_each_bus_and_key_in_order(frames: list[Frame]) -> None:
    pack = PackedFrames.from_frames(frames)
    expected: dict[tuple[int, int], list[int]] = defaultdict(list)
    for i, f in enumerate(frames):
        expected[(pack.buses.index(f.bus), frame_key(f.arbitration_id, f.is_extended))].append(i)

    groups = pack.groups()

    assert {k: list(v) for k, v in groups.items()} == expected
    assert list(groups) == list(expected)  # in the order of their first row
    assert all(isinstance(v, array) and v.typecode == "I" for v in groups.values())
    assert pack.payloads() == [f.data for f in frames]


def test_the_buffer_has_no_pickled_frames_and_is_compact() -> None:
    frames = [Frame(i * 1000, f"can{i % 3}", 0x100 + i % 50, bytes(8), dlc=8)
              for i in range(4096)]

    buffer = PackedFrames.from_frames(frames).to_bytes()

    assert b"Frame" not in buffer and pickle.PROTO not in buffer[:1]
    assert len(buffer) < 4096 * (8 + 4 + 4 + 3 + 8) + 64  # t, key, end, bus/flags/dlc, data


def test_a_dlc_beyond_a_byte_still_comes_back() -> None:
    frames = [Frame(1, "can0", 0x10, b"", is_remote=True, dlc=0x999),
              Frame(2, "can0", 0x10, b"", dlc=-1)]

    check_round_trip(frames)


def test_frames_beyond_the_bounds_are_a_clear_error() -> None:
    with pytest.raises(ValueError, match=r"frame 1 of the pack .*id 2147483648 is beyond"):
        PackedFrames.from_frames([Frame(0, "can0", 1, b""),
                                Frame(0, "can0", 1 << 31, b"", is_extended=True)])
    with pytest.raises(ValueError, match=r"frame 0 .*time 9223372036854775808 does not fit"):
        PackedFrames.from_frames([Frame(1 << 63, "can0", 1, b"")])
    with pytest.raises(ValueError, match=r"at most 255 buses"):
        PackedFrames.from_frames([Frame(0, f"b{i}", 1, b"") for i in range(MAX_BUSES + 1)])
    with pytest.raises(ValueError, match="cut or too long"):
        PackedFrames.from_bytes(PackedFrames.from_frames(every_kind()).to_bytes()[:-1])
    with pytest.raises(ValueError, match="not a frame pack"):
        PackedFrames.from_bytes(b"\0" * 32)


def test_more_buses_than_a_block_holds_make_more_blocks() -> None:
    frames = [Frame(i, f"bus{i % 600}", i, bytes([i % 256])) for i in range(2000)]

    made = packs(frames)

    assert len(made) == -(-2000 // MAX_BUSES)  # every bus new in its pack: cut at each 256th
    assert all(len(b.buses) <= MAX_BUSES for b in made)
    assert [f for b in made for f in b] == frames
    assert len(packs(frames[:100])) == 1


def test_flags_of_other_types_are_taken_as_true_or_false() -> None:
    frames = [Frame(1, "can0", 1, b"", is_fd=2, is_remote="yes"),  # type: ignore[arg-type]
              Frame(2, "can0", 1, b"", is_fd=0, is_error=None)]  # type: ignore[arg-type]

    got = list(PackedFrames.from_frames(frames))

    assert [(f.is_fd, f.is_remote, f.is_error) for f in got] == \
        [(True, True, False), (False, False, False)]
    assert all(type(v) is bool for f in got for v in f[4:10])
