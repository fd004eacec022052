"""The fault tests' harness on a drive without a fault: everything sent is recorded, and the
viewer gets the scene all along."""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from harness import Viewer, assert_survived, start, steady


def clean_drive() -> Iterator[tuple[float, Any]]:
    yield from steady(3.0)


@pytest.mark.slow
def test_a_drive_without_a_fault_is_watched_and_recorded_whole(tmp_path: Path) -> None:
    car = start(tmp_path, f"{__file__}:clean_drive")
    viewer = Viewer(car.url)
    started = car.when("Ctrl+C")
    recording = assert_survived(car, viewer, fault_ended=started + 1.0, on_log=None)
    scenes = viewer.scenes_after(started)
    assert len(scenes) >= 2.0 * 20  # 20 Hz
    assert max(b - a for a, b in itertools.pairwise(scenes)) < 0.5
    assert len(recording["/scene/ego"]) >= 2.5 * 20


def slow_to_make() -> Iterator[tuple[float, Any]]:
    """A steady drive whose frames take 1.5 s to make, as simulating them does on a loaded
    machine."""
    time.sleep(1.5)  # (the car's own slowness, not a wait of the test)
    yield from steady(2.0)


def stalled() -> Iterator[tuple[float, Any]]:
    """A steady drive whose car stops for 1 s after 0.5 s, as a stalled process's thread does."""
    for at, frame in steady(2.0):
        if at >= 0.5:
            yield at, lambda: time.sleep(1.0)  # (the stall itself, not a wait of the test)
            break
        yield at, frame
    yield from ((at, frame) for at, frame in steady(2.0) if at >= 0.5)


@pytest.mark.slow
@pytest.mark.parametrize("script, late", [("slow_to_make", False), ("stalled", True)])
def test_the_car_says_how_late_it_sent(tmp_path: Path, script: str, late: bool) -> None:
    """The car's clock starts with its first frame (making frames slowly is not sending late);
    a car held up sends late, and says by how much (at least the hold-up)."""
    car = start(tmp_path, f"{__file__}:{script}")
    assert_survived(car, None, fault_ended=car.when("Ctrl+C"), on_log=None)
    assert (car.late_s >= 0.9) if late else (car.late_s < 0.5), car.late_s
