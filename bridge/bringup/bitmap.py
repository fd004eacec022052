"""``/can/bits``: the bit-change map of every id of every bus as one PNG, and its labels.

A row per (bus, id), sorted and named in the image's own pixels, and a column per bit (byte 0's
bits 7 to 0, then byte 1's, up to :data:`MAX_BYTES`); a cell's shade is the share of the id's
frames in the last second that flipped the bit, never-changed bits dark blue. At most
:data:`MAX_ROWS` ids, unknown ones first; ``/can/bits/labels`` holds the same texts at their places.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation

from bridge.bringup.columns import id_text
from bridge.bringup.font import GLYPH_HEIGHT, draw_text, text_width
from bridge.frame import timestamp

#: A cell's pitch across, in pixels (the cell, and a pixel of gap on its right).
CELL = 12
#: A row's pitch down, in pixels (its cells, and a pixel of gap below them): room for a label.
ROW = 16
#: The labels' font (:mod:`bridge.bringup.font`) is drawn this many pixels a font pixel.
TEXT_SCALE = 2
#: The labels' height, in image pixels.
FONT = GLYPH_HEIGHT * TEXT_SCALE
#: A line of the header, in pixels.
LINE = 20
#: The header: a title, the legend, the bytes' numbers.
HEADER = 3 * LINE + 4
#: A label's characters at the most.
LABEL_CHARS = 28
#: Pixels between two bytes' columns (besides a cell's own gap).
BYTE_GAP = 4
#: Bytes drawn per id (CAN FD ids longer than that show their first ones; the header says so).
MAX_BYTES = 8
#: Ids drawn at most (unknown ids first; the header says how many are left out).
MAX_ROWS = 150
#: The narrowest image, in pixels (room for the header).
MIN_WIDTH = 800
#: Shares of frames, as levels of colour: any flip at all is level 1, every frame the last.
LEVELS = 10

# Palette indices: the cells', then the labels' colours
BACKGROUND, NEVER, QUIET, FIRST_LEVEL = 0, 1, 2, 3
TEXT, AMBER = FIRST_LEVEL + LEVELS, FIRST_LEVEL + LEVELS + 1
_PALETTE = [
    (24, 24, 28),  # background, gaps, bits past a payload
    (28, 44, 86),  # never changed since the start
    (6, 6, 6),  # changed before, not in the last second
    # a few frames to every frame: dim orange, amber, yellow, white
    *[(round(r), round(g), round(b)) for r, g, b in (
        (110 + 145 * min(1.0, k / 5), 40 + 215 * k / (LEVELS - 1), 255 * max(0.0, k - 6) / 3)
        for k in range(LEVELS))],
    (235, 235, 235),  # text
    (255, 184, 64),  # an unknown id's label
]
_WHITE = Color(r=0.92, g=0.92, b=0.92, a=1.0)
_AMBER = Color(r=1.0, g=0.72, b=0.25, a=1.0)

Cells = npt.NDArray[np.uint8]


class MapRow(NamedTuple):
    """One id as the map draws it."""

    bus: str
    key: int
    #: the databases' name of its message (None: unknown)
    message: str | None
    #: its payload's length in bytes (the widest seen)
    width: int
    #: per bit (bring-up's numbering: byte * 8 + bit), whether it ever changed
    ever: npt.NDArray[np.bool_]
    #: per bit, the share of its frames in the last second that flipped it (0 to 1)
    share: npt.NDArray[np.float64]

    @property
    def label(self) -> str:
        return f"{self.bus} {id_text(self.key)} {self.message or 'unknown'}"


def cells(rows: Sequence[MapRow], nbytes: int) -> Cells:
    """The rows' palette indices, a column per bit of ``nbytes`` bytes (byte 0 bit 7 first)."""
    columns = nbytes * 8
    share = np.zeros((len(rows), columns))
    ever = np.zeros((len(rows), columns), dtype=np.bool_)
    present = np.zeros((len(rows), columns), dtype=np.bool_)
    for r, row in enumerate(rows):
        bits = min(row.width * 8, columns, len(row.ever))
        share[r, :bits] = row.share[:bits]
        ever[r, :bits] = row.ever[:bits]
        present[r, :bits] = True
    levels = np.where(share > 0, FIRST_LEVEL - 1 + np.ceil(np.minimum(share, 1.0) * LEVELS),
                      QUIET)
    by_bit = np.where(present, np.where(ever, levels, NEVER), BACKGROUND).astype(np.uint8)
    # bit b of byte k is drawn in column k * 8 + 7 - b
    drawn: Cells = by_bit.reshape(len(rows), nbytes, 8)[:, :, ::-1].reshape(len(rows), columns)
    return drawn


