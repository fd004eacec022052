"""A full disk, or a drives folder that cannot be written.

The folder is checked at start (one line, exit 1). When the disk fills, the part being written is
finished cleanly (its summary fits in the reserve kept), ``recorder.disk_full`` is raised on /log
and /health, viewers are still served, the frames that come meanwhile are kept, and recording
resumes in a new part when there is room. A full disk is a real one: a small tmpfs (these tests
run as root, as CI does; they are skipped where mounting is not allowed).
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from harness import Viewer, assert_survived, start, steady
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.frame import Frame
from bridge.pb import health_pb2
from bridge.sinks.drives import RESERVE_NAME, PartsRecorder
from bridge.sinks.raw import cut

MB = 1_000_000


@contextlib.contextmanager
def tmpfs(path: Path, size_mb: int, *options: str) -> Iterator[Path]:
    """A file system of ``size_mb`` at ``path`` (skips the test where it cannot be mounted)."""
    path.mkdir(parents=True, exist_ok=True)
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", ",".join([f"size={size_mb}m", *options]), "tmpfs",
         str(path)], capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs to fill (needs root): {mounted.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def fill(folder: Path) -> Path:
    """Take every free byte of ``folder``'s file system; returns the filler to delete."""
    filler = folder / "filler"
    with filler.open("wb", buffering=0) as f:
        block = b"\xff" * 65536
        with contextlib.suppress(OSError):
            while True:
                f.write(block)
        with contextlib.suppress(OSError):
            while True:
                f.write(b"\xff")
    return filler


def frame(i: int) -> Frame:
    return Frame(1_000_000_000 + i * 1_000_000, "can0", 0x100 + i % 7, i.to_bytes(8, "little"),
                 False, False, False, False, False, False, 8)


def complete(path: Path) -> dict[str, int]:
    """Messages per topic of a part, from its summary (which a cut file does not have)."""
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None, f"{path} is not finished"
    return {summary.channels[i].topic: n
            for i, n in summary.statistics.channel_message_counts.items()}


@pytest.mark.slow
def test_a_drives_folder_that_cannot_be_written_is_an_error_at_start(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "ro", 1, "ro") as drives:
        result = subprocess.run(
            [sys.executable, "-m", "bridge", "live", "--bus", "can0=virtual:nothing-comes",
             "--dbc", "ecocar", "--drives", str(drives), "--no-server", "--for", "10"],
            capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert result.returncode == 1, result.stdout + result.stderr
    assert result.stderr.strip() == f"error: {drives}: cannot record: Read-only file system"


def test_a_full_disk_finishes_the_part_and_recording_resumes_when_there_is_room(
        tmp_path: Path) -> None:
    now = [0.0]
    with tmpfs(tmp_path / "disk", 16) as drives:
        recorder = PartsRecorder(drives, lambda r, part: r.add_metadata(dict(part)),
                                 reserve=2 * MB, clock=lambda: now[0])
        assert (drives / RESERVE_NAME).stat().st_size == 2 * MB
        for i in range(1000):
            recorder.on_raw(cut([frame(i)]))
        filler = fill(drives)
        i = 1000
        while recorder.disk_full is None:  # the chunks written find the disk full
            for _ in range(500):
                recorder.on_raw(cut([frame(i)]))
                i += 1
            now[0] += 1.2
            recorder.tick()
            assert i < 10_000_000
        (first,) = recorder.files
        notices = recorder.take_notices()
        assert notices and notices[0].startswith("recorder.disk_full: disk full"), notices
        recorded = complete(first)["/can/can0/frames"]
        for _ in range(300):  # while the disk is full: kept
            recorder.on_raw(cut([frame(i)]))
            i += 1
        now[0] += 1.2
        recorder.tick()
        assert recorder.disk_full is not None and len(recorder.files) == 1  # no room yet
        filler.unlink()
        now[0] += 1.2
        recorder.tick()
        assert recorder.disk_full is None
        assert recorder.take_notices()[0].startswith("recorder.disk_full cleared: recording "
                                                     "resumed in ")
        recorder.finish()
        second = recorder.files[1]
        assert second.name.endswith("_part002.mcap")
        assert recorded + complete(second)["/can/can0/frames"] == i  # every frame
        with second.open("rb") as f:
            meta = next(m.metadata for m in make_reader(f).iter_metadata())
        (gap,) = json.loads(meta["recording_gaps"])
        assert gap["reason"].startswith("disk full") and gap["to_ns"] > gap["from_ns"]
        with first.open("rb") as f:
            logs = [m.message for _, c, _, m in make_reader(
                f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
                if c.topic == "/log"]
        assert any(text.startswith("recorder.disk_full: ") for text in logs), logs
        assert not (drives / RESERVE_NAME).exists()


def test_below_min_free_recording_stops_before_the_disk_is_full(tmp_path: Path) -> None:
    free = [500 * MB]
    now = [0.0]
    recorder = PartsRecorder(tmp_path, lambda r, part: None, min_free=200 * MB, reserve=MB,
                             free_space=lambda folder: free[0], clock=lambda: now[0])
    recorder.on_raw(cut([frame(0)]))
    free[0] = 150 * MB
    recorder.on_raw(cut([frame(1)]))
    recorder.tick()  # not checked at every frame, nor at every tick
    assert recorder.disk_full is None
    now[0] += 1.0
    recorder.tick()
    assert recorder.disk_full == f"150 MB free in {tmp_path}, below --min-free 200 MB"
    assert complete(recorder.files[0])["/can/can0/frames"] == 2
    recorder.on_raw(cut([frame(2)]))
    free[0] = 201 * MB  # not enough to start again: min_free, the reserve and a 1 MiB margin
    now[0] += 1.0
    recorder.tick()
    assert recorder.disk_full is not None
    free[0] = 203 * MB
    now[0] += 1.0
    recorder.tick()
    assert recorder.disk_full is None
    recorder.finish()
    assert complete(recorder.files[1])["/can/can0/frames"] == 1


# --- live: the disk fills in the middle of a drive, and room comes back ---------------------

FILLER: dict[str, Path] = {}


def full_disk() -> Iterator[tuple[float, Any]]:
    frames = list(steady(7.0))
    drives = Path.cwd() / "disk" / "drives"
    yield from (f for f in frames if f[0] < 2.0)
    yield 2.0, "the disk fills"
    yield 2.0, lambda: FILLER.setdefault("filler", fill(drives))
    yield from (f for f in frames if 2.0 <= f[0] < 4.5)
    yield 4.5, lambda: FILLER["filler"].unlink()
    yield 4.5, "room again"
    yield from (f for f in frames if f[0] >= 4.5)


@pytest.mark.slow
def test_live_survives_a_full_disk_and_records_every_frame(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "disk", 48):
        car = start(tmp_path, f"{__file__}:full_disk", "--drives",
                    str(tmp_path / "disk" / "drives"), "--min-free", "0")
        car.drives = tmp_path / "disk" / "drives"
        viewer = Viewer(car.url)
        fault_ended = car.when("car: room again")
        recording = assert_survived(car, viewer, fault_ended=fault_ended,
                                    on_log="recorder.disk_full: disk full")
        parts = sorted(car.drives.glob("*.mcap"))
        assert len(parts) >= 2, car.output
        for part in parts:
            complete(part)
    assert "recorder.disk_full" in car.output
    healths = [health_pb2.Health.FromString(payload) for _, topic, payload in viewer.got
               if topic == "/health"]
    assert any(a.id == "recorder.disk_full" and a.active
               and a.kind == health_pb2.ALARM_KIND_DISK_FULL for h in healths for a in h.alarms)
    assert recording["/log"]
