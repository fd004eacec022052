"""Reading the values of a profile's TOML: each of the right type and within its range, or one
line naming the file, the key and what is wrong.

Every problem is a :class:`~bridge.profile.model.ProfileError`; no value read can overflow the
drive's arithmetic.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from bridge.profile.model import ProfileError

#: The largest time a profile may give (a lifetime, a lane's stale_after), in seconds: longer
#: would outlast any drive, and its nanoseconds would not fit the 64-bit times of the scene.
MAX_SECONDS = 3600.0
#: The largest distance a profile may give (a lane drawn ahead, a sensor's range), in metres:
#: the scene samples lanes along it, so a longer one would never be drawn.
MAX_METRES = 1000.0
#: The largest size of the ego vehicle, a sensor's mounting offset or a lane fallback, in metres.
MAX_VEHICLE_METRES = 100.0
#: The largest bitrate of a bus, in bit/s (CAN XL reaches 20 Mbit/s).
MAX_BITRATE = 100_000_000
SECONDS: dict[str, Any] = {"at_most": MAX_SECONDS, "unit": " s"}
DISTANCE: dict[str, Any] = {"at_most": MAX_METRES, "unit": " m"}
VEHICLE: dict[str, Any] = {"at_most": MAX_VEHICLE_METRES, "unit": " m"}
BITRATE: dict[str, Any] = {"at_most": MAX_BITRATE, "unit": " bit/s"}

def closest(word: str, choices: Iterable[str], *, or_all: bool = False) -> str:
    """``; closest: …`` naming likely meant names; with ``or_all``, else every name."""
    choices = list(choices)
    matches = difflib.get_close_matches(word, choices, n=3, cutoff=0.75)
    if not matches:  # WheelSpeedFL for WHEEL_SPEED_FL: the same letters in another case
        lower = {c.lower(): c for c in choices}
        matches = [lower[m] for m in difflib.get_close_matches(word.lower(), lower, n=3,
                                                              cutoff=0.75)]
    if matches:
        return f"; closest: {', '.join(matches)}"
    if or_all and choices:
        return f"; there are: {', '.join(sorted(choices))}"
    return ""


class ValueReader:
    """Reads the values of one profile file, checking each: tables (only the allowed keys: an
    unknown one names the closest), sections, numbers (finite, of the sign asked, and within
    :data:`MAX_SECONDS`, :data:`MAX_METRES`, :data:`MAX_VEHICLE_METRES` or :data:`MAX_BITRATE` where
    the keyword :data:`SECONDS`, :data:`DISTANCE`, :data:`VEHICLE` or :data:`BITRATE` asks) and
    strings (one of their choices).
    """

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, reason: str) -> ProfileError:
        return ProfileError(self.path, key, reason)

    def table(self, value: Any, key: str, allowed: set[str],
              required: Sequence[str] = ()) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a table, got {type_name(value)}")
        for name in value:
            if name not in allowed:
                raise self.fail(f"{key}.{name}" if key else name,
                                f"unknown key{closest(name, allowed)} "
                                f"(allowed: {', '.join(sorted(allowed))})")
        for name in required:
            if name not in value:
                raise self.fail(key, f"missing required key '{name}'")
        return value

    def section(self, value: Any, key: str) -> dict[str, Any]:
        """A table whose keys are names the user chooses (sensors, groups, classes)."""
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a table, got {type_name(value)}")
        return value

    def number(self, table: Mapping[str, Any], key: str, name: str, default: float | None = None,
               *, positive: bool = False, non_negative: bool = False,
               at_most: float | None = None, unit: str = "") -> float:
        """A number of the table: finite, and within ``at_most`` (of either sign) where it is a
        time or a distance the drive computes with (:data:`MAX_SECONDS`, :data:`MAX_METRES`)."""
        value = table.get(name, default)
        full = f"{key}.{name}"
        if value is None:
            raise self.fail(key, f"missing required key '{name}'")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(full, f"expected a number, got {type_name(value)}")
        try:
            finite = math.isfinite(value)
        except OverflowError:  # an integer too large for a float
            finite = False
        if not finite:
            text = str(value)
            if len(text) > 20:
                text = f"{text[:20]}… ({len(text.lstrip('-'))} digits)"
            raise self.fail(full, f"must be finite, got {text}")
        if positive and value <= 0:
            raise self.fail(full, f"must be greater than 0, got {value}")
        if non_negative and value < 0:
            raise self.fail(full, f"must not be negative, got {value}")
        if at_most is not None and abs(value) > at_most:
            raise self.fail(full, f"must be at most {at_most:g}{unit}"
                            f"{' either way' if not (positive or non_negative) else ''}, "
                            f"got {value:g}")
        return float(value)

    def string(self, table: Mapping[str, Any], key: str, name: str, default: str | None = None,
               choices: Sequence[str] | None = None) -> str:
        value = table.get(name, default)
        full = f"{key}.{name}"
        if value is None:
            raise self.fail(key, f"missing required key '{name}'")
        if not isinstance(value, str):
            raise self.fail(full, f"expected a string, got {type_name(value)}")
        if choices is not None and value not in choices:
            raise self.fail(full, f"must be one of {', '.join(choices)}, got {value!r}")
        return value


def type_name(value: Any) -> str:
    """What a TOML value is, for an error: ``a number (3)``, ``a table``."""
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, int | float):
        return f"a number ({value})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__
