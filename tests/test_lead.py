"""Twins and a steady lead (bridge.world.lead), on hand-made observations.

A real Denso radar reports most objects in two slots at once, and its lead alternated between
those twins several times a second. Here: twins are found, the lead is followed through them,
and the lead changes only for a cut-in, a lead that left the lane or one that vanished.
"""

from __future__ import annotations

from collections.abc import Iterable

from bridge.frame import NS
from bridge.world.lead import (
    GRACE_S,
    NEARER_S,
    LeadKeeper,
    SteadyLead,
    key,
    twin_sets,
)
from bridge.world.observe import ObjectObservation

T0 = 1_767_268_800_000_000_000
TICK = NS // 20


def obj(i: int, x: float, y: float = 0.0, vx: float | None = -2.0, t: int = T0,
        group: str = "tracks") -> ObjectObservation:
    return ObjectObservation(group, i, t, x, y, True, vx)


def test_twins_are_near_and_at_the_same_speed() -> None:
    found = twin_sets([obj(2, 50.0, 0.1), obj(8, 50.6, -0.4), obj(3, 50.5, 3.6),
                       obj(5, 80.0), obj(6, 80.5, vx=-9.0), obj(7, 120.0, vx=None),
                       obj(9, 120.8, vx=4.0)])
    assert found[2] == found[8] == (2, 8)  # 0.8 m apart, the same speed
    assert 3 not in found  # the next lane: 3.5 m away
    assert 5 not in found and 6 not in found  # one passes the other: 7 m/s faster
    assert found[7] == found[9] == (7, 9)  # a slot without velocity: by place alone


def test_a_chain_of_twins_is_one_set() -> None:
    found = twin_sets([obj(1, 40.0), obj(2, 41.2), obj(3, 42.4)])
    assert found[1] == found[2] == found[3] == (1, 2, 3)


class Road:
    """Ticks of tracks at 20 Hz: the ego lane is |y| < 1.8 m ahead."""

    def __init__(self) -> None:
        self.keeper = LeadKeeper()
        self.t = T0
        self.leads: list[SteadyLead] = []

    def tick(self, *tracks: ObjectObservation) -> SteadyLead:
        now = {key(o): ObjectObservation(o.group, o.object_id, self.t, o.x, o.y, True, o.vx)
               for o in tracks}
        outside = {k: max(0.0, abs(o.y) - 1.8) for k, o in now.items() if o.x >= 0}
        in_lane = [k for k, d in outside.items() if d == 0.0]
        lead = self.keeper.update(now, in_lane, outside, self.t)
        self.leads.append(lead)
        self.t += TICK
        return lead

    def ticks(self, seconds: float, *tracks: ObjectObservation) -> SteadyLead:
        lead = self.tick(*tracks)
        for _ in range(round(seconds * 20) - 1):
            lead = self.tick(*tracks)
        return lead

    def changes(self) -> list[str]:
        return [lead.change for lead in self.leads if lead.change]


def ids(leads: Iterable[SteadyLead]) -> list[int | None]:
    return [None if lead.lead is None else lead.lead.object_id for lead in leads]


def test_the_lead_is_followed_through_its_twins_without_a_change() -> None:
    road = Road()
    assert road.tick(obj(2, 50.0)).serial == 1
    # the twin comes and goes, the lead's own slot drops out and comes back
    for _ in range(10):
        road.ticks(0.3, obj(2, 50.0), obj(8, 50.7, 0.3))
        road.ticks(0.3, obj(8, 50.7, 0.3))  # slot 2 gone: the twin is the lead now
        road.ticks(0.3, obj(8, 50.7, 0.3), obj(2, 50.0))
        road.ticks(0.3, obj(2, 50.0))
    assert {lead.serial for lead in road.leads} == {1}
    assert road.changes() == ["appeared"]
    assert set(ids(road.leads)) == {2, 8}  # its id is the slot it is seen in


def test_a_cut_in_takes_the_lead_once_it_is_clearly_nearer() -> None:
    road = Road()
    road.ticks(2.0, obj(2, 50.0), obj(5, 25.0, 3.6))  # a car in the next lane, 25 m ahead
    assert road.leads[-1].lead is not None and road.leads[-1].lead.object_id == 2
    road.ticks(NEARER_S - 0.1, obj(2, 50.0), obj(5, 25.0, 0.5))  # it cuts in: not yet
    assert road.leads[-1].lead is not None and road.leads[-1].lead.object_id == 2
    lead = road.ticks(0.2, obj(2, 50.0), obj(5, 25.0, 0.5))
    assert lead.lead is not None and lead.lead.object_id == 5 and lead.serial == 2
    assert road.changes()[-1] == f"#5 nearer by over 5 m for {NEARER_S:g} s"


def test_a_car_a_little_nearer_or_briefly_nearer_does_not_take_the_lead() -> None:
    road = Road()
    road.ticks(1.0, obj(2, 50.0))
    road.ticks(3.0, obj(2, 50.0), obj(4, 47.0, 0.5))  # 3 m nearer: within the margin
    for _ in range(5):  # 20 m nearer, but never for long
        road.ticks(0.3, obj(2, 50.0), obj(6, 30.0, 1.0))
        road.ticks(0.3, obj(2, 50.0), obj(6, 30.0, 2.5))
    assert {lead.serial for lead in road.leads} == {1}


def test_a_lead_that_leaves_the_lane_or_vanishes_is_replaced() -> None:
    road = Road()
    road.ticks(1.0, obj(2, 50.0), obj(3, 80.0))
    lead = road.ticks(0.1, obj(2, 50.0, 2.3), obj(3, 80.0))  # 0.5 m over the lane line
    assert lead.lead is not None and lead.lead.object_id == 3 and lead.serial == 2
    assert road.changes()[-1] == "left the ego lane"
    road.ticks(GRACE_S - 0.1, obj(9, 120.0))  # 3 is gone: held for the grace time
    assert road.leads[-1].lead is not None and road.leads[-1].lead.object_id == 3
    lead = road.ticks(0.2, obj(9, 120.0))
    assert lead.lead is not None and lead.lead.object_id == 9 and lead.serial == 3
    assert road.changes()[-1] == f"vanished for over {GRACE_S:g} s"


def test_a_clock_step_keeps_the_lead() -> None:
    road = Road()
    road.ticks(0.5, obj(2, 50.0))
    road.keeper.shift(-3600 * NS)
    road.t -= 3600 * NS
    lead = road.ticks(0.5, obj(2, 50.0))
    assert lead.serial == 1 and lead.lead is not None and lead.lead.object_id == 2
