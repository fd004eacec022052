"""The ego car's own messages: EgoMotion, Steering, DriverInputs and EgoPosition.

All follow the scripted ego (:class:`bridge.sim.world.Script`) at each message's measurement
tick, with measurement noise.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

from bridge.frame import NS, Frame
from bridge.sim.frames import Run, checksum
from bridge.sim.world import ROAD_CURVATURE, ROAD_PHASE_M

#: Ego bicycle model: wheelbase (m) and steering ratio (steering wheel angle / road wheel angle).
WHEELBASE_M = 2.8
STEERING_RATIO = 15.0


def ego_motion(run: Run) -> Iterator[Frame]:
    """``EgoMotion`` every 10 ms, the run's first frame exactly at ``start_ns``: vehicle speed
    (km/h), yaw rate (speed x path curvature), longitudinal and lateral acceleration, rolling
    counter and checksum.
    """
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
        yield run.out.frame(ts, codec, checksum(codec, values))
        counter = (counter + 1) % codec.counter_mod


def steering_wheel_angle_deg(curvature: float) -> float:
    """Steering wheel angle (deg, positive left) for a path curvature (1/m, positive left):
    bicycle model with :data:`WHEELBASE_M` and :data:`STEERING_RATIO`."""
    return math.degrees(math.atan(WHEELBASE_M * curvature)) * STEERING_RATIO


def steering(run: Run) -> Iterator[Frame]:
    """``Steering`` every 10 ms: the steering wheel angle of the path curvature
    (:func:`steering_wheel_angle_deg`), its rate, the driver torque, rolling counter and checksum.
    """
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
        yield run.out.frame(ts, codec, checksum(codec, values))
        counter = (counter + 1) % codec.counter_mod


def driver_inputs(run: Run) -> Iterator[Frame]:
    """``DriverInputs`` every 20 ms: in D, ACC on (set speed 90, gap setting 2), no pedal pressed;
    the brake pressure follows the ego's deceleration while the ACC brakes.
    """
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


def ego_position(run: Run) -> Iterator[Frame]:
    """``EgoPosition`` every 100 ms: the GNSS latitude and longitude of the ego driving the road
    from a start on a test track near Ann Arbor, MI (heading 30 degrees), with about 0.3 m of noise.
    """
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
