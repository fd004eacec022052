"""Labels: one text block per place, and no block drawn over another.

Every label the scene would draw is first a :class:`Label` request (anchor, full text, compact
text, priority: the MIO check, the lead, tracks, detections; nearer first). :func:`lay_out` turns
one tick's requests into :class:`Block` s, with two promises:

1. **One block per place.** Requests within :data:`PLACE_M` of each other on the ground, directly
   or through a chain, are one place and get one block at the first request's anchor: its full
   text, then one line per other request (a line once). No two blocks stand within
   :data:`PLACE_M`.
2. **No block covers another on screen** (seen from the range view's camera,
   :mod:`bridge.scene.camera`). Places go in priority order; a block whose box (:func:`box`,
   :func:`lifted`) would overlap one drawn or leave the panel is drawn compact; if that does too,
   it moves one block width aside (towards the middle first), then up by up to :data:`MAX_RAISES`
   block heights, to the first spot that covers nothing, stays on the panel and keeps
   :data:`PLACE_M`, with a leader line to its object. Where none fits it is not drawn; its objects
   keep their marks and their details in the entity metadata.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from operator import attrgetter
from typing import NamedTuple

from bridge.scene.camera import ViewCamera

#: Labels anchored this close (m, ground plane) share one block.
PLACE_M = 2.5
#: Width of a character and height of a line of a label (px, font size 14, on the panel).
CHAR_PX = 9.0
LINE_PX = 17.0
#: Room kept free around each block (px).
MARGIN_PX = 4.0
#: A block that covers another may be raised by up to this many times its height.
MAX_RAISES = 3


class Label(NamedTuple):
    """A label the scene would draw for one thing (an object, the lead, the MIO check)."""

    owner: object  # who carries the block's text (the scene's entity key)
    x: float
    y: float
    z: float
    text: str  # the full text, one line per "\n"
    compact: str  # one line, drawn where the full text does not fit
    line: str  # one line, added to the block of another label at its place
    priority: tuple[int, float]  # lower first: (kind, distance ahead)


class Block(NamedTuple):
    """A text block to draw: carried by ``owner``'s entity at (x, y, z)."""

    owner: object
    x: float
    y: float
    z: float
    text: str
    #: the owners of the other labels of its place (drawn in this block)
    merged: tuple[object, ...] = ()
    #: a block moved off its place: a leader line from where its label would have stood to the
    #: edge of the block (not across its text)
    leader: tuple[Point, Point] | None = None


def places(labels: Sequence[Label]) -> list[list[Label]]:
    """The labels grouped by place (anchors within PLACE_M, transitively), each place in order
    of priority and the places by their first label's priority."""
    order = sorted(labels, key=attrgetter("priority"))
    n = len(order)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    limit = PLACE_M ** 2
    spots = [(label.x, label.y) for label in order]
    near = [(i, j) for i, (ax, ay) in enumerate(spots) for j in range(i + 1, n)
            if (ax - spots[j][0]) ** 2 + (ay - spots[j][1]) ** 2 < limit]
    if not near:  # every label a place of its own (the common case), in order of priority
        return [[label] for label in order]
    for i, j in near:
        parent[root(j)] = root(i)
    grouped: dict[int, list[Label]] = {}
    for i, label in enumerate(order):
        grouped.setdefault(root(i), []).append(label)
    return sorted(grouped.values(), key=_first_priority)


def _first_priority(place: list[Label]) -> tuple[int, float]:
    return place[0].priority


Box = tuple[float, float, float, float]  # left, top, right, bottom (px from the panel's centre)
Point = tuple[float, float, float]


def box(camera: ViewCamera, x: float, y: float, z: float, text: str) -> Box | None:
    """Where a block of ``text`` anchored at (x, y, z) lies on the panel (Foxglove centres it
    on its anchor), with MARGIN_PX around it; None where the anchor is behind the camera."""
    at = camera.project(x, y, z)
    if at is None:
        return None
    lines = text.split("\n")
    half = max(len(line) for line in lines) * CHAR_PX / 2 + MARGIN_PX
    tall = len(lines) * LINE_PX / 2 + MARGIN_PX
    return at[0] - half, at[1] - tall, at[0] + half, at[1] + tall


def lifted(camera: ViewCamera, x: float, y: float, z: float, text: str) -> float:
    """The height of the anchor that puts the bottom of a block of ``text`` at height ``z``
    (on the panel): Foxglove centres a block on its anchor, which would cover the mark below."""
    rows = text.count("\n") + 1
    vertical = camera.px_per_m(x, y, z) * camera.vertical  # px per vertical metre there
    return z + (rows * LINE_PX / 2 + MARGIN_PX) / vertical


def _overlaps(a: Box, b: Box) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