def chosen(rows: Sequence[MapRow], limit: int = MAX_ROWS) -> list[MapRow]:
    """The rows drawn: all of them, or the unknown ids first and then the others up to
    ``limit``, in their order (by bus and id)."""
    if len(rows) <= limit:
        return list(rows)
    keep = {id(r) for r in [*(r for r in rows if r.message is None),
                            *(r for r in rows if r.message is not None)][:limit]}
    return [r for r in rows if id(r) in keep]


def _label(row: MapRow) -> str:
    """A row's label as drawn: at most :data:`LABEL_CHARS` characters."""
    text = row.label
    return text if len(text) <= LABEL_CHARS else text[:LABEL_CHARS - 2] + ".."


def margin(rows: Sequence[MapRow]) -> int:
    """The label margin's width: the longest label's, and a little room."""
    longest = max((len(_label(r)) for r in rows), default=0)
    return max(140, text_width("x" * longest, TEXT_SCALE) + 16)


def row_top(r: int) -> int:
    """The first pixel row of map row ``r``."""
    return HEADER + r * ROW


def byte_left(left: int, k: int) -> int:
    """The first pixel column of byte ``k`` (its bit 7)."""
    return left + k * (8 * CELL + BYTE_GAP)


def bit_map(rows: Sequence[MapRow], t_ns: int) -> tuple[CompressedImage, ImageAnnotations]:
    """The map of ``rows`` (sorted by bus and id) at log time ``t_ns``, and its labels."""
    shown = chosen(rows)
    widest = max((r.width for r in shown), default=1)
    nbytes = max(1, min(MAX_BYTES, widest))
    columns = nbytes * 8
    left = margin(shown)
    width = max(MIN_WIDTH, byte_left(left, nbytes) + 4)
    # pixel column -> map column (the last index: background)
    xs = np.full(width, columns)
    for c in range(columns):
        x = byte_left(left, c // 8) + (c % 8) * CELL
        xs[x:x + CELL - 1] = c
    grid = np.full((len(shown), columns + 1), BACKGROUND, dtype=np.uint8)
    grid[:, :columns] = cells(shown, nbytes)
    lines = grid[:, xs]
    pixels = np.full((row_top(len(shown)) + 4, width), BACKGROUND, dtype=np.uint8)
    for r, line in enumerate(lines):
        pixels[row_top(r):row_top(r) + ROW - 1] = line
        draw_text(pixels, 4, row_top(r) + 1, _label(shown[r]),
                  AMBER if shown[r].message is None else TEXT, scale=TEXT_SCALE)
    head = _head(rows, shown, widest)
    draw_text(pixels, 4, 3, head, TEXT, scale=TEXT_SCALE)
    legend_x = _legend(pixels, left)
    for k in range(nbytes):
        draw_text(pixels, byte_left(left, k), 2 * LINE + 3, f"byte {k}", TEXT, scale=TEXT_SCALE)
    image = CompressedImage(timestamp=timestamp(t_ns), format="png",
                            data=png(pixels, _PALETTE))
    return image, _labels(head, shown, nbytes, left, legend_x, t_ns)


#: The legend's swatches, and what each says.
_LEGEND = ((NEVER, "never changed"), (QUIET, "not this second"),
           (FIRST_LEVEL, "few frames"), (FIRST_LEVEL + LEVELS // 2, "half"),
           (FIRST_LEVEL + LEVELS - 1, "every frame"))


def _legend(pixels: Cells, left: int) -> list[int]:
    """Draw the legend on the header's second line; the x of each swatch."""
    at, xs = 4, []
    y = LINE + 3
    for index, text in _LEGEND:
        pixels[y:y + LINE - 6, at:at + CELL - 1] = index
        draw_text(pixels, at + CELL + 4, y, text, TEXT, scale=TEXT_SCALE)
        xs.append(at)
        at += CELL + 4 + text_width(text, TEXT_SCALE) + 16
    return xs


def _head(rows: Sequence[MapRow], shown: Sequence[MapRow], widest: int) -> str:
    buses = sorted({r.bus for r in rows})
    unknown = sum(1 for r in rows if r.message is None)
    head = (f"bits flipped in the last second: {len(rows)} ids on "
            f"{', '.join(buses) or 'no bus'}, {unknown} unknown")
    if len(shown) < len(rows):
        head += f" ({len(shown)} shown, unknown first)"
    if widest > MAX_BYTES:
        head += f" (first {MAX_BYTES} bytes)"
    return head


def _text(text: str, x: float, y: float, t_ns: int, color: Color = _WHITE,
          size: float = FONT) -> TextAnnotation:
    return TextAnnotation(timestamp=timestamp(t_ns), position=Point2(x=x, y=y), text=text,
                          font_size=size, text_color=color)


def _labels(head: str, shown: Sequence[MapRow], nbytes: int, left: int,
            legend_x: Sequence[int], t_ns: int) -> ImageAnnotations:
    """The texts drawn into the image, as annotations at their places (bottom left corners):
    for a program, or a viewer without the image (the bring-up layout does not show them)."""
    texts = [_text(head, 4, 3 + FONT, t_ns)]
    texts += [_text(what, x + CELL + 4, LINE + 3 + FONT, t_ns)
              for x, (_, what) in zip(legend_x, _LEGEND, strict=True)]
    texts += [_text(f"byte {k}", byte_left(left, k), 2 * LINE + 3 + FONT, t_ns)
              for k in range(nbytes)]
    texts += [_text(row.label, 4, row_top(r) + 1 + FONT, t_ns,
                    _AMBER if row.message is None else _WHITE)
              for r, row in enumerate(shown)]
    # (Foxglove matches annotations to the image by the message's timestamp; older versions by
    # each annotation's)
    return ImageAnnotations(timestamp=timestamp(t_ns), texts=texts)


def png(pixels: Cells, palette: Sequence[tuple[int, int, int]], level: int = 6) -> bytes:
    """A paletted PNG of ``pixels`` (rows of palette indices below 16): 4 bits a pixel, each
    row filtered with "up"; ``level``: zlib's."""
    return png_of_runs(pixels, [(y, 1) for y in range(len(pixels))], palette, level)


def png_of_runs(lines: Cells, runs: Sequence[tuple[int, int]],
                palette: Sequence[tuple[int, int, int]], level: int = 6) -> bytes:
    """:func:`png` of an image whose pixel rows are ``lines[i]`` ``n`` times for each ``(i, n)``
    of ``runs``, in order (a row the same as the one above it is all zeros once filtered: only
    the first of each run is made)."""
    width = lines.shape[1]
    if width % 2:
        lines = np.pad(lines, ((0, 0), (0, 1)))
    packed = (lines[:, 0::2] << 4) | lines[:, 1::2]
    which = np.array([i for i, n in runs if n > 0])
    counts = np.array([n for _, n in runs if n > 0])
    height = int(counts.sum())
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    filtered = np.zeros((height, packed.shape[1] + 1), dtype=np.uint8)
    filtered[:, 0] = 2  # "up": each byte less the byte above it
    filtered[starts[0], 1:] = packed[which[0]]
    filtered[starts[1:], 1:] = packed[which[1:]] - packed[which[:-1]]  # (uint8: modulo 256)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data)))

    return b"".join((
        b"\x89PNG\r\n\x1a\n",
        chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 4, 3, 0, 0, 0)),
        chunk(b"PLTE", bytes(c for rgb in palette for c in rgb)),
        chunk(b"IDAT", zlib.compress(filtered.tobytes(), level)),
        chunk(b"IEND", b"")))
