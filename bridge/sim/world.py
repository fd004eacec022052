"""The road, the ego car and the other road users: the scripted world as pure functions of time.

Positions are in the ego vehicle frame (x forward, y left, origin at the front bumper, where radar
and camera are mounted), lanes :data:`LANE_WIDTH_M` apart (ego lane y=0, left +3.6, right -3.6,
oncoming +7.2). No randomness: the world is the same for every seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from bridge.sim.scenario import TIMELINE

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

#: Radar object classes (DBC value table of RadarObj*_B.Class and FusionTrack*.Class).
CLASS_UNKNOWN, CLASS_FOUR_WHEEL, CLASS_TWO_WHEEL, CLASS_PEDESTRIAN, CLASS_STATIONARY = range(5)

# Camera obstacle types (CamObstacle*_A.Type); -1: the camera does not report the object.
CAM_VEHICLE, CAM_TRUCK, CAM_BIKE, CAM_PEDESTRIAN, CAM_BICYCLE = 0, 1, 2, 3, 4
CAM_NONE = -1


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
class Ego:
    s: float  # distance along the road (m)
    v: float  # speed (m/s)
    a: float  # longitudinal acceleration (m/s^2)
    d: float  # lateral offset from the ego lane centre (m, left)
    psi: float  # heading relative to the road (rad, left)
    kappa: float  # path curvature (1/m, left)
    cos_phi: float  # road phase at the ego, for the road geometry ahead
    sin_phi: float


class Script:
    """The scripted world as pure functions of time (seconds since the start of the run).

    The road's curvature is a sine of the distance along it (:data:`ROAD_CURVATURE`,
    :data:`ROAD_WAVELENGTH_M`, :data:`ROAD_PHASE_M`): a 10 s drive has a left and a right bend. The
    :data:`~bridge.sim.scenario.TIMELINE`'s events are placed at their fractions of ``duration_s``:
    ``ego(t)`` (:class:`Ego`) cruises at :data:`EGO_SPEED_MPS` (25 m/s) with about 0.1 m of lane
    wander, slows by :data:`LEAD_SPEED_DROP_MPS` a second after the lead brakes and follows it back
    up (distance, speed and acceleration are exact integrals of each other); ``lead_gap(t)``:
    :data:`LEAD_GAP_M` (40 m), shrinking to about 25 m while the lead brakes, opening to about 37 m
    after; ``road_y`` / ``to_ego``: road coordinates to the ego frame.
    """

    def __init__(self, duration_s: float) -> None:
        self.duration = duration_s
        self.t_brake = TIMELINE.lead_braking.start * duration_s
        self.t_accel = TIMELINE.lead_braking.end * duration_s
        self.t_cut = TIMELINE.cut_in.start * duration_s
        self.cut_duration = min(3.0, 0.8 * (TIMELINE.cut_in.end - TIMELINE.cut_in.start)
                                * duration_s)
        self.omega = 2 * math.pi / ROAD_WAVELENGTH_M

    # The ego ACC reacts a second after the lead brakes and follows it back up later.
    def ego(self, t: float) -> Ego:
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
        return Ego(s, v, a, d, d_dot / v, kappa, math.cos(phi), math.sin(phi))

    def lead_gap(self, t: float) -> float:
        """Distance along the road from ego to the lead vehicle."""
        _, _, i1 = _ramp(t, self.t_brake, 1.5)
        _, _, i2 = _ramp(t, self.t_accel, 3.5)
        lead = EGO_SPEED_MPS * t - LEAD_SPEED_DROP_MPS * (i1 - i2)
        return LEAD_GAP_M + lead - self.ego(t).s

    def road_y(self, ego: Ego, u: float) -> float:
        """Lateral position of the ego lane centre ``u`` metres ahead, in the road frame at the
        ego (small-angle integral of the heading change of the sine-curvature road)."""
        w = self.omega
        k_w = ROAD_CURVATURE / w
        sin_ahead = math.sin(w * u) * ego.cos_phi + math.cos(w * u) * ego.sin_phi
        return k_w * (u * ego.cos_phi - (sin_ahead - ego.sin_phi) / w)

    def to_ego(self, ego: Ego, ds: float, d: float) -> tuple[float, float]:
        """Road coordinates (distance ahead, lateral offset) to the ego frame (x fwd, y left)."""
        return ds, self.road_y(ego, ds) + d - ego.d - ego.psi * ds


# ---------------------------------------------------------------------------------------------
# Actors
# ---------------------------------------------------------------------------------------------

Place = Callable[[float, float], tuple[float, float]]  # (t, ego s) -> (ds unwrapped, d)


@dataclass(frozen=True)
class Actor:
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


def make_actors(sc: Script) -> list[Actor]:
    """The lead; ``cut_in`` (right lane into the ego lane within the ``cut_in`` window, at most 3
    s); a car and a truck in the left lane; an oncoming car and van; a cyclist and a pedestrian on
    the right roadside; four guard-rail posts beyond the oncoming lane. Streams of traffic wrap
    around the ego (``Actor.loop_m``). Each actor has a radar class (``CLASS_*``), a camera type
    (``CAM_*``; :data:`CAM_NONE`: not reported), a size and a radar cross-section.
    """
    def lead(t: float, s_ego: float) -> tuple[float, float]:
        return sc.lead_gap(t), 0.08 * math.sin(2 * math.pi * t / 5.1)

    def cut_in(t: float, s_ego: float) -> tuple[float, float]:
        ds = 6.0 + 12.0 * math.tanh((t - sc.t_cut) / 4.0)
        r, _, _ = _ramp(t, sc.t_cut, sc.cut_duration)
        return ds, RIGHT_LANE_Y + LANE_WIDTH_M * r

    def pedestrian(t: float, s_ego: float) -> tuple[float, float]:
        return 95.0 + 1.3 * t - s_ego, -6.6 + 0.25 * math.sin(0.5 * t)

    actors = [
        Actor("lead", CLASS_FOUR_WHEEL, CAM_VEHICLE, 4.7, 1.85, 12.0, lead),
        Actor("cut_in", CLASS_FOUR_WHEEL, CAM_VEHICLE, 4.4, 1.8, 10.0, cut_in),
        Actor("left_car", CLASS_FOUR_WHEEL, CAM_VEHICLE, 4.5, 1.8, 10.0,
              _stream(22.0, 27.5, LEFT_LANE_Y, 0.1), 360.0),
        Actor("left_truck", CLASS_FOUR_WHEEL, CAM_TRUCK, 12.0, 2.5, 22.0,
              _stream(202.0, 27.5, LEFT_LANE_Y, 0.1), 360.0),
        Actor("oncoming_car", CLASS_FOUR_WHEEL, CAM_VEHICLE, 4.6, 1.8, 10.0,
              _stream(150.0, -23.0, ONCOMING_LANE_Y, 0.1), 700.0),
        Actor("oncoming_van", CLASS_FOUR_WHEEL, CAM_TRUCK, 6.0, 2.1, 15.0,
              _stream(500.0, -22.0, ONCOMING_LANE_Y, 0.1), 700.0),
        Actor("cyclist", CLASS_TWO_WHEEL, CAM_BICYCLE, 1.8, 0.6, 0.0,
              _stream(70.0, 6.0, -5.9, 0.15), 900.0),
        Actor("pedestrian", CLASS_PEDESTRIAN, CAM_PEDESTRIAN, 0.5, 0.6, -8.0, pedestrian,
              800.0),
    ]
    for i in range(4):  # guard-rail posts beyond the oncoming lane
        actors.append(Actor(f"post{i}", CLASS_STATIONARY, CAM_NONE, 0.3, 0.3, 6.0,
                            _stream(30.0 + 50.0 * i, 0.0, 9.8), 200.0))
    return actors
