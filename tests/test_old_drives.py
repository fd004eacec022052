"""Drives recorded before raw frames were archived in blocks (one ``tankviz.CanFrame`` a message
on ``/can/<bus>/frames``) still re-derive, replay, recover and go into the catalogue, with their
frames counted exactly.

The old drive is made here from a new one: the same file with every block of raw frames written
as one ``tankviz.CanFrame`` message per frame (as tankviz wrote them then), everything else
(attachments, metadata, decoded, scene and health topics) copied as it is.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from bridge.apps.recover import recover_file
from bridge.apps.replay import replay_mcap
from bridge.fleet.catalog import read_drive
from bridge.io.drives import ArchiveSource, BlockMerger, block_frames, raw_frame_counts
from bridge.pb.can_frame_pb2 import CanFrame, CanFrameBlock
from bridge.pipeline.convert import convert


def canframe_schema() -> bytes:
    from mcap_protobuf.schema import build_file_descriptor_set

    return bytes(build_file_descriptor_set(CanFrame).SerializeToString())


def as_old_drive(new: Path, old: Path) -> int:
    """``new`` rewritten with one CanFrame a frame; returns how many frames it holds."""
    frames = 0
    with new.open("rb") as f, old.open("wb") as out:
        reader = make_reader(f)
        writer = Writer(out)
        writer.start(profile="", library="tankviz 0.1.0 (before blocks)")
        for a in reader.iter_attachments():
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        merger = BlockMerger()
        old_schema = writer.register_schema("tankviz.CanFrame", "protobuf", canframe_schema())
        frame_channels: dict[str, int] = {}

        def write_frames(batch: list) -> None:  # type: ignore[type-arg]
            nonlocal frames
            for fr in batch:
                topic = f"/can/{fr.bus}/frames"
                if topic not in frame_channels:
                    frame_channels[topic] = writer.register_channel(topic, "protobuf", old_schema)
                writer.add_message(frame_channels[topic], fr.timestamp_ns, CanFrame(
                    bus=fr.bus, id=fr.arbitration_id, extended=fr.is_extended, fd=fr.is_fd,
                    bitrate_switch=fr.bitrate_switch,
                    error_state_indicator=fr.error_state_indicator, error=fr.is_error,
                    remote=fr.is_remote, dlc=fr.dlc, data=fr.data).SerializeToString(),
                    fr.timestamp_ns)
                frames += 1

        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic.endswith("/frames"):
                write_frames(merger.add(block_frames(
                    message.log_time, CanFrameBlock.FromString(message.data))))
                continue
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                            schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id])
            writer.add_message(channels[channel.id], message.log_time, message.data,
                               message.publish_time)
        write_frames(merger.finish())
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, dict(m.metadata))
        writer.finish()
    return frames


@pytest.fixture(scope="module")
def drives(tmp_path_factory: pytest.TempPathFactory, sample_drive: Path
           ) -> tuple[Path, Path, int]:
    new = sample_drive
    old = tmp_path_factory.mktemp("old") / "old.mcap"
    return new, old, as_old_drive(new, old)


def test_an_old_drive_holds_one_canframe_a_frame(drives: tuple[Path, Path, int]) -> None:
    new, old, frames = drives
    with old.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        schemas = {summary.channels[i].topic: summary.schemas[summary.channels[i].schema_id].name
                   for i in summary.channels}
        assert schemas["/can/can0/frames"] == "tankviz.CanFrame"
        assert raw_frame_counts(reader) == {"can0": frames}
    assert list(ArchiveSource(old)) == list(ArchiveSource(new))


def test_an_old_drive_re_derives_to_the_drive_blocks_make(drives: tuple[Path, Path, int],
                                                           tmp_path: Path) -> None:
    new, old, frames = drives
    again_old, again_new = tmp_path / "from_old.mcap", tmp_path / "from_new.mcap"
    assert convert([old], again_old, []).frames == frames
    assert convert([new], again_new, []).frames == frames

    def topics(path: Path) -> dict[str, list[tuple[int, bytes]]]:
        out: dict[str, list[tuple[int, bytes]]] = {}
        with path.open("rb") as f:
            for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
                out.setdefault(channel.topic, []).append((message.log_time, message.data))
        return out

    assert topics(again_old) == topics(again_new)  # blocks again, every topic the same


def test_an_old_drive_is_catalogued_and_recovered_with_its_frames(
        drives: tuple[Path, Path, int], tmp_path: Path) -> None:
    _, old, frames = drives
    with old.open("rb") as f:
        statistics = json.loads(next(m.metadata for m in make_reader(f).iter_metadata()
                                     if m.name == "tankviz")["statistics"])
    assert statistics["frames"] == {"can0": frames}
    assert read_drive(old).tables["drives"][0][12] == frames  # the drives table's frames
    cut = tmp_path / "cut.mcap"
    data = old.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])  # a power loss
    fixed = tmp_path / "fixed.mcap"
    report = recover_file(cut, fixed)
    assert report.messages > 0
    held = list(ArchiveSource(fixed))
    assert 0 < len(held) < frames
    assert held == list(ArchiveSource(old))[:len(held)]
    with fixed.open("rb") as f:
        assert raw_frame_counts(make_reader(f)) == {"can0": len(held)}
    # recovered: no tankviz record; the catalogue counts what the file holds
    assert read_drive(fixed).tables["drives"][0][12] == len(held)


class Served:
    """What a replay serves: schema and messages per topic (a stand-in for the server)."""

    def __init__(self) -> None:
        self.schemas: dict[str, str] = {}
        self.messages: dict[int, int] = {}
        self.ids: dict[str, int] = {}

    def channel_for_schema(self, topic: str, schema_name: str, schema: bytes,
                           **_: str) -> int:
        self.schemas[topic] = schema_name
        return self.ids.setdefault(topic, len(self.ids))

    def publish(self, channel: int, t_ns: int, payload: bytes) -> None:
        self.messages[channel] = self.messages.get(channel, 0) + 1

    def flush(self) -> None:
        pass

    def broadcast_time(self, t_ns: int) -> None:
        pass


def test_old_and_new_drives_are_replayed_as_recorded(drives: tuple[Path, Path, int]) -> None:
    new, old, frames = drives
    for path, schema, count in ((old, "tankviz.CanFrame", frames),
                                (new, "tankviz.CanFrameBlock", None)):
        served = Served()
        replay_mcap(path, served, speed=1e6)  # type: ignore[arg-type]
        assert served.schemas["/can/can0/frames"] == schema
        sent = served.messages[served.ids["/can/can0/frames"]]
        assert sent == count if count is not None else 0 < sent < frames
