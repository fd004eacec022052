"""The world is observed per scene tick, and an object whose signals did not change since its last
observation is not evaluated again: only its time moves on.

The car here is made up (a small DBC and profile written in tmp_path), not the bundled ecocar: a
lidar (a sensor of kind radar, for the profile format) reporting tracks in range and bearing
(degrees, positive to the right), each in a main and an auxiliary message with a rolling counter
that nothing reads, a computed range, and a validity rule over both messages.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any
from unittest import mock

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.pipeline.perception import Perception
from bridge.profile.expr import Expression
from bridge.profile.loader import load_profile
from bridge.profile.model import ObjectClass, Profile
from bridge.world.model import World
from bridge.world.observe import _Object

NS = 1_000_000_000
MS = 1_000_000
T0 = 1_800_000_000 * NS

DBC = "".join(["""\
VERSION ""

NS_ :

BS_:

BU_: LIDAR CAR

BO_ 200 Speed: 8 CAR
 SG_ Kph : 0|16@1+ (0.01,0) [0|655.35] "km/h" Vector__XXX
"""] + [f"""
BO_ {1056 + 2 * i} Trk{i}_Main: 8 LIDAR
 SG_ RangeRaw : 0|16@1+ (0.02,0) [0|1310.7] "m" Vector__XXX
 SG_ Bearing : 16|16@1- (0.01,0) [-327.68|327.67] "deg" Vector__XXX
 SG_ State : 32|2@1+ (1,0) [0|3] "" Vector__XXX
 SG_ Alive : 60|4@1+ (1,0) [0|15] "" Vector__XXX

BO_ {1057 + 2 * i} Trk{i}_Aux: 8 LIDAR
 SG_ Kind : 0|4@1+ (1,0) [0|15] "" Vector__XXX
 SG_ Confidence : 8|7@1+ (1,0) [0|100] "%" Vector__XXX
 SG_ Alive : 60|4@1+ (1,0) [0|15] "" Vector__XXX
""" for i in range(3)])

PROFILE = """\
[profile]
name = "lidar_kart"

[sensors.lidar]
kind = "radar"                      # a lidar, as the profile format calls it
mount = { x = 2.0, y = 0.5, z = 1.0, yaw = 0.0 }
coordinates = "polar"
angle_unit = "deg"
lateral = "right"

[objects.lidar]
sensor = "lidar"
messages = ["Trk{i}_Main", "Trk{i}_Aux"]
index = [0, 2]
range = "if(RangeRaw == 0, none, RangeRaw + 0.5)"
azimuth = "Bearing"
probability = "Confidence"
class = "Kind"
classes = { 1 = "car", 2 = "pedestrian" }
valid = "State != 0 and Trk{i}_Aux.Confidence > 10"
lifetime = 0.2

