"""Profile numbers that are finite but cannot be used (a lifetime of 1e10 s, a lane 1e300 m
long): the loader refuses each with its one-line error naming the key, or the drive converts.
Never a traceback in the middle of a conversion.

Every number of the bundled ecocar profile is tried at the extremes, one at a time (the family,
not only the keys a user happened to try).
"""

from __future__ import annotations

import io
import re
from functools import cache
from pathlib import Path

import pytest

from bridge.frame import Frame
from bridge.pipeline.drive import Drive, load_stages
from bridge.profile.model import ProfileError
from bridge.resources import data_dir
from bridge.sim.ecocar import simulate

PROFILE = data_dir() / "ecocar.toml"
NUMBER = re.compile(r"(?P<key>\b[a-z_]+)\s*=\s*(?P<value>-?\d+(?:\.\d+)?)(?=\s*[,}#\n])")
EXTREMES = ("1e10", "1e300", "-1e300")


def numbers() -> list[tuple[int, str, int]]:
    """(line number, key, column) of every number in the profile's text."""
    out = []
    for n, line in enumerate(PROFILE.read_text().splitlines(keepends=True)):
        if line.lstrip().startswith("#"):
            continue
        out += [(n, m["key"], m.start("value")) for m in NUMBER.finditer(line)]
    return out


def with_value(folder: Path, line: int, column: int, value: str) -> Path:
    lines = PROFILE.read_text().splitlines(keepends=True)
    text = lines[line]
    number = re.match(r"-?\d+(?:\.\d+)?", text[column:])
    assert number is not None
    end = column + len(number[0])
    lines[line] = text[:column] + value + text[end:]
    path = folder / "ecocar.toml"
    path.write_text("".join(lines))
    (folder / "ecocar.dbc").write_bytes((data_dir() / "ecocar.dbc").read_bytes())
    return path


def test_the_profile_has_numbers_to_try() -> None:
    keys = {key for _, key, _ in numbers()}
    assert {"lifetime", "stale_after", "length", "wheelbase", "range", "bitrate"} <= keys


@cache
def one_second() -> tuple[Frame, ...]:
    """The simulated ecocar's first second, made once for the many profiles driven on it."""
    return tuple(simulate(duration_s=1.0))


@pytest.mark.slow
@pytest.mark.parametrize("value", EXTREMES)
@pytest.mark.parametrize("line,key,column", numbers(),
                         ids=[f"line{n + 1}-{key}" for n, key, _ in numbers()])
def test_an_extreme_profile_number_is_refused_or_the_drive_converts(
        tmp_path: Path, line: int, key: str, column: int, value: str) -> None:
    path = with_value(tmp_path, line, column, value)
    try:
        stages = load_stages([], path)
    except ProfileError as exc:
        message = str(exc)
        assert "\n" not in message and key in message and str(path) in message
        return
    drive = Drive(stages, scene_rate=20)
    drive.record(io.BytesIO())
    drive.run(one_second())
    drive.finish()


def test_a_lifetime_of_1e10_seconds_is_one_line_saying_the_limit(tmp_path: Path) -> None:
    line, _, column = next(n for n in numbers() if n[1] == "lifetime")
    path = with_value(tmp_path, line, column, "1e10")
    with pytest.raises(ProfileError) as error:
        load_stages([], path)
    assert str(error.value) == (f"{path}: objects.radar.lifetime: must be at most 3600 s, "
                                "got 1e+10")
