"""The scenario of the simulated drive: what happens when, and which faults the bus carries.

Scripted events happen at fixed fractions of the run (:data:`TIMELINE`), so a 10 s and a 60 s run
both contain them: ``lead_braking`` (the lead, 40 m ahead, brakes from 25 to 16 m/s at the window's
start, the ego follows a second later, the gap shrinks to about 25 m and opens again from the
window's end), ``cut_in`` (a car from the right lane changes in between ego and lead within the
window and becomes the lead), ``lane_dropout`` (the camera reports no lanes), ``radar_dropout``
(the radar sends nothing) and ``radar_misalignment`` (every radar detection rotated
:data:`MISALIGNMENT_DEG` clockwise, reported in ``RadarStatus.HorizontMisalignment``). Episodes
are judged on frame timestamps: no radar frame inside the radar dropout, every lane frame inside
the lane dropout says "no lanes".

Scenarios (``simulate(scenario=...)``, :data:`SCENARIOS`): ``drive`` (the default) has the
episodes above; the others have the same traffic and at most one fault, from
:data:`FAULT_ONSET_S` to :data:`FAULT_RECOVERY_S` after the start (``onset <= t < recovery``):
``clean`` (none), ``radar_dropout``, ``radar_yaw`` (misaligned, not reported: stays 0),
``radar_blind`` (every frame, no valid object), ``radar_slow`` (one cycle in
:data:`RADAR_SLOW_EVERY`), ``lane_loss``, ``bus_silent`` (no frame at all) and ``babbling`` (one
``SensorDiag`` frame every :data:`BABBLE_PERIOD_US` us on top of the traffic). The seed never
changes any of this. :func:`fault_windows` gives one run's absolute windows (:class:`Faults`,
``begin <= timestamp_ns < end``; a fault that does not happen has an empty window), under the
fault's name (``radar_yaw`` is ``radar_misalignment`` with ``misalignment_reported`` false,
``lane_loss`` is ``lane_dropout``).
"""

from __future__ import annotations

from dataclasses import dataclass

from bridge.frame import NS

#: The default absolute start time: 2026-01-01T12:00:00Z in integer nanoseconds since the epoch.
DEFAULT_START_NS = 1_767_268_800_000_000_000

#: Radar azimuth misalignment during the misalignment episode (positive = sensor points left).
MISALIGNMENT_DEG = 3.0


@dataclass(frozen=True)
class Episode:
    """A scripted event, placed at fractions of the run: active while start <= t/duration < end."""

    name: str
    start: float
    end: float

    def window_s(self, duration_s: float) -> tuple[float, float]:
        """Seconds since the start of the run: ``(begin, end)``."""
        return self.start * duration_s, self.end * duration_s

    def window_ns(self, duration_s: float, start_ns: int = DEFAULT_START_NS) -> tuple[int, int]:
        """Absolute integer-nanosecond timestamps: ``begin <= timestamp_ns < end``."""
        return (start_ns + round(self.start * duration_s * NS),
                start_ns + round(self.end * duration_s * NS))

    def contains(self, timestamp_ns: int, duration_s: float,
                 start_ns: int = DEFAULT_START_NS) -> bool:
        begin, end = self.window_ns(duration_s, start_ns)
        return begin <= timestamp_ns < end


@dataclass(frozen=True)
class Timeline:
    """When each scripted event of :func:`~bridge.sim.ecocar.simulate` happens (fractions of the
    duration).

    - ``lead_braking``: the lead brakes hard at the start; the gap shrinks from 40 m to about
      25 m; at the end the lead speeds up again (the ego follows, the gap opens to about 37 m).
    - ``lane_dropout``: every camera lane frame inside says "no lanes" (Source/Quality none).
    - ``cut_in``: the right-lane car starts its lane change at the start and is inside the ego
      lane (and the lead vehicle) well before the end, for the rest of the drive.
    - ``radar_dropout``: no radar frame (header, objects, status) has a timestamp inside.
    - ``radar_misalignment``: radar objects inside are rotated by :data:`MISALIGNMENT_DEG`
      clockwise and ``RadarStatus.HorizontMisalignment`` reports it (0 outside).
    """

    lead_braking: Episode = Episode("lead_braking", 0.10, 0.35)
    lane_dropout: Episode = Episode("lane_dropout", 0.40, 0.50)
    cut_in: Episode = Episode("cut_in", 0.45, 0.70)
    radar_dropout: Episode = Episode("radar_dropout", 0.60, 0.65)
    radar_misalignment: Episode = Episode("radar_misalignment", 0.75, 0.85)

    def episodes(self) -> tuple[Episode, ...]:
        return (self.lead_braking, self.lane_dropout, self.cut_in, self.radar_dropout,
                self.radar_misalignment)


