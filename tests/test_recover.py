"""``tankviz recover``: a drive cut anywhere gives back every message before the cut.

The drives are recorded by the real :class:`Recorder` with small chunks (so there are many), then
cut, zero-filled or damaged the way a power loss, a killed recorder or a bad disk leaves them.
"""

from __future__ import annotations

import functools
import io
import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import pytest
from foxglove_schemas_protobuf.Log_pb2 import Log
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import McapReader, make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.summary import Summary

from bridge.apps.inspect import format_summary, summarize_file
from bridge.apps.recover import METADATA_NAME, RecoverReport, format_report, recover, recover_file
from bridge.errors import FileError, InputError
from bridge.frame import Frame
from bridge.sinks.mcap import Recorder
from bridge.sinks.raw import cut as blocks

T0 = 1_700_000_000_000_000_000
DBC = b'VERSION ""\n\nBU_: ECU\n\nBO_ 256 Speed: 8 ECU\n SG_ V : 0|16@1+ (0.01,0) [0|655] "" ECU\n'

#: A message as the tests compare them: topic, log time, publish time, sequence, data.
Msg = tuple[str, int, int, int, bytes]


@dataclass(frozen=True)
class Drive:
    data: bytes
    messages: list[Msg]  # in file order
    chunks: list[tuple[int, int, int]]  # start, end, messages in this and every earlier chunk
    starts: list[int]  # where each record and the closing magic start
    data_end: int  # where the data end record starts: every message is before it


def record(stream: IO[bytes], frames: int = 1200) -> None:
    """Two buses of raw frames, a log topic, an attachment and notes mid-drive, the tankviz
    metadata at the end (as ``tankviz convert`` writes it).

    The attachment and notes come after the first 4 chunks (and after the first window of
    :func:`test_every_cut_across_a_chunk_and_the_attachment`), not halfway: every cut across them
    is recovered and read back, and each would otherwise recover 15 chunks before them again.
    """
    recorder = Recorder(stream, chunk_size=2048)
    for i in range(frames):
        t = T0 + i * 1_000_000
        bus = "radar" if i % 3 else "vehicle"
        frame = Frame(t, bus, 0x100 + i % 7, bytes([i % 256] * (i % 9)), dlc=i % 9)
        recorder.on_raw(blocks([frame]))  # a block a frame: as many messages
        if i % 40 == 0:
            recorder.write("/log", Log(message=f"frame {i}", name="test"), t)
        if i == frames // 8:
            recorder.add_attachment("vehicle.dbc", DBC)
            recorder.add_metadata({"driver": "test", "laps": 3}, name="notes")
    recorder.add_metadata({"tankviz_version": "test", "frames": frames})
    recorder.finish()


def summary(data: bytes) -> Summary:
    found = make_reader(io.BytesIO(data)).get_summary()
    assert found is not None
    return found


def messages(data: bytes) -> list[Msg]:
    return read_messages(make_reader(io.BytesIO(data)))


def read_messages(reader: McapReader) -> list[Msg]:
    return [(channel.topic, m.log_time, m.publish_time, m.sequence, m.data)
            for _, channel, m in reader.iter_messages(log_time_order=False)]


@functools.cache
def drive() -> Drive:
    out = io.BytesIO()
    record(out)
    data = out.getvalue()
    chunks, total = [], 0
    for index in summary(data).chunk_indexes:
        start, end = index.chunk_start_offset, index.chunk_start_offset + index.chunk_length
        chunk = next(StreamReader(io.BytesIO(data[start:end]), skip_magic=True,
                                  emit_chunks=True).records)
        assert isinstance(chunk, Chunk)
        total += sum(isinstance(r, Message) for r in breakup_chunk(chunk))
        chunks.append((start, end, total))
    starts, at, data_end = [], 8, 0
    while at < len(data) - 8:
        starts.append(at)
        opcode, length = struct.unpack_from("<BQ", data, at)
        data_end = at if opcode == 0x0F else data_end
        at += 9 + length
    return Drive(data, messages(data), chunks, [*starts, at], data_end)


def run(data: bytes) -> tuple[RecoverReport, bytes]:
    fixed = io.BytesIO()
    report = recover(io.BytesIO(data), fixed, source_name="drive.mcap")
    return report, fixed.getvalue()


