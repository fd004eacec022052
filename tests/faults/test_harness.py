"""The fault tests' harness on a drive without a fault: everything sent is recorded, and the
viewer gets the scene all along."""

from __future__ import annotations

import itertools
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
