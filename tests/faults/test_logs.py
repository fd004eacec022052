"""Damaged, cut and odd CAN logs: every one is read to its end, what could not be read is reported
with its place (byte offset or line), and nothing is lost without a word (issue #13, items 6, 7, 8
and 14, and the candump timestamps of item 2)."""

from __future__ import annotations

import random
import sqlite3
import struct
import subprocess
import sys
import threading
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest
from conftest import T0, WriteLog, timeout_scale
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.errors import BridgeError, InputError
from bridge.frame import Frame
from bridge.io.can_logs import LogSource
from bridge.pipeline.convert import convert

#: What reading one small damaged log may take at most: a hang fails, not freezes, the suite.
LIMIT_S = 20.0


def read(path: Path, **kwargs: bool) -> tuple[list[Frame], LogSource]:
    source = LogSource(path, **kwargs)
    return list(source), source


def within_limit(run: Callable[[], object], limit_s: float = LIMIT_S) -> object:
    """``run()`` in a thread; a run still going after ``limit_s`` fails the test (a hang)."""
    outcome: list[tuple[object, BaseException | None]] = []

    def target() -> None:
        try:
            outcome.append((run(), None))
        except BaseException as exc:
            outcome.append((None, exc))

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(limit_s * timeout_scale())
    assert not thread.is_alive(), f"still running after {limit_s} s: a hang"
    ((result, error),) = outcome
    if error is not None:
        raise error
    return result


def drive(n: int, channel: object = 0) -> list[can.Message]:
    """``n`` classic frames, 1 ms apart, ids 0x100 to 0x13F, each carrying its number."""
    return [can.Message(timestamp=T0 + i * 0.001, arbitration_id=0x100 + i % 64,
                        data=i.to_bytes(4, "big") * 2, channel=channel, is_extended_id=False)
            for i in range(n)]


def number(frame: Frame) -> int:
    """The number a frame of :func:`drive` carries."""
    return int.from_bytes(frame.data[:4], "big")


# BLF as python-can writes it: a 144-byte file header, then "log containers" (LOBJ objects of
# type 10), each holding zlib-compressed CAN message objects.
OBJ = struct.Struct("<4sHHLL")
CONTAINER = struct.Struct("<H6xL4x")


def containers(blob: bytes) -> Iterator[tuple[int, int, bytes]]:
    """(offset, size, uncompressed data) of each container of an intact BLF."""
    pos = 144
    while pos + OBJ.size <= len(blob):
        _, _, _, size, kind = OBJ.unpack_from(blob, pos)
        body = blob[pos + OBJ.size + CONTAINER.size: pos + size]
        yield pos, size, zlib.decompress(body) if kind == 10 else b""
        pos += size + size % 4


def rewrite_container(blob: bytes, index: int, change: Callable[[bytearray], None]) -> bytes:
    """The BLF with the data of container ``index`` changed (and compressed again)."""
    offset, size, data = list(containers(blob))[index]
    inner = bytearray(data)
    change(inner)
    body = CONTAINER.pack(2, len(inner)) + zlib.compress(bytes(inner))
    new_size = OBJ.size + len(body)
    obj = OBJ.pack(b"LOBJ", OBJ.size, 1, new_size, 10) + body + b"\0" * (new_size % 4)
    return blob[:offset] + obj + blob[offset + size + size % 4:]


@pytest.fixture
def blf(write_log: WriteLog) -> Path:
    """A BLF of 20,000 frames in 8 containers."""
    return write_log("drive.blf", drive(20_000))


def test_a_blf_with_200_bytes_overwritten_keeps_the_frames_after_the_damage(blf: Path) -> None:
    whole = blf.read_bytes()
    middle = len(whole) // 2
    damaged = bytearray(whole)
    damaged[middle:middle + 200] = random.Random(7).randbytes(200)
    blf.write_bytes(damaged)
    hit = [o for o, size, _ in containers(whole) if o <= middle < o + size]

    frames, source = read(blf)

    numbers = [number(f) for f in frames]
    assert numbers == sorted(numbers)
    assert numbers[0] == 0 and numbers[-1] == 19_999  # before and after the damage
    assert len(frames) > 20_000 - 2 * 4000  # at most the damaged container (~2,700 frames) lost
    assert [i.where for i in source.issues] == [f"byte {hit[0]}"]
    assert "damaged" in source.issues[0].reason and "frames in it are lost" in \
        source.issues[0].reason


