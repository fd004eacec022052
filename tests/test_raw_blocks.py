"""Raw frames in blocks (bridge/sinks/raw.py): how windows are cut, the wire bytes, and reading
the frames back in the pipeline's order (bridge/io/drives.py)."""

from __future__ import annotations

import io
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st
from mcap_protobuf.writer import Writer as ProtobufWriter

from bridge.frame import Frame
from bridge.io.drives import ArchiveSource, BlockMerger, block_frames
from bridge.packed import PackedFrames
from bridge.pb.can_frame_pb2 import CanFrame, CanFrameBlock
from bridge.sinks.mcap import Recorder
from bridge.sinks.raw import WINDOW_NS, BlockCutter, RawBlock, cut, encode_block

MS = 1_000_000
T0 = 1_700_000_000_000_000_000


def frame(t_ms: float, bus: str = "can0", arbitration_id: int = 0x123, data: bytes = b"\x01\x02",
          **flags: bool | int) -> Frame:
    flags.setdefault("dlc", len(data))
    return Frame(T0 + round(t_ms * MS), bus, arbitration_id, data, **flags)  # type: ignore[arg-type]


def blocks_of(frames: list[Frame]) -> list[RawBlock]:
    return cut(frames)


def read_back(blocks: list[RawBlock]) -> list[Frame]:
    """The frames of the blocks as a drive's reader gives them."""
    merger = BlockMerger()
    frames: list[Frame] = []
    for b in blocks:
        frames += merger.add(block_frames(b.t_ns, CanFrameBlock.FromString(b.payload)))
    return frames + merger.finish()


frames_strategy = st.builds(
    Frame,
    timestamp_ns=st.integers(0, WINDOW_NS - 1).map(lambda n: T0 + n),
    bus=st.sampled_from(["can0", "radar", ""]),
    arbitration_id=st.integers(0, (1 << 29) - 1),
    data=st.binary(max_size=64),
    is_extended=st.booleans(), is_fd=st.booleans(), is_error=st.booleans(),
    is_remote=st.booleans(), bitrate_switch=st.booleans(),
    error_state_indicator=st.booleans(), dlc=st.integers(0, 64))


@given(st.lists(frames_strategy, min_size=1, max_size=20))
def test_rows_are_written_as_protobuf_writes_them(frames: list[Frame]) -> None:
    t0 = min(f.timestamp_ns for f in frames)
    expected = CanFrameBlock(bus=frames[0].bus)
    for f in frames:
        row = expected.frames.add(
            id=f.arbitration_id, data=f.data, offset_ns=f.timestamp_ns - t0,
            extended=f.is_extended, fd=f.is_fd, bitrate_switch=f.bitrate_switch,
            error_state_indicator=f.error_state_indicator, error=f.is_error, remote=f.is_remote)
        if f.dlc != len(f.data):
            row.dlc = f.dlc
    assert encode_block(frames[0].bus, t0, frames) == expected.SerializeToString()



def cut_in_rows(frames: list[Frame], size: int) -> list[RawBlock]:
    """The blocks of ``frames`` fed as rows of FrameBlocks of ``size`` (offline convert)."""
    blocks: list[RawBlock] = []
    cutter = BlockCutter(blocks.extend)
    for i in range(0, len(frames), size):
        rows = PackedFrames.from_frames(frames[i:i + size])
        for j in range(0, len(rows), 2):  # in runs, as the pipeline feeds them
            cutter.add_rows(rows, j, min(j + 2, len(rows)))
    cutter.flush()
    return blocks


@given(st.lists(st.tuples(st.integers(0, 3 * WINDOW_NS), st.sampled_from(["can0", "radar"]),
                          st.binary(max_size=12), st.booleans(), st.booleans(),
                          st.integers(0, 15)), min_size=1, max_size=40),
       st.integers(1, 7))
