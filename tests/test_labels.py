"""Labels laid out for reading (bridge.scene.labels) and marks that stay visible far away
(bridge.scene.camera), on hand-made requests: one block per place, none covering another."""

from __future__ import annotations

import dataclasses
import itertools
import math
import random

import pytest

from bridge.scene.camera import BEYOND, MIN_MARK_PX, camera_for, chase_camera
from bridge.scene.labels import LINE_PX, PLACE_M, Label, _overlaps, box, lay_out

CAMERA = camera_for(200.0)


def track(i: int, x: float, y: float) -> Label:
    full = f"TrackID: {i}\nx: {x:.2f}\ny: {y:.2f}"
    compact = f"TrackID: {i} · {math.hypot(x, y):.0f} m"
    return Label(f"tracks-{i}", x, y, 1.6, full, compact, compact, (2, x))


def test_labels_within_a_place_share_one_block() -> None:
    lead = Label("lead", 40.0, 0.2, 2.9, "Lead Vehicle\nx: 40.00\ny: 0.20", "Lead · 40 m",
                 "Lead · 40 m", (1, 40.0))
    blocks = lay_out([track(3, 41.0, 0.0), lead, track(4, 42.5, 1.0)], CAMERA)
    (block,) = blocks
    assert block.owner == "lead"
    assert block.text == "Lead Vehicle\nx: 40.00\ny: 0.20\nTrackID: 3 · 41 m\nTrackID: 4 · 43 m"
    assert set(block.merged) == {"tracks-3", "tracks-4"}


def test_the_camera_frames_the_range_and_keeps_marks_visible() -> None:
    half = CAMERA.height_px / 2
    assert CAMERA.project(-6.0, 0.0, 0.0) == pytest.approx((0.0, half))  # the bottom edge
    top = CAMERA.project(200.0 * (1 + BEYOND), 0.0, 0.0)
    assert top is not None and top[1] == pytest.approx(-half)  # the top edge, beyond 200 m
    far = CAMERA.project(200.0, 0.0, 0.0)
    assert far is not None and far[1] > -half + 2 * LINE_PX  # room for a compact label above
    for x in (10.0, 50.0, 100.0, 200.0):
        assert 0.5 * CAMERA.scale(x, 0.0, 0.5) * CAMERA.px_per_m(x, 0.0) >= MIN_MARK_PX - 1e-9
    assert camera_for(60.0).scale(5.0, 0.0, 0.5) == 1.0  # near: the seed's sizes
    assert CAMERA.scale(5.0, 0.0, 0.5) < 1.15


def test_far_labels_are_made_compact_moved_or_left_to_the_metadata() -> None:
    # a highway at 120-190 m: cars in three lanes, a few metres apart on the road, a few pixels
    # apart on the panel
    labels = [track(i, 120.0 + 10 * (i // 3), 3.6 * (i % 3 - 1)) for i in range(24)]
    blocks = lay_out(labels, CAMERA)
    boxes = [box(CAMERA, b.x, b.y, b.z, b.text) for b in blocks]
    assert all(b is not None and CAMERA.on_panel(*b) for b in boxes)
    for (a, b), (p, q) in zip(itertools.combinations(boxes, 2),
                              itertools.combinations(blocks, 2), strict=True):
        assert a is not None and b is not None and not _overlaps(a, b), (p.text, q.text)
        assert math.hypot(p.x - q.x, p.y - q.y) >= PLACE_M
    assert any("\n" not in b.text for b in blocks)  # compact where the full one does not fit
    assert len(blocks) < len(labels)  # and some left to the metadata
    moved = [b for b in blocks if b.leader is not None]
    assert all(b.owner in {label.owner for label in labels} for b in moved)


def test_near_labels_are_drawn_in_full() -> None:
    blocks = lay_out([track(1, 15.0, 7.2), track(2, 20.0, -7.2), track(3, 40.0, 0.0)], CAMERA)
    assert sorted(b.text.split("\n")[0] for b in blocks) == [
        "TrackID: 1", "TrackID: 2", "TrackID: 3"]
    assert all(b.leader is None for b in blocks)


#: The 3D panels of the generated layouts as Foxglove Studio draws them (width, height px), by
#: view: tank-viz's two (its chase view above the Mark button) and engineer's chase view, in
#: 1280 x 800 and 1920 x 1080 windows.
PANELS = {"chase": [(676, 585), (442, 498), (1028, 823), (673, 702)],
          "range": [(553, 693), (841, 973)]}
VIEWS = {"chase": chase_camera(), "range": CAMERA}


def highway(seed: int) -> list[Label]:
    """A busy road: 10-190 m ahead, up to four lanes either side, cars a few metres apart."""
    rng = random.Random(seed)
    return [track(i, rng.uniform(8.0, 190.0), 3.6 * rng.randint(-4, 4) + rng.uniform(-1, 1))
            for i in range(rng.randint(5, 40))]


@pytest.mark.parametrize("view", sorted(VIEWS))
def test_each_views_labels_stay_apart_and_on_every_panel_of_that_view(view: str) -> None:
    """Laid out for the view's smallest panel, the blocks stay whole on every panel the layouts
    give it, small window or large: none leaves the panel, none covers another."""
    camera = VIEWS[view]
    for width, height in PANELS[view]:
        assert camera.holds(height, width), (view, width, height)
    for seed in range(40):
        blocks = lay_out(highway(seed), camera)
        assert blocks
        for width, height in PANELS[view]:
            seen = dataclasses.replace(camera, height_px=height, aspect=width / height)
            boxes = [box(seen, b.x, b.y, b.z, b.text) for b in blocks]
            for b, block in zip(boxes, blocks, strict=True):
                assert b is not None and seen.on_panel(*b), (view, width, height, block.text)
            for a, b in itertools.combinations(boxes, 2):
                assert a is not None and b is not None and not _overlaps(a, b), (
                    view, width, height, seed)


def test_a_panel_smaller_than_the_view_was_laid_out_for_is_not_held() -> None:
    camera = VIEWS["range"]
    assert not camera.holds(camera.height_px - 1, camera.height_px)  # shorter
    assert not camera.holds(camera.height_px, camera.height_px * camera.aspect - 1)  # narrower