def test_strict_stops_at_the_first_damage_of_a_blf_with_its_byte(blf: Path) -> None:
    whole = blf.read_bytes()
    offset, _, _ = list(containers(whole))[3]
    blf.write_bytes(whole[:offset] + b"JUNK" + whole[offset + 4:])
    with pytest.raises(InputError, match=rf"drive\.blf:byte {offset}: damaged data: .*--strict"):
        read(blf, strict=True)


@pytest.mark.slow
def test_an_object_of_size_zero_inside_a_container_does_not_hang_the_reader(blf: Path) -> None:
    def zero_size(inner: bytearray) -> None:
        first = inner.find(b"LOBJ")  # a container may begin with the end of an object
        inner[first + 8:first + 12] = (0).to_bytes(4, "little")  # the object's size

    blf.write_bytes(rewrite_container(blf.read_bytes(), 2, zero_size))

    frames, source = within_limit(lambda: read(blf))  # type: ignore[misc]

    assert 0 < len(frames) < 20_000
    assert number(frames[-1]) == 19_999
    (issue,) = source.issues
    assert issue.where.startswith("byte ")
    assert "damaged object" in issue.reason


@pytest.mark.slow
def test_a_damaged_object_inside_a_container_loses_only_that_object(blf: Path) -> None:
    lost: list[int] = []

    def break_tenth(inner: bytearray) -> None:
        tenth = inner.find(b"LOBJ") + 9 * 48  # python-can writes a classic frame in 48 bytes
        assert inner[tenth:tenth + 4] == b"LOBJ"
        inner[tenth:tenth + 4] = b"XXXX"
        lost.append(int.from_bytes(inner[tenth + 40:tenth + 44], "big"))  # its data: its number

    blf.write_bytes(rewrite_container(blf.read_bytes(), 3, break_tenth))

    frames, source = read(blf)

    assert [number(f) for f in frames] == [i for i in range(20_000) if i not in lost]
    (issue,) = source.issues
    assert "damaged object" in issue.reason


