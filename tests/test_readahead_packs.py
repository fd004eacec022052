"""Read ahead in packs: the child hands over frame packs; ``packs()`` gives them, read ahead or
here, with the same frames, notes and errors as reading the sources here."""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from conftest import T0, WriteLog

from bridge.errors import InputError
from bridge.frame import Frame
from bridge.io import readahead
from bridge.io.can_logs import LogSource, SourceIssue, merge
from bridge.io.readahead import BATCH, ReadAhead
from bridge.packed import MAX_BUSES, PackedFrames


@pytest.fixture(autouse=True)
def always_ahead(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(readahead, "MIN_BYTES", 0)
    monkeypatch.setattr(readahead, "can_fork", lambda: True)


def messages(count: int, channel: int, step: float) -> list[can.Message]:
    out = []
    for k in range(count):
        fd = k % 7 == 0
        out.append(can.Message(timestamp=T0 + k * step, arbitration_id=0x100 + channel + k % 5,
                               channel=channel, data=bytes([k % 256] * (12 if fd else 8)),
                               is_extended_id=k % 3 == 0, is_fd=fd, bitrate_switch=fd))
    out.append(can.Message(timestamp=T0 + count * step, arbitration_id=0x10, channel=channel,
                           is_remote_frame=True, dlc=4))
    out.append(can.Message(timestamp=T0 + (count + 1) * step, channel=channel,
                           is_error_frame=True))
    return out


def logs(write_log: WriteLog) -> list[Path]:
    blf = write_log("radar.blf", messages(9000, 0, 0.001))
    asc = write_log("camera.asc", messages(3000, 1, 0.003))
    lines = asc.read_text().splitlines(keepends=True)
    lines[100:100] = ["1.000000 this line is garbled\n"]
    asc.write_text("".join(lines))
    return [blf, asc]


@pytest.mark.parametrize("ahead", [True, False], ids=["ahead", "here"])
def test_blocks_hold_the_merged_frames_and_the_sources_their_notes(
        write_log: WriteLog, ahead: bool) -> None:
    paths = logs(write_log)
    here = [LogSource(p) for p in paths]
    expected = list(merge(here))
    sources = [LogSource(p) for p in paths]
    reading = ReadAhead(sources, ahead=ahead)

    made = list(reading.packs())

    assert reading.ahead is ahead
    assert all(type(b) is PackedFrames and 0 < len(b) <= BATCH for b in made)
    assert [f for b in made for f in b] == expected
    assert any(f.is_fd for f in expected) and any(f.is_remote for f in expected)
    assert [(s.frames, s.backwards, s.issues) for s in sources] == \
        [(s.frames, s.backwards, s.issues) for s in here]
    assert reading.progress()[0] == reading.progress()[1]
    assert multiprocessing.active_children() == []


def test_frames_read_ahead_are_the_same_as_blocks_read_ahead(write_log: WriteLog) -> None:
    paths = logs(write_log)

    frames = list(ReadAhead([LogSource(p) for p in paths]))
    made = list(ReadAhead([LogSource(p) for p in paths]).packs())

    assert frames == [f for b in made for f in b]
    assert all(type(f) is Frame for f in frames)


class ManyBuses:
    """Frames on 300 buses, from whichever process reads them."""

    def __init__(self, count: int) -> None:
        self.count = count
        self.issues: list[SourceIssue] = []
        self.frames = self.backwards = 0

    def progress(self) -> tuple[int, int]:
        return self.frames, self.count

    def __iter__(self) -> Iterator[Frame]:
        for i in range(self.count):
            self.frames += 1
            yield Frame(i, f"bus{i % 300}", i % 2048, os.getpid().to_bytes(4, "little"))


class Counting(ManyBuses):
    """Frames of one bus; its progress is the frames read so far (two sources: a total per
    source)."""

    def __iter__(self) -> Iterator[Frame]:
        for i in range(self.count):
            self.frames += 1
            yield Frame(i, "can0", 0x10, b"")


def test_the_progress_is_what_the_child_has_read_when_it_sent_the_block() -> None:
    reading = ReadAhead([Counting(3 * BATCH), Counting(10 * BATCH)])
    packs = reading.packs()

    next(packs)
    first = reading.progress()
    next(packs)
    second = reading.progress()
    packs.close()  # type: ignore[attr-defined]

    # merged by time (each source one frame ahead of the merge): what was read when sent
    assert BATCH <= first[0] <= BATCH + 2 and first[1] == 13 * BATCH
    assert 2 * BATCH <= second[0] <= 2 * BATCH + 2


def test_more_buses_than_a_block_holds_are_handed_over_in_more_blocks() -> None:
    reading = ReadAhead([ManyBuses(10_000)])

    made = list(reading.packs())

    assert all(len(b.buses) <= MAX_BUSES for b in made)
    frames = [f for b in made for f in b]
    assert [f.timestamp_ns for f in frames] == list(range(10_000))
    assert {int.from_bytes(f.data, "little") for f in frames} != {os.getpid()}


def test_an_input_error_comes_after_the_blocks_before_it(write_log: WriteLog) -> None:
    log = messages(6000, 0, 0.001)
    log[5000].timestamp = T0
    path = write_log("drive.log", log)
    got: list[PackedFrames] = []

    with pytest.raises(InputError, match="line 5001: time jumps backwards"):
        got.extend(ReadAhead([LogSource(path, strict=True)]).packs())

    assert sum(len(b) for b in got) == 5000


def test_stopping_the_blocks_early_ends_the_reading_process() -> None:
    packs = ReadAhead([ManyBuses(10_000_000)]).packs()
    first = next(packs)

    packs.close()  # type: ignore[attr-defined]

    assert len(first) == BATCH or len(first) == MAX_BUSES
    assert multiprocessing.active_children() == []


@pytest.mark.slow
def test_the_benchmarks_run_and_report_every_row(tmp_path: Path) -> None:
    """tools/bench_readahead.py and bench_decode.py --pack run (tiny sizes: no timing is
    checked) and print every contender."""
    tools = Path(__file__).resolve().parents[1] / "tools"
    env = {**os.environ, "PYTHONPATH": str(tools.parent)}
    ahead = subprocess.run(
        [sys.executable, str(tools / "bench_readahead.py"), "--frames", "30000", "--runs", "1",
         "--input", "memory", "--input", "BLF", "--workdir", str(tmp_path)],
        capture_output=True, text=True, env=env, timeout=600, check=True).stdout
    decode = subprocess.run(
        [sys.executable, str(tools / "bench_decode.py"), "--frames", "5000", "--repeat", "1",
         "--pack", "1000", "--warm"],
        capture_output=True, text=True, env=env, timeout=600, check=True).stdout

    for row in ("old frames", "new frames", "new packs", "child old", "child new"):
        assert ahead.count(row) == 2, ahead
    assert "(d packs of 1000):" in decode and "ratio to (b)" in decode
    assert "MISMATCH" not in decode
