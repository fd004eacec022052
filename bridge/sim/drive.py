"""A deterministic scenario engine: realistic CAN traffic of the ecocar test vehicle.

:func:`simulate` drives the ego car along a gently S-curved three-lane road (plus one oncoming
lane) and yields, in time order, every frame the car's bus would carry: radar objects and status,
camera obstacles and lanes, fusion tracks, the lead vehicle, ego motion, steering, driver inputs,
GNSS position and diagnostics, each message family at its DBC cycle time, with small per-family
phase offsets, a little timing jitter, rolling counters, checksums and measurement noise. Every
payload is encoded with cantools against the bundled DBC (:func:`load_ecocar`).

The same ``seed`` gives byte-identical frames; the seed changes noise, jitter, phases, counter
start values and the spurious radar detections, never the scenario itself. Scripted events happen
at fixed fractions of the run (:data:`TIMELINE`), so a 10 s and a 60 s run both contain them:

- ``lead_braking``: the lead vehicle (40 m ahead in the ego lane) brakes hard from 25 to 16 m/s at
  the start of the window, the ego (ACC) follows a second later and the gap shrinks to about 25 m;
  from the end of the window the lead speeds up again and the gap opens.
- ``cut_in``: a car from the right neighbour lane changes into the ego lane between ego and lead
  (lane change starts at the window start, done before its end) and becomes the lead vehicle.
- ``lane_dropout``: the camera reports no lanes (``Source`` none, ``Quality`` none, coefficients 0).
- ``radar_dropout``: the radar sends nothing (no header, objects or status).
- ``radar_misalignment``: the radar points :data:`MISALIGNMENT_DEG` to the left: every radar
  detection is rotated by that angle clockwise (appears further right) and
  ``RadarStatus.HorizontMisalignment`` reports it.

Geometry: everything is placed in the ego vehicle frame (x forward, y left, origin at the front
bumper, where radar and camera are mounted: no mounting offsets). Lanes are 3.6 m wide: ego lane
centre y=0, left neighbour +3.6, right neighbour -3.6, oncoming lane +7.2. The camera reports y
positive RIGHT (as its DBC comments say), radar, fusion and lead vehicle y positive LEFT.

Episodes are judged on frame timestamps (``Episode.window_ns``): no radar frame has a timestamp
inside the radar dropout, every lane frame inside the lane dropout says "no lanes". The moving
scenario itself is evaluated at each family's nominal cycle tick (its measurement time).

Scenarios (``simulate(scenario=...)``, :data:`SCENARIOS`): ``drive`` (the default) is the drive
above with its episodes. The others are the same traffic (lead braking, cut-in) with at most one
sensor or bus fault, from :data:`FAULT_ONSET_S` to :data:`FAULT_RECOVERY_S` seconds after the
start (timestamps ``onset <= t < recovery``, see :meth:`Scenario.window_ns`), for the health
monitor to catch: ``clean`` has no fault at all (no lane dropout, no radar episode);
``radar_dropout`` (the radar sends nothing), ``radar_yaw`` (the radar is knocked
:data:`MISALIGNMENT_DEG` to the left and does not know it: ``HorizontMisalignment`` stays 0),
``radar_blind`` (the radar sends every frame, but no valid object), ``radar_slow`` (the radar
sends one cycle in :data:`RADAR_SLOW_EVERY`), ``lane_loss`` (the camera reports no lanes),
``bus_silent`` (no frame at all on the bus) and ``babbling`` (a stuck gateway floods the bus with
one ``SensorDiag`` frame every :data:`BABBLE_PERIOD_US` microseconds, on top of the traffic).
"""

from __future__ import annotations

import functools
import heapq
import math
import random
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass

import cantools

from bridge.frame import NS, Frame
from bridge.resources import data_dir

#: The default absolute start time: 2026-01-01T12:00:00Z in integer nanoseconds since the epoch.
DEFAULT_START_NS = 1_767_268_800_000_000_000

#: Ego bicycle model: wheelbase (m) and steering ratio (steering wheel angle / road wheel angle).
WHEELBASE_M = 2.8
STEERING_RATIO = 15.0

#: Road layout: lane width and the lateral centre of each lane (ego frame, y positive left).
LANE_WIDTH_M = 3.6
EGO_LANE_Y = 0.0
LEFT_LANE_Y = LANE_WIDTH_M
RIGHT_LANE_Y = -LANE_WIDTH_M
ONCOMING_LANE_Y = 2 * LANE_WIDTH_M

#: The ego cruise speed (m/s), the lead vehicle's initial gap (m), how much lead and ego slow down.
EGO_SPEED_MPS = 25.0
LEAD_GAP_M = 40.0
LEAD_SPEED_DROP_MPS = 9.0

#: The road: curvature (1/m) = ROAD_CURVATURE * sin(2*pi*(s + ROAD_PHASE_M) / ROAD_WAVELENGTH_M).
ROAD_CURVATURE = 1.0 / 400.0
ROAD_WAVELENGTH_M = 700.0
ROAD_PHASE_M = 0.35 * ROAD_WAVELENGTH_M

#: Radar azimuth misalignment during the misalignment episode (positive = sensor points left).
MISALIGNMENT_DEG = 3.0

#: Radar object classes (DBC value table of RadarObj*_B.Class and FusionTrack*.Class).
CLASS_UNKNOWN, CLASS_FOUR_WHEEL, CLASS_TWO_WHEEL, CLASS_PEDESTRIAN, CLASS_STATIONARY = range(5)

# Camera obstacle types (CamObstacle*_A.Type); -1: the camera does not report the object.
_CAM_VEHICLE, _CAM_TRUCK, _CAM_BIKE, _CAM_PEDESTRIAN, _CAM_BICYCLE = 0, 1, 2, 3, 4
_CAM_NONE = -1