def test_rows_of_frame_blocks_make_the_blocks_frames_make(
        rows: list[tuple[int, str, bytes, bool, bool, int]], size: int) -> None:
    # stamps out of order across buses and within one, frames right at a window's end, short
    # and long DLCs, extended ids and CAN FD frames
    frames = [Frame(T0 + t, bus, 0x18DAF100 + i % 3 if extended else 0x100 + i % 3, data,
                    is_extended=extended, is_fd=fd, bitrate_switch=fd, dlc=dlc)
              for i, (t, bus, data, extended, fd, dlc) in enumerate(rows)]
    frames.append(frames[0]._replace(timestamp_ns=frames[0].timestamp_ns + WINDOW_NS))
    assert cut_in_rows(frames, size) == cut(frames)



def test_a_frame_at_a_windows_end_opens_the_next_block_in_rows_too() -> None:
    frames = [frame(0), frame(19.999), frame(20), frame(20, "radar")]
    assert [b.frames for b in cut_in_rows(frames, 4)] == [2, 1, 1] == [
        b.frames for b in cut(frames)]


def test_a_block_holds_20_ms_of_one_bus_from_its_first_frame() -> None:
    """Each bus's block starts at its own first frame; blocks closed together (the time of a
    frame passed their ends) are written in the order of their starts."""
    frames = [frame(0, "can0"), frame(3, "radar"), frame(19.9, "can0"),
              frame(20, "can0"), frame(23.5, "radar"), frame(25, "can0")]
    blocks = blocks_of(frames)
    assert [(b.bus, (b.t_ns - T0) / MS, b.frames) for b in blocks] == [
        ("can0", 0, 2), ("radar", 3, 1), ("can0", 20, 2), ("radar", 23.5, 1)]
    first = CanFrameBlock.FromString(blocks[0].payload)
    assert first.bus == "can0"
    assert [r.offset_ns for r in first.frames] == [0, round(19.9 * MS)]
    assert not first.frames[0].HasField("dlc")


def test_a_frame_before_its_block_closes_it() -> None:
    """A clock that steps back: the bus's block ends there, and the frames after the step start
    a block of their own. (A frame a little out of order but not before its block's start
    stays in it, in its place.)"""
    blocks = blocks_of([frame(100), frame(105), frame(101), frame(90), frame(92)])
    assert [(b.t_ns - T0, b.frames) for b in blocks] == [(100 * MS, 3), (90 * MS, 2)]


def test_the_clock_passing_a_window_closes_it() -> None:
    out: list[RawBlock] = []
    cutter = BlockCutter(out.extend)
    cutter.add(frame(0))
    cutter.add(frame(15, "radar"))
    assert not cutter.due(T0 + 19 * MS)
    assert cutter.due(T0 + 20 * MS)
    cutter.flush_due(T0 + 20 * MS)
    assert [(b.bus, b.frames) for b in out] == [("can0", 1)]
    cutter.flush()
    assert [b.bus for b in out] == ["can0", "radar"]
    cutter.flush()  # nothing open: nothing more
    assert len(out) == 2


def test_frames_are_read_back_in_the_order_the_pipeline_saw_them() -> None:
    """Interleaved buses, equal stamps on two buses, a step back and a step forward, a remote
    frame with its requested length, CAN FD and extended ids."""
    frames = [frame(0, "can0"), frame(0, "radar"), frame(0.5, "radar"), frame(1, "can0"),
              frame(2, "can0", 0x18FF0001, bytes(64), is_extended=True, is_fd=True,
                    bitrate_switch=True, dlc=64),
              frame(2.5, "chassis", 0x7DF, b"", is_remote=True, dlc=8),
              frame(30, "radar"), frame(-5000, "can0"), frame(-4999, "radar"),
              frame(90_000, "can0"), frame(90_000.001, "radar", 0, b"", is_error=True)]
    assert read_back(blocks_of(frames)) == frames


@given(st.dictionaries(st.integers(0, 200_000_000), st.sampled_from(["a", "b", "c"]),
                       max_size=60))
def test_frames_in_time_order_come_back_exactly(stamps: dict[int, str]) -> None:
    frames = [Frame(T0 + t, bus, i, bytes([i % 256]))
              for i, (t, bus) in enumerate(sorted(stamps.items()))]
    assert read_back(blocks_of(frames)) == frames


