"""The garbage collector's settings for a live process: a steady stream of short-lived objects.

Live makes millions of short-lived objects a minute (frames, tuples, decoded messages, protobuf
bytes) and no reference cycles per frame: reference counting frees them (``gc.DEBUG_SAVEALL``
over 60,000 frames of the ecocar traffic finds 8 cyclic objects, all made once). CPython's
defaults (thresholds 700, 10, 10) were made for the opposite: a young collection every 700
surviving allocations, which promotes whatever lives for one scene period (frames and messages
waiting for a flush) into the older generations, and a full collection every hundred young
ones, each walking every tracked object: pauses of tens of ms, three a minute (issue #15),
during which the pipeline and the server (one GIL) stand still. :func:`steady_stream` sets, for
the time it runs:

* :func:`gc.freeze` of what start-up loaded (databases, profile, schemas, libraries): it lives as
  long as the process, so no collection walks it again;
* young and middle collections a little rarer than the defaults (:data:`LIVE_THRESHOLDS`), but
  still small: a young collection walks what survived since the last one, so its pause grows
  with the threshold (at 50,000 one young collection of the benchmark's traffic took 22 ms of
  CPU, more than a full one: long-lived caches filling up survive it);
* no automatic full collection (its threshold is out of reach): :meth:`Steady.quiet`, called by
  the live loop where it would sleep until the next read, runs one every
  :data:`FULL_EVERY_S` seconds, so cycles (a viewer that left, an exception's traceback) are
  still freed and memory stays flat.

On the way out the process's own settings come back (and the freeze is undone when there was
none before). Convert needs none of this: :meth:`bridge.pipeline.drive.Drive.run` turns the
collector off for its loop, which ends.
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
