"""A deterministic scenario engine: realistic CAN traffic of the ecocar test vehicle.

:func:`simulate` yields, in non-decreasing timestamp order, every frame the car's bus would carry,
each family at its DBC cycle time with phases, jitter, counters, checksums and noise. The same
``seed`` gives byte-identical frames, and never changes the scenario (:mod:`bridge.sim.scenario`).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterator

import cantools

from bridge.frame import NS, Frame
from bridge.sim.camera import LANES, camera
from bridge.sim.ego import driver_inputs, ego_motion, ego_position, steering
from bridge.sim.frames import Codec, Out, Run, default_database
from bridge.sim.fusion import fusion
from bridge.sim.gateway import babbler, diagnostics
from bridge.sim.radar import radar, radar_status
from bridge.sim.scenario import DEFAULT_START_NS, SCENARIOS, fault_windows
from bridge.sim.sensors import Snapshots

#: Every message the simulator sends.
_MESSAGES = (
    "EgoMotion", "Steering", "DriverInputs", "EgoPosition", "RadarHeader", "RadarStatus",
    *(f"RadarObj{i}_{part}" for i in range(32) for part in "AB"),
    *(f"CamObstacle{i}_{part}" for i in range(10) for part in "AB"),
    *(name for name, _, _, _ in LANES),
    *(f"FusionTrack{i}" for i in range(20)), "LeadVehicle", "SensorDiag",
)

_FAMILIES = (ego_motion, steering, driver_inputs, ego_position, radar, radar_status,
             camera, fusion, diagnostics)


def simulate(*, duration_s: float, seed: int = 0, start_ns: int = DEFAULT_START_NS,
             bus: str = "can0", database: cantools.database.can.Database | None = None,
             scenario: str = "drive") -> Iterator[Frame]:
    """Frames of a simulated drive, in non-decreasing timestamp order.

    - ``duration_s``: length of the drive in seconds (frames have ``start_ns <= timestamp <
      start_ns + duration``); the scripted events sit at fractions of it (:data:`TIMELINE`).
    - ``seed``: noise, jitter, phases and spurious detections; the same seed gives identical
      frames.
    - ``start_ns``: the timestamp of the first frame (default :data:`DEFAULT_START_NS`).
    - ``bus``: the bus name of every frame (default ``"can0"``).
    - ``database``: the DBC to encode with (default: the bundled ecocar DBC); it must have the
      ecocar messages.
    - ``scenario``: a name in :data:`SCENARIOS` (default ``"drive"``, the scripted drive of the
      sample log); the fault scenarios place their fault at fixed seconds, not fractions
      (:data:`FAULT_ONSET_S`, :data:`FAULT_RECOVERY_S`).

    The data named here live in :mod:`bridge.sim.scenario`.
    """
    if not duration_s > 0 or not math.isfinite(duration_s):
        raise ValueError(f"duration_s must be a positive number of seconds, not {duration_s!r}")
    if scenario not in SCENARIOS:
        raise ValueError(f"no scenario {scenario!r}; one of {', '.join(SCENARIOS)}")
    db = database if database is not None else default_database()
    codecs = {name: Codec(db, name) for name in _MESSAGES}
    run = Run(Snapshots(duration_s), Out(bus), seed, start_ns,
              start_ns + round(duration_s * NS), duration_s, codecs,
              fault_windows(SCENARIOS[scenario], duration_s, start_ns))
    families = [family(run) for family in _FAMILIES]
    if scenario == "babbling":
        families.append(babbler(run))
    frames: Iterator[Frame] = heapq.merge(*families)
    silent = run.faults.bus_silent
    if scenario == "bus_silent":
        frames = (f for f in frames if not silent[0] <= f.timestamp_ns < silent[1])
    return frames
