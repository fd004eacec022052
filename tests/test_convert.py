"""Round trips: CAN logs → tankviz convert → MCAP, read back with mcap and mcap_protobuf."""

from __future__ import annotations

import hashlib
import io
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import can
import cantools
import pytest
from conftest import ECOCAR_DBC, T0, WriteLog, message
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.apps.inspect import format_summary, summarize, summarize_file
from bridge.errors import FileError, InputError
from bridge.frame import Frame
from bridge.io.can_logs import LogSource
from bridge.io.drives import BlockMerger, block_frames
from bridge.pipeline.convert import convert, record_drive
from bridge.pipeline.drive import build_decoder
from bridge.topics import BITS_LABELS_TOPIC, BITS_TOPIC


def drive(db: cantools.database.can.Database) -> list[can.Message]:
    """Two buses of ecocar traffic with everything a converter must cope with."""
    out: list[can.Message] = []
    for i in range(50):
        t = T0 + i * 0.02
        out.append(message(db, "EgoMotion", t, 0, VehicleSpeed=80 + i * 0.1, Counter=i % 16))
        out.append(message(db, "Steering", t + 0.001, 0, SteeringWheelAngle=-10 + i))
        out.append(message(db, "RadarObj0_A", t + 0.002, 1, LongDist=40 - i * 0.1, LatDist=0.5,
                           ProbExist=90, Valid=1))
        out.append(message(db, "RadarObj0_B", t + 0.003, 1, Class=3, Length=0.5))
        out.append(message(db, "SensorDiag", t + 0.004, 0, DiagPage=i % 4))
    out.append(message(db, "RadarHeader", T0 + 0.5, 1, ObjectCount=3))  # CAN FD
    out.append(can.Message(timestamp=T0 + 0.6, arbitration_id=0x7AB, data=b"\x01\x02",
                           channel=0, is_extended_id=False))  # not in the DBC
    out.append(can.Message(timestamp=T0 + 0.7, is_error_frame=True, channel=1))
    short = message(db, "EgoMotion", T0 + 0.8, 0, VehicleSpeed=12.5)
    short.data, short.dlc = short.data[:3], 3
    out.append(short)
    return sorted(out, key=lambda m: m.timestamp)


@dataclass
class RawFrame:
    """A recorded raw frame, by the field names of its schema, and its log time."""

    frame: Frame
    NAMES: ClassVar[dict[str, str]] = {
        "log_time": "timestamp_ns", "id": "arbitration_id", "extended": "is_extended",
        "fd": "is_fd", "error": "is_error", "remote": "is_remote"}

    def __getattr__(self, name: str) -> Any:
        return getattr(self.frame, self.NAMES.get(name, name))


def read_back(stream: io.BytesIO | Path) -> tuple[dict[str, list[Any]], list[RawFrame]]:
    """Every decoded message by topic, and the raw frames in the order they were recorded
    (read back from their blocks as a drive's reader does)."""
    by_topic: dict[str, list[Any]] = {}
    raw: list[RawFrame] = []
    merger = BlockMerger()
    handle = stream.open("rb") if isinstance(stream, Path) else stream
    with handle:
        handle.seek(0)
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            by_topic.setdefault(channel.topic, []).append(decoded)
            if channel.topic.endswith("/frames"):
                raw += map(RawFrame, merger.add(block_frames(message.log_time, decoded)))
    raw += map(RawFrame, merger.finish())
    return by_topic, raw


def read_signals(decoded: Any) -> dict[str, Any]:
    """A decoded message's signals as a reader sees them: the fields with presence that are
    set, and every field of implicit presence (0 where none was written)."""
    out = {d.name: v for d, v in decoded.ListFields()}
    for d in decoded.DESCRIPTOR.fields:
        if not d.has_presence:
            out.setdefault(d.name, getattr(decoded, d.name))
    return out


def bring_up_topic(topic: str) -> bool:
    """A topic of bring-up's (tests/test_bringup_topics.py), not a frame's or a message's."""
    return topic in (BITS_TOPIC, BITS_LABELS_TOPIC) or topic.endswith(("/ids", "/unknown"))


