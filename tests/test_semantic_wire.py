"""semantic.objects builds its objects from wire bytes: the message is the one perceived() makes."""

from __future__ import annotations

import random

import pytest

from bridge.frame import timestamp
from bridge.pb.perception_pb2 import PerceivedObjects
from bridge.profile.model import ObjectClass
from bridge.scene import semantic
from bridge.topics import VEHICLE_FRAME
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
