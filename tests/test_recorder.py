"""The recorder's fast paths give exactly the bytes mcap and protobuf would have written."""

from __future__ import annotations

import io
import itertools
import random

import pytest
from mcap.reader import make_reader
from mcap.writer import IndexType
from mcap.writer import Writer as McapWriter

from bridge.frame import Frame
from bridge.pb.can_frame_pb2 import CanFrameBlock
from bridge.sinks.mcap import FastWriter, Recorder
from bridge.sinks.raw import cut

FRAME = Frame(1_000, "can0", 0x100, b"\x01\x02", dlc=2)


def write_with(cls: type[McapWriter], fast: bool = True,
               index_types: IndexType = IndexType.ALL) -> bytes:
    rng = random.Random(7)
    out = io.BytesIO()
    writer = cls(out, chunk_size=4096, index_types=index_types)
    if not fast:
        writer._fast = False
    writer.start(profile="", library="test")
    schema = writer.register_schema("s", "protobuf", b"schema")
    channels = [writer.register_channel(f"/t{i}", "protobuf", schema) for i in range(3)]
    for i in range(3000):  # several chunks, times a little out of order, sizes varying
        t = 1_000_000 + i * 1000 + rng.randint(-3000, 3000)
        writer.add_message(rng.choice(channels), t, rng.randbytes(rng.randint(0, 80)), t + 5, i)
        if i == 1000:  # a chunk closed early, as a drive's flush every second does
            writer.flush()
        if i == 2000:  # a channel that comes later, into a chunk that is nearly full
            channels.append(writer.register_channel("/late", "protobuf", schema))
    writer.add_metadata("m", {"k": "v"})
    writer.finish()
    return out.getvalue()


def test_the_fast_writer_writes_what_mcap_writes() -> None:
    assert write_with(FastWriter) == write_with(McapWriter)


def test_the_fallback_path_writes_the_same() -> None:
    assert write_with(FastWriter, fast=False) == write_with(McapWriter)



def write_runs(cls: type[McapWriter], fast: bool = True) -> bytes:
    """Runs of messages (offline convert's decoded messages), a run at once where the writer
    can (FastWriter.add_many), else one by one."""
    rng = random.Random(11)
    out = io.BytesIO()
    writer = cls(out, chunk_size=4096)
    if not fast:
        writer._fast = False
    writer.start(profile="", library="test")
    schema = writer.register_schema("s", "protobuf", b"schema")
    channels = [writer.register_channel(f"/t{i}", "protobuf", schema) for i in range(3)]
    t = 1_000_000
    for size in [rng.randint(0, 300) for _ in range(40)]:  # runs across several chunks
        run = []
        for _ in range(size):
            t += rng.randint(-2000, 3000)
            run.append((rng.choice(channels), t, rng.randbytes(rng.randint(0, 80))))
        if isinstance(writer, FastWriter):
            writer.add_many(run)
        else:
            for channel_id, log_time, data in run:
                writer.add_message(channel_id, log_time, data, log_time)
    writer.finish()
    return out.getvalue()


def test_runs_of_messages_are_written_as_mcap_writes_them_one_by_one() -> None:
    assert write_runs(FastWriter) == write_runs(McapWriter)
    assert write_runs(FastWriter, fast=False) == write_runs(McapWriter)


def test_without_message_indexes_the_fast_writer_writes_what_mcap_writes() -> None:
    """Chunk indexes and the summary without the per-message MessageIndex records."""
    chunks_only = IndexType.ALL & ~IndexType.MESSAGE
    written = write_with(FastWriter, index_types=chunks_only)
    assert written == write_with(McapWriter, index_types=chunks_only)
    assert len(written) < len(write_with(McapWriter)) - 16 * 3000


def test_raw_frames_serialize_exactly_like_a_whole_canframeblock() -> None:
    """Every flag, lengths from none to longer than CAN (other sources), a requested length
    that is not the data's: the recorder's blocks are what protobuf writes."""
    recorder_out = io.BytesIO()
    recorder = Recorder(recorder_out)
    frames = []
    for n, flags in enumerate(itertools.product([False, True], repeat=6)):
        for length in (0, 1, 8, 12, 64, 127, 128, 300):
            ext, fd, err, rtr, brs, esi = flags
            frames.append(Frame(n * 100 + length, "radar", 0x1ABCDEF if ext else 0x7FF,
                                bytes(i % 256 for i in range(length)), ext, fd, err, rtr, brs,
                                esi, 8 if rtr else length))
    frames.sort(key=lambda f: f.timestamp_ns)
    recorder.on_raw(cut(frames))
    recorder.finish()
    expected = CanFrameBlock(bus="radar")
    for frame in frames:
        row = expected.frames.add(
            id=frame.arbitration_id, extended=frame.is_extended, fd=frame.is_fd,
            error=frame.is_error, remote=frame.is_remote, bitrate_switch=frame.bitrate_switch,
            error_state_indicator=frame.error_state_indicator, data=frame.data,
            offset_ns=frame.timestamp_ns - frames[0].timestamp_ns)
        if frame.dlc != len(frame.data):
            row.dlc = frame.dlc
    recorder_out.seek(0)
    (got,) = [(c.topic, m.data) for _, c, m in make_reader(recorder_out).iter_messages()]
    assert got == ("/can/radar/frames", expected.SerializeToString())


def test_a_topic_keeps_its_one_message_type() -> None:
    """A second message type on a topic is refused, as mcap_protobuf's writer refuses it;
    the first type goes on being written."""
    from foxglove_schemas_protobuf.Log_pb2 import Log
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    out = io.BytesIO()
    recorder = Recorder(out)
    recorder.write("/scene/ego", SceneUpdate(), 1)
    with pytest.raises(ValueError, match=r"'/scene/ego' has type foxglove\.SceneUpdate, cannot "
                                         r"write a foxglove\.Log"):
        recorder.write("/scene/ego", Log(message="hello"), 2)
    with pytest.raises(ValueError, match=r"cannot write a foxglove\.Log"):
        recorder.channel("/scene/ego", "foxglove.Log", b"")
    recorder.write("/scene/ego", SceneUpdate(), 3)
    recorder.finish()
    out.seek(0)
    schemas = {channel.topic: schema.name for schema, channel, _ in
               make_reader(out).iter_messages()}
    assert schemas == {"/scene/ego": "foxglove.SceneUpdate"}


def test_a_recorder_describes_its_drive_once_just_before_it_is_finished() -> None:
    """As a sink, the recorder has its drive described (attachments, metadata) when it is
    finished, and only once."""
    described: list[int] = []

    def describe(recorder: Recorder) -> None:
        described.append(recorder.messages)
        recorder.add_metadata({"note": "described"}, name="test")

    out = io.BytesIO()
    recorder = Recorder(out, describe=describe)
    recorder.on_raw(cut([FRAME]))
    assert described == []
    recorder.finish()
    recorder.finish()
    assert described == [1]
    out.seek(0)
    assert [m.name for m in make_reader(out).iter_metadata()] == ["test"]
