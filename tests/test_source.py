"""Reading CAN logs: every python-can format, merged in time order, damage reported not fatal."""

from __future__ import annotations

import gzip
import shutil
from collections.abc import Callable
from pathlib import Path

import can
import pytest
from can.io.trc import TRCFileVersion
from conftest import ECOCAR_DBC, T0, WriteLog

from bridge.errors import InputError
from bridge.frame import Frame, to_ns
from bridge.io.can_logs import LogSource, bus_name, merge, supported_suffixes
from bridge.pipeline.convert import convert
from bridge.sim.ecocar import simulate
from bridge.sinks.can_log_writer import write_log


def classic(i: int, channel: object = 0, t: float | None = None) -> can.Message:
    """Frame number ``i``: id 0x100 + i, at T0 + i·10 ms unless ``t`` says otherwise."""
    return can.Message(timestamp=T0 + i * 0.01 if t is None else t, arbitration_id=0x100 + i,
                       data=bytes([i] * 8), channel=channel, is_extended_id=False)


FD = can.Message(timestamp=T0 + 0.5, arbitration_id=0x1ABCDEF, data=bytes(range(64)), channel=1,
                 is_extended_id=True, is_fd=True, bitrate_switch=True)
ERROR = can.Message(timestamp=T0 + 0.6, is_error_frame=True, channel=0)
REMOTE = can.Message(timestamp=T0 + 0.7, arbitration_id=0x7, is_remote_frame=True, dlc=3,
                     channel=0, is_extended_id=False)


def read(path: Path, **kwargs: bool) -> tuple[list[Frame], LogSource]:
    source = LogSource(path, **kwargs)
    return list(source), source


# Which frame kinds each python-can writer keeps (TRC writes classic data frames only).
FULL = [".blf", ".asc", ".log"]
NO_CHANNEL = [".csv", ".db"]


@pytest.mark.parametrize("suffix", FULL + NO_CHANNEL + [".trc", ".log.gz", ".asc.gz", ".blf.gz"])
def test_every_format_reads_back_what_python_can_wrote(write_log: WriteLog, suffix: str) -> None:
    messages = [classic(i) for i in range(5)]
    if suffix != ".trc":
        messages += [FD, ERROR, REMOTE]
    plain = suffix.removesuffix(".gz")
    path = write_log(f"drive{plain}", messages)
    if suffix.endswith(".gz"):
        packed = path.with_name(path.name + ".gz")
        with path.open("rb") as src, gzip.open(packed, "wb") as dst:
            shutil.copyfileobj(src, dst)
        path = packed

    frames, source = read(path)

    assert source.issues == []
    assert len(frames) == len(messages)
    first = frames[0]
    assert first.timestamp_ns == 1_700_000_000_000_000_000
    assert (first.arbitration_id, first.data, first.dlc) == (0x100, bytes(8), 8)
    assert frames[4].timestamp_ns == 1_700_000_000_040_000_000
    if plain not in NO_CHANNEL:
        assert {f.bus for f in frames[:5]} == {"can0"} or plain == ".trc"
    if suffix != ".trc":
        fd, error, remote = frames[5:]
        assert (fd.arbitration_id, fd.is_extended, fd.data) == (0x1ABCDEF, True, bytes(range(64)))
        if plain not in NO_CHANNEL:
            assert fd.is_fd and fd.bitrate_switch
            assert fd.bus == "can1"
        assert error.is_error
        assert remote.is_remote and remote.arbitration_id == 0x7


def trc(version: TRCFileVersion) -> Callable[[Path, list[can.Message]], None]:
    """Writes a TRC of ``version`` with python-can's writer."""
    def write(path: Path, messages: list[can.Message]) -> None:
        writer = can.TRCWriter(path)
        writer.file_version = version
        with writer:
            for m in messages:
                writer.on_message_received(m)
    return write


def written(path: Path, messages: list[can.Message]) -> None:
    with can.Logger(path) as logger:
        for m in messages:
            logger.on_message_received(m)


#: Each format with numbered channels, as python-can writes it (it numbers them from 1 in the
#: file: channel 0 is written 1); TRC 1.0 has no bus column (every frame is on its one bus).
NUMBERED: dict[str, Callable[[Path, list[can.Message]], None]] = {
    "drive.asc": written, "drive.blf": written, "drive.trc": trc(TRCFileVersion.V2_1),
    "v1.trc": trc(TRCFileVersion.V1_0), "drive.log": written, "drive.asc.gz": written,
}