def test_every_frame_is_recorded_raw_and_every_known_one_decoded(
        write_log: WriteLog, ecocar: cantools.database.can.Database) -> None:
    messages = drive(ecocar)
    log = write_log("drive.blf", messages)
    out = io.BytesIO()
    report = record_drive([LogSource(log)], build_decoder([str(ECOCAR_DBC)]), out)

    by_topic, raw = read_back(out)

    assert report.frames == len(messages) == len(raw)
    # in time order; two buses' frames stamped alike in the order of their blocks
    raw.sort(key=lambda f: (f.log_time, f.bus))
    messages.sort(key=lambda m: (m.timestamp, m.channel))
    assert [(f.id, f.data, f.log_time, f.fd, f.error) for f in raw] == [
        (m.arbitration_id, bytes(m.data), round(m.timestamp * 1e6) * 1000, m.is_fd,
         m.is_error_frame) for m in messages]
    assert {f.bus for f in raw} == {"can0", "can1"}
    for m, f in zip(messages, raw, strict=True):
        if m.is_error_frame or m.arbitration_id == 0x7AB:
            continue
        definition = ecocar.get_message_by_frame_id(m.arbitration_id)
        bus = f.bus
        expected = definition.decode(bytes(m.data), decode_choices=False, allow_truncated=True)
        topic = f"/can/{bus}/{definition.name}"
        if len(m.data) < definition.length:  # a short frame: its signals beside the message's
            topic += "/short"
        decoded = by_topic[topic].pop(0)
        assert read_signals(decoded) == expected, topic
    assert all(not left for topic, left in by_topic.items()
               if topic.startswith("/can/") and not topic.endswith("/frames")
               and not bring_up_topic(topic))
    stats = report.statistics
    assert stats["unknown_ids"] == {"can0/0x7AB": 1}
    assert stats["error_frames"] == {"can1": 1}
    assert stats["truncated"] == {"/can/can0/EgoMotion": 1}


def test_the_archive_is_self_contained_and_can_be_decoded_again_from_it_alone(
        write_log: WriteLog, ecocar: cantools.database.can.Database) -> None:
    log = write_log("drive.blf", drive(ecocar))
    out = io.BytesIO()
    record_drive([LogSource(log)], build_decoder([f"can0={ECOCAR_DBC}", f"can1={ECOCAR_DBC}"]),
                 out)
    out.seek(0)
    reader = make_reader(out)
    (attachment,) = list(reader.iter_attachments())
    meta = next(m.metadata for m in reader.iter_metadata() if m.name == "tankviz")

    assert attachment.name == "ecocar.dbc"
    assert attachment.data == ECOCAR_DBC.read_bytes()
    assert f'"sha256": "{hashlib.sha256(attachment.data).hexdigest()}"' in meta["databases"]
    assert meta["bus_databases"] == '{"can0": ["ecocar.dbc"], "can1": ["ecocar.dbc"]}'
    assert '"frames": 254' in meta["inputs"]

    again = cantools.database.load_string(attachment.data.decode(), database_format="dbc")
    by_topic, raw = read_back(out)
    speeds = [again.decode_message(f.id, f.data)["VehicleSpeed"] for f in raw
              if f.id == 0x100 and len(f.data) == 8]
    # the short frame's signals are on their own topic
    assert speeds == [m.VehicleSpeed for m in by_topic["/can/can0/EgoMotion"]]
    (short,) = by_topic["/can/can0/EgoMotion/short"]
    assert short.HasField("VehicleSpeed") and not short.HasField("Checksum")


def test_chunks_are_zstd_and_the_summary_counts_every_topic(
        write_log: WriteLog, ecocar: cantools.database.can.Database) -> None:
    log = write_log("drive.blf", drive(ecocar))
    out = io.BytesIO()
    record_drive([LogSource(log)], build_decoder([str(ECOCAR_DBC)]), out)
    out.seek(0)
    summary = make_reader(out).get_summary()
    assert summary is not None and summary.statistics is not None
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    counts = {summary.channels[i].topic: n
              for i, n in summary.statistics.channel_message_counts.items()}
    _, raw = read_back(out)
    assert len(raw) == 254
    assert 0 < counts["/can/can0/frames"] + counts["/can/can1/frames"] < 254  # in blocks
    assert counts["/can/can0/SensorDiag"] == 50