def check_valid(report: RecoverReport, fixed: bytes) -> list[Msg]:
    """The recovered file is a complete MCAP whose summary agrees with the report."""
    reader = make_reader(io.BytesIO(fixed))  # one reader: it reads the summary once
    found = reader.get_summary()
    assert found is not None
    statistics = found.statistics
    assert statistics is not None and statistics.message_count == report.messages
    got = read_messages(reader)
    assert len(got) == report.messages
    counts: dict[str, int] = {}
    for topic, *_ in got:
        counts[topic] = counts.get(topic, 0) + 1
    assert report.per_topic == counts
    assert [m.name for m in reader.iter_metadata()][-1] == METADATA_NAME
    return got


def recover_record(fixed: bytes) -> dict[str, Any]:
    (values,) = [m.metadata for m in make_reader(io.BytesIO(fixed)).iter_metadata()
                 if m.name == METADATA_NAME]
    text = ("source", "source_library", "created", "tankviz_version", "stopped")
    return {k: v if k in text else json.loads(v) for k, v in values.items()}


# -- a complete drive -------------------------------------------------------------------------


def test_a_complete_drive_is_copied_whole() -> None:
    d = drive()
    report, fixed = run(d.data)
    assert report.stopped is None and report.stopped_at is None and report.skipped == []
    assert report.bytes_read == report.bytes_total == len(d.data)
    assert check_valid(report, fixed) == d.messages
    assert report.per_topic == {"/can/radar/frames": 800, "/can/vehicle/frames": 400, "/log": 30}
    assert (report.first_ns, report.last_ns) == (T0, T0 + 1199 * 1_000_000)
    assert (report.metadata, report.attachments) == (2, 1)

    original, recovered = make_reader(io.BytesIO(d.data)), make_reader(io.BytesIO(fixed))
    assert [(m.name, m.metadata) for m in original.iter_metadata()] == [
        (m.name, m.metadata) for m in recovered.iter_metadata()][:-1]
    assert [(a.name, a.media_type, a.data, a.log_time, a.create_time)
            for a in original.iter_attachments()] == [
        (a.name, a.media_type, a.data, a.log_time, a.create_time)
        for a in recovered.iter_attachments()]
    assert {(s.name, s.encoding, s.data) for s in summary(d.data).schemas.values()} == {
        (s.name, s.encoding, s.data) for s in summary(fixed).schemas.values()}

    said = recover_record(fixed)
    assert said["source"] == "drive.mcap" and said["complete"] is True
    assert said["stopped"] == "" and said["stopped_at"] is None and said["messages"] == 1230
    assert said["bytes_read"] == said["bytes_total"] == len(d.data)
    assert said["messages_per_topic"] == report.per_topic


def test_the_report_of_a_complete_drive() -> None:
    report, _ = run(drive().data)
    size = len(drive().data)
    assert format_report(report, "drive.mcap", "fixed.mcap").splitlines() == [
        "recovered 1,230 messages in 3 topics spanning 1.199 s "
        "(from 2023-11-14T22:13:20.000+00:00 to 2023-11-14T22:13:21.199+00:00)",
        "  /can/radar/frames    800",
        "  /can/vehicle/frames  400",
        "  /log                  30",
        "  2 metadata records, 1 attachment",
        f"read {size:,} of {size:,} bytes of drive.mcap (100.0 %)",
        "the file was complete",
        "wrote fixed.mcap (its tankviz.recover metadata record says what was recovered)",
    ]


def test_a_recovered_drive_recovers_to_itself() -> None:
    report, fixed = run(drive().data[:30_000])
    again, fixed_again = run(fixed)
    assert again.stopped is None
    assert messages(fixed_again) == messages(fixed)
    assert again.metadata == report.metadata + 1  # the first recovery's record is kept


# -- cut drives -------------------------------------------------------------------------------


@functools.cache
def check_cut(cut: int) -> RecoverReport:
    """Recover the drive cut at ``cut``: a prefix of its messages, read up to the cut record.

    Each cut is recovered and checked once: recovering is deterministic, so a test that comes to
    a cut already checked (hypothesis draws a cut again, the tests' cuts overlap) gets its report.
    """
    d = drive()
    if cut < 8:  # not even the MCAP magic: nothing to recover, nothing written
        with pytest.raises(InputError, match="not an MCAP file"):
            run(d.data[:cut])
        return RecoverReport()
    report, fixed = run(d.data[:cut])
    got = check_valid(report, fixed)
    assert got == d.messages[:len(got)]
    assert report.bytes_total == cut
    # Reading stops exactly where the first record the cut damaged starts.
    assert report.stopped_at == max([0, *(at for at in d.starts if at <= cut)])
    assert report.bytes_read == report.stopped_at and report.stopped is not None
    assert report.skipped == [] and report.dropped == 0
    if cut > d.data_end:  # in the data end record, the summary or the closing magic
        assert got == d.messages and "no data was lost" in report.stopped
    return report


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(st.data())
def test_a_drive_cut_anywhere_gives_back_a_prefix(data: st.DataObject) -> None:
    check_cut(data.draw(st.integers(0, len(drive().data) - 1), label="cut"))


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(st.data())
def test_a_later_cut_never_recovers_less(data: st.DataObject) -> None:
    # b after a: hypothesis readily draws the same number twice, and a cut is never later than
    # itself (half the examples of b in [a, end] were a == b)
    a = data.draw(st.integers(0, len(drive().data) - 2), label="a")
    b = data.draw(st.integers(a + 1, len(drive().data) - 1), label="b")
    assert check_cut(a).messages <= check_cut(b).messages


