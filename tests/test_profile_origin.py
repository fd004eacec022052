"""Where the vehicle origin is: ``[vehicle] origin`` places the ego box in /scene/ego.

Profiles put the vehicle frame's origin at different places on the car. A rear-axle origin has
the box's rear ``rear_overhang`` metres behind it, a front-bumper origin has the box's front at it,
and ``centre`` (the default, as ecocar) centres the box on it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.pipeline.perception import Perception
from bridge.profile.loader import load_profile
from bridge.profile.model import Profile, ProfileError

T0 = 1_767_268_800_000_000_000


def car(tmp_path: Path, vehicle: str) -> Path:
    """A car without sensors: only its ``[vehicle]`` table (a SUV, 4.8 m long)."""
    path = tmp_path / "suv.toml"
    path.write_text(f"[vehicle]\nlength = 4.8\nwidth = 1.9\nheight = 1.7\n{vehicle}")
    return path


def ego_box(profile: Profile) -> tuple[float, float, float]:
    """Centre x, y and length of the cube drawn on /scene/ego."""
    perception = Perception(profile)
    perception.advance(T0)
    outputs = perception.advance(T0 + 200_000_000)
    [scene] = [m.message for m in outputs if m.topic == "/scene/ego"][-1:]
    [cube] = scene.entities[0].cubes
    return cube.pose.position.x, cube.pose.position.y, cube.size.x


def test_a_rear_axle_car_has_its_box_ahead_of_the_origin(tmp_path: Path) -> None:
    profile = load_profile(car(tmp_path, 'origin = "rear_axle"\nrear_overhang = 1.1\n'), [])
    # The rear is 1.1 m behind the axle, the front 3.7 m ahead of it.
    assert ego_box(profile) == pytest.approx((4.8 / 2 - 1.1, 0.0, 4.8))


def test_the_rear_overhang_has_a_default(tmp_path: Path) -> None:
    profile = load_profile(car(tmp_path, 'origin = "rear_axle"\n'), [])
    assert ego_box(profile) == pytest.approx((4.8 / 2 - 1.0, 0.0, 4.8))


def test_a_front_bumper_car_has_its_box_behind_the_origin(tmp_path: Path) -> None:
    profile = load_profile(car(tmp_path, 'origin = "front_bumper"\n'), [])
    assert ego_box(profile) == pytest.approx((-4.8 / 2, 0.0, 4.8))


def test_the_box_is_centred_on_the_origin_by_default(tmp_path: Path) -> None:
    assert ego_box(load_profile(car(tmp_path, ""), [])) == pytest.approx((0.0, 0.0, 4.8))
    centre = load_profile(car(tmp_path, 'origin = "centre"\n'), [])
    assert ego_box(centre) == pytest.approx((0.0, 0.0, 4.8))


@pytest.mark.parametrize(("vehicle", "expected"), [
    ('origin = "rear-axle"\n',
     "suv.toml: vehicle.origin: must be one of centre, rear_axle, front_bumper, got 'rear-axle'"),
    ("origin = 1\n", "suv.toml: vehicle.origin: expected a string, got a number (1)"),
    ('origin = "rear_axle"\nrear_overhang = -0.5\n',
     "suv.toml: vehicle.rear_overhang: must not be negative, got -0.5"),
    ('origin = "front_bumper"\nrear_overhang = 1.0\n',
     "suv.toml: vehicle.rear_overhang: only for origin = \"rear_axle\", the origin is "
     "'front_bumper'"),
    ('origin = "rear_axle"\nrear_overhang = 5.0\n',
     "suv.toml: vehicle.rear_overhang: must be less than the length 4.8, got 5.0"),
])
def test_a_bad_origin_is_a_one_line_error(tmp_path: Path, vehicle: str, expected: str) -> None:
    with pytest.raises(ProfileError) as exc:
        load_profile(car(tmp_path, vehicle), [])
    message = str(exc.value)
    assert "\n" not in message
    assert message.endswith(expected), message