[ego]
speed = { signal = "Speed.Kph", scale = 0.2777778 }
"""


@pytest.fixture(scope="module")
def car(tmp_path_factory: pytest.TempPathFactory
        ) -> tuple[Profile, cantools.database.can.Database]:
    tmp_path = tmp_path_factory.mktemp("lidar_kart")
    dbc = tmp_path / "lidar_kart.dbc"
    dbc.write_text(DBC)
    path = tmp_path / "lidar_kart.toml"
    path.write_text(PROFILE)
    db = cantools.database.load_file(dbc)
    assert isinstance(db, cantools.database.can.Database)
    return load_profile(path, [db]), db


def signals(db: cantools.database.can.Database, name: str, **values: float) -> dict[str, Any]:
    """``values`` (others at 0) as the bridge sees them: encoded, then decoded with the DBC."""
    m = db.get_message_by_name(name)
    data = m.encode({s.name: values.get(s.name, 0) for s in m.signals})
    decoded: dict[str, Any] = m.decode(data, decode_choices=False)  # type: ignore[assignment]
    return decoded


@contextmanager
def counting_evaluations() -> Iterator[Counter[str]]:
    """Counts every evaluation of a profile expression (a computed value or a validity rule)."""
    counts: Counter[str] = Counter()
    value, judge = Expression.value, Expression.judge

    def counted_value(self: Expression, values: Any) -> float | None:
        counts[self.text] += 1
        return value(self, values)

    def counted_judge(self: Expression, values: Any) -> tuple[bool, str]:
        counts[self.text] += 1
        return judge(self, values)

    with mock.patch.object(Expression, "value", counted_value), \
            mock.patch.object(Expression, "judge", counted_judge):
        yield counts


class Drive:
    """Sends lidar messages to Perception and ticks the scene every 50 ms, as convert does."""

    def __init__(self, profile: Profile, db: cantools.database.can.Database) -> None:
        self.db = db
        self.perception = Perception(profile, scene_rate=20)
        self.perception.advance(T0)  # first scene at T0 + 50 ms
        self.alive = 0

    def send(self, t_ms: float, name: str, **values: float) -> None:
        t = T0 + round(t_ms * MS)
        self.perception.advance(t)
        self.alive = (self.alive + 1) % 16  # the rolling counter: every frame differs
        self.perception.feed(name, signals(self.db, name, Alive=self.alive, **values), t)

    def track(self, t_ms: float, index: int, *, kind: int = 1, **main: float) -> None:
        self.send(t_ms, f"Trk{index}_Main", **main)
        self.send(t_ms + 0.2, f"Trk{index}_Aux", Kind=kind, Confidence=80)

    def world(self) -> World:
        return self.perception.world


def test_an_object_whose_signals_did_not_change_is_not_evaluated_again_only_its_time_moves(
        car: tuple[Profile, cantools.database.can.Database]) -> None:
    drive = Drive(*car)
    with counting_evaluations() as evaluations:
        drive.track(10, 1, RangeRaw=30.0, Bearing=-4.0, State=2)
        drive.send(60, "Speed", Kph=36.0)  # the tick at 50 ms observes track 1
        first = dict(evaluations)
        (before,) = drive.world().objects["lidar"].values()

        for t_ms in (110, 160, 210, 260, 310):  # the same track re-sent, counters rolling
            drive.track(t_ms, 1, RangeRaw=30.0, Bearing=-4.0, State=2)
        drive.send(360, "Speed", Kph=36.0)  # ticks up to 350 ms

    assert first == {"if(RangeRaw == 0, none, RangeRaw + 0.5)": 1,  # the first tick evaluated
                     "State != 0 and Trk1_Aux.Confidence > 10": 1}  # the range and the rule
    assert dict(evaluations) == first  # and no tick after did
    (after,) = drive.world().objects["lidar"].values()
    assert after.t_ns == T0 + 310 * MS  # the newest position's time: its lifetime goes on
    assert (after.x, after.y, after.probability, after.object_class, after.valid) == (
        before.x, before.y, before.probability, before.object_class, before.valid)
    assert after.x == pytest.approx(2.0 + 30.5 * math.cos(math.radians(4.0)))


def test_a_changed_companion_makes_its_object_observed_again(
        car: tuple[Profile, cantools.database.can.Database]) -> None:
    drive = Drive(*car)
    with counting_evaluations() as evaluations:
        drive.track(10, 0, RangeRaw=12.0, Bearing=3.0, State=1, kind=1)
        drive.send(60, "Speed", Kph=10.0)
        (first,) = drive.world().objects["lidar"].values()
        judged = evaluations["State != 0 and Trk0_Aux.Confidence > 10"]

        drive.send(70, "Trk0_Aux", Kind=2, Confidence=80)  # only the companion, changed
        drive.send(110, "Speed", Kph=10.0)

    (second,) = drive.world().objects["lidar"].values()
    assert (first.object_class, second.object_class) == (ObjectClass.CAR, ObjectClass.PEDESTRIAN)
    assert evaluations["State != 0 and Trk0_Aux.Confidence > 10"] == judged + 1
    assert second.t_ns == first.t_ns == T0 + 10 * MS  # the position did not come again
    assert (second.x, second.y) == (first.x, first.y)


def test_a_companion_that_makes_the_object_invalid_removes_it_at_the_next_tick(
        car: tuple[Profile, cantools.database.can.Database]) -> None:
    drive = Drive(*car)
    drive.track(10, 2, RangeRaw=50.0, Bearing=0.0, State=3)
    drive.send(60, "Speed", Kph=10.0)
    assert list(drive.world().objects["lidar"]) == [2]

    drive.send(70, "Trk2_Aux", Kind=1, Confidence=5)  # the rule no longer holds
    drive.send(110, "Speed", Kph=10.0)
    assert drive.world().objects["lidar"] == {}

    drive.send(120, "Trk2_Aux", Kind=1, Confidence=80)  # as it was at first: valid again
    drive.send(160, "Speed", Kph=10.0)
    assert list(drive.world().objects["lidar"]) == [2]


_NAMES = ["Trk0_Main", "Trk0_Aux", "Trk1_Main", "Trk1_Aux", "Speed"]
#: Few values, so that messages often repeat what their object already had; -0.0 beside 0.0.
_VALUES: dict[str, Any] = {
    "Main": st.fixed_dictionaries({"RangeRaw": st.sampled_from([0.0, 20.0, 20.02, 75.5]),
                                   "Bearing": st.sampled_from([0.0, -0.0, 5.0, -12.5]),
                                   "State": st.sampled_from([0, 1, 3])}),
    "Aux": st.fixed_dictionaries({"Kind": st.sampled_from([0, 1, 2]),
                                  "Confidence": st.sampled_from([5, 50, 99])}),
    "Speed": st.fixed_dictionaries({"Kph": st.sampled_from([0.0, 50.0])}),
}


@st.composite
def sequences(draw: st.DrawFn) -> list[tuple[int, str, dict[str, Any]]]:
    out = []
    t = T0
    for _ in range(draw(st.integers(1, 50))):
        t += draw(st.integers(0, 40)) * MS
        name = draw(st.sampled_from(_NAMES))
        values = dict(draw(_VALUES[name.split("_")[-1]]))
        values["Alive"] = draw(st.integers(0, 15))
        out.append((t, name, values))
    return out


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(sequence=sequences())
def test_reusing_unchanged_observations_gives_the_world_evaluating_every_one_gives(
        car: tuple[Profile, cantools.database.can.Database],
        sequence: list[tuple[int, str, dict[str, Any]]]) -> None:
    """At every tick, the world is the one a perception that evaluates every object anew makes
    (-0.0 and 0.0 alike, rules that fail and hold, companions alone, expiry)."""
    profile, _ = car

    def worlds() -> list[Any]:
        perception = Perception(profile, scene_rate=20)
        perception.advance(T0)
        out = []
        for t, name, values in [*sequence, (sequence[-1][0] + 60 * MS, "Speed", {"Kph": 1.0})]:
            if perception.advance(t):
                world = perception.world
                out.append(({i: (o.t_ns, o.x, o.y, o.probability, o.object_class, o.valid)
                             for i, o in world.objects["lidar"].items()},
                            dict(world.rule_errors), world.ego.speed))
            perception.feed(name, values, t)
        return out

    reusing = worlds()
    with mock.patch.object(_Object, "read_key", lambda self: object()):  # never the same
        evaluating = worlds()
    assert reusing == evaluating


# --- one message, one object per frame ----------------------------------------------------------

LIST_DBC = """\
VERSION ""