@pytest.mark.parametrize("name", NUMBERED)
def test_one_numbering_of_channels_for_every_format(tmp_path: Path, name: str) -> None:
    messages = [classic(i, channel=i % 3) for i in range(6)]
    path = tmp_path / name
    NUMBERED[name](path, messages)

    frames, source = read(path)

    assert source.issues == []
    buses = ["can0"] * 6 if name == "v1.trc" else ["can0", "can1", "can2"] * 2
    assert [f.bus for f in frames] == buses


@pytest.mark.parametrize(("line", "bus"), [
    ("      1         0.000 DT  1     0100 Rx -  1    00", "can0"),
    ("      1         0.000 DT  4     0100 Rx -  1    00", "can3"),
])
def test_a_trc_bus_1_is_can0_as_an_asc_channel_1_is(tmp_path: Path, line: str, bus: str) -> None:
    trc = tmp_path / "drive.trc"
    trc.write_text(";$FILEVERSION=2.1\n;$STARTTIME=45000.5\n;$COLUMNS=N,O,T,B,I,d,R,L,D\n"
                   f"{line}\n")
    asc = tmp_path / "drive.asc"
    asc.write_text("base hex  timestamps absolute\nBegin Triggerblock\n"
                   f" 0.000000 {int(bus[3:]) + 1}  100             Rx   d 1 00\nEnd TriggerBlock\n")
    assert [f.bus for f in read(trc)[0]] == [f.bus for f in read(asc)[0]] == [bus]


@pytest.mark.parametrize("suffix", [".asc", ".trc"])
def test_a_drive_logged_as_trc_decodes_with_the_bus_names_of_its_asc(tmp_path: Path,
                                                                    suffix: str) -> None:
    log = tmp_path / f"drive{suffix}"
    write_log((f for f in simulate(duration_s=0.5) if not f.is_fd), log, suffix)

    report = convert([log], tmp_path / "drive.mcap", [f"can0={ECOCAR_DBC}"])

    assert report.warnings == []  # no "--dbc can0=…: no input has bus can0"
    assert list(report.statistics["frames"]) == ["can0"]
    assert report.statistics["decoded"] and not report.statistics["unknown_ids"]


def test_candump_keeps_interface_names_as_bus_names(write_log: WriteLog) -> None:
    path = write_log("drive.log", [classic(0, "radar"), classic(1, "vcan1")])
    frames, _ = read(path)
    assert [f.bus for f in frames] == ["radar", "vcan1"]


def test_bus_names_for_numbered_and_missing_channels() -> None:
    assert bus_name(0) == "can0"
    assert bus_name(3) == "can3"
    assert bus_name("2") == "can2"
    assert bus_name(None) == "can0"
    assert bus_name("chassis") == "chassis"
    assert (bus_name(1, 1), bus_name("4", 1), bus_name("radar", 1)) == ("can0", "can3", "radar")


def test_time_is_integer_nanoseconds_rounded_to_the_microsecond() -> None:
    assert to_ns(1_700_000_000.123456) == 1_700_000_000_123_456_000
    assert to_ns(0.0000015) == 2000


def test_several_inputs_merge_in_time_order(write_log: WriteLog) -> None:
    a = write_log("a.blf", [classic(i, 0) for i in range(0, 10, 2)])
    b = write_log("b.log", [classic(i, "can1", T0 + i * 0.01 + 0.005) for i in range(0, 10, 2)])
    frames = list(merge([LogSource(a), LogSource(b)]))
    times = [f.timestamp_ns for f in frames]
    assert times == sorted(times)
    assert [f.bus for f in frames[:4]] == ["can0", "can1", "can0", "can1"]
    assert len(frames) == 10


def test_a_bad_candump_line_is_skipped_and_reported_with_its_line(write_log: WriteLog) -> None:
    path = write_log("drive.log", [classic(i) for i in range(5)])
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join([*lines[:2], "(garbage) what is this\n", *lines[2:]]))

    frames, source = read(path)

    assert len(frames) == 5
    (issue,) = source.issues
    assert str(issue).startswith(f"{path}:line 3: skipped a line python-can cannot parse "
                                 "(ValueError: ")


def test_a_bad_csv_line_resumes_after_the_header_without_losing_a_frame(
        write_log: WriteLog) -> None:
    path = write_log("drive.csv", [classic(i) for i in range(5)])
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join([*lines[:3], "1700000000.1,0x1\n", "nonsense\n", *lines[3:]]))

    frames, source = read(path)

    assert [f.arbitration_id for f in frames] == [0x100, 0x101, 0x102, 0x103, 0x104]
    assert [i.where for i in source.issues] == ["line 4", "line 5"]


