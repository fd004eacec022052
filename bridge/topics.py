"""Every topic name and frame id the bridge publishes: the one place that defines them.

Code, layouts and docs use these; tests check layouts against this module, not a copy.
"""

from __future__ import annotations

import re

#: The vehicle frame (x forward, y left, z up) in which the whole scene is drawn.
VEHICLE_FRAME = "vehicle"

_UNSAFE = re.compile(r"[^A-Za-z0-9_]")


def bus_segment(bus: str) -> str:
    """A bus name made safe for one topic path segment (``can0``, ``radar``)."""
    cleaned = _UNSAFE.sub("_", bus.strip())
    return cleaned or "unnamed"


def frames_topic(bus: str) -> str:
    """Every raw frame of one bus, for re-decoding a drive later with another DBC."""
    return f"/can/{bus_segment(bus)}/frames"


def message_topic(bus: str, message_name: str) -> str:
    """The decoded signals of one DBC message on one bus."""
    return f"/can/{bus_segment(bus)}/{message_name}"
