"""Read ahead: a second process reads and merges the logs; the frames, what the sources noted
and the errors are the same as when this process reads them."""

from __future__ import annotations

import errno
import io
import multiprocessing
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
from conftest import ECOCAR_DBC, T0, WriteLog, summary_counts

from bridge.errors import HelperDied, InputError
from bridge.frame import Frame
from bridge.io import readahead
from bridge.io.can_logs import LogSource, SourceIssue, merge
from bridge.io.readahead import ReadAhead, can_fork
from bridge.pipeline.convert import convert, record_drive
from bridge.pipeline.drive import load_stages
from bridge.resources import data_dir


@pytest.fixture(autouse=True)
def always_ahead(monkeypatch: pytest.MonkeyPatch) -> None:
    """The small logs of these tests are read ahead too, even in a test process where earlier
    tests left threads behind (a server's, a Dask client's), where tankviz would read them in
    the process itself."""
    monkeypatch.setattr(readahead, "MIN_BYTES", 0)
    monkeypatch.setattr(readahead, "can_fork", lambda: True)


class PidSource:
    """``count`` frames whose data is the id of the process that read them; ``fail_after``: a
    ValueError instead of the frame of that number."""

    def __init__(self, count: int, fail_after: int | None = None) -> None:
        self.count, self.fail_after = count, fail_after
        self.issues: list[SourceIssue] = []
        self.frames = self.backwards = 0

    def progress(self) -> tuple[int, int]:
        return self.frames, self.count

    def __iter__(self) -> Iterator[Frame]:
        for i in range(self.count):
            if i == self.fail_after:
                raise ValueError(f"frame {i} is broken")
            self.frames += 1
            yield Frame(i, "can0", 0x10, os.getpid().to_bytes(4, "little"))


def frames(i: int, channel: int, step: float) -> list[can.Message]:
    return [can.Message(timestamp=T0 + k * step, arbitration_id=0x100 + channel, channel=channel,
                        data=bytes([k % 256] * 8), is_extended_id=False) for k in range(i)]


def test_the_frames_are_read_in_another_process() -> None:
    reading = ReadAhead([PidSource(10_000)])

    pids = {int.from_bytes(f.data, "little") for f in reading}

    assert reading.ahead
    assert pids and os.getpid() not in pids
    assert reading.sources[0].frames == 10_000
    assert reading.progress() == (10_000, 10_000)
    assert multiprocessing.active_children() == []


@pytest.mark.slow
def test_merged_logs_give_the_same_frames_and_the_same_notes_as_reading_here(
        write_log: WriteLog) -> None:
    blf = write_log("radar.blf", frames(9000, 0, 0.001))
    asc = write_log("camera.asc", frames(3000, 1, 0.003))
    lines = asc.read_text().splitlines(keepends=True)
    lines[100:100] = ["1.000000 this line is garbled\n"] * 2  # python-can cannot parse them
    asc.write_text("".join(lines))
    here = [LogSource(blf), LogSource(asc)]
    ahead = [LogSource(blf), LogSource(asc)]

    expected = list(merge(here))
    got = list(ReadAhead(ahead))

    assert got == expected and all(type(f) is Frame for f in got)
    assert [(s.frames, s.backwards, s.issues) for s in ahead] == \
        [(s.frames, s.backwards, s.issues) for s in here]
    assert len(ahead[1].issues) == 2


def test_strict_gives_the_frames_before_the_problem_then_the_same_error(
        write_log: WriteLog) -> None:
    messages = frames(6000, 0, 0.001)
    messages[5000].timestamp = T0  # back in time
    path = write_log("drive.log", messages)
    with pytest.raises(InputError) as here:
        list(LogSource(path, strict=True))

    got: list[Frame] = []
    with pytest.raises(InputError) as ahead:
        got.extend(ReadAhead([LogSource(path, strict=True)]))

    assert str(ahead.value) == str(here.value)
    assert "line 5001: time jumps backwards" in str(ahead.value)
    assert len(got) == 5000


def test_a_log_without_frames_is_the_same_one_line_error(tmp_path: Path) -> None:
    path = tmp_path / "empty.log"
    path.write_text("this is not candump\n")

    with pytest.raises(InputError, match=r"empty\.log: no CAN frames in this file \(line 1: "):
        list(ReadAhead([LogSource(path)]))


def test_a_failure_while_reading_is_raised_here_with_the_childs_traceback() -> None:
    reading = ReadAhead([PidSource(10_000, fail_after=7000)])
    got: list[Frame] = []

    with pytest.raises(RuntimeError, match=r"(?s)read-ahead process failed.*"
                       r"ValueError: frame 7000 is broken"):
        got.extend(reading)

    assert len(got) == 7000
    assert multiprocessing.active_children() == []


class Killed(PidSource):
    """A reading process that dies without a word (the kernel's OOM killer) after 5000 frames;
    read in this process, it only stops there."""

    def __init__(self, count: int) -> None:
        super().__init__(count)
        self.test_process = os.getpid()

    def __iter__(self) -> Iterator[Frame]:
        for frame in super().__iter__():
            if self.frames > 5000:
                if os.getpid() == self.test_process:
                    return
                os._exit(137)
            yield frame


def test_a_reading_process_that_dies_is_one_line_not_a_short_drive() -> None:
    with pytest.raises(HelperDied, match=r"^the process reading the inputs ahead ended without "
                       r"a word \(exit code 137; out of memory\?\); --no-read-ahead"):
        list(ReadAhead([Killed(10_000)]))