#: A try of a block: its text, where it stands (x, y, z), and the height its text stands at
#: unmoved (so a block at another height was moved)
Place = tuple[str, float, float, float, float]


def _tries(first: Label, others: Sequence[Label], camera: ViewCamera) -> Iterator[Place]:
    """The texts and places to try for a place's block, in order (see the module's rules),
    each with the height its text stands at unmoved (:func:`lifted` at its anchor)."""
    x, y = first.x, first.y
    full = "\n".join([first.text, *dict.fromkeys(o.line for o in others)]) if others \
        else first.text
    # lifted(camera, x, y, first.z, text) of each text, its camera's terms once
    cos, sin = camera.sight
    ahead = (x - camera.eye_x) * cos - (first.z - camera.eye_z) * sin
    vertical = camera.focal_px / max(ahead, 0.1) * cos
    z = first.z + ((full.count("\n") + 1) * LINE_PX / 2 + MARGIN_PX) / vertical
    yield full, x, y, z, z
    z = first.z + ((first.compact.count("\n") + 1) * LINE_PX / 2 + MARGIN_PX) / vertical
    yield first.compact, x, y, z, z
    metre = camera.px_per_m(x, y, z)
    aside = (len(first.compact) * CHAR_PX + 2 * MARGIN_PX) / metre  # one block width, m
    up = (LINE_PX + 2 * MARGIN_PX) / metre  # one line's height, m
    for side in (1, -1) if y < 0 else (-1, 1):  # towards the middle first (y points left)
        yield first.compact, x, y + side * aside, z, z
    for k in range(1, MAX_RAISES + 1):
        yield first.compact, x, y, z + k * up, z


def lay_out(labels: Sequence[Label], camera: ViewCamera) -> list[Block]:
    """The blocks to draw for one tick's ``labels`` (see the module's rules)."""
    drawn: list[Box] = []
    blocks: list[Block] = []
    spots: list[tuple[float, float]] = []  # where each block stands (x, y)
    limit = PLACE_M ** 2
    # camera.project's terms
    cos, sin = camera.sight
    eye_x, eye_z, focal = camera.eye_x, camera.eye_z, camera.focal_px
    # camera.on_panel's bounds
    half_h, half_w = camera.height_px / 2, camera.height_px * camera.aspect / 2
    for place in places(labels):
        first, others = place[0], place[1:]
        size: tuple[str, float, float] = ("", 0.0, 0.0)  # a text, its half width and height
        for text, x, y, z, base in _tries(first, others, camera):  # noqa: B007 (kept)
            # box(camera, x, y, z, text), camera.project inline and its text's size once
            d = (x - eye_x) * cos - (z - eye_z) * sin
            if d <= 0.1:
                continue
            across = -y * focal / d
            down = -((x - eye_x) * sin + (z - eye_z) * cos) * focal / d
            if size[0] is not text:
                lines = text.split("\n")
                size = (text, max(map(len, lines)) * CHAR_PX / 2 + MARGIN_PX,
                        len(lines) * LINE_PX / 2 + MARGIN_PX)
            half, tall = size[1], size[2]
            left, top, right, bottom = across - half, down - tall, across + half, down + tall
            if not (-half_w <= left and right <= half_w and -half_h <= top
                    and bottom <= half_h):  # camera.on_panel
                continue
            for o in drawn:  # _overlaps
                if left < o[2] and o[0] < right and top < o[3] and o[1] < bottom:
                    break
            else:
                for bx, by in spots:
                    if (bx - x) ** 2 + (by - y) ** 2 < limit:
                        break
                else:
                    break
        else:
            continue
        drawn.append((left, top, right, bottom))
        spots.append((x, y))
        # where its text would stand unmoved: lifted() of its text at its anchor (which does
        # not depend on y), as _tries computed it
        moved = (x, y) != (first.x, first.y) or z != base
        own = (first.x, first.y, first.z)
        blocks.append(Block(first.owner, x, y, z, text, tuple(o.owner for o in others),
                            (own, _edge(camera, own, (x, y, z), text)) if moved else None))
    return blocks


def _edge(camera: ViewCamera, start: Point, centre: Point, text: str) -> Point:
    """Where the line from ``start`` to the ``centre`` of a block of ``text`` meets the block's
    edge on the panel (its start, where the block covers it)."""
    a, b = camera.project(*start), camera.project(*centre)
    if a is None or b is None:
        return start
    lines = text.split("\n")
    half_w, half_h = max(len(line) for line in lines) * CHAR_PX / 2, len(lines) * LINE_PX / 2
    dx, dy = abs(a[0] - b[0]), abs(a[1] - b[1])
    share = min(half_w / dx if dx else math.inf, half_h / dy if dy else math.inf, 1.0)
    return tuple(c + (s - c) * share for s, c in zip(start, centre, strict=True))  # type: ignore[return-value]
