"""Old drives still re-derive, replay, recover, go into the catalogue and are inspected:

- drives recorded before raw frames were archived in blocks (one ``tankviz.CanFrame`` a message
  on ``/can/<bus>/frames``), with their frames counted exactly; made here from a new drive: the
  same file with every block of raw frames written as one ``tankviz.CanFrame`` message per frame
  (as tankviz wrote them then), everything else copied as it is;
- drives recorded before #36, whose decoded topics have every signal ``optional`` (a zero
  written) and a short frame's message on its message's topic: made here from a new drive by
  :func:`as_before_36` (on the sample drive's first 2 s its decoded topics were checked byte for
  byte, schemas and messages, against a drive converted by tankviz before #36). Re-derived, such a
  drive gives its scene, perception, health and raw topics back byte for byte.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader
from mcap.writer import Writer

from bridge.apps.inspect import summarize_file
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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_old_and_new_drives_are_replayed_as_recorded(drives: tuple[Path, Path, int]) -> None:
    new, old, frames = drives
    for path, schema, count in ((old, "tankviz.CanFrame", frames),
                                (new, "tankviz.CanFrameBlock", None)):
        served = Served()
        replay_mcap(path, served, speed=1e6)  # type: ignore[arg-type]
        assert served.schemas["/can/can0/frames"] == schema
        sent = served.messages[served.ids["/can/can0/frames"]]
        assert sent == count if count is not None else 0 < sent < frames


# ---------------------------------------------------------------------------------------------
# Drives recorded before #36: every decoded signal optional


def optional_everywhere(data: bytes, name: str) -> tuple[bytes, str]:
    """A decoded topic's FileDescriptorSet and type as tankviz wrote them before #36: every field
    ``optional`` (its synthetic oneofs in field order), a short frame's type its message's."""
    files = descriptor_pb2.FileDescriptorSet.FromString(data)
    for f in files.file:
        if f.package.endswith(".short"):
            f.package = f.package.removesuffix(".short")
            f.name = f.name.replace("/short/", "/")
        for m in f.message_type:
            del m.oneof_decl[:]
            for fd in m.field:
                if fd.HasField("type_name"):
                    fd.type_name = fd.type_name.replace(".short.", ".")
                fd.proto3_optional, fd.oneof_index = True, len(m.oneof_decl)
                m.oneof_decl.add(name=f"_{fd.name}")
    return files.SerializeToString(), name.replace(".short.", ".")


def message_class(data: bytes, name: str) -> Any:
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def as_before_36(new: Path, old: Path) -> None:
    """``new`` rewritten as tankviz wrote it before #36: each decoded message with every signal
    it holds written, zeros too, in the all-optional type, on its message's topic."""
    with new.open("rb") as f, old.open("wb") as out:
        reader = make_reader(f)
        writer = Writer(out)
        writer.start(profile="", library="tankviz (before #36)")
        for a in reader.iter_attachments():
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        classes: dict[int, tuple[Any, Any]] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert schema is not None
            data, name, topic, payload = schema.data, schema.name, channel.topic, message.data
            if name.startswith("tankviz.dbc."):
                data, name = optional_everywhere(schema.data, schema.name)
                topic = topic.removesuffix("/short")
                if schema.id not in classes:
                    classes[schema.id] = (message_class(schema.data, schema.name),
                                          message_class(data, name))
                new_class, old_class = classes[schema.id]
                decoded = new_class.FromString(payload)
                values = {d.name: v for d, v in decoded.ListFields()}
                values.update((d.name, getattr(decoded, d.name))
                              for d in decoded.DESCRIPTOR.fields if not d.has_presence)
                payload = old_class(**values).SerializeToString()
            if name not in schemas:
                schemas[name] = writer.register_schema(name, schema.encoding, data)
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, channel.message_encoding,
                                                          schemas[name])
            writer.add_message(channels[topic], message.log_time, payload, message.publish_time)
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, dict(m.metadata))
        writer.finish()


def by_topic(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


def decoded_topic(topic: str) -> bool:
    return topic.startswith("/can/") and not topic.endswith(("/frames", "/ids", "/unknown"))


@pytest.fixture(scope="module")
def before_36(drives: tuple[Path, Path, int],
              tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    new = drives[0]
    old = tmp_path_factory.mktemp("before36") / "before36.mcap"
    as_before_36(new, old)
    return new, old


@pytest.mark.slow
def test_a_drive_before_36_writes_zeros_and_has_presence_everywhere(
        before_36: tuple[Path, Path]) -> None:
    _, old = before_36
    with old.open("rb") as f:
        for schema, _, message in make_reader(f).iter_messages(topics=[
                "/can/can0/EgoMotion"]):
            assert schema is not None
            decoded = message_class(schema.data, schema.name).FromString(message.data)
            assert all(d.has_presence for d in decoded.DESCRIPTOR.fields)
            assert decoded.HasField("VehicleSpeed") and decoded.HasField("Counter")


@pytest.mark.slow
def test_a_drive_before_36_re_derives_its_scene_byte_for_byte(
        before_36: tuple[Path, Path], tmp_path: Path) -> None:
    new, old = before_36
    again = tmp_path / "again.mcap"
    convert([old], again, [])
    old_topics, again_topics, new_topics = by_topic(old), by_topic(again), by_topic(new)
    kept = {t for t in old_topics if not decoded_topic(t)}
    assert kept >= {"/scene/ego", "/scene/tracks", "/perception/lead", "/health",
                    "/can/can0/frames"}
    assert {t: again_topics[t] for t in kept} == {t: old_topics[t] for t in kept}
    # and its decoded topics are as a new drive's: zeros not written where absence cannot be
    assert {t: v for t, v in again_topics.items() if decoded_topic(t)} == {
        t: v for t, v in new_topics.items() if decoded_topic(t)}


@pytest.mark.slow
def test_a_drive_before_36_is_replayed_recovered_catalogued_and_inspected(
        before_36: tuple[Path, Path], tmp_path: Path) -> None:
    _, old = before_36
    served = Served()
    replay_mcap(old, served, speed=1e6)  # type: ignore[arg-type]
    assert served.schemas["/can/can0/EgoMotion"] == "tankviz.dbc.ecocar.EgoMotion"
    assert served.messages[served.ids["/can/can0/EgoMotion"]] == len(
        by_topic(old)["/can/can0/EgoMotion"])
    frames = len(list(ArchiveSource(old)))
    assert read_drive(old).tables["drives"][0][12] == frames
    summary = summarize_file(old)
    assert {t.topic for t in summary.topics} == set(by_topic(old))
    cut, fixed = tmp_path / "cut.mcap", tmp_path / "fixed.mcap"
    data = old.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    assert recover_file(cut, fixed).messages > 0
    held = by_topic(fixed)["/can/can0/EgoMotion"]
    assert held and held == by_topic(old)["/can/can0/EgoMotion"][:len(held)]
