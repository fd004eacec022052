"""A 5 x 7 pixel font, to write labels into an image's own pixels (every viewer shows them, at
any size the image is drawn).

Digits (a zero as round as an O, for people and OCR alike), capitals, a small ``x`` and
``_ - . / : # , ( )``; other small letters are written as capitals, anything else as a blank.
Text advances 6 pixels a character (times ``scale``).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import numpy.typing as npt

#: Width and height of a glyph, and its advance, in font pixels.
GLYPH_WIDTH, GLYPH_HEIGHT, ADVANCE = 5, 7, 6

_ROWS = {
    "0": "01110 10001 10001 10001 10001 10001 01110",
    "1": "00100 01100 00100 00100 00100 00100 01110",
    "2": "01110 10001 00001 00010 00100 01000 11111",
    "3": "11111 00010 00100 00010 00001 10001 01110",
    "4": "00010 00110 01010 10010 11111 00010 00010",
    "5": "11111 10000 11110 00001 00001 10001 01110",
    "6": "00110 01000 10000 11110 10001 10001 01110",
    "7": "11111 00001 00010 00100 01000 01000 01000",
    "8": "01110 10001 10001 01110 10001 10001 01110",
    "9": "01110 10001 10001 01111 00001 00010 01100",
    "A": "01110 10001 10001 11111 10001 10001 10001",
    "B": "11110 10001 10001 11110 10001 10001 11110",
    "C": "01111 10000 10000 10000 10000 10000 01111",
    "D": "11100 10010 10001 10001 10001 10010 11100",
    "E": "11111 10000 10000 11110 10000 10000 11111",
    "F": "11111 10000 10000 11110 10000 10000 10000",
    "G": "01110 10001 10000 10111 10001 10001 01111",
    "H": "10001 10001 10001 11111 10001 10001 10001",
    "I": "01110 00100 00100 00100 00100 00100 01110",
    "J": "00111 00010 00010 00010 00010 10010 01100",
    "K": "10001 10010 10100 11000 10100 10010 10001",
    "L": "10000 10000 10000 10000 10000 10000 11111",
    "M": "10001 11011 10101 10101 10001 10001 10001",
    "N": "10001 11001 11001 10101 10011 10011 10001",
    "O": "01110 10001 10001 10001 10001 10001 01110",
    "P": "11110 10001 10001 11110 10000 10000 10000",
    "Q": "01110 10001 10001 10001 10101 10010 01101",
    "R": "11110 10001 10001 11110 10100 10010 10001",
    "S": "01111 10000 10000 01110 00001 00001 11110",
    "T": "11111 00100 00100 00100 00100 00100 00100",
    "U": "10001 10001 10001 10001 10001 10001 01110",
    "V": "10001 10001 10001 10001 10001 01010 00100",
    "W": "10001 10001 10001 10101 10101 10101 01010",
    "X": "10001 10001 01010 00100 01010 10001 10001",
    "Y": "10001 10001 10001 01010 00100 00100 00100",
    "Z": "11111 00001 00010 00100 01000 10000 11111",
    "x": "00000 00000 10001 01010 00100 01010 10001",
    "_": "00000 00000 00000 00000 00000 00000 11111",
    "-": "00000 00000 00000 11111 00000 00000 00000",
    ".": "00000 00000 00000 00000 00000 01100 01100",
    "/": "00000 00001 00010 00100 01000 10000 00000",
    ":": "00000 01100 01100 00000 01100 01100 00000",
    "#": "01010 01010 11111 01010 11111 01010 01010",
    ",": "00000 00000 00000 00000 01100 00100 01000",
    "(": "00010 00100 01000 01000 01000 00100 00010",
    ")": "01000 00100 00010 00010 00010 00100 01000",
}

#: Each glyph as a boolean array, 7 rows by 5 columns.
GLYPHS: dict[str, npt.NDArray[np.bool_]] = {
    char: np.array([[c == "1" for c in row] for row in rows.split()], dtype=bool)
    for char, rows in _ROWS.items()}


def glyph(char: str) -> npt.NDArray[np.bool_] | None:
    """The glyph of a character (small letters but ``x`` as capitals), None for a blank."""
    found = GLYPHS.get(char)
    return found if found is not None else GLYPHS.get(char.upper())


def text_width(text: str, scale: int = 1) -> int:
    """Pixels the text takes across."""
    return max(0, len(text) * ADVANCE - 1) * scale


@lru_cache(maxsize=4096)
def text_mask(text: str, scale: int = 1) -> npt.NDArray[np.bool_]:
    """The pixels ``text`` sets, :func:`text_width` across and ``GLYPH_HEIGHT * scale`` down
    (read-only: a label drawn again and again is made once)."""
    small = np.zeros((GLYPH_HEIGHT, max(0, len(text) * ADVANCE - 1)), dtype=bool)
    for i, char in enumerate(text):
        shape = glyph(char)
        if shape is not None:
            small[:, i * ADVANCE:i * ADVANCE + GLYPH_WIDTH] = shape
    big = small.repeat(scale, axis=0).repeat(scale, axis=1)
    big.setflags(write=False)
    return big


def draw_text(canvas: npt.NDArray[np.uint8], x: int, y: int, text: str, value: int, *,
              scale: int = 1) -> None:
    """Write ``text`` into ``canvas`` (a 2-D array of colour indices) with its top left corner
    at ``(x, y)``, its pixels set to ``value``; what falls outside the canvas is cut."""
    height, width = canvas.shape
    big = text_mask(text, scale)
    right, bottom = min(width, x + big.shape[1]), min(height, y + big.shape[0])
    if x >= width or y >= height or right <= max(x, 0) or bottom <= max(y, 0):
        return
    part = big[max(0, -y):bottom - y, max(0, -x):right - x]
    canvas[max(y, 0):bottom, max(x, 0):right][part] = value
