"""Frames on the bus: the DBC encoding, counters and checksums, and the timing of every family.

Each family sends at its DBC cycle time with a phase and jitter, every timestamp ``start_ns`` plus
whole microseconds; ``rng(family)`` is seeded with the seed and the family's name, so the same
seed gives byte-identical frames, and the seed changes noise, jitter, phases, counter starts and
the ghosts, never the scenario.
"""

from __future__ import annotations

import functools
import random
from collections.abc import Hashable, Iterator
from dataclasses import dataclass

import cantools

from bridge.frame import Frame
from bridge.resources import data_dir
from bridge.sim.scenario import Faults
from bridge.sim.sensors import Snapshots

#: Nanoseconds per microsecond and per millisecond.
US = 1_000
MS = 1_000_000


def load_ecocar() -> cantools.database.can.Database:
    """The bundled ecocar DBC (``data_dir()/"ecocar.dbc"``), freshly loaded."""
    path = data_dir() / "ecocar.dbc"
    database = cantools.database.load_file(path)
    if not isinstance(database, cantools.database.can.Database):
        raise TypeError(f"{path} is not a CAN database")
    return database


@functools.lru_cache(maxsize=1)
def default_database() -> cantools.database.can.Database:
    """The bundled ecocar DBC, loaded once: what ``simulate`` encodes with by default."""
    return load_ecocar()


# ---------------------------------------------------------------------------------------------
# Encoding
# ---------------------------------------------------------------------------------------------


class Codec:
    """One DBC message: clamps values to the signal ranges (saturating, never failing), encodes,
    remembers its counter (wrapping at ``2 ** length`` of the ``Counter`` signal). A message the
    database lacks is a ``ValueError`` naming it.
    """

    __slots__ = ("counter_mod", "fd", "frame_id", "limits", "message")

    def __init__(self, database: cantools.database.can.Database, name: str) -> None:
        try:
            self.message = database.get_message_by_name(name)
        except KeyError:
            raise ValueError(f"the database has no message {name!r}, which the simulator "
                             "needs (simulate() drives the ecocar DBC)") from None
        self.frame_id: int = self.message.frame_id
        self.fd: bool = bool(self.message.is_fd)
        self.limits = tuple((s.name, s.minimum, s.maximum) for s in self.message.signals
                            if s.minimum is not None and s.maximum is not None)
        counter = next((s for s in self.message.signals if s.name == "Counter"), None)
        self.counter_mod = 2 ** counter.length if counter is not None else 1

    def encode(self, values: dict[str, float]) -> bytes:
        for name, lo, hi in self.limits:
            value = values.get(name)
            if value is not None:
                if value < lo:
                    values[name] = lo
                elif value > hi:
                    values[name] = hi
        data: bytes = self.message.encode(values, strict=False)
        return data


class Out:
    """Builds frames for one bus: 11-bit ids, no error or remote frames, a CAN-FD message as CAN-FD
    with BRS.
    """

    def __init__(self, bus: str) -> None:
        self.bus = bus

    def frame(self, ts: int, codec: Codec, data: bytes) -> Frame:
        return Frame(ts, self.bus, codec.frame_id, data, False, codec.fd, False, False, codec.fd,
                     False, len(data))


def checksum(codec: Codec, values: dict[str, float]) -> bytes:
    """Encode with ``Checksum`` = (byte0 + ... + byte6) & 0xFF, as the DBC comments say."""
    values["Checksum"] = 0
    first = codec.encode(values)
    values["Checksum"] = sum(first[:7]) & 0xFF
    return codec.encode(values)


class Slots:
    """Stable slot assignment: an object keeps its slot while it stays in the list."""

    def __init__(self, size: int) -> None:
        self.owner: list[Hashable | None] = [None] * size
        self.where: dict[Hashable, int] = {}

    def assign(self, keys: list[Hashable]) -> list[Hashable | None]:
        """``keys`` in priority order (those beyond the slot count are left out)."""
        keep = set(keys[: len(self.owner)])
        for key in [k for k in self.where if k not in keep]:
            self.owner[self.where.pop(key)] = None
        free = (i for i, o in enumerate(self.owner) if o is None)
        for key in keys[: len(self.owner)]:
            if key not in self.where:
                slot = next(free)
                self.where[key] = slot
                self.owner[slot] = key
        return self.owner

    def clear(self) -> None:
        self.owner = [None] * len(self.owner)
        self.where.clear()


class Ids:
    """Track ids 1..255, stable per object while it is tracked, reused only after a full turn."""

    def __init__(self, first: int) -> None:
        self.next = first
        self.ids: dict[Hashable, int] = {}

    def get(self, key: Hashable) -> int:
        found = self.ids.get(key)
        if found is None:
            used = set(self.ids.values())
            while self.next in used:
                self.next = self.next % 255 + 1
            found = self.ids[key] = self.next
            self.next = self.next % 255 + 1
        return found

    def retain(self, keys: set[Hashable]) -> None:
        for key in [k for k in self.ids if k not in keys]:
            del self.ids[key]


def ticks(rng: random.Random, start_ns: int, end_ns: int, cycle_ms: int,
          phase_us: tuple[int, int], jitter_us: int = 200) -> Iterator[tuple[int, int]]:
    """``(tick_ns, transmit_ns)`` per cycle of a family sent every ``cycle_ms`` from
    ``start_ns`` until ``end_ns``: the nominal measurement time since the start, and the
    absolute transmit time (a phase drawn once from ``phase_us``, plus up to ``jitter_us`` of
    jitter; whole microseconds)."""
    phase = rng.randrange(*phase_us) * US
    cycle = cycle_ms * MS
    k = 0
    while True:
        tick = k * cycle
        if tick >= end_ns - start_ns:
            return
        yield tick, start_ns + phase + tick + rng.randrange(jitter_us) * US
        k += 1


# ---------------------------------------------------------------------------------------------
# One run: what the message families share (timing, randomness, codecs, faults)
# ---------------------------------------------------------------------------------------------


@dataclass
class Run:
    """One run as its message families see it: the world's snapshots, the bus, the seed, the run's
    time span, the codecs, the fault windows, and the object count of the radar's latest cycle (for
    RadarStatus).

    Each family measures at ``k * cycle`` and sends at start + its phase + ``k * cycle`` + jitter, a
    cycle's frames 130 to 169 us apart.
    """

    world: Snapshots
    out: Out
    seed: int
    start_ns: int
    end_ns: int
    duration_s: float
    codecs: dict[str, Codec]
    faults: Faults
    radar_object_count: int = 0  # of the radar's latest cycle, for RadarStatus

    def codec(self, name: str) -> Codec:
        return self.codecs[name]

    def rng(self, family: str) -> random.Random:
        return random.Random(f"tankviz-simulate:{self.seed}:{family}")

    def ticks(self, rng: random.Random, cycle_ms: int, phase_us: tuple[int, int],
              jitter_us: int = 200) -> Iterator[tuple[int, int]]:
        """:func:`ticks` of this run."""
        return ticks(rng, self.start_ns, self.end_ns, cycle_ms, phase_us, jitter_us)

    @staticmethod
    def burst(rng: random.Random, ts: int, count: int) -> list[int]:
        """Transmit times of ``count`` back-to-back frames starting at ``ts``."""
        times = [ts]
        for _ in range(count - 1):
            ts += (130 + rng.randrange(40)) * US
            times.append(ts)
        return times