@pytest.mark.slow
def test_every_cut_across_a_chunk_and_the_attachment() -> None:
    """Every byte offset of two windows: across the 3rd chunk and its message indexes, and
    across the attachment and metadata written mid-drive."""
    d = drive()
    messages = [check_cut(cut).messages
                for cut in range(d.chunks[1][1] - 10, d.chunks[3][0] + 10)]
    assert messages == sorted(messages) and messages[0] < messages[-1]
    attachment = summary(d.data).attachment_indexes[0].offset
    counts = [(r.messages, r.attachments, r.metadata)
              for r in map(check_cut, range(attachment - 40, attachment + 400))]
    assert counts == sorted(counts) and counts[0][1:] == (0, 0) and counts[-1][1:] == (1, 1)


@pytest.mark.slow
def test_a_cut_right_after_a_chunk_keeps_all_its_messages() -> None:
    d = drive()
    before = 0
    for start, end, total in d.chunks:
        report = check_cut(end)  # its message indexes are gone: not needed
        assert report.messages == total
        assert report.stopped == ("the file ends after the last complete record (the recording "
                                  "was cut before it wrote its summary)")
        assert check_cut(end - 1).messages == before  # one byte short: the chunk is lost
        assert str(check_cut(start + 20).stopped).startswith("the file ends inside a chunk record")
        before = total


def test_the_report_of_a_cut_drive(tmp_path: Path) -> None:
    d = drive()
    start, end, _ = d.chunks[5]
    broken, fixed = tmp_path / "broken.mcap", tmp_path / "fixed.mcap"
    broken.write_bytes(d.data[:end - 100])
    report = recover_file(broken, fixed)
    assert report.messages == d.chunks[4][2]
    lines = format_report(report, broken, fixed).splitlines()
    assert lines[0].startswith(f"recovered {report.messages:,} messages in 3 topics spanning ")
    assert f"read {start:,} of {end - 100:,} bytes of {broken} (" in lines[-3]
    assert lines[-2] == (f"stopped at byte {start:,}: the file ends inside a chunk record of "
                         f"{end - start:,} bytes ({end - 100 - start:,} of them are there)")
    # the recovered drive is an ordinary drive: tankviz inspect reads its summary
    summary = summarize_file(fixed)
    assert summary.messages == report.messages
    assert summary.metadata[METADATA_NAME]["stopped_at"] == str(start)
    assert summary.metadata[METADATA_NAME]["source"] == str(broken)


def test_inspect_prints_a_recovered_drives_counts_per_topic_a_line_each(tmp_path: Path) -> None:
    d = drive()
    _, end, _ = d.chunks[5]
    broken, fixed = tmp_path / "broken.mcap", tmp_path / "fixed.mcap"
    broken.write_bytes(d.data[:end - 100])
    report = recover_file(broken, fixed)
    lines = format_summary(str(fixed), summarize_file(fixed)).splitlines()
    at = lines.index(f"  messages_per_topic ({len(report.per_topic)}):")
    assert [line.split() for line in lines[at + 1:at + 1 + len(report.per_topic)]] == [
        [topic, f"{n:,}"] for topic, n in report.per_topic.items()]
    assert not any(line.lstrip().startswith("messages_per_topic: {") for line in lines)


def test_zeros_where_the_data_never_reached_the_disk() -> None:
    d = drive()
    _, end, total = d.chunks[2]
    data = d.data[:end] + bytes(len(d.data) - end)  # the file has its length, not its data
    report, fixed = run(data)
    assert check_valid(report, fixed) == d.messages[:total]
    assert report.stopped_at == end
    assert str(report.stopped).startswith("zero bytes where the next record should start")