def test_stopping_early_ends_the_reading_process() -> None:
    stream = iter(ReadAhead([PidSource(10_000_000)]))
    first = [next(stream) for _ in range(100)]

    stream.close()  # type: ignore[attr-defined]

    assert [f.timestamp_ns for f in first] == list(range(100))
    assert multiprocessing.active_children() == []


def test_small_inputs_and_processes_with_threads_are_read_here(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(readahead, "can_fork", can_fork)  # the real one
    assert not ReadAhead([PidSource(100)], ahead=False).ahead
    monkeypatch.setattr(readahead, "MIN_BYTES", 101)
    assert not ReadAhead([PidSource(100)]).ahead
    monkeypatch.setattr(readahead, "MIN_BYTES", 0)
    busy = threading.Event()
    worker = threading.Thread(target=busy.wait)
    worker.start()
    try:
        reading = ReadAhead([PidSource(100)])
        pids = {int.from_bytes(f.data, "little") for f in reading}
    finally:
        busy.set()
        worker.join()
    assert not reading.ahead and pids == {os.getpid()}


@pytest.mark.slow
def test_convert_writes_the_same_drive_either_way(tmp_path: Path) -> None:
    sample = data_dir() / "ecocar_sample.blf"
    ahead = convert([sample], tmp_path / "ahead.mcap", [], profile="ecocar")
    here = convert([sample], tmp_path / "here.mcap", [], profile="ecocar", read_ahead=False)

    assert summary_counts(tmp_path / "ahead.mcap") == summary_counts(tmp_path / "here.mcap")
    assert (ahead.frames, ahead.statistics, ahead.issues) == \
        (here.frames, here.statistics, here.issues)
    assert messages(tmp_path / "ahead.mcap") == messages(tmp_path / "here.mcap")


def messages(path: Path) -> list[tuple[str, int, bytes]]:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [(c.topic, m.log_time, m.data)
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


class Stubborn(PidSource):
    """Frames from a reading process that does not die of SIGTERM (it has not yet set its
    handlers, or is busy in C code)."""

    def __iter__(self) -> Iterator[Frame]:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        return super().__iter__()


def test_a_reader_that_outlives_sigterm_is_still_ended_when_reading_stops() -> None:
    stream = iter(ReadAhead([Stubborn(10_000_000)]))
    [next(stream) for _ in range(100)]
    closing = threading.Thread(target=stream.close, daemon=True)  # type: ignore[attr-defined]

    closing.start()
    closing.join(timeout=30)

    leftover = multiprocessing.active_children()
    for child in leftover:
        child.kill()
    assert not closing.is_alive() and leftover == []


def gm_drive_with_a_clock_step_cut_short(dbc: Path, write_log: WriteLog) -> Path:
    """A car unlike ecocar (the public GM object DBC: polar radar tracks numbered by slot) whose
    clock steps 30 s back halfway, logged as a BLF that ends in the middle of an object."""
    db = cantools.database.load_file(dbc)
    messages = []
    for i in range(1500):
        t = T0 + i * 0.01 - (30.0 if i >= 750 else 0.0)
        for slot in (1, 2, 3):
            m = db.get_message_by_name(f"LRRObject{slot:02d}")
            values = {s.name: 0 for s in m.signals} | {
                "TrkRange": 20 + slot * 10 - i * 0.01, "TrkAzimuth": slot - 2,
                "TrkRangeRate": -1.5, "TrkObjectID": slot + 4}
            data = m.encode(values, strict=False)
            messages.append(can.Message(timestamp=t + slot * 1e-4, arbitration_id=m.frame_id,
                                        data=data, channel=0, is_extended_id=False))
    log = write_log("gm.blf", messages)
    log.write_bytes(log.read_bytes()[:-7])
    return log


@pytest.mark.slow
def test_a_car_unlike_ecocar_with_a_clock_step_and_a_cut_log_converts_the_same_ahead(
        shared_dbc: Path, write_log: WriteLog, tmp_path: Path) -> None:
    dbc = shared_dbc / "gm_global_a_object.dbc"
    log = gm_drive_with_a_clock_step_cut_short(dbc, write_log)
    profile = Path(__file__).resolve().parent / "profiles" / "gm_object.toml"

    ahead = convert([log], tmp_path / "ahead.mcap", [str(dbc)], profile=profile)
    here = convert([log], tmp_path / "here.mcap", [str(dbc)], profile=profile, read_ahead=False)

    assert [str(i) for i in ahead.issues] == [str(i) for i in here.issues]
    assert any("ends in the middle of an object" in str(i) for i in ahead.issues)
    assert ahead.statistics == here.statistics
    got = messages(tmp_path / "ahead.mcap")
    assert got == messages(tmp_path / "here.mcap")
    assert any(topic == "/log" and b"clock" in data for topic, _, data in got)
    assert any(topic == "/scene/tracks" for topic, _, _ in got)


class FullDisk(io.BytesIO):
    """An output whose disk fills after 256 KiB."""

    def write(self, data: Any) -> int:
        if self.tell() + len(data) > 256 * 1024:
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data)


@pytest.mark.slow
def test_a_disk_that_fills_while_reading_ahead_stops_the_reader_too(write_log: WriteLog) -> None:
    log = write_log("long.blf", frames(60_000, 0, 0.001))
    decoder, _ = load_stages([str(ECOCAR_DBC)], None)

    with pytest.raises(OSError, match="No space left on device"):
        record_drive([LogSource(log)], decoder, FullDisk())

    assert multiprocessing.active_children() == []
