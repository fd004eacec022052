"""The lateral sign on a highway: the vehicles ahead lean into the curves.

A highway turns at 1 or 2 deg/s, too gently for stationary objects to sweep clearly (the check
needs 3 deg/s of them): there the verdict comes from the vehicles ahead. A vehicle driving
along the road x metres ahead sits on the inside of the curve, by about curvature * x^2 / 2;
when the curve comes and goes its lateral offset follows. With a wrong sign in the profile,
the lead and its lane-mates lean OUT of every curve.

The highway car (``simulate_highway(road="winding")``: five curves of 1.1 to 1.9 deg/s, left and
right, the same seven cars) is driven through the whole drive assembly, as ``tankviz profile
check`` does, with the bundled profile (``lateral = "right"``, as the radar is) and with the sign
flipped. On the same traffic on a straight road the verdict is "unknown", whichever the sign,
and says why with the figures; so it is when the ego changes lanes there (``road="weaving"``):
its turn is not held as a curve's, and its swing would move every vehicle ahead.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable
from pathlib import Path

import pytest

from bridge.cli import main
from bridge.pipeline.drive import Drive, load_stages
from bridge.resources import data_dir
from bridge.sim.highway import ROADS, ego_at, simulate_highway
from bridge.sinks.can_log_writer import write_log
from bridge.world.lateral import LateralSettings, LateralVerdict

FLIPPED = "left"  # the radar's LAT_DIST is positive to the right: "left" mirrors its scene


def highway_profile(lateral: str, folder: Path) -> Path:
    """The bundled highway profile with the radar's ``lateral`` as given."""
    text = (data_dir() / "highway.toml").read_text()
    assert text.count('lateral = "right"') == 1
    path = folder / f"highway_{lateral}.toml"
    path.write_text(text.replace('lateral = "right"', f'lateral = "{lateral}"'))
    return path


Verdict = Callable[[str, str], LateralVerdict]


@pytest.fixture(scope="module")
def verdict(tmp_path_factory: pytest.TempPathFactory) -> Verdict:
    """The radar's verdict of the health monitor after 60 s of the highway car on a road, with
    the radar's ``lateral`` as given (each drive run once for the module)."""
    folder = tmp_path_factory.mktemp("profiles")

    @functools.cache
    def run(road: str, lateral: str) -> LateralVerdict:
        drive = Drive(load_stages([], highway_profile(lateral, folder)))
        drive.run(simulate_highway(road=road))
        drive.finish()
        assert drive.health.lateral is not None
        (found,) = drive.health.lateral.verdicts()
        return found

    return run


def test_the_winding_highway_turns_at_1_to_2_deg_per_s_left_and_right() -> None:
    turns = [math.degrees(ego_at(t / 10, ROADS["winding"]).yaw_rate) for t in range(600)]

    assert 1.7 < max(turns) < 2.0 and -2.0 < min(turns) < -1.8
    # each curve holds its radius between its 2 s transitions: 1.1 to 1.9 deg/s
    for begin, end in ((6.5, 9.5), (18.5, 21.5), (30.5, 32.5), (42.5, 45.5), (53.5, 55.5)):
        held = [abs(r) for t, r in enumerate(turns) if begin <= t / 10 <= end]
        assert all(1.0 < r < 2.0 for r in held), (begin, held)
    assert max(abs(r) for r in turns) < LateralSettings().min_yaw_rate * 180 / math.pi


def test_on_the_weaving_highway_the_ego_changes_lanes_on_a_straight_road() -> None:
    weaving = ROADS["weaving"]
    lane = [round(ego_at(t, weaving).d / 3.6) for t in (5.0, 15.0, 28.0, 40.0, 55.0)]
    turns = [math.degrees(ego_at(t / 10, weaving).yaw_rate) for t in range(600)]

    assert lane == [0, 1, 0, -1, 0]  # left lane, back, right lane, back
    assert 2.5 < max(abs(r) for r in turns) < LateralSettings().min_yaw_rate * 180 / math.pi
    # straight between the lane changes: the lane keeping's wander only
    assert all(abs(turns[k]) < 0.1 for k in (20, 180, 300, 580))  # at 2, 18, 30 and 58 s


@pytest.mark.slow
def test_vehicles_ahead_leaning_into_the_curves_say_the_sign_is_right(verdict: Verdict) -> None:
    found = verdict("winding", "right")

    assert found.verdict == "ok", found.message
    assert found.samples < LateralSettings().min_samples  # not from stationary objects
    assert found.lean_samples >= LateralSettings().min_lean_samples
    assert found.lean_out <= 0.05 * found.lean_samples
    assert found.message == (f"radar: vehicles ahead lean into the curves in {found.lean_into} "
                             f'of {found.lean_samples} samples: lateral = "right" agrees')


@pytest.mark.slow
def test_a_flipped_sign_makes_the_vehicles_ahead_lean_out_of_the_curves(verdict: Verdict) -> None:
    found = verdict("winding", FLIPPED)

    assert found.verdict == "flipped", found.message
    assert found.lean_into <= 0.05 * found.lean_samples
    assert found.message == (
        f"radar: vehicles ahead lean OUT of the curves in {found.lean_out} of "
        f'{found.lean_samples} samples: lateral = "left" looks wrong, try lateral = "right"')


@pytest.mark.slow
@pytest.mark.parametrize("lateral", ["right", FLIPPED])
def test_a_straight_highway_gives_no_verdict_and_says_why(verdict: Verdict,
                                                           lateral: str) -> None:
    found = verdict("straight", lateral)

    assert found.verdict == "unknown"
    assert found.samples == found.lean_samples == 0
    assert re.fullmatch(
        r"radar: lateral sign not judged: 0 samples of stationary objects while turning "
        r"\(50 needed\): turned at most 0\.\d°/s \(2\.9°/s needed\) over 60 s; 0 samples of "
        r"vehicles ahead in curves \(20 needed\): no vehicle ahead in a curve \(a turn of "
        r"0\.6°/s or more held for 2 s\)", found.message)


@pytest.mark.slow
@pytest.mark.parametrize("lateral", ["right", FLIPPED])
def test_lane_changes_on_a_straight_highway_are_no_curves(verdict: Verdict, lateral: str) -> None:
    # changing lanes, the ego turns at up to 2.7 deg/s and swings every vehicle ahead aside
    found = verdict("weaving", lateral)

    assert found.verdict == "unknown"
    assert found.samples == found.lean_samples == 0
    assert found.message.endswith("no vehicle ahead in a curve (a turn of 0.6°/s or more held "
                                  "for 2 s)")


@pytest.mark.slow
def test_profile_check_prints_the_verdict_of_a_winding_highway_drive(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "winding.blf"
    write_log(simulate_highway(road="winding"), log, ".blf")

    assert main(["profile", "check", str(highway_profile(FLIPPED, tmp_path)), str(log)]) == 0

    lines = capsys.readouterr().out.splitlines()
    (said,) = lines[lines.index("lateral sign:") + 1:]
    assert re.fullmatch(r"  radar: vehicles ahead lean OUT of the curves in (\d+) of \1 "
                        r'samples: lateral = "left" looks wrong, try lateral = "right"', said)