class Stream(io.RawIOBase):
    """A pipe: cannot seek, returns short reads; or a disk that fails at ``bad`` bytes."""

    def __init__(self, data: bytes, bad: int | None = None) -> None:
        self.data, self.at, self.bad = data, 0, bad

    def readable(self) -> bool:
        return True

    def read(self, n: int = -1) -> bytes:
        if self.bad is not None and self.at >= self.bad:
            raise OSError(5, "Input/output error")
        n = min(n if n >= 0 else len(self.data), 1000)
        if self.bad is not None:
            n = min(n, self.bad - self.at)
        piece = self.data[self.at:self.at + n]
        self.at += len(piece)
        return piece


def test_a_stream_that_cannot_seek() -> None:
    d = drive()
    for cut in (len(d.data), d.chunks[3][1] + 5, d.chunks[3][1] + 12, d.chunks[3][1] - 5):
        fixed = io.BytesIO()
        report = recover(Stream(d.data[:cut]), fixed)  # type: ignore[arg-type]
        expected, _ = run(d.data[:cut])
        assert (report.messages, report.stopped_at, report.bytes_total) == (
            expected.messages, expected.stopped_at, cut)
        assert messages(fixed.getvalue()) == d.messages[:report.messages]
    assert report.stopped == "the file ends inside a chunk record"


def test_a_read_error_stops_reading_there() -> None:
    d = drive()
    start = d.chunks[4][0]
    fixed = io.BytesIO()
    report = recover(Stream(d.data, bad=start + 100), fixed)  # type: ignore[arg-type]
    assert report.stopped_at == start
    assert report.stopped == "the disk cannot read this chunk record: Input/output error"
    assert messages(fixed.getvalue()) == d.messages[:d.chunks[3][2]]


# -- damaged drives ---------------------------------------------------------------------------


def damage(data: bytes, at: int) -> bytes:
    return data[:at] + bytes([data[at] ^ 0x55]) + data[at + 1:]