def test_several_inputs_of_different_formats_merge_into_one_drive(
        write_log: WriteLog, ecocar: cantools.database.can.Database) -> None:
    messages = drive(ecocar)
    a = write_log("front.asc", messages[::2])
    b = write_log("rear.log", messages[1::2])
    out = io.BytesIO()
    report = record_drive([LogSource(a), LogSource(b)], build_decoder([str(ECOCAR_DBC)]), out)
    _, raw = read_back(out)
    assert report.frames == len(messages)
    times = [f.log_time for f in raw]
    assert times == sorted(times)


def test_convert_writes_the_file_and_inspect_describes_it(
        write_log: WriteLog, ecocar: cantools.database.can.Database, tmp_path: Path) -> None:
    log = write_log("drive.blf", drive(ecocar))
    output = tmp_path / "drive.mcap"
    report = convert([log], output, [str(ECOCAR_DBC)])
    assert report.output == output
    summary = summarize_file(output)
    assert summary.messages == report.messages
    assert summary.duration_s == pytest.approx(0.984)  # first to last frame
    text = format_summary(str(output), summary)
    for expected in ("duration:", "/can/can0/EgoMotion", "tankviz.dbc.ecocar.EgoMotion",
                     "unknown ids: 1 — can0/0x7AB (1)", "ecocar.dbc  application/x-dbc",
                     "short frames (decoded what fits): 1", "can1: 102 frames, 1 error frames"):
        assert expected in text, expected


def test_an_existing_output_is_refused_unless_forced(
        write_log: WriteLog, ecocar: cantools.database.can.Database, tmp_path: Path) -> None:
    log = write_log("drive.blf", drive(ecocar)[:5])
    output = tmp_path / "drive.mcap"
    output.write_bytes(b"precious")
    with pytest.raises(FileError, match=r"drive\.mcap: exists already; use --force"):
        convert([log], output, [str(ECOCAR_DBC)])
    assert output.read_bytes() == b"precious"
    convert([log], output, [str(ECOCAR_DBC)], force=True)
    assert summarize_file(output).messages > 0


def test_an_unwritable_output_is_refused(write_log: WriteLog) -> None:
    log = write_log("drive.log", [can.Message(timestamp=T0, arbitration_id=1, data=b"1")])
    with pytest.raises(FileError, match=r"cannot write: folder .*missing does not exist"):
        convert([log], log.parent / "missing" / "out.mcap", [])
    # /proc takes no new files, not even from root
    with pytest.raises(FileError, match=r"^/proc/out\.mcap: cannot write"):
        convert([log], Path("/proc/out.mcap"), [])


def test_a_failed_conversion_leaves_no_file(write_log: WriteLog, tmp_path: Path) -> None:
    log = write_log("drive.log", [can.Message(timestamp=T0, arbitration_id=1, data=b"1")])
    log.write_text(log.read_text() + "garbage\n")
    output = tmp_path / "drive.mcap"
    with pytest.raises(InputError, match=r"drive\.log:line 2: skipped a line"):
        convert([log], output, [str(ECOCAR_DBC)], strict=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drive.log"]


def test_skipped_input_is_reported_in_the_archive(write_log: WriteLog, tmp_path: Path) -> None:
    log = write_log("drive.log", [can.Message(timestamp=T0, arbitration_id=1, data=b"1")])
    log.write_text(log.read_text() + "garbage\n" + "(1700000001.0) can0 002#02\n")
    out = io.BytesIO()
    report = record_drive([LogSource(log)], build_decoder([]), out)
    assert report.frames == 2
    assert [i.where for i in report.issues] == ["line 2"]
    out.seek(0)
    text = format_summary("drive.mcap", summarize(out))
    assert "skipped in the inputs (1):" in text
    assert "drive.log:line 2: skipped a line python-can cannot parse" in text


def test_raw_frames_are_complete_for_unknown_ids(write_log: WriteLog) -> None:
    frames = [can.Message(timestamp=T0 + i, arbitration_id=i, data=bytes([i]), channel=0,
                          is_extended_id=False) for i in range(20)]
    out = io.BytesIO()
    record_drive([LogSource(write_log("drive.blf", frames))], build_decoder([]), out)
    by_topic, raw = read_back(out)
    assert [t for t in by_topic if t.startswith("/can/") and not bring_up_topic(t)] == [
        "/can/can0/frames"]
    assert Counter(f.id for f in raw) == Counter(range(20))
