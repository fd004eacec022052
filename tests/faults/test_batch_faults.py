"""What ``tankviz batch`` says about its drives (issue #23, item 12 and the tail of item 3).

- A damaged BLF in a batch was salvaged, but the batch said only ``wrote broken.mcap: 29,678
  frames``. Now the drive's line counts its input issues, and the summary names every drive
  with input issues, with their count, the first (the damaged container, its byte) and where all
  are listed.
- One log in two formats (``trip.blf`` + ``trip.asc``) was one drive that recorded every frame
  twice (with a warning): now that drive is refused in one line naming both files (#33 item
  12), and the other drives go on.
- A drive that takes far longer than its size allows is named in the progress line.
"""

from __future__ import annotations

import random
from pathlib import Path

import can
import pytest
from conftest import T0, WriteLog

from bridge.cli import main
from bridge.fleet.batch import (
    ConvertJob,
    JobResult,
    Running,
    Settings,
    convert_task,
    input_issue_lines,
    progress_line,
    slow_drives,
)
from bridge.pipeline.convert import convert

MB = 10**6


def frames(n: int) -> list[can.Message]:
    """``n`` classic frames, 1 ms apart, each carrying its number."""
    return [can.Message(timestamp=T0 + i * 0.001, arbitration_id=0x100 + i % 64,
                        data=i.to_bytes(4, "big") * 2, channel=0, is_extended_id=False)
            for i in range(n)]


def damage(path: Path) -> Path:
    """Overwrite 200 bytes in the middle of the file, as a bad sector or copy would."""
    blob = bytearray(path.read_bytes())
    middle = len(blob) // 2
    blob[middle:middle + 200] = random.Random(7).randbytes(200)
    path.write_bytes(blob)
    return path


@pytest.fixture
def broken(write_log: WriteLog) -> Path:
    return damage(write_log("broken.blf", frames(20_000)))


def job(tmp_path: Path, name: str, *inputs: Path) -> ConvertJob:
    return ConvertJob(name, tuple(map(str, inputs)), str(tmp_path / "out" / f"{name}.mcap"))


# --- damaged inputs -----------------------------------------------------------------------------

@pytest.mark.slow
def test_a_drive_converted_from_a_damaged_blf_says_how_much_was_skipped(
        broken: Path, tmp_path: Path) -> None:
    (tmp_path / "out").mkdir()
    result = convert_task(job(tmp_path, "broken", broken), convert, Settings((), None, None, False))
    assert result.error is None and result.frames > 0
    assert result.issues == 1
    assert result.first_issue.startswith(f"{broken}:byte ") and "damaged" in result.first_issue


def test_the_summary_names_every_drive_with_damaged_inputs(tmp_path: Path) -> None:
    good = JobResult(job(tmp_path, "good", tmp_path / "good.blf"), frames=100, seconds=1.0)
    bad = JobResult(job(tmp_path, "week/bad", tmp_path / "bad.blf"), frames=90, seconds=1.0,
                      issues=3, first_issue="bad.blf:byte 4096: the container is damaged")
    failed = JobResult(job(tmp_path, "gone", tmp_path / "gone.blf"), error="gone.blf: no such")
    assert input_issue_lines([good, failed]) == []
    assert input_issue_lines([good, bad, failed]) == [
        "input issues in 1 of 2 drives written (what a log could not give was skipped, the rest "
        "converted):",
        "  week/bad: 3 issues, the first bad.blf:byte 4096: the container is damaged; "
        f"tankviz inspect {tmp_path / 'out' / 'week' / 'bad.mcap'} lists them"]