@pytest.mark.parametrize("complete", [True, False])
def test_a_chunk_that_fails_its_crc_is_skipped_and_reading_goes_on(complete: bool) -> None:
    d = drive()
    start, end, total = d.chunks[6]
    before = d.chunks[5][2]
    data = damage(d.data, (start + end) // 2)  # a byte of its compressed records
    if not complete:
        data = data[:d.chunks[9][1]]
    report, fixed = run(data)
    (line,) = report.skipped
    assert line.startswith("chunk (log time 2023-11-14T22:13:20.")
    assert f"at byte {start:,}: " in line
    assert ("its CRC does not match its content" in line or "it does not decompress" in line)
    assert line.endswith(f"; {total - before:,} messages lost")
    got = check_valid(report, fixed)
    assert got == d.messages[:before] + d.messages[total:total + len(got) - before]
    assert (report.stopped is None) == complete
    assert report.messages == (len(d.messages) if complete else d.chunks[9][2]) - (total - before)
    text = format_report(report, "drive.mcap", "fixed.mcap")
    assert "skipped the damaged chunk (log time" in text
    assert recover_record(fixed)["skipped"] == report.skipped


def test_channels_defined_in_a_skipped_chunk() -> None:
    """The first chunk defines every channel. With the summary still there its copies stand in;
    a cut drive has none, so the later messages of those channels are dropped and counted."""
    d = drive()
    start, end, first = d.chunks[0]
    data = damage(d.data, (start + end) // 2)
    report, fixed = run(data)
    assert report.dropped == 0 and report.messages == len(d.messages) - first
    assert check_valid(report, fixed) == d.messages[first:]

    report, fixed = run(data[:d.chunks[4][1]])
    assert check_valid(report, fixed) == []
    assert report.dropped == d.chunks[4][2] - first
    assert (f"dropped {report.dropped:,} messages whose channel was defined only in a skipped "
            "chunk") in format_report(report, "a", "b").splitlines()


def test_a_damaged_record_length_is_repaired_from_the_summary() -> None:
    d = drive()
    start = d.chunks[3][0]
    report, fixed = run(damage(d.data, start + 2))  # the chunk's record length
    assert report.stopped is None and report.skipped == []
    (line,) = report.repaired
    assert line.startswith(f"chunk record at byte {start:,}: its length field says ")
    assert line.endswith("; read with the opcode and length the summary's index gives it")
    assert check_valid(report, fixed) == d.messages
    assert f"repaired the damaged {line}" in format_report(report, "a", "b").splitlines()


def test_a_chunk_with_a_damaged_length_in_a_cut_drive_is_skipped() -> None:
    """No summary: the next chunk that proves itself by its CRC is where reading goes on."""
    d = drive()
    start = d.chunks[3][0]
    before = d.chunks[2][2]
    cut = d.chunks[8][1]
    report, fixed = run(damage(d.data, start + 2)[:cut])
    (line,) = report.skipped
    assert line.startswith(f"chunk record at byte {start:,}: its length field says ")
    after = min(at for at in d.starts if at > start and d.data[at] != 0x07)  # the attachment
    assert line.endswith(f"reading went on at byte {after:,}, the next record found intact")
    assert report.attachments == 1
    got = check_valid(report, fixed)
    assert got == d.messages[:before] + d.messages[d.chunks[3][2]:d.chunks[8][2]]


def test_a_damaged_stretch_with_nothing_intact_after_it_stops_reading() -> None:
    d = drive()
    start = d.chunks[3][0]
    report, fixed = run(d.data[:start] + bytes([0x55]) * 20 + d.data[start + 20:d.chunks[3][1]])
    assert report.stopped_at == start
    assert report.stopped == "no MCAP record starts here (opcode 0x55): the data is damaged"
    assert check_valid(report, fixed) == d.messages[:d.chunks[2][2]]


def test_an_attachment_that_fails_its_crc_is_skipped() -> None:
    d = drive()
    index = summary(d.data).attachment_indexes[0]
    report, fixed = run(damage(d.data, index.offset + index.length - 10))  # in its data
    assert report.attachments == 0
    assert report.skipped == [f"attachment 'vehicle.dbc' at byte {index.offset:,}: its CRC "
                              "does not match its content"]
    assert check_valid(report, fixed) == d.messages and report.stopped is None


# -- files ------------------------------------------------------------------------------------


def test_recover_file_writes_the_output(tmp_path: Path) -> None:
    d = drive()
    broken, fixed = tmp_path / "broken.mcap", tmp_path / "out" / "fixed.mcap"
    fixed.parent.mkdir()
    broken.write_bytes(d.data[:20_000])
    report = recover_file(broken, fixed)
    assert messages(fixed.read_bytes()) == d.messages[:report.messages]
    assert sorted(p.name for p in fixed.parent.iterdir()) == ["fixed.mcap"]  # no .partial left


def test_an_existing_output_is_refused_without_force(tmp_path: Path) -> None:
    broken, fixed = tmp_path / "broken.mcap", tmp_path / "fixed.mcap"
    broken.write_bytes(drive().data[:20_000])
    fixed.write_bytes(b"keep me")
    with pytest.raises(FileError, match="exists already; use --force to overwrite it"):
        recover_file(broken, fixed)
    assert fixed.read_bytes() == b"keep me"
    assert recover_file(broken, fixed, force=True).messages > 0
    with pytest.raises(FileError, match="is the file to recover"):
        recover_file(broken, broken, force=True)


def test_a_missing_input_or_not_an_mcap_is_one_line(tmp_path: Path) -> None:
    fixed = tmp_path / "fixed.mcap"
    with pytest.raises(InputError) as missing:
        recover_file(tmp_path / "nope.mcap", fixed)
    assert str(missing.value) == f"{tmp_path / 'nope.mcap'}: no such file"

    log = tmp_path / "drive.asc"
    log.write_text("date Mon Jan 1 00:00:00.000 am 2024\nbase hex timestamps absolute\n")
    with pytest.raises(InputError) as wrong:
        recover_file(log, fixed)
    assert str(wrong.value) == (f"{log}: not an MCAP file (it starts with b'date Mon', not "
                                "b'\\x89MCAP0\\r\\n')")
    assert not fixed.exists() and list(tmp_path.iterdir()) == [log]


@pytest.mark.parametrize("cut", [0, 5, 8])
def test_a_file_cut_before_its_first_record(cut: int) -> None:
    if cut < 8:  # no MCAP magic: not an MCAP file (tests/faults/test_recover_damage.py)
        with pytest.raises(InputError, match={
                0: r"^drive\.mcap: not an MCAP file \(it is empty\)$",
                5: r"^drive\.mcap: not an MCAP file \(its 5 bytes are the start of the MCAP "
                   r"magic, nothing more\)$"}[cut]):
            run(drive().data[:cut])
        return
    report, fixed = run(drive().data[:cut])
    assert check_valid(report, fixed) == []
    assert report.stopped_at == 8
    assert report.stopped == "the file ends right after the MCAP magic"
    assert format_report(report, "a", "b").startswith("recovered no messages\n")
