"""The garbage collector's settings for a live process, a steady stream of short-lived objects.

:func:`steady_stream` freezes what start-up loaded and leaves full collections to
:meth:`Steady.quiet`, which the live loop calls where it would sleep, so cycles are still freed
and memory stays flat; on the way out the process's own settings come back.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from dataclasses import dataclass, field

#: Young, middle and full generation thresholds while live runs: young collections every
#: 1,000 surviving allocations, middle ones every 10 of those, full ones only by
#: :meth:`Steady.quiet` (the third threshold is never reached between two of those).
LIVE_THRESHOLDS = (1_000, 10, 1_000_000)

#: Seconds between two full collections made by :meth:`Steady.quiet`.
FULL_EVERY_S = 60.0


@dataclass
class Steady:
    """The settings in force (:func:`steady_stream`): :meth:`quiet` runs the full collections,
    :meth:`restore` (or the end of a ``with`` block) brings back what was there before."""

    thresholds: tuple[int, int, int]
    #: the process's thresholds before, and whether it had frozen objects already
    previous: tuple[int, int, int]
    was_frozen: bool
    every_s: float = FULL_EVERY_S
    clock: Callable[[], float] = time.monotonic
    #: when the last full collection ran (the clock's time)
    last_full: float = field(default=0.0)
    #: full collections made by :meth:`quiet`
    full_collections: int = 0

    def __post_init__(self) -> None:
        self.last_full = self.clock()

    def quiet(self, *, force: bool = False) -> bool:
        """A quiet moment (the loop is about to wait): a full collection if one is due (every
        :attr:`every_s` seconds) or ``force``. Returns whether it ran."""
        now = self.clock()
        if not force and now - self.last_full < self.every_s:
            return False
        gc.collect()
        self.last_full = self.clock()
        self.full_collections += 1
        return True

    def restore(self) -> None:
        """The process's own thresholds again; the freeze undone if there was none before."""
        gc.set_threshold(*self.previous)
        if not self.was_frozen:
            gc.unfreeze()

    def __enter__(self) -> Steady:
        return self

    def __exit__(self, *exc: object) -> None:
        self.restore()


def steady_stream(thresholds: tuple[int, int, int] = LIVE_THRESHOLDS, *,
                  every_s: float = FULL_EVERY_S,
                  clock: Callable[[], float] = time.monotonic) -> Steady:
    """From now on (until :meth:`Steady.restore`; or ``with steady_stream() as steady:``):
    what exists now frozen, ``thresholds`` set, full collections left to :meth:`Steady.quiet`.
    Call it once start-up has loaded everything that lives on."""
    previous = gc.get_threshold()
    was_frozen = gc.get_freeze_count() > 0
    gc.collect()  # start-up's garbage, so that only what lives on is frozen
    gc.freeze()
    gc.set_threshold(*thresholds)
    return Steady(thresholds, previous, was_frozen, every_s, clock)