@pytest.mark.slow
def test_a_batch_names_its_damaged_drive_and_refuses_one_log_in_two_formats(
        broken: Path, write_log: WriteLog, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    trip = [write_log("trip.blf", frames(3000)), write_log("trip.asc", frames(3000))]
    write_log("good.blf", frames(3000))
    out = tmp_path / "out"
    assert main(["batch", "convert", str(tmp_path), "--out", str(out), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    (wrote_broken,) = [line for line in lines if line.startswith(f"wrote {out / 'broken.mcap'}")]
    assert wrote_broken.endswith("; 1 input issue")
    (wrote_good,) = [line for line in lines if line.startswith(f"wrote {out / 'good.mcap'}")]
    assert "issue" not in wrote_good
    at = lines.index("input issues in 1 of 2 drives written (what a log could not give was "
                     "skipped, the rest converted):")
    assert lines[at + 1].startswith(f"  broken: 1 issue, the first {broken}:byte ")
    assert lines[at + 1].endswith(f"; tankviz inspect {out / 'broken.mcap'} lists them")
    # one log saved twice is not one drive holding every frame twice: it is refused, in one
    # line naming both files, and the other drives go on (issue #33, item 12)
    (failed_trip,) = [line for line in lines if line.startswith("failed")]
    assert failed_trip == (
        f"failed {out / 'trip.mcap'}: {trip[1]} and {trip[0]} are one log saved twice (their "
        "first 16 frames match in id, data and time): not converted, as the drive would hold "
        "every frame twice; convert one of them (tankviz convert FILE -o OUTPUT), or move the "
        "other out of the folder")
    assert not (out / "trip.mcap").exists()
    assert "3 drives: 2 written, 0 skipped, 1 failed" in captured.out
    assert captured.err.strip().splitlines()[-1] == "error: 1 of 3 drives failed"


def test_the_bus_files_of_one_drive_are_not_taken_for_one_log_twice(
        write_log: WriteLog, tmp_path: Path) -> None:
    """``trip_can0.blf`` and ``trip_can1.blf``: one drive, each frame once."""
    first = write_log("trip_can0.blf", frames(100))
    second = write_log("trip_can1.blf", [can.Message(
        timestamp=m.timestamp, arbitration_id=m.arbitration_id + 0x200, data=m.data, channel=1)
        for m in frames(100)])
    (tmp_path / "out").mkdir()
    result = convert_task(job(tmp_path, "trip", first, second), convert,
                          Settings((), None, None, False))
    assert result.error is None and result.frames == 200


# --- slow drives --------------------------------------------------------------------------------

def test_a_drive_far_slower_than_its_size_allows_is_named() -> None:
    # drives done so far: 100 MB in 100 s, 1 MB/s; a 12 MB drive should take about 12 s
    done = {"done_bytes": 100 * MB, "done_seconds": 100.0}
    assert slow_drives([Running("trip7", 240.0, 12 * MB)], **done) == ["trip7 (4 min, 12 MB)"]
    assert slow_drives([Running("trip7", 59.0, 12 * MB)], **done) == []  # under 5 x 12 s
    assert slow_drives([Running("tiny", 29.0, MB // 10)], **done) == []  # 290 x, under 30 s
    assert slow_drives([Running("tiny", 31.0, MB // 10)], **done) == ["tiny (31 s, 100 kB)"]
    # slowest first
    assert slow_drives([Running("a", 100.0, MB), Running("b", 200.0, MB)], **done) == [
        "b (3 min, 1 MB)", "a (100 s, 1 MB)"]


def test_nothing_is_slow_before_a_drive_is_done() -> None:
    assert slow_drives([Running("trip7", 3600.0, MB)], done_bytes=0, done_seconds=0.0) == []


def test_the_progress_line_ends_with_the_slow_drives() -> None:
    line = progress_line(done=5, failed=0, total=6, frames=1000, elapsed=100.0, fraction=1.0,
                         slow=["trip7 (4 min, 12 MB)"])
    assert line.endswith("5/6 drives  1,000 frames  10 frames/s  ETA 00:00; slow: trip7 "
                         "(4 min, 12 MB)")
    assert "slow" not in progress_line(done=5, failed=0, total=6, frames=1000, elapsed=100.0,
                                       fraction=1.0)