#: The scenario's timeline; tests and health monitoring check against it.
TIMELINE = Timeline()

#: When the fault of a fault scenario starts and ends, in seconds since the start of the run, and
#: the duration the scenarios are made for (a shorter run ends inside the fault).
FAULT_ONSET_S = 6.0
FAULT_RECOVERY_S = 11.0
SCENARIO_DURATION_S = 16.0

#: ``radar_slow``: the radar sends one cycle in this many (a third of its rate).
RADAR_SLOW_EVERY = 3
#: ``babbling``: the stuck gateway's repetition period (1 kHz), on top of the normal traffic.
BABBLE_PERIOD_US = 1000


@dataclass(frozen=True)
class Scenario:
    """A named scenario of :func:`~bridge.sim.ecocar.simulate` and when its fault happens
    (seconds since the start of the run)."""

    name: str
    description: str
    #: The fault's start and end (None: no fault); frames with ``onset <= t < recovery``.
    onset_s: float | None = None
    recovery_s: float | None = None
    #: The run length the scenario is made for.
    duration_s: float = SCENARIO_DURATION_S

    def window_ns(self, start_ns: int = DEFAULT_START_NS) -> tuple[int, int] | None:
        """The fault as absolute timestamps ``(onset, recovery)``, or None without a fault."""
        if self.onset_s is None or self.recovery_s is None:
            return None
        return start_ns + round(self.onset_s * NS), start_ns + round(self.recovery_s * NS)


def _fault(name: str, description: str) -> Scenario:
    return Scenario(name, description, FAULT_ONSET_S, FAULT_RECOVERY_S)


#: Every scenario by name; ``drive`` is the default.
SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("drive", "the scripted drive with every TIMELINE episode (the sample log)", None,
             None, 10.0),
    Scenario("clean", "the same traffic without any fault: no lane dropout, no radar episode",
             None, None, 20.0),
    _fault("radar_dropout", "the radar sends nothing"),
    _fault("radar_yaw", f"the radar points {MISALIGNMENT_DEG:g} degrees left and does not know"),
    _fault("radar_blind", "the radar sends every frame but reports no valid object"),
    _fault("radar_slow", f"the radar sends one cycle in {RADAR_SLOW_EVERY}"),
    _fault("lane_loss", "the camera reports no lanes"),
    _fault("bus_silent", "no frame at all on the bus"),
    _fault("babbling", "a stuck gateway floods the bus with one SensorDiag frame"),
)}

#: A window no timestamp is in (an absent fault).
_NEVER = (-(1 << 62), -(1 << 62))


@dataclass(frozen=True)
class Faults:
    """The fault windows of one run (absolute timestamps, ``begin <= t < end``)."""

    lane_dropout: tuple[int, int] = _NEVER
    radar_dropout: tuple[int, int] = _NEVER
    radar_misalignment: tuple[int, int] = _NEVER
    #: when RadarStatus and SensorDiag report the misalignment
    misalignment_reported: tuple[int, int] = _NEVER
    radar_blind: tuple[int, int] = _NEVER
    radar_slow: tuple[int, int] = _NEVER
    bus_silent: tuple[int, int] = _NEVER
    babbling: tuple[int, int] = _NEVER


def fault_windows(scenario: Scenario, duration_s: float, start_ns: int) -> Faults:
    """The fault windows of ``scenario`` in a run of ``duration_s`` from ``start_ns``."""
    if scenario.name == "drive":
        misaligned = TIMELINE.radar_misalignment.window_ns(duration_s, start_ns)
        return Faults(lane_dropout=TIMELINE.lane_dropout.window_ns(duration_s, start_ns),
                      radar_dropout=TIMELINE.radar_dropout.window_ns(duration_s, start_ns),
                      radar_misalignment=misaligned, misalignment_reported=misaligned)
    window = scenario.window_ns(start_ns)
    if window is None:
        return Faults()
    field_name = {"radar_yaw": "radar_misalignment", "lane_loss": "lane_dropout"}.get(
        scenario.name, scenario.name)
    return Faults(**{field_name: window})