NS_ :

BS_:

BU_: CAM

BO_ 1280 ObjList: 8 CAM
 SG_ ObjId : 0|8@1+ (1,0) [0|255] "" Vector__XXX
 SG_ Dx : 8|12@1+ (0.1,0) [0|409.5] "m" Vector__XXX
 SG_ Dy : 20|12@1- (0.1,0) [-204.8|204.7] "m" Vector__XXX
"""

LIST_PROFILE = """\
[profile]
name = "object_list"

[sensors.cam]
kind = "camera"

[objects.cam]
sensor = "cam"
messages = ["ObjList"]              # no index range: each frame is one object, ObjId says which
id = "ObjId"
x = "Dx"
y = "Dy"
lifetime = 0.2
"""


def test_every_object_of_a_list_message_sent_between_two_ticks_reaches_the_world(
        tmp_path: Any) -> None:
    # A camera sends its object list as one message per object, all between two scene ticks:
    # keeping only the newest frame of the message would lose every object but the last.
    (tmp_path / "list.dbc").write_text(LIST_DBC)
    (tmp_path / "list.toml").write_text(LIST_PROFILE)
    db = cantools.database.load_file(tmp_path / "list.dbc")
    assert isinstance(db, cantools.database.can.Database)
    perception = Perception(load_profile(tmp_path / "list.toml", [db]), scene_rate=20)
    perception.advance(T0)
    for n, (obj, dx, dy) in enumerate([(4, 12.0, 1.5), (7, 30.0, -2.0), (9, 55.5, 0.3)]):
        t = T0 + (10 + n) * MS
        perception.advance(t)
        perception.feed("ObjList", signals(db, "ObjList", ObjId=obj, Dx=dx, Dy=dy), t)
    perception.advance(T0 + 60 * MS)
    perception.observe_pending()
    world = perception.world.objects["cam"]
    assert {i: (round(o.x, 1), round(o.y, 1)) for i, o in world.items()} == {
        4: (12.0, 1.5), 7: (30.0, -2.0), 9: (55.5, 0.3)}
