"""A one-line progress bar for a terminal: count, rate, percentage and ETA."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Redraws one line on ``stream`` at most ``hz`` times a second; silent off a terminal."""

    def __init__(self, stream: TextIO = sys.stderr, *, width: int = 30, hz: float = 5.0,
                 unit: str = "frames") -> None:
        self.stream = stream
        self.unit = unit
        self.width = width
        self._interval = 1.0 / hz
        self._start = time.monotonic()
        self._last = 0.0
        self.enabled = stream.isatty()

    @staticmethod
    def render(count: int, fraction: float | None, elapsed: float, width: int = 30,
               unit: str = "frames") -> str:
        """The text of the bar (pure, for tests)."""
        rate = count / elapsed if elapsed > 0 else 0.0
        text = f"{count:>12,} {unit}  {rate:>10,.0f} {unit}/s"
        if fraction is not None:
            fraction = min(max(fraction, 0.0), 1.0)
            filled = round(fraction * width)
            eta_text = "--:--"
            if fraction > 0:
                eta = int(elapsed * (1 - fraction) / fraction)
                eta_text = f"{eta // 60:02d}:{eta % 60:02d}"
            bar = "#" * filled + "." * (width - filled)
            text = f"[{bar}] {fraction:4.0%} {text}  ETA {eta_text}"
        return text

    def __call__(self, frames: int, fraction: float | None) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < self._interval and fraction != 1.0:
            return
        self._last = now
        self.stream.write("\r" + self.render(frames, fraction, now - self._start, self.width,
                                             self.unit))
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
