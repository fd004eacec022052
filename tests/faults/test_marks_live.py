"""Marks from a viewer in a live run (#34 items 1 and 5): a viewer publishes marks on ``/marks``
while a car drives with a bus clock hours off the laptop's; each mark is in the recording on
``/marks`` at the drive's clock (where the frames of that moment are, not at the laptop's time),
on ``/log`` and ``/scene/marks``, shown to the viewers at once and said on the console.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from harness import LiveCar, Viewer, assert_survived, start
from marker import Marker, mark_json
from mcap.reader import make_reader

from bridge.frame import NS
from bridge.sim.ecocar import simulate

with contextlib.suppress(ImportError):  # (not in the car's process, livecar.py: it drives)
    from conftest import timeout_scale

#: The bus clock's offset from the laptop's: five hours behind.
OFF_NS = -5 * 3600 * NS
#: The car drives laps of this many seconds until the test says stop (its file exists).
LAP_S = 4.0
STOP_FILE = "TANKVIZ_TEST_MARKS_STOP"


def until_told(off_ns: int = OFF_NS, *, most_laps: int = 60) -> Iterator[tuple[float, Any]]:
    """The simulated ecocar, lap after lap, stamped with a clock ``off_ns`` off the wall clock,
    until the file named by $TANKVIZ_TEST_MARKS_STOP exists (at least two laps)."""
    stop = Path(os.environ[STOP_FILE])
    frames = list(simulate(duration_s=LAP_S))
    t0 = frames[0].timestamp_ns
    now = time.time_ns() + off_ns
    for lap in range(most_laps):
        if lap >= 2 and stop.exists():
            return
        for frame in frames:
            at = lap * LAP_S + (frame.timestamp_ns - t0) / NS
            yield at, frame._replace(timestamp_ns=now + round(at * NS))


def block_times(drives: Path) -> list[int]:
    """The log times of the drive's blocks of raw frames (each its first frame's time)."""
    times = []
    for path in sorted(drives.glob("*.mcap")):
        with path.open("rb") as f:
            times += [message.log_time for _, _, message
                      in make_reader(f).iter_messages(topics=["/can/can0/frames"])]
    return times


def hours_off() -> Iterator[tuple[float, Any]]:
    return until_told()


def drive_until_told(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, inject: str,
                     *live_args: str) -> tuple[LiveCar, Path]:
    """tankviz live with the car ``inject`` (``FILE.py:FUNC``, of :func:`until_told`), and
    the file that stops it once it exists."""
    stop = tmp_path / "stop"
    monkeypatch.setenv(STOP_FILE, str(stop))
    return start(tmp_path, inject, *live_args), stop


async def three_marks(url: str) -> tuple[Marker, list[int]]:
    """Publishes three marks, each once the one before came back on /log; the drive's time
    (the latest scene's) when each was published."""
    marker = await Marker(url).open()
    await marker.subscribe("/log", "/scene/ego", "/scene/marks")
    wait = 30.0 * timeout_scale()
    await marker.until(lambda: marker.latest("/scene/ego") > 0, wait)
    await marker.advertise(1)
    published = []
    for number, content in enumerate([mark_json("ghost", "radar"), mark_json(),
                                      mark_json("lane lost", "lanes")], start=1):
        published.append(marker.latest("/scene/ego"))
        await marker.publish(1, content)
        said = f"MARK {number}:"
        await marker.until(lambda: bool(marker.logged(said)), wait)  # noqa: B023 (awaited)
    await marker.until(lambda: len([1 for name, _, _ in marker.got
                                    if name == "/scene/marks"]) >= 3, wait)
    await marker.close()
    return marker, published


@pytest.mark.slow
def test_a_viewers_marks_land_at_the_drives_clock_hours_off_the_laptops(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    car, stop = drive_until_told(tmp_path, monkeypatch, f"{__file__}:hours_off")
    viewer = Viewer(car.url)  # another viewer, watching
    try:
        marker, published = asyncio.run(three_marks(car.url))
        ended = time.time()
    finally:
        stop.touch()
    recording = assert_survived(car, viewer, fault_ended=ended, on_log=None)

    marks = recording["/marks"]
    by = marker.address
    assert [(m.number, m.text, m.category, m.source, m.by) for m in marks] == [
        (1, "ghost", "radar", "viewer", by), (2, "mark", "", "viewer", by),
        (3, "lane lost", "lanes", "viewer", by)]
    times = [m.timestamp.seconds * NS + m.timestamp.nanos for m in marks]
    blocks = block_times(car.drives)
    slack = round(2 * NS * timeout_scale())
    for t, before in zip(times, published, strict=True):
        # at the drive's clock when it came: after the scene the viewer had seen, soon after
        assert before <= t <= before + slack, (before, t)
        assert abs(t - time.time_ns()) > 4 * 3600 * NS  # (not the laptop's clock)
        # where the frames of that moment are (a block of frames every 20 ms)
        assert min(abs(b - t) for b in blocks) < NS // 10
    # said on /log and shown in the scene at the same time, recorded and live
    logged = [m for m in recording["/log"] if m.message.startswith("MARK ")]
    assert [m.message for m in logged] == [
        f"MARK 1: ghost [radar] (viewer {by})", f"MARK 2: mark (viewer {by})",
        f"MARK 3: lane lost [lanes] (viewer {by})"]
    assert [m.timestamp.seconds * NS + m.timestamp.nanos for m in logged] == times
    scene = recording["/scene/marks"]
    assert [u.entities[0].timestamp.seconds * NS + u.entities[0].timestamp.nanos
            for u in scene if u.entities] == times
    assert [marker.logged(f"MARK {n}:") for n in (1, 2, 3)] == [[t] for t in times]
    assert [t for name, t, _ in marker.got if name == "/scene/marks"][:3] == times
    # said on the console, once each
    for line in (f"MARK 1: ghost [radar] (viewer {by})", f"MARK 3: lane lost [lanes] (viewer "
                 f"{by})"):
        assert sum(line in text for _, text in car.lines) == 1, car.output
    assert marker.statuses == []