_US = 1_000
_MS = 1_000_000


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
    """When each scripted event of :func:`simulate` happens (fractions of the duration).

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
    """A named scenario of :func:`simulate` and when its fault happens (seconds since start)."""

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
class _Faults:
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


def _faults(scenario: Scenario, duration_s: float, start_ns: int) -> _Faults:
    if scenario.name == "drive":
        misaligned = TIMELINE.radar_misalignment.window_ns(duration_s, start_ns)
        return _Faults(lane_dropout=TIMELINE.lane_dropout.window_ns(duration_s, start_ns),
                       radar_dropout=TIMELINE.radar_dropout.window_ns(duration_s, start_ns),
                       radar_misalignment=misaligned, misalignment_reported=misaligned)
    window = scenario.window_ns(start_ns)
    if window is None:
        return _Faults()
    field_name = {"radar_yaw": "radar_misalignment", "lane_loss": "lane_dropout"}.get(
        scenario.name, scenario.name)
    return _Faults(**{field_name: window})


def load_ecocar() -> cantools.database.can.Database:
    """The bundled ecocar DBC (``data_dir()/"ecocar.dbc"``), freshly loaded."""
    path = data_dir() / "ecocar.dbc"
    database = cantools.database.load_file(path)
    if not isinstance(database, cantools.database.can.Database):
        raise TypeError(f"{path} is not a CAN database")
    return database


@functools.lru_cache(maxsize=1)
def _default_database() -> cantools.database.can.Database:
    return load_ecocar()


# ---------------------------------------------------------------------------------------------
# Kinematics: smooth ramps with closed-form integrals
# ---------------------------------------------------------------------------------------------


def _ramp(t: float, t0: float, duration: float) -> tuple[float, float, float]:
    """A smoothstep from 0 to 1 over ``[t0, t0 + duration]``: value, derivative, integral."""
    if t <= t0:
        return 0.0, 0.0, 0.0
    u = (t - t0) / duration
    if u >= 1.0:
        return 1.0, 0.0, duration / 2 + (t - t0 - duration)
    return u * u * (3 - 2 * u), 6 * u * (1 - u) / duration, duration * (u**3 - u**4 / 2)


@dataclass(frozen=True)
class _Ego:
    s: float  # distance along the road (m)
    v: float  # speed (m/s)
    a: float  # longitudinal acceleration (m/s^2)
    d: float  # lateral offset from the ego lane centre (m, left)
    psi: float  # heading relative to the road (rad, left)
    kappa: float  # path curvature (1/m, left)
    cos_phi: float  # road phase at the ego, for the road geometry ahead
    sin_phi: float


class _Scenario:
    """The scripted world as pure functions of time (seconds since the start of the run)."""

    def __init__(self, duration_s: float) -> None:
        self.duration = duration_s
        self.t_brake = TIMELINE.lead_braking.start * duration_s
        self.t_accel = TIMELINE.lead_braking.end * duration_s
        self.t_cut = TIMELINE.cut_in.start * duration_s
        self.cut_duration = min(3.0, 0.8 * (TIMELINE.cut_in.end - TIMELINE.cut_in.start)
                                * duration_s)
        self.omega = 2 * math.pi / ROAD_WAVELENGTH_M

    # The ego ACC reacts a second after the lead brakes and follows it back up later.
    def ego(self, t: float) -> _Ego:
        r1, dr1, i1 = _ramp(t, self.t_brake + 1.0, 3.0)
        r2, dr2, i2 = _ramp(t, self.t_accel + 1.2, 4.0)
        drop = LEAD_SPEED_DROP_MPS
        v = EGO_SPEED_MPS - drop * r1 + drop * r2
        a = -drop * dr1 + drop * dr2
        s = EGO_SPEED_MPS * t - drop * i1 + drop * i2
        # A little lane wander: offset, lateral speed and lateral acceleration.
        w1, w2 = 2 * math.pi / 8.3, 2 * math.pi / 3.7
        d = 0.10 * math.sin(w1 * t) + 0.015 * math.sin(w2 * t)
        d_dot = 0.10 * w1 * math.cos(w1 * t) + 0.015 * w2 * math.cos(w2 * t)
        d_ddot = -0.10 * w1 * w1 * math.sin(w1 * t) - 0.015 * w2 * w2 * math.sin(w2 * t)
        phi = self.omega * (s + ROAD_PHASE_M)
        kappa = ROAD_CURVATURE * math.sin(phi) + d_ddot / (v * v)
        return _Ego(s, v, a, d, d_dot / v, kappa, math.cos(phi), math.sin(phi))

    def lead_gap(self, t: float) -> float:
        """Distance along the road from ego to the lead vehicle."""
        _, _, i1 = _ramp(t, self.t_brake, 1.5)
        _, _, i2 = _ramp(t, self.t_accel, 3.5)
        lead = EGO_SPEED_MPS * t - LEAD_SPEED_DROP_MPS * (i1 - i2)
        return LEAD_GAP_M + lead - self.ego(t).s

    def road_y(self, ego: _Ego, u: float) -> float:
        """Lateral position of the ego lane centre ``u`` metres ahead, in the road frame at the
        ego (small-angle integral of the heading change of the sine-curvature road)."""
        w = self.omega
        k_w = ROAD_CURVATURE / w
        sin_ahead = math.sin(w * u) * ego.cos_phi + math.cos(w * u) * ego.sin_phi
        return k_w * (u * ego.cos_phi - (sin_ahead - ego.sin_phi) / w)

    def to_ego(self, ego: _Ego, ds: float, d: float) -> tuple[float, float]:
        """Road coordinates (distance ahead, lateral offset) to the ego frame (x fwd, y left)."""
        return ds, self.road_y(ego, ds) + d - ego.d - ego.psi * ds


# ---------------------------------------------------------------------------------------------
# Actors
# ---------------------------------------------------------------------------------------------

Place = Callable[[float, float], tuple[float, float]]  # (t, ego s) -> (ds unwrapped, d)


@dataclass(frozen=True)
class _Actor:
    name: str
    radar_class: int
    camera_type: int
    length: float
    width: float
    rcs: float
    place: Place
    loop_m: float = math.inf  # traffic streams wrap around the ego: ds in [-loop/2, loop/2)


def _stream(s0: float, speed: float, d: float, wander: float = 0.0) -> Place:
    def place(t: float, s_ego: float) -> tuple[float, float]:
        return s0 + speed * t - s_ego, d + wander * math.sin(0.7 * t + s0)

    return place


def _actors(sc: _Scenario) -> list[_Actor]:
    def lead(t: float, s_ego: float) -> tuple[float, float]:
        return sc.lead_gap(t), 0.08 * math.sin(2 * math.pi * t / 5.1)

    def cut_in(t: float, s_ego: float) -> tuple[float, float]:
        ds = 6.0 + 12.0 * math.tanh((t - sc.t_cut) / 4.0)
        r, _, _ = _ramp(t, sc.t_cut, sc.cut_duration)
        return ds, RIGHT_LANE_Y + LANE_WIDTH_M * r

    def pedestrian(t: float, s_ego: float) -> tuple[float, float]:
        return 95.0 + 1.3 * t - s_ego, -6.6 + 0.25 * math.sin(0.5 * t)

    actors = [
        _Actor("lead", CLASS_FOUR_WHEEL, _CAM_VEHICLE, 4.7, 1.85, 12.0, lead),
        _Actor("cut_in", CLASS_FOUR_WHEEL, _CAM_VEHICLE, 4.4, 1.8, 10.0, cut_in),
        _Actor("left_car", CLASS_FOUR_WHEEL, _CAM_VEHICLE, 4.5, 1.8, 10.0,
               _stream(22.0, 27.5, LEFT_LANE_Y, 0.1), 360.0),
        _Actor("left_truck", CLASS_FOUR_WHEEL, _CAM_TRUCK, 12.0, 2.5, 22.0,
               _stream(202.0, 27.5, LEFT_LANE_Y, 0.1), 360.0),
        _Actor("oncoming_car", CLASS_FOUR_WHEEL, _CAM_VEHICLE, 4.6, 1.8, 10.0,
               _stream(150.0, -23.0, ONCOMING_LANE_Y, 0.1), 700.0),
        _Actor("oncoming_van", CLASS_FOUR_WHEEL, _CAM_TRUCK, 6.0, 2.1, 15.0,
               _stream(500.0, -22.0, ONCOMING_LANE_Y, 0.1), 700.0),
        _Actor("cyclist", CLASS_TWO_WHEEL, _CAM_BICYCLE, 1.8, 0.6, 0.0,
               _stream(70.0, 6.0, -5.9, 0.15), 900.0),
        _Actor("pedestrian", CLASS_PEDESTRIAN, _CAM_PEDESTRIAN, 0.5, 0.6, -8.0, pedestrian,
               800.0),
    ]
    for i in range(4):  # guard-rail posts beyond the oncoming lane
        actors.append(_Actor(f"post{i}", CLASS_STATIONARY, _CAM_NONE, 0.3, 0.3, 6.0,
                             _stream(30.0 + 50.0 * i, 0.0, 9.8), 200.0))
    return actors


# Sensor coverage: (max range by radar class, half field of view in degrees, minimum x).
_RADAR_RANGE = {CLASS_FOUR_WHEEL: 200.0, CLASS_TWO_WHEEL: 120.0, CLASS_PEDESTRIAN: 100.0,
                CLASS_STATIONARY: 120.0, CLASS_UNKNOWN: 120.0}
_RADAR_FOV = math.radians(60.0)
_CAMERA_RANGE = {CLASS_FOUR_WHEEL: 120.0, CLASS_TWO_WHEEL: 80.0, CLASS_PEDESTRIAN: 80.0}
_CAMERA_FOV = math.radians(50.0)


class _Seen:
    """One actor at one instant, in the ego frame (true values, no noise)."""

    __slots__ = ("a_abs", "actor", "ax", "camera", "d", "key", "radar", "range", "v_abs", "vx",
                 "vy", "x", "y")

    def __init__(self, key: Hashable, actor: _Actor, x: float, y: float, vx: float, vy: float,
                 ax: float, d: float, v_abs: float, a_abs: float) -> None:
        self.key = key
        self.actor = actor
        self.x, self.y, self.vx, self.vy, self.ax = x, y, vx, vy, ax
        self.d, self.v_abs, self.a_abs = d, v_abs, a_abs
        self.range = math.hypot(x, y)
        azimuth = abs(math.atan2(y, x))
        cls = actor.radar_class
        self.radar = x > 0.5 and azimuth <= _RADAR_FOV and self.range <= _RADAR_RANGE[cls]
        self.camera = (actor.camera_type != _CAM_NONE and x > 2.0 and azimuth <= _CAMERA_FOV
                       and self.range <= _CAMERA_RANGE.get(cls, 0.0))


@dataclass(frozen=True)
class _Snapshot:
    t: float
    ego: _Ego
    objects: list[_Seen]


class _World:
    """Snapshots of the scenario at measurement times, cached for the families that share them."""

    _H = 0.05  # step of the central differences (s)

    def __init__(self, duration_s: float) -> None:
        self.scenario = _Scenario(duration_s)
        self.actors = _actors(self.scenario)
        self._cache: dict[int, _Snapshot] = {}

    def at(self, tick_ns: int) -> _Snapshot:
        snap = self._cache.get(tick_ns)
        if snap is None:
            snap = self._compute(tick_ns / NS)
            if len(self._cache) > 16:
                del self._cache[next(iter(self._cache))]
            self._cache[tick_ns] = snap
        return snap

    def _compute(self, t: float) -> _Snapshot:
        sc, h = self.scenario, self._H
        egos = (sc.ego(t - h), sc.ego(t), sc.ego(t + h))
        ego = egos[1]
        seen = []
        for index, actor in enumerate(self.actors):
            points = []
            for e, tt in zip(egos, (t - h, t, t + h), strict=True):
                ds, d = actor.place(tt, e.s)
                points.append((ds, d, e))
            ds0, d0, _ = points[1]
            shift, visit = 0.0, 0
            if actor.loop_m != math.inf:
                visit = math.floor((ds0 + actor.loop_m / 2) / actor.loop_m)
                shift = visit * actor.loop_m
            (x_m, y_m), (x, y), (x_p, y_p) = (sc.to_ego(e, ds - shift, d) for ds, d, e in points)
            vx, vy = (x_p - x_m) / (2 * h), (y_p - y_m) / (2 * h)
            ax = (x_p - 2 * x + x_m) / (h * h)
            seen.append(_Seen((index, visit), actor, x, y, vx, vy, ax, d0, ego.v + vx,
                              ego.a + ax))
        return _Snapshot(t, ego, seen)


# ---------------------------------------------------------------------------------------------
# Encoding
# ---------------------------------------------------------------------------------------------


class _Codec:
    """One DBC message: clamps values to the signal ranges, encodes, remembers its counter."""

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


class _Out:
    """Builds frames for one bus."""

    def __init__(self, bus: str) -> None:
        self.bus = bus

    def frame(self, ts: int, codec: _Codec, data: bytes) -> Frame:
        return Frame(ts, self.bus, codec.frame_id, data, False, codec.fd, False, False, codec.fd,
                     False, len(data))


def _checksum(codec: _Codec, values: dict[str, float]) -> bytes:
    """Encode with ``Checksum`` = (byte0 + ... + byte6) & 0xFF, as the DBC comments say."""
    values["Checksum"] = 0
    first = codec.encode(values)
    values["Checksum"] = sum(first[:7]) & 0xFF
    return codec.encode(values)


class _Slots:
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


class _Ids:
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


# ---------------------------------------------------------------------------------------------
# Message families
# ---------------------------------------------------------------------------------------------


@dataclass
class _Run:
    world: _World
    out: _Out
    seed: int
    start_ns: int
    end_ns: int
    duration_s: float
    codecs: dict[str, _Codec]
    faults: _Faults
    radar_object_count: int = 0  # of the radar's latest cycle, for RadarStatus

    def codec(self, name: str) -> _Codec:
        return self.codecs[name]

    def rng(self, family: str) -> random.Random:
        return random.Random(f"tankviz-simulate:{self.seed}:{family}")

    def ticks(self, rng: random.Random, cycle_ms: int, phase_us: tuple[int, int],
              jitter_us: int = 200) -> Iterator[tuple[int, int]]:
        """``(tick_ns, transmit_ns)`` per cycle: the nominal measurement time since the start of
        the run, and the absolute transmit time (phase + jitter, whole microseconds)."""
        phase = rng.randrange(*phase_us) * _US
        cycle = cycle_ms * _MS
        k = 0
        while True:
            tick = k * cycle
            if tick >= self.end_ns - self.start_ns:
                return
            yield tick, self.start_ns + phase + tick + rng.randrange(jitter_us) * _US
            k += 1

    @staticmethod
    def burst(rng: random.Random, ts: int, count: int) -> list[int]:
        """Transmit times of ``count`` back-to-back frames starting at ``ts``."""
        times = [ts]
        for _ in range(count - 1):
            ts += (130 + rng.randrange(40)) * _US
            times.append(ts)
        return times


def _ego_motion(run: _Run) -> Iterator[Frame]:
    rng = run.rng("EgoMotion")
    codec = run.codec("EgoMotion")
    counter = rng.randrange(codec.counter_mod)
    sc = run.world.scenario
    for tick, ts in run.ticks(rng, 10, (0, 1)):
        if tick == 0:
            ts = run.start_ns  # the run starts with this frame, exactly at start_ns
        if ts >= run.end_ns:
            return
        e = sc.ego(tick / NS)
        values: dict[str, float] = {
            "VehicleSpeed": e.v * 3.6 + rng.gauss(0, 0.03),
            "YawRate": math.degrees(e.v * e.kappa) + rng.gauss(0, 0.03),
            "LongAccel": e.a + rng.gauss(0, 0.03),
            "LatAccel": e.v * e.v * e.kappa + rng.gauss(0, 0.05),
            "Counter": counter,
        }
        yield run.out.frame(ts, codec, _checksum(codec, values))
        counter = (counter + 1) % codec.counter_mod


def steering_wheel_angle_deg(curvature: float) -> float:
    """Steering wheel angle (deg, positive left) for a path curvature (1/m, positive left):
    bicycle model with :data:`WHEELBASE_M` and :data:`STEERING_RATIO`."""
    return math.degrees(math.atan(WHEELBASE_M * curvature)) * STEERING_RATIO


def _steering(run: _Run) -> Iterator[Frame]:
    rng = run.rng("Steering")
    codec = run.codec("Steering")
    counter = rng.randrange(codec.counter_mod)
    sc = run.world.scenario
    for tick, ts in run.ticks(rng, 10, (1000, 4000)):
        if ts >= run.end_ns:
            return
        t = tick / NS
        e = sc.ego(t)
        angle = steering_wheel_angle_deg(e.kappa)
        rate = (steering_wheel_angle_deg(sc.ego(t + 0.01).kappa) - angle) / 0.01
        values: dict[str, float] = {
            "SteeringWheelAngle": angle + rng.gauss(0, 0.1),
            "SteeringWheelRate": rate + rng.gauss(0, 0.3),
            "DriverTorque": 0.35 * e.v * e.v * e.kappa + rng.gauss(0, 0.05),
            "AngleValid": 1,
            "RateValid": 1,
            "Counter": counter,
        }
        yield run.out.frame(ts, codec, _checksum(codec, values))
        counter = (counter + 1) % codec.counter_mod


def _driver_inputs(run: _Run) -> Iterator[Frame]:
    rng = run.rng("DriverInputs")
    codec = run.codec("DriverInputs")
    counter = rng.randrange(codec.counter_mod)
    sc = run.world.scenario
    for tick, ts in run.ticks(rng, 20, (4000, 9000)):
        if ts >= run.end_ns:
            return
        e = sc.ego(tick / NS)
        pressure = max(0.0, -e.a) * 12.0
        values: dict[str, float] = {
            "Gear": 3,  # D
            "TurnSignal": 0,
            "BrakePedalPressed": 0,
            "AccMainSwitch": 1,
            "AccCancel": 0,
            "AccelPedalPosition": 0,
            "BrakePressure": pressure + abs(rng.gauss(0, 0.2)) if pressure > 0.5 else 0,
            "AccGapSetting": 2,
            "AccSetSpeed": 90,
            "Counter": counter,
        }
        yield run.out.frame(ts, codec, codec.encode(values))
        counter = (counter + 1) % codec.counter_mod


# A start position and heading for the GNSS track (a test track near Ann Arbor, MI).
_ORIGIN_LAT, _ORIGIN_LON, _ORIGIN_HEADING = 42.2995, -83.6990, math.radians(30.0)


def _ego_position(run: _Run) -> Iterator[Frame]:
    rng = run.rng("EgoPosition")
    codec = run.codec("EgoPosition")
    sc = run.world.scenario
    east = north = 0.0
    last_s = 0.0
    m_per_deg_lat = 111_320.0
    m_per_deg_lon = m_per_deg_lat * math.cos(math.radians(_ORIGIN_LAT))
    k_w = ROAD_CURVATURE / sc.omega
    for tick, ts in run.ticks(rng, 100, (30_000, 60_000)):
        if ts >= run.end_ns:
            return
        e = sc.ego(tick / NS)
        mid = (last_s + e.s) / 2  # heading of a sine-curvature road at the step's midpoint
        heading = _ORIGIN_HEADING - k_w * (math.cos(sc.omega * (mid + ROAD_PHASE_M))
                                           - math.cos(sc.omega * ROAD_PHASE_M))
        east += (e.s - last_s) * math.sin(heading)
        north += (e.s - last_s) * math.cos(heading)
        last_s = e.s
        values: dict[str, float] = {
            "Latitude": _ORIGIN_LAT + (north + rng.gauss(0, 0.3)) / m_per_deg_lat,
            "Longitude": _ORIGIN_LON + (east + rng.gauss(0, 0.3)) / m_per_deg_lon,
        }
        yield run.out.frame(ts, codec, codec.encode(values))


def _quantize_prob(value: float) -> float:
    return round(value / 3.125) * 3.125


def _moving_state(seen: _Seen) -> int:
    if seen.actor.radar_class == CLASS_STATIONARY:
        return 4  # standing
    if seen.v_abs < -1.0:
        return 2  # oncoming
    return 1 if abs(seen.v_abs) > 0.5 else 3  # moving / stopped


@dataclass(frozen=True)
class _Ghost:
    key: Hashable
    t0: float
    t1: float
    x: float
    y: float
    prob: float


def _ghosts(run: _Run) -> list[_Ghost]:
    """Spurious radar detections: short-lived, low existence probability, random places."""
    rng = run.rng("ghosts")
    count = max(6, round(1.2 * run.duration_s))
    ghosts = []
    for j in range(count):
        t0 = rng.uniform(0.0, run.duration_s)
        ghosts.append(_Ghost(("ghost", j), t0, t0 + rng.uniform(0.3, 1.2),
                             rng.uniform(8.0, 90.0), rng.uniform(-14.0, 14.0),
                             rng.choice([6.25, 9.375, 12.5, 15.625, 18.75, 21.875, 25.0, 28.125])))
    return ghosts


# A sensor pointing MISALIGNMENT_DEG to the left sees the world rotated clockwise by that angle.
_MISALIGNED_COS = math.cos(math.radians(-MISALIGNMENT_DEG))
_MISALIGNED_SIN = math.sin(math.radians(-MISALIGNMENT_DEG))


def _radar(run: _Run) -> Iterator[Frame]:
    """RadarHeader (CAN-FD) then RadarObj0..31 A and B every 50 ms."""
    rng = run.rng("Radar")
    header = run.codec("RadarHeader")
    objs = [(run.codec(f"RadarObj{i}_A"), run.codec(f"RadarObj{i}_B")) for i in range(32)]
    counter = rng.randrange(16)
    cycle_counter = rng.randrange(65536)
    power_up_us = rng.randrange(60_000_000, 900_000_000)
    ghosts = sorted(_ghosts(run), key=lambda g: g.t0)
    next_ghost = 0
    active: list[_Ghost] = []
    slots = _Slots(32)
    age: dict[Hashable, int] = {}
    empty_cache: dict[tuple[int, int], bytes] = {}
    faults = run.faults
    dropout = faults.radar_dropout
    misaligned = faults.radar_misalignment
    blind, slow = faults.radar_blind, faults.radar_slow
    n_frames = 1 + 2 * len(objs)
    for tick, ts in run.ticks(rng, 50, (2000, 8000), 300):
        times = run.burst(rng, ts, n_frames)
        if times[0] >= run.end_ns:
            return
        if times[0] < dropout[1] and times[-1] >= dropout[0]:
            slots.clear()  # the radar restarts its tracker after the outage
            age.clear()
            continue
        if slow[0] <= times[0] < slow[1] and (tick // (50 * _MS)) % RADAR_SLOW_EVERY:
            continue
        snap = run.world.at(tick)
        t = snap.t
        ego = snap.ego
        # Measurements: (key, x, y, vx, vy, ax, seen or None, prob)
        detections: list[tuple[Hashable, float, float, float, float, float, _Seen | None,
                               float]] = []
        for o in snap.objects:
            if o.radar:
                detections.append((o.key, o.x, o.y, o.vx, o.vy, o.ax, o, 0.0))
        while next_ghost < len(ghosts) and ghosts[next_ghost].t0 <= t:
            active.append(ghosts[next_ghost])
            next_ghost += 1
        active = [g for g in active if t < g.t1]
        for g in active:  # ground clutter: it stays where it is while the ego passes
            if rng.random() < 0.6:
                x = g.x - ego.v * (t - g.t0)
                if x > 1.0:
                    detections.append((g.key, x, g.y, -ego.v, 0.0, 0.0, None, g.prob))
        detections.sort(key=lambda m: (m[6] is None, m[1] * m[1] + m[2] * m[2]))
        by_key = {m[0]: m for m in detections}
        owners = slots.assign([m[0] for m in detections])
        if blind[0] <= times[0] < blind[1]:
            owners = [None] * len(objs)  # blocked: every slot reports "no object"
        for key in [k for k in age if k not in by_key]:
            del age[key]
        rotate = misaligned[0] <= times[0] < misaligned[1]
        ca, sa = _MISALIGNED_COS, _MISALIGNED_SIN
        mask = 0
        frames: list[tuple[_Codec, bytes]] = []
        for slot, (codec_a, codec_b) in enumerate(objs):
            key = owners[slot]
            if key is None:
                for codec in (codec_a, codec_b):
                    cache_key = (codec.frame_id, counter)
                    data = empty_cache.get(cache_key)
                    if data is None:
                        values: dict[str, float] = {s.name: 0 for s in codec.message.signals}
                        values["Counter"] = counter
                        data = empty_cache[cache_key] = codec.encode(values)
                    frames.append((codec, data))
                continue
            mask |= 1 << slot
            _, x, y, vx, vy, ax, seen, prob = by_key[key]
            n = age[key] = age.get(key, 0) + 1
            r = math.hypot(x, y)
            x += rng.gauss(0, 0.08 + 0.0015 * r)
            y += rng.gauss(0, 0.08 + 0.0026 * r)
            vx += rng.gauss(0, 0.06)
            vy += rng.gauss(0, 0.15)
            ax += rng.gauss(0, 0.1)
            if rotate:
                x, y = x * ca - y * sa, x * sa + y * ca
                vx, vy = vx * ca - vy * sa, vx * sa + vy * ca
            if seen is None:  # a ghost
                cls, prob_class, moving, rcs = CLASS_UNKNOWN, 25.0, 0, -12.0
                length, width, obstacle = 0.5, 0.5, 9.375
            else:
                actor = seen.actor
                prob = 84.375 if n < 3 else _quantize_prob(rng.uniform(90.0, 96.875))
                cls, moving, rcs = actor.radar_class, _moving_state(seen), actor.rcs
                prob_class = _quantize_prob(rng.uniform(75.0, 96.875))
                length, width = actor.length, actor.width
                obstacle = 40.625 if cls == CLASS_STATIONARY else 90.625
            frames.append((codec_a, codec_a.encode({
                "LongDist": x, "LongSpeed": vx, "LatDist": y, "ProbExist": prob,
                "LongAccel": ax, "Valid": 1, "Meas": 0 if rng.random() < 0.04 else 1,
                "Tracked": 1 if n >= 3 else 0, "ProbObstacle": obstacle, "Counter": counter})))
            frames.append((codec_b, codec_b.encode({
                "LatSpeed": vy, "Length": length, "Width": width, "MovingState": moving,
                "ProbClass": prob_class, "Class": cls, "RCS": rcs + rng.gauss(0, 1.5),
                "Counter": counter})))
        run.radar_object_count = bin(mask).count("1")
        head = header.encode({
            "CycleCounter": cycle_counter, "ObjectCount": run.radar_object_count, "RadarMode": 1,
            "Timestamp": (power_up_us + tick // _US) % 2**32,
            "EgoSpeedUsed": ego.v + rng.gauss(0, 0.02),
            "EgoYawRateUsed": math.degrees(ego.v * ego.kappa) + rng.gauss(0, 0.03),
            "ObjValidMask": mask, "Latency": 22.0 + rng.uniform(0.0, 6.0)})
        out = run.out
        yield out.frame(times[0], header, head)
        for when, (codec, data) in zip(times[1:], frames, strict=True):
            if when >= run.end_ns:
                return
            yield out.frame(when, codec, data)
        counter = (counter + 1) % 16
        cycle_counter = (cycle_counter + 1) % 65536


def _radar_status(run: _Run) -> Iterator[Frame]:
    rng = run.rng("RadarStatus")
    codec = run.codec("RadarStatus")
    counter = rng.randrange(codec.counter_mod)
    dropout = run.faults.radar_dropout
    misaligned = run.faults.misalignment_reported
    for tick, ts in run.ticks(rng, 100, (40_000, 60_000)):
        if ts >= run.end_ns:
            return
        if dropout[0] <= ts < dropout[1]:
            continue
        t = tick / NS
        bias = MISALIGNMENT_DEG if misaligned[0] <= ts < misaligned[1] else 0.0
        restarting = dropout[1] <= ts < dropout[1] + 300 * _MS
        values: dict[str, float] = {
            "HorizontMisalignment": bias + rng.choice((-0.05, 0.0, 0.0, 0.05)),
            "VerticalMisalignment": rng.choice((0.0, 0.1)),
            "SensorDirty": 0, "HWFail": 0, "Blocked": 0, "AlignmentInProgress": 0,
            "Interference": 0,
            "RadarState": 0 if restarting else 1,  # init after the outage, else ok
            "Temperature": 41.0 + 0.02 * t,
            "ObjectCount": 0 if restarting else run.radar_object_count,
            "Counter": counter,
        }
        yield run.out.frame(ts, codec, codec.encode(values))
        counter = (counter + 1) % codec.counter_mod


def _lane_fit_matrix(xs: list[float]) -> list[list[float]]:
    """The least-squares cubic fit y(x) = c0 + c1 x + c2 x^2 + c3 x^3 as a 4 x n matrix."""
    a = [[x**p for p in range(4)] for x in xs]
    ata = [[sum(row[i] * row[j] for row in a) for j in range(4)] for i in range(4)]
    inverse = [[float(i == j) for j in range(4)] for i in range(4)]
    for col in range(4):  # Gauss-Jordan
        pivot = ata[col][col]
        ata[col] = [v / pivot for v in ata[col]]
        inverse[col] = [v / pivot for v in inverse[col]]
        for row in range(4):
            if row != col:
                f = ata[row][col]
                ata[row] = [v - f * w for v, w in zip(ata[row], ata[col], strict=True)]
                inverse[row] = [v - f * w for v, w in zip(inverse[row], inverse[col], strict=True)]
    return [[sum(inverse[i][k] * a[n][k] for k in range(4)) for n in range(len(xs))]
            for i in range(4)]


_LANE_XS = [5.0 * i for i in range(17)]  # 0..80 m
_LANE_FIT = _lane_fit_matrix(_LANE_XS)

# Camera lane lines: (message, offset of the line from the ego lane centre (left), type, range).
_LANES = (("CamLaneLeft", LANE_WIDTH_M / 2, 0, 80),
          ("CamLaneRight", -LANE_WIDTH_M / 2, 0, 80),
          ("CamLaneNextLeft", 1.5 * LANE_WIDTH_M, 4, 60),
          ("CamLaneNextRight", -1.5 * LANE_WIDTH_M, 1, 60))


def _camera(run: _Run) -> Iterator[Frame]:
    """CamObstacle0..9 A and B, then the four lane lines, every 66 ms."""
    rng = run.rng("Camera")
    obstacles = [(run.codec(f"CamObstacle{i}_A"), run.codec(f"CamObstacle{i}_B"))
                 for i in range(10)]
    lanes = [(run.codec(name), offset, kind, view) for name, offset, kind, view in _LANES]
    counter = rng.randrange(16)
    lane_counter = rng.randrange(4)
    slots = _Slots(10)
    ids = _Ids(rng.randrange(1, 200))
    age: dict[Hashable, int] = {}
    dropout = run.faults.lane_dropout
    sc = run.world.scenario
    n_frames = 2 * len(obstacles) + len(lanes)
    for tick, ts in run.ticks(rng, 66, (0, 20_000)):
        times = run.burst(rng, ts, n_frames)
        if times[0] >= run.end_ns:
            return
        snap = run.world.at(tick)
        t = snap.t
        visible = sorted((s for s in snap.objects if s.camera), key=lambda s: s.range)[:10]
        by_key = {s.key: s for s in visible}
        owners = slots.assign([s.key for s in visible])
        ids.retain(set(by_key))
        for key in [k for k in age if k not in by_key]:
            del age[key]
        frames: list[tuple[_Codec, bytes]] = []
        for slot, (codec_a, codec_b) in enumerate(obstacles):
            key = owners[slot]
            if key is None:
                frames.append((codec_a, codec_a.encode({
                    "ObstacleID": 0, "PosX": 0, "PosY": 0, "RelVelX": 0, "Type": 0, "Status": 0,
                    "Valid": 0, "BrakeLights": 0, "CutInOut": 0, "Blinker": 0,
                    "Counter": counter})))
                frames.append((codec_b, codec_b.encode({
                    "ObstacleID": 0, "Width": 0, "Length": 0, "Age": 0, "Lane": 0,
                    "RelAccelX": 0, "Counter": counter})))
                continue
            s = by_key[key]
            actor = s.actor
            obstacle_id = ids.get(key)
            n = age[key] = min(255, age.get(key, 0) + 1)
            vehicle = actor.camera_type in (_CAM_VEHICLE, _CAM_TRUCK)
            changing = actor.name == "cut_in" and sc.t_cut - 1.0 <= t < sc.t_cut + sc.cut_duration
            in_lane = abs(s.d) < LANE_WIDTH_M / 2
            lane = 1 if in_lane else 2 if abs(s.d) < 1.5 * LANE_WIDTH_M else 0
            if s.v_abs < -1.0:
                status = 4  # oncoming
            elif abs(s.v_abs) > 0.5:
                status = 3  # moving
            else:
                status = 2  # stopped
            frames.append((codec_a, codec_a.encode({
                "ObstacleID": obstacle_id,
                "PosX": s.x + rng.gauss(0, 0.05 + 0.01 * s.x),
                "PosY": -(s.y + rng.gauss(0, 0.08)),  # camera: y positive RIGHT
                "RelVelX": s.vx + rng.gauss(0, 0.15),
                "Type": actor.camera_type, "Status": status, "Valid": 1,
                "BrakeLights": int(vehicle and s.a_abs < -1.0),
                "CutInOut": (3 if changing else 1 if in_lane else 2) if vehicle else 0,
                "Blinker": (2 if changing else 1) if vehicle else 0,
                "Counter": counter})))
            frames.append((codec_b, codec_b.encode({
                "ObstacleID": obstacle_id, "Width": actor.width + rng.gauss(0, 0.03),
                "Length": actor.length, "Age": n, "Lane": lane,
                "RelAccelX": s.ax + rng.gauss(0, 0.1), "Counter": counter})))
        lane_times = times[len(frames):]
        centre = [sc.road_y(snap.ego, x) for x in _LANE_XS]
        fit = [sum(m * y for m, y in zip(row, centre, strict=True)) for row in _LANE_FIT]
        c0, c1, c2, c3 = fit[0] - snap.ego.d, fit[1] - snap.ego.psi, fit[2], fit[3]
        for when, (codec, offset, kind, view) in zip(lane_times, lanes, strict=True):
            if dropout[0] <= when < dropout[1]:
                values: dict[str, float] = {
                    "C0_Offset": 0, "C1_Heading": 0, "C2_Curvature": 0,
                    "C3_CurvatureDerivative": 0, "Quality": 0, "LaneType": 7, "Source": 0,
                    "ViewRange": 0, "Counter": lane_counter}
            else:  # the camera reports y positive RIGHT: every coefficient changes sign
                values = {
                    "C0_Offset": -(c0 + offset + rng.gauss(0, 0.02)),
                    "C1_Heading": -(c1 + rng.gauss(0, 0.0008)),
                    "C2_Curvature": -(c2 + rng.gauss(0, 0.00002)),
                    "C3_CurvatureDerivative": -(c3 + rng.gauss(0, 0.0000002)),
                    "Quality": 3, "LaneType": kind, "Source": 1,
                    "ViewRange": view - rng.randrange(4), "Counter": lane_counter}
            frames.append((codec, codec.encode(values)))
        for when, (codec, data) in zip(times, frames, strict=True):
            if when >= run.end_ns:
                return
            yield run.out.frame(when, codec, data)
        counter = (counter + 1) % 16
        lane_counter = (lane_counter + 1) % 4


@dataclass
class _Track:
    x: float
    y: float
    vx: float
    vy: float
    cls: int
    d: float
    age: int = 0
    missing: int = 0


def _fusion(run: _Run) -> Iterator[Frame]:
    """FusionTrack0..19 then LeadVehicle every 50 ms (radar + camera fused, y positive left)."""
    rng = run.rng("Fusion")
    tracks_codecs = [run.codec(f"FusionTrack{i}") for i in range(20)]
    lead_codec = run.codec("LeadVehicle")
    counter = rng.randrange(16)
    lead_counter = rng.randrange(16)
    slots = _Slots(20)
    ids = _Ids(rng.randrange(1, 100))
    tracks: dict[Hashable, _Track] = {}
    radar_out = run.faults.radar_dropout
    radar_blind = run.faults.radar_blind
    for tick, ts in run.ticks(rng, 50, (18_000, 28_000)):
        times = run.burst(rng, ts, len(tracks_codecs) + 1)
        if times[0] >= run.end_ns:
            return
        snap = run.world.at(tick)
        radar_ok = not (radar_out[0] <= ts < radar_out[1] or radar_blind[0] <= ts < radar_blind[1])
        sources: dict[Hashable, int] = {}
        for s in snap.objects:
            by_radar, by_camera = s.radar and radar_ok, s.camera
            if by_radar or by_camera:
                sources[s.key] = int(by_radar) + 2 * int(by_camera)
                old = tracks.get(s.key)
                track = _Track(s.x, s.y, s.vx, s.vy, s.actor.radar_class, s.d)
                track.age = old.age + 1 if old is not None else 0
                tracks[s.key] = track
        for key in [k for k in tracks if k not in sources]:
            track = tracks[key]  # coast for a few cycles, then drop
            track.missing += 1
            track.x += track.vx * 0.05
            track.y += track.vy * 0.05
            if track.missing > 3 or track.x < 0.5:
                del tracks[key]
        ordered = sorted(tracks, key=lambda k: (tracks[k].missing > 0,
                                                tracks[k].x**2 + tracks[k].y**2))
        owners = slots.assign(ordered)
        ids.retain(set(tracks))
        frames: list[tuple[_Codec, bytes]] = []
        fused: dict[Hashable, tuple[int, float, float, float]] = {}
        for slot, codec in enumerate(tracks_codecs):
            key = owners[slot]
            if key is None:
                frames.append((codec, codec.encode({
                    "TrackID": 0, "PosX": 0, "PosY": 0, "RelVelX": 0, "RelVelY": 0, "Class": 0,
                    "Status": 0, "Confidence": 0, "Counter": counter})))
                continue
            track = tracks[key]
            track_id = ids.get(key)
            source = sources.get(key, 0)
            if track.missing:
                status, confidence = 3, 50.0  # coasted
            else:
                status = 1 if track.age < 2 else 2  # new / updated
                confidence = {3: 96.875, 1: 81.25, 2: 71.875}[source]
            x = track.x + rng.gauss(0, 0.05)
            y = track.y + rng.gauss(0, 0.04)
            vx = track.vx + rng.gauss(0, 0.05)
            fused[key] = (track_id, x, y, vx)
            frames.append((codec, codec.encode({
                "TrackID": track_id, "PosX": x, "PosY": y, "RelVelX": vx,
                "RelVelY": track.vy + rng.gauss(0, 0.05), "Class": track.cls, "Status": status,
                "Confidence": confidence, "Counter": counter})))
        # Lead vehicle: the closest in-lane vehicle or two-wheeler ahead.
        candidates = [k for k in fused if abs(tracks[k].d) < 1.6 and fused[k][1] > 0.0
                      and tracks[k].cls in (CLASS_FOUR_WHEEL, CLASS_TWO_WHEEL)]
        ego_v = snap.ego.v
        if candidates:
            track_id, x, y, vx = fused[min(candidates, key=lambda k: fused[k][1])]
            values: dict[str, float] = {
                "Valid": 1, "AccState": 2, "Counter": lead_counter, "TrackID": track_id,
                "PosX": x, "PosY": y, "RelVelX": vx,
                "TimeGap": min(6.3, x / ego_v) if ego_v > 0.1 else 6.3,
                "TTC": min(102.3, x / -vx) if vx < -0.1 else 102.3}
        else:
            values = {"Valid": 0, "AccState": 2, "Counter": lead_counter, "TrackID": 0,
                      "PosX": 0, "PosY": 0, "RelVelX": 0, "TimeGap": 6.3, "TTC": 102.3}
        frames.append((lead_codec, lead_codec.encode(values)))
        for when, (codec, data) in zip(times, frames, strict=True):
            if when >= run.end_ns:
                return
            yield run.out.frame(when, codec, data)
        counter = (counter + 1) % 16
        lead_counter = (lead_counter + 1) % 16


def _diagnostics(run: _Run) -> Iterator[Frame]:
    """SensorDiag every second, cycling pages 0..3; the source changes after each full turn."""
    rng = run.rng("SensorDiag")
    codec = run.codec("SensorDiag")
    counter = rng.randrange(codec.counter_mod)
    misaligned = run.faults.misalignment_reported
    uptime_min = rng.randrange(2, 120)
    for k, (tick, ts) in enumerate(run.ticks(rng, 1000, (200_000, 400_000))):
        if ts >= run.end_ns:
            return
        t = tick / NS
        page, source = k % 4, (k // 4) % 4
        values: dict[str, float] = {"DiagPage": page, "DiagSource": source, "Counter": counter}
        if page == 0:
            values.update(FwVersionMajor=2, FwVersionMinor=4 + source, FwVersionPatch=1,
                          HwRevision=3, SerialNumber=41_000 + 17 * source)
        elif page == 1:
            values.update(TempCore=55 + 0.02 * t + rng.gauss(0, 0.5), TempBoard=47 + 0.01 * t,
                          TempHousing=33 + 0.01 * t, HeaterActive=0)
        elif page == 2:
            values.update(SupplyVoltage=13.8 + rng.gauss(0, 0.05),
                          SupplyCurrent=0.45 + 0.1 * source + rng.gauss(0, 0.01), PowerMode=1)
        else:
            fault = source == 0 and misaligned[0] <= ts < misaligned[1]
            values.update(ActiveDtcCount=1 if fault else 0, LastDtc=0xC2_34_00 if fault else 0,
                          UptimeMinutes=uptime_min + int(t // 60))
        yield run.out.frame(ts, codec, codec.encode(values))
        counter = (counter + 1) % codec.counter_mod


#: Every message the simulator sends.
_MESSAGES = (
    "EgoMotion", "Steering", "DriverInputs", "EgoPosition", "RadarHeader", "RadarStatus",
    *(f"RadarObj{i}_{part}" for i in range(32) for part in "AB"),
    *(f"CamObstacle{i}_{part}" for i in range(10) for part in "AB"),
    *(name for name, _, _, _ in _LANES),
    *(f"FusionTrack{i}" for i in range(20)), "LeadVehicle", "SensorDiag",
)

def _babbler(run: _Run) -> Iterator[Frame]:
    """``babbling``: a stuck gateway repeats one SensorDiag frame (page 0) every
    :data:`BABBLE_PERIOD_US` microseconds during the fault."""
    codec = run.codec("SensorDiag")
    data = codec.encode({"DiagPage": 0, "DiagSource": 0, "Counter": 0, "FwVersionMajor": 2,
                         "FwVersionMinor": 4, "FwVersionPatch": 1, "HwRevision": 3,
                         "SerialNumber": 41_000})
    begin, end = run.faults.babbling
    ts = begin
    while ts < min(end, run.end_ns):
        yield run.out.frame(ts, codec, data)
        ts += BABBLE_PERIOD_US * _US


_FAMILIES = (_ego_motion, _steering, _driver_inputs, _ego_position, _radar, _radar_status,
             _camera, _fusion, _diagnostics)


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
    """
    if not duration_s > 0 or not math.isfinite(duration_s):
        raise ValueError(f"duration_s must be a positive number of seconds, not {duration_s!r}")
    if scenario not in SCENARIOS:
        raise ValueError(f"no scenario {scenario!r}; one of {', '.join(SCENARIOS)}")
    db = database if database is not None else _default_database()
    codecs = {name: _Codec(db, name) for name in _MESSAGES}
    run = _Run(_World(duration_s), _Out(bus), seed, start_ns,
               start_ns + round(duration_s * NS), duration_s, codecs,
               _faults(SCENARIOS[scenario], duration_s, start_ns))
    families = [family(run) for family in _FAMILIES]
    if scenario == "babbling":
        families.append(_babbler(run))
    frames: Iterator[Frame] = heapq.merge(*families)
    silent = run.faults.bus_silent
    if scenario == "bus_silent":
        frames = (f for f in frames if not silent[0] <= f.timestamp_ns < silent[1])
    return frames