def test_equal_stamps_on_two_buses_come_back_in_the_order_their_blocks_were_written() -> None:
    """What the blocks do not keep: the order of frames of two buses stamped alike. Every
    topic's messages come out the same either way (each bus keeps its own order)."""
    frames = [frame(0, "b"), frame(1, "a"), frame(1, "b")]
    assert read_back(blocks_of(frames)) == [frames[0], frames[2], frames[1]]


def test_a_bus_stamped_a_little_back_comes_back_in_time_order() -> None:
    """Frames of two buses out of time order (merged logs of clocks 5 ms apart): each bus
    keeps its order, and across buses they come back in time order."""
    frames = [frame(10, "a"), frame(6, "b"), frame(31, "a"), frame(26, "b"), frame(52, "a")]
    assert read_back(blocks_of(frames)) == sorted(frames, key=lambda f: f.timestamp_ns)


def test_a_drive_of_blocks_and_a_drive_of_one_frame_a_message_read_alike(tmp_path: Path) -> None:
    """Drives recorded before blocks keep one tankviz.CanFrame a message: both are read."""
    frames = [frame(i * 7.0, ("can0", "radar")[i % 2], 0x100 + i, bytes([i])) for i in range(40)]
    blocked = tmp_path / "blocks.mcap"
    with blocked.open("wb") as f:
        recorder = Recorder(f)
        recorder.on_raw(blocks_of(frames))
        recorder.finish()
    old = tmp_path / "old.mcap"
    with old.open("wb") as f:
        writer = ProtobufWriter(f)
        for fr in frames:
            writer.write_message(f"/can/{fr.bus}/frames", CanFrame(
                bus=fr.bus, id=fr.arbitration_id, data=fr.data, dlc=fr.dlc),
                log_time=fr.timestamp_ns, publish_time=fr.timestamp_ns)
        writer.finish()
    for path in (blocked, old):
        source = ArchiveSource(path)
        assert list(source) == frames, path.name
        assert source.frames == 40 and not source.issues


def test_a_damaged_block_is_skipped_and_said(tmp_path: Path) -> None:
    frames = [frame(0), frame(30), frame(60)]
    blocks = blocks_of(frames)
    blocks[1] = blocks[1]._replace(payload=b"\x12\xff")  # a row longer than the block
    out = io.BytesIO()
    recorder = Recorder(out)
    recorder.on_raw(blocks)
    recorder.finish()
    path = tmp_path / "damaged.mcap"
    path.write_bytes(out.getvalue())
    source = ArchiveSource(path)
    assert list(source) == [frames[0], frames[2]]
    assert len(source.issues) == 1
    assert "not a tankviz.CanFrameBlock" in source.issues[0].reason


def test_a_frame_no_bus_could_carry_is_skipped_and_said(tmp_path: Path) -> None:
    """A damaged or hand-made drive: an id beyond 29 bits, a time past 2262. Each is one issue
    naming it; the others are converted (the read-ahead could not hand them over)."""
    from bridge.pipeline.convert import convert

    frames = [frame(0), frame(1, arbitration_id=(1 << 31) + 5), frame(2)]
    blocks = blocks_of(frames)
    late = CanFrameBlock(bus="can0")
    late.frames.add(id=0x123, data=b"\x01", offset_ns=5)
    blocks.append(RawBlock("can0", (1 << 64) - 1, late.SerializeToString(), 1))
    path = tmp_path / "odd.mcap"
    with path.open("wb") as f:
        recorder = Recorder(f)
        recorder.on_raw(blocks)
        recorder.finish()
    source = ArchiveSource(path)
    assert list(source) == [frames[0], frames[2]]
    assert [i.reason for i in source.issues] == [
        "skipped a frame with id 0x80000005, which no CAN bus carries",
        "skipped a frame stamped 18446744073709551620 ns, after 2262 (the latest time a drive "
        "can hold)"]
    report = convert([path], tmp_path / "out.mcap", [], read_ahead=True)
    assert report.frames == 2 and len(report.issues) == 2