@pytest.mark.slow
@pytest.mark.parametrize("part", [0.1, 0.5, 0.99])
def test_a_blf_cut_inside_a_log_container_keeps_its_frames_before_the_cut(
        blf: Path, part: float) -> None:
    whole = blf.read_bytes()
    spans = list(containers(whole))
    offset, size, _ = spans[4]
    end = offset + 32 + int(part * (size - 32))  # in the container's compressed data
    blf.write_bytes(whole[:end])
    # the frames of the containers before, and the bytes of this one zlib gives up to the cut
    before = sum(len(data) for _, _, data in spans[:4])
    given = zlib.decompressobj().decompress(whole[offset + 32:end])

    frames, source = read(blf)

    assert [number(f) for f in frames] == list(range((before + len(given)) // 48))
    (issue,) = source.issues
    assert (issue.where, issue.kind, issue.group) == (f"byte {offset}", "stop", "file cut short")
    assert issue.reason.startswith("the file ends in the middle of an object (a log container")


@pytest.mark.slow
@pytest.mark.parametrize("flags", [1, 2])
def test_a_blf_frame_with_an_impossible_time_is_reported_and_the_rest_converts(
        blf: Path, tmp_path: Path, flags: int) -> None:
    def far_future(inner: bytearray) -> None:
        # an object's header: flags (10 µs or 1 ns), client, version, timestamp
        first = inner.find(b"LOBJ")
        inner[first + 16:first + 32] = struct.pack("<LHHQ", flags, 0, 0, 2**64 - 1)

    blf.write_bytes(rewrite_container(blf.read_bytes(), 1, far_future))

    report = within_limit(lambda: convert([blf], tmp_path / "out.mcap", []))

    # 2^64 ns or 10 µs after the start is after 2262, more than a drive can hold: that one frame
    # is skipped and said to be
    assert report.frames == 19_999  # type: ignore[attr-defined]
    (issue,) = report.issues  # type: ignore[attr-defined]
    assert issue.where.startswith("frame ")
    assert "cannot be recorded" in issue.reason


@pytest.mark.slow
@settings(max_examples=25, deadline=None)
@given(offset=st.floats(0.0, 1.0), length=st.integers(1, 400), seed=st.integers(0, 2**32))
def test_any_damage_to_a_blf_is_read_past(tmp_path_factory: pytest.TempPathFactory,
                                         offset: float, length: int, seed: int) -> None:
    base = tmp_path_factory.mktemp("blf")
    path = base / "drive.blf"
    with can.Logger(path) as logger:
        for m in drive(6000):
            logger.on_message_received(m)
    whole = path.read_bytes()
    at = 144 + int(offset * (len(whole) - 144 - 1))
    damaged = bytearray(whole)
    damaged[at:at + length] = random.Random(seed).randbytes(length)[: len(whole) - at]
    path.write_bytes(damaged)
    spans = [(o, o + size) for o, size, _ in containers(whole)]
    untouched_last = spans[-1][0] >= at + length

    frames, source = within_limit(lambda: read(path))  # type: ignore[misc]

    assert source.issues or len(frames) == 6000  # damage is reported, or harmless
    assert all(0 <= f.timestamp_ns < 2**63 for f in frames)
    if untouched_last:  # frames after the damage are kept
        assert 5999 in {number(f) for f in frames if f.arbitration_id == 0x100 + 5999 % 64}
    assert all(i.where.startswith(("byte ", "frame ")) for i in source.issues)


# --- text logs: every line gives a frame or a word ---


def test_asc_lines_python_can_skips_are_reported_with_their_line(write_log: WriteLog) -> None:
    path = write_log("drive.asc", drive(5))
    lines = path.read_text().splitlines(keepends=True)
    first = next(i for i, line in enumerate(lines) if " 100 " in line)
    lines[first + 1:first + 1] = [
        " 5 1  101             Rx   d 8 00 00 00 00 00 00 00 00\n",  # a time without a dot
        " 0.006000 CAN 1 Status:chip status error active\n",
        "what is this\n",
    ]
    path.write_text("".join(lines))

    frames, source = read(path)

    assert len(frames) == 5
    assert [i.where for i in source.issues] == [f"line {first + n}" for n in (2, 3, 4)]
    assert all("no frame" in i.reason for i in source.issues)
    assert "'what is this'" in source.issues[2].reason
    with pytest.raises(InputError, match=rf"drive\.asc:line {first + 2}: .*no frame"):
        read(path, strict=True)


def test_an_asc_frame_read_as_header_is_reported(tmp_path: Path) -> None:
    path = tmp_path / "drive.asc"  # no "internal events logged": python-can eats the next line
    path.write_text("date Mon Nov 23 15:42:09.871 2026\n"
                    "base hex  timestamps absolute\n"
                    " 0.000000 1  100             Rx   d 1 00\n"
                    " 0.010000 1  101             Rx   d 1 01\n")

    frames, source = read(path)

    assert [f.arbitration_id for f in frames] == [0x101]
    assert [i.where for i in source.issues] == ["line 3"]


def test_a_normal_asc_header_and_trailer_are_not_reported(write_log: WriteLog) -> None:
    path = write_log("drive.asc", drive(5))
    path.write_text(path.read_text() + "\n// a comment\n")
    frames, source = read(path)
    assert len(frames) == 5 and source.issues == []


def test_a_candump_cut_in_its_last_line_reports_the_truncation(write_log: WriteLog) -> None:
    path = write_log("drive.log", drive(5))
    text = path.read_text()
    path.write_text(text[: text.rindex("#") + 2])  # "(…) can0 104#0": cut inside the data

    frames, source = read(path)

    assert [number(f) for f in frames] == [0, 1, 2, 3]
    (issue,) = source.issues
    assert issue.where == "line 5"
    assert "ends in the middle of this line" in issue.reason


def test_a_last_line_without_newline_that_is_complete_is_still_a_truncation(
        write_log: WriteLog) -> None:
    path = write_log("drive.log", drive(5))
    path.write_text(path.read_text().rstrip("\n"))
    frames, source = read(path)
    assert len(frames) == 4
    assert [i.where for i in source.issues] == ["line 5"]


@pytest.mark.parametrize("stamp", ["-5.000000", "1e30", "inf", "nan", "99999999999999999999"])
def test_a_candump_timestamp_out_of_range_is_reported_and_the_conversion_goes_on(
        tmp_path: Path, stamp: str) -> None:
    path = tmp_path / "drive.log"
    path.write_text("(1700000000.000000) can0 100#00\n"
                    f"({stamp}) can0 101#01\n"
                    "(1700000000.020000) can0 102#02\n")

    report = convert([path], tmp_path / "out.mcap", [])

    assert report.frames == 2
    (issue,) = report.issues
    assert str(issue).startswith(f"{path}:line 2: ")
    assert "time" in issue.reason


@pytest.mark.parametrize("content", ["", "\n\n", "nothing here\nat all\n"])
@pytest.mark.parametrize("suffix", [".log", ".asc", ".csv", ".trc", ".blf"])
def test_an_input_without_frames_is_an_error(tmp_path: Path, suffix: str, content: str) -> None:
    path = tmp_path / f"drive{suffix}"
    path.write_text(content)
    # an empty BLF said "unpack requires a buffer of 72 bytes" (#33 item 12); text is no BLF
    with pytest.raises(BridgeError, match=rf"drive\{suffix}: .*no CAN frames"
                       if suffix != ".blf" or not content
                       else r"drive\.blf: not a readable \.blf log"):
        read(path)


@pytest.mark.slow
def test_an_empty_input_fails_the_conversion_with_one_line(tmp_path: Path) -> None:
    (tmp_path / "drive.log").write_text("")
    result = subprocess.run([sys.executable, "-m", "bridge", "convert", "drive.log", "-o",
                             "out.mcap", "-q"], capture_output=True, text=True, cwd=tmp_path,
                            timeout=120)
    assert result.returncode == 1
    assert result.stderr.splitlines()[-1].startswith("error: drive.log: no CAN frames")
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["logs", "logs.blf"])
def test_a_folder_given_as_a_log_is_one_line(tmp_path: Path, name: str) -> None:
    (tmp_path / name).mkdir()
    result = subprocess.run([sys.executable, "-m", "bridge", "convert", name, "-o", "out.mcap",
                             "-q"], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.splitlines()[-1] == (
        f"error: {name}: is a folder, not a log file: name the log files in it "
        f"({name}/*.blf …)")


# --- SQLite: rows python-can reads wrongly, and a damaged page (issue #23, item 7) ---


def test_a_sqlite_row_without_a_readable_timestamp_is_named_by_its_row(
        write_log: WriteLog) -> None:
    path = write_log("drive.db", drive(10))
    with sqlite3.connect(path) as db:
        db.execute("UPDATE messages SET ts = NULL WHERE rowid = 5")
        db.execute("UPDATE messages SET ts = 'noon' WHERE rowid = 7")
    db.close()

    frames, source = read(path)

    assert [number(f) for f in frames] == [0, 1, 2, 3, 5, 7, 8, 9]
    assert [(i.where, i.reason, i.kind) for i in source.issues] == [
        ("row 5", "skipped a frame with no readable timestamp (None)", "skip"),
        ("row 7", "skipped a frame with no readable timestamp ('noon')", "skip")]
    assert source.issues[0].group == source.issues[1].group  # one family, counted together


def test_a_damaged_sqlite_page_stops_the_reading_at_its_row_as_a_stop(
        write_log: WriteLog) -> None:
    path = write_log("drive.db", drive(3000))
    whole = bytearray(path.read_bytes())
    middle = len(whole) // 2
    whole[middle:middle + 4096] = bytes(range(256)) * 16  # one page of 4 KiB, or two halves
    path.write_bytes(whole)

    frames, source = read(path)

    assert [number(f) for f in frames] == list(range(len(frames)))  # the rows before it
    assert 0 < len(frames) < 3000
    stop = source.issues[-1]
    assert stop.kind == "stop" and stop.where == f"row {len(frames) + 1}"
    assert stop.reason.startswith(f"stopped at row {len(frames) + 1}, which python-can cannot "
                                  "read (DatabaseError: ")
    assert stop.reason.endswith("the rest of the file is not read")
    assert all(i.kind != "stop" for i in source.issues[:-1])


# --- what each issue did to the reading: a summary tells a stop from a skip ---


@pytest.mark.slow
def test_each_issue_says_whether_the_reading_stopped_skipped_damage_or_lost_nothing(
        write_log: WriteLog, blf: Path) -> None:
    log = write_log("drive.log", drive(5))
    lines = log.read_text().splitlines(keepends=True)
    lines[1:2] = ["not a frame\n", "(1699999999.000000) can0 101#01\n"]
    log.write_text("".join(lines)[:-5])  # cut in its last line
    whole = blf.read_bytes()
    offset, _, _ = list(containers(whole))[2]
    blf.write_bytes(whole[:offset + 40] + bytes(64) + whole[offset + 104:])

    kinds = {(i.where, i.kind, i.group) for i in read(log)[1].issues + read(blf)[1].issues}

    assert kinds == {("line 2", "skip", "line python-can cannot parse"),
                     ("line 3", "note", "time jumps backwards"),
                     ("line 6", "stop", "file cut short"),
                     (f"byte {offset}", "damage", "damaged log container")}


def test_trc_lines_python_can_skips_are_reported_in_the_order_of_the_lines(
        tmp_path: Path) -> None:
    path = tmp_path / "drive.trc"
    path.write_text(";$FILEVERSION=1.1\n"
                    ";$STARTTIME=45000.5\n"
                    ";   Message Number\n"
                    "      1)      1.0  Rx         0100  8  00 01 02 03 04 05 06 07\n"
                    "      2)      2.0  Rx         0101  8  00 01\n"  # 2 bytes of 8
                    "      3)      3.0  Warng      FFFFFFFF  4  00 00 00 08 BUSHEAVY\n"
                    "      4)      4.0  Rx         0102  8  00 01 02 03 04 05 06 07\n")

    frames, source = read(path)

    assert [f.arbitration_id for f in frames] == [0x100, 0x102]
    assert [(i.where, i.group) for i in source.issues] == [
        ("line 5", "python-can warning"), ("line 6", "line without a frame")]
    assert "Warng" in source.issues[1].reason


def test_candump_error_frames_of_every_class_are_error_frames(tmp_path: Path) -> None:
    """candump marks an error frame by the CAN_ERR_FLAG bit (0x20000000) of its id, with its
    class in the low bits. python-can's reader makes an error frame only of a bus error
    (0x80); the other classes (controller 0x04, protocol 0x08, transceiver 0x10, no ack 0x20,
    bus off 0x40, restarted 0x100, ...) came out as extended data frames with ids 0x4, 0x8, ...
    Every class is an error frame, and an extended data frame stays data."""
    path = tmp_path / "errors.log"
    classes = (0x4, 0x8, 0x10, 0x20, 0x40, 0x80, 0x100)
    lines = [f"(1700000000.{i:06d}) can0 {0x20000000 | c:08X}#0000000000000000"
             for i, c in enumerate(classes)]
    lines += ["(1700000001.000000) can0 123#0102", "(1700000001.000100) can0 18FEF100#0304"]
    path.write_text("\n".join(lines) + "\n")
    frames = list(LogSource(path))
    assert [f.is_error for f in frames] == [True] * len(classes) + [False, False]
    assert [(f.arbitration_id, f.is_extended, f.data) for f in frames[-2:]] == [
        (0x123, False, b"\x01\x02"), (0x18FEF100, True, b"\x03\x04")]