def test_a_truncated_asc_line_is_reported(write_log: WriteLog) -> None:
    path = write_log("drive.asc", [classic(i) for i in range(5)])
    lines = path.read_text().splitlines(keepends=True)
    bad = next(i for i, line in enumerate(lines) if " 102 " in line)
    lines[bad] = lines[bad][: len(lines[bad]) // 2 + 3] + "\n"  # cut inside the data bytes
    path.write_text("".join(lines))

    frames, source = read(path)

    assert [f.arbitration_id for f in frames] == [0x100, 0x101, 0x103, 0x104]
    assert [i.where for i in source.issues] == [f"line {bad + 1}"]


def test_a_blf_cut_mid_object_keeps_what_is_complete_and_says_where(write_log: WriteLog) -> None:
    path = write_log("drive.blf", [classic(i % 200, t=T0 + i) for i in range(5000)])
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) * 3 // 4])

    frames, source = read(path)

    assert 0 < len(frames) < 5000
    assert [f.timestamp_ns for f in frames] == [to_ns(T0 + i) for i in range(len(frames))]
    assert any("ends in the middle of an object" in i.reason for i in source.issues)


def test_backwards_time_is_kept_counted_and_strict_makes_it_an_error(tmp_path: Path) -> None:
    path = tmp_path / "drive.log"  # python-can's writers never go backwards: write it by hand
    path.write_text("(1700000000.000000) can0 100#00\n"
                    "(1700000000.010000) can0 101#01\n"
                    "(1699999999.000000) can0 102#02\n"
                    "(1700000000.030000) can0 103#03\n")

    frames, source = read(path)
    assert len(frames) == 4
    assert source.backwards == 1
    assert source.issues[0].where == "line 3"
    assert "time jumps backwards by 1.010000 s" in source.issues[0].reason

    with pytest.raises(InputError, match=r"drive\.log:line 3: time jumps backwards .*--strict"):
        read(path, strict=True)


def test_a_long_text_log_names_the_line_of_each_issue_and_keeps_the_frames_in_order(
        tmp_path: Path) -> None:
    """Lines are read in batches: an issue deep in one still names its own line, and the frames
    around a damaged line keep their order."""
    lines = [f"({1700000000 + i / 100:.6f}) can0 {i % 0x700:03X}#{i % 256:02X}\n"
             for i in range(1000)]
    lines[399] = "(1699999999.000000) can0 123#45\n"  # line 400: a second back in time
    lines[600] = "(1700000006.000000) can0 1\0\0#00\n"  # line 601: zero bytes
    path = tmp_path / "drive.log"
    path.write_text("".join(lines))

    frames, source = read(path)

    assert [(i.where, i.group) for i in source.issues] == [
        ("line 400", "time jumps backwards"), ("line 601", "zero bytes in a line")]
    assert [f.timestamp_ns for f in frames] == [
        to_ns(float(line[1:18])) for n, line in enumerate(lines) if n != 600]


def test_strict_stops_at_the_first_bad_line(write_log: WriteLog) -> None:
    path = write_log("drive.log", [classic(i) for i in range(3)])
    path.write_text(path.read_text() + "nonsense\n")
    with pytest.raises(InputError, match=r"drive\.log:line 4: skipped a line"):
        read(path, strict=True)


def test_unknown_suffix_and_missing_file_are_one_line_errors(tmp_path: Path) -> None:
    odd = tmp_path / "drive.xyz"
    odd.write_text("")
    with pytest.raises(InputError, match=r"drive\.xyz: unknown log format '\.xyz'; python-can "
                       r"reads \.asc, \.blf"):
        LogSource(odd)
    with pytest.raises(InputError, match=r"missing\.blf: no such file"):
        LogSource(tmp_path / "missing.blf")


def test_a_file_that_is_not_a_blf_is_named(tmp_path: Path) -> None:
    fake = tmp_path / "fake.blf"
    fake.write_bytes(b"this is not a binary logging file at all")
    with pytest.raises(InputError, match=r"fake\.blf: not a readable \.blf log"):
        list(LogSource(fake))


def test_supported_suffixes_come_from_python_can() -> None:
    assert {".asc", ".blf", ".log", ".trc", ".csv", ".db", ".mf4", ".asc.gz"} <= set(
        supported_suffixes())
