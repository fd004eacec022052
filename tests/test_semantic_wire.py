"""semantic builds its messages from wire bytes: objects are the ones perceived() makes, the
lead, lanes and ego the messages setting each field makes."""

from __future__ import annotations

import random

import pytest

from bridge.frame import timestamp
from bridge.pb.perception_pb2 import EgoState as EgoMessage
from bridge.pb.perception_pb2 import LaneLine, Lanes, LeadVehicle, PerceivedObjects
from bridge.pipeline.drive import load_stages
from bridge.profile.model import ObjectClass
from bridge.scene import semantic
from bridge.topics import VEHICLE_FRAME
from bridge.world.lead import SteadyLead
from bridge.world.model import EgoState, LaneCurve, LaneModel, MioCheck, World, steering_curvature
from bridge.world.observe import ObjectObservation

_EDGES = [0.0, -0.0, 1.5, -3.25, 1e300, 5e-324]


@pytest.mark.parametrize("seed", range(4))
def test_objects_are_what_perceived_makes(seed: int) -> None:
    rnd = random.Random(seed)

    def place() -> float:
        return rnd.choice(_EDGES) if rnd.random() < 0.5 else rnd.uniform(-200.0, 200.0)

    def optional() -> float | None:
        return rnd.choice([*_EDGES, float("nan"), None]) if rnd.random() < 0.5 else \
            rnd.uniform(-50.0, 50.0)

    for _ in range(300):
        found = [ObjectObservation(
            "g", rnd.choice([0, 1, 127, 128, 300, 2**32 - 1, rnd.randint(0, 2**32 - 1)]),
            rnd.randint(0, 10**10), place(), place(), True, optional(), optional(), optional(),
            rnd.choice(list(ObjectClass)), "") for _ in range(rnd.randint(0, 5))]
        twins = {o.object_id: tuple(sorted({o.object_id, rnd.randint(0, 300), 2**31}))
                 for o in found if rnd.random() < 0.3}
        t_ns = rnd.randint(0, 10**10)
        items = [semantic.perceived(o, t_ns, twins.get(o.object_id, ()))
                 for o in sorted(found, key=lambda o: o.object_id)]
        expected = PerceivedObjects(timestamp=timestamp(t_ns), frame_id=VEHICLE_FRAME,
                                    group="g", sensor="s", count=len(items), objects=items)
        got = semantic.objects("g", "s", found, t_ns, twins)
        assert got.SerializeToString() == expected.SerializeToString()


def _field_by_field_lead(check: MioCheck, t_ns: int, steady: SteadyLead | None) -> LeadVehicle:
    msg = LeadVehicle(timestamp=timestamp(t_ns), frame_id=VEHICLE_FRAME,
                      present=check.lead is not None, expected_present=check.expected is not None,
                      mio_ok=check.ok, mio_reason=check.reason)
    if steady is not None:
        msg.lead_number, msg.change = steady.serial, steady.change
    if check.lead is not None:
        msg.object.CopyFrom(semantic.perceived(check.lead, t_ns))
    if check.expected is not None:
        msg.expected.CopyFrom(semantic.perceived(check.expected, t_ns))
    return msg


@pytest.mark.parametrize("seed", range(3))
def test_lead_lanes_and_ego_are_what_setting_their_fields_makes(seed: int) -> None:
    """semantic.lead, lanes and ego parse their wire bytes: the messages setting each field
    makes (zeros, -0.0, empty and long texts, no lead, no lines, no steering angle)."""
    rnd = random.Random(seed)

    def number() -> float:
        return rnd.choice(_EDGES) if rnd.random() < 0.5 else rnd.uniform(-100.0, 100.0)

    def observation() -> ObjectObservation | None:
        return rnd.choice([None, ObjectObservation(
            "g", rnd.randint(0, 300), rnd.randint(0, 10**10), number(), number(), True,
            rnd.choice([None, number()]), None, None, rnd.choice(list(ObjectClass)), "")])

    def words() -> str:
        return rnd.choice(["", "lead is track #3", "é" * rnd.randint(0, 200)])

    profile = load_stages([], "ecocar").profile
    assert profile is not None
    for _ in range(300):
        t_ns = rnd.randint(0, 10**10)
        check = MioCheck(observation(), observation(), rnd.random() < 0.5, words())
        steady = rnd.choice([None, SteadyLead(None, rnd.choice([0, 1, 200, 2**32 - 1]),
                                              words())])
        assert (semantic.lead(check, t_ns, steady).SerializeToString()
                == _field_by_field_lead(check, t_ns, steady).SerializeToString())
        model = LaneModel(rnd.choice(["camera", "steering", "none", ""]), tuple(
            LaneCurve(name, (), (number(), number(), number(), number()))
            for name in rnd.sample(["left", "right", "next_left", "x" * 200], rnd.randint(0, 4))),
            rnd.choice([-1.0, 0.0, -0.0, number()]))
        expected_lanes = Lanes(
            timestamp=timestamp(t_ns), frame_id=VEHICLE_FRAME, source=model.source,
            camera_age=model.camera_age_s,
            lines=[LaneLine(name=line.name, c0=line.coefficients[0], c1=line.coefficients[1],
                            c2=line.coefficients[2], c3=line.coefficients[3])
                   for line in model.lines])
        assert (semantic.lanes(model, t_ns).SerializeToString()
                == expected_lanes.SerializeToString())
        world = World(profile)
        world.ego = EgoState(t_ns, rnd.choice([None, number()]), rnd.choice([None, number()]),
                             rnd.choice([None, number()]))
        state = world.ego
        expected_ego = EgoMessage(timestamp=timestamp(t_ns), speed=state.speed or 0.0,
                                  yaw_rate=state.yaw_rate or 0.0,
                                  steering_wheel_angle=state.steering_wheel_angle or 0.0)
        if state.steering_wheel_angle is not None:
            expected_ego.curvature = steering_curvature(
                state.steering_wheel_angle, profile.vehicle.wheelbase_m,
                profile.vehicle.steering_ratio)
        assert (semantic.ego(world, profile, t_ns).SerializeToString()
                == expected_ego.SerializeToString())
