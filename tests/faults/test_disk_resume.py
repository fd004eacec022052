"""A full disk: when recording resumes, a drive started with little room, what was not recorded.

The rules (:mod:`bridge.sinks.drives`): recording starts when the free space is at least
``--min-free`` (with a smaller reserve when there is little room), stops below it or when the
disk is full, and resumes when the free space is above ``--min-free`` + 9 MiB (the 8 MiB reserve
and a 1 MiB margin). What a pause did not record is in the metadata of the part after it
(``recording_gaps``) and ``tankviz inspect`` shows it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from test_disk import complete, frame, tmpfs

from bridge.apps.inspect import format_summary, summarize_file
from bridge.io.drives import ArchiveSource
from bridge.sinks.drives import PartsRecorder
from bridge.sinks.raw import cut

MB = 1_000_000
MIB = 1024 * 1024


def describe(recorder: Any, part: Any) -> None:
    recorder.add_metadata(dict(part))


def metadata(path: Path) -> dict[str, str]:
    with path.open("rb") as f:
        return next(m.metadata for m in make_reader(f).iter_metadata() if m.name == "tankviz")


class Disk:
    """Free space and time as a test sets them."""

    def __init__(self, free: int) -> None:
        self.free = free
        self.now = 0.0

    def recorder(self, folder: Path, **options: Any) -> PartsRecorder:
        return PartsRecorder(folder, describe, free_space=lambda _: self.free,
                             clock=lambda: self.now, **options)

    def tick(self, recorder: PartsRecorder) -> None:
        self.now += 1.0
        recorder.tick()


def send(recorder: PartsRecorder, first: int, count: int) -> int:
    for i in range(first, first + count):
        recorder.on_raw(cut([frame(i)]))
    return first + count


def test_recording_resumes_when_min_free_plus_9_mib_is_free_and_does_not_flap(
        tmp_path: Path) -> None:
    disk = Disk(500 * MB)
    recorder = disk.recorder(tmp_path, min_free=100 * MB)
    i = send(recorder, 0, 10)
    disk.free = 99 * MB
    disk.tick(recorder)
    assert recorder.disk_full is not None
    i = send(recorder, i, 10)
    disk.free = 100 * MB + 9 * MIB  # not above the rule's line
    disk.tick(recorder)
    disk.tick(recorder)
    assert recorder.disk_full is not None and len(recorder.files) == 1
    disk.free = 100 * MB + 9 * MIB + 200_000  # 11 MB freed since the stop: enough
    disk.tick(recorder)
    assert recorder.disk_full is None and len(recorder.files) == 2
    for _ in range(5):  # the room stays: no stop, no new part
        i = send(recorder, i, 10)
        disk.tick(recorder)
    assert recorder.disk_full is None and len(recorder.files) == 2
    recorder.finish()
    assert sum(complete(p)["/can/can0/frames"] for p in recorder.files) == i


def test_a_drive_started_with_less_than_the_reserve_free_records(tmp_path: Path) -> None:
    """6 MiB of disk, less than the 8 MiB reserve: ``--min-free 1`` allows recording."""
    with tmpfs(tmp_path / "disk", 6) as drives:
        recorder = PartsRecorder(drives, describe, min_free=1 * MB)
        assert recorder.disk_full is None, recorder.disk_full
        i = send(recorder, 0, 2000)
        recorder.finish()
        assert recorder.files and complete(recorder.files[0])["/can/can0/frames"] == i


def test_a_drive_started_below_min_free_does_not_record_and_says_why(tmp_path: Path) -> None:
    disk = Disk(50 * MB)
    recorder = disk.recorder(tmp_path, min_free=200 * MB)
    assert recorder.disk_full == f"50 MB free in {tmp_path}, below --min-free 200 MB"
    assert recorder.take_notices()[0].startswith(f"recorder.disk_full: {recorder.disk_full}")


def test_what_a_pause_did_not_record_is_in_the_next_parts_metadata_and_inspect(
        tmp_path: Path) -> None:
    disk = Disk(500 * MB)
    recorder = disk.recorder(tmp_path, min_free=100 * MB, backlog_limit=10)
    i = send(recorder, 0, 5)
    disk.free = 10 * MB
    disk.tick(recorder)
    i = send(recorder, i, 25)  # 10 kept, the 15 oldest not recorded
    recorder.on_messages([])
    disk.free = 500 * MB
    disk.tick(recorder)
    recorder.finish()
    first, second = recorder.files
    (open_gap,) = json.loads(metadata(first)["recording_gaps"])
    assert open_gap["to_ns"] is None and open_gap["frames_not_recorded"] is None
    (gap,) = json.loads(metadata(second)["recording_gaps"])
    assert gap["frames_kept"] == 10 and gap["frames_not_recorded"] == 15
    assert gap["to_ns"] > gap["from_ns"] and gap["reason"].startswith("10 MB free")
    assert complete(first)["/can/can0/frames"] + complete(second)["/can/can0/frames"] == i - 15

    before = format_summary(str(first), summarize_file(first))
    assert "0 frames" not in before
    assert ": recording stopped: 10 MB free in" in before
    assert "what it did not record is in the next part" in before
    after = format_summary(str(second), summarize_file(second))
    assert "15 frames not recorded (backlog full), 10 recorded at the start of this part" in after


def test_frames_kept_when_the_drive_ends_go_into_a_last_part_if_there_is_room(
        tmp_path: Path) -> None:
    disk = Disk(500 * MB)
    recorder = disk.recorder(tmp_path, min_free=200 * MB)
    i = send(recorder, 0, 5)
    disk.free = 150 * MB
    disk.tick(recorder)
    i = send(recorder, i, 7)
    disk.free = 202 * MB  # too little to resume, room for the last frames
    disk.tick(recorder)
    assert recorder.disk_full is not None
    recorder.finish()
    assert [complete(p)["/can/can0/frames"] for p in recorder.files] == [5, 7]
    (gap,) = json.loads(metadata(recorder.files[1])["recording_gaps"])
    assert gap["frames_kept"] == 7 and gap["frames_not_recorded"] == 0


def test_frames_the_drive_ends_without_room_for_are_told(tmp_path: Path) -> None:
    disk = Disk(500 * MB)
    recorder = disk.recorder(tmp_path, min_free=200 * MB)
    send(recorder, 0, 5)
    disk.free = 150 * MB
    disk.tick(recorder)
    send(recorder, 5, 7)
    recorder.take_notices()
    recorder.finish()
    assert recorder.take_notices() == [
        "recorder.disk_full: 7 frames received while the disk was full are not recorded (no "
        "room for them when the drive ended)"]


def test_the_backlog_keeps_whole_blocks_and_counts_frames(tmp_path: Path) -> None:
    """Blocks of several frames while the disk is full: the newest blocks that fit in
    ``backlog_limit`` frames are kept, the older ones dropped whole, and both counted in
    frames."""
    disk = Disk(500 * MB)
    recorder = disk.recorder(tmp_path, min_free=100 * MB, backlog_limit=10)
    send(recorder, 0, 3)
    disk.free = 10 * MB
    disk.tick(recorder)
    for first in range(3, 23, 4):  # five blocks of 4 frames (1 ms apart: one block each)
        recorder.on_raw(cut([frame(i) for i in range(first, first + 4)]))
    disk.free = 500 * MB
    disk.tick(recorder)
    recorder.finish()
    _, second = recorder.files
    (gap,) = json.loads(metadata(second)["recording_gaps"])
    assert (gap["frames_kept"], gap["frames_not_recorded"]) == (8, 12)
    assert [f.timestamp_ns for f in ArchiveSource(second)] == [
        frame(i).timestamp_ns for i in range(15, 23)]
