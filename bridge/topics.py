"""Every topic name and frame id the bridge publishes: the one place that defines them.

Code, layouts and docs use these; tests check layouts against this module, not a copy.
"""

from __future__ import annotations

import re
from typing import Any, NamedTuple


class TopicMessage(NamedTuple):
    """A message for the sinks: its topic, the protobuf message, its log time."""

    topic: str
    message: Any
    t_ns: int


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


#: tankviz's own topics under every bus, ``/can/<bus>/<leaf>``: each leaf and what it carries
#: (:func:`frames_topic`, :func:`ids_topic`, :func:`unknown_topic`). A new one goes here.
BUS_LEAVES = {"frames": "tankviz's raw frames", "ids": "bring-up's ids",
              "unknown": "bring-up's unknown ids"}
#: Where a message goes whose topic would be one of tankviz's own: ``/can/<bus>/msg/<Message>``.
MOVED_SEGMENT = "msg"


def own_topic(bus: str, message_name: str) -> str | None:
    """What tankviz publishes on the topic that ``message_name`` of ``bus`` would plainly take
    (``/can/<bus>/<Message>``), or None when that topic is no topic of tankviz's own.
    Topics are case-sensitive: ``Frames`` takes none."""
    what = BUS_LEAVES.get(message_name)
    if what is None:
        what = _CAN_TOPICS.get(f"/can/{bus_segment(bus)}/{message_name}")
    return what


def message_topic(bus: str, message_name: str) -> str:
    """The decoded signals of one DBC message on one bus: ``/can/<bus>/<Message>``, the name as
    the database spells it, or ``/can/<bus>/msg/<Message>`` where that would be one of tankviz's
    own topics (:func:`own_topic`); a name that starts with ``msg/`` (a KCD may have one) goes
    there too, so that no two names share a topic. Every topic of a message is this
    function's."""
    if (own_topic(bus, message_name) is not None
            or message_name.startswith(f"{MOVED_SEGMENT}/")):
        return f"/can/{bus_segment(bus)}/{MOVED_SEGMENT}/{message_name}"
    return f"/can/{bus_segment(bus)}/{message_name}"


def short_topic(topic: str) -> str:
    """The decoded signals of a message's frames shorter than it, beside its ``topic``:
    ``/can/<bus>/<Message>/short`` (their type lets any signal be absent; the message's own
    writes a signal that every whole frame has without presence, so 0 is not written)."""
    return f"{topic}/short"


def scene_topic(category: str) -> str:
    """``foxglove.SceneUpdate`` of one category: ego, lanes, lead, mio, or an object group."""
    return f"/scene/{category}"


#: Sensor mounts as ``foxglove.FrameTransforms`` (parent: the vehicle frame).
TF_TOPIC = "/tf"


def objects_topic(group: str) -> str:
    """Every valid object of one group as ``tankviz.PerceivedObjects``."""
    return f"/perception/{group}"


#: The lead vehicle and its MIO check (``tankviz.LeadVehicle``).
LEAD_TOPIC = "/perception/lead"
#: The lane model of the moment (``tankviz.Lanes``).
LANES_TOPIC = "/perception/lanes"
#: Ego speed, yaw rate, steering (``tankviz.EgoState``).
EGO_TOPIC = "/ego"
#: Messages for people (``foxglove.Log``): alarms, bus loss, skipped input.
LOG_TOPIC = "/log"
#: Moments somebody marked (``tankviz.Mark``): from a viewer's Publish panel (the one topic a
#: viewer may publish to), a profile's ``[marks]`` rule, live's terminal.
MARKS_TOPIC = "/marks"
#: The scene category of the marks, each shown for a few seconds.
MARKS_CATEGORY = "marks"
#: Bus, message family and sensor health with its alarms (``tankviz.Health``).
HEALTH_TOPIC = "/health"
#: The scene category of the alarm overlay and the sensors' fields of view.
HEALTH_CATEGORY = "health"


def ids_topic(bus: str) -> str:
    """Bring-up: every id of one bus, a row each, about once a second (``tankviz.CanIds``)."""
    return f"/can/{bus_segment(bus)}/ids"


def unknown_topic(bus: str) -> str:
    """Bring-up: each data frame of an id no database of the bus defines, its bytes and 16-bit
    words (``tankviz.CanPayload``)."""
    return f"/can/{bus_segment(bus)}/unknown"


#: Bring-up: the bit-change map of every id of every bus, about once a second
#: (``foxglove.CompressedImage``, PNG).
BITS_TOPIC = "/can/bits"
#: Bring-up: the map's row labels and header (``foxglove.ImageAnnotations``, the image's stamp).
BITS_LABELS_TOPIC = "/can/bits/labels"
#: tankviz's own topics under ``/can/`` of no bus, and what they carry (as :data:`BUS_LEAVES`)
_CAN_TOPICS = {BITS_TOPIC: "bring-up's bit map", BITS_LABELS_TOPIC: "bring-up's bit-map labels"}
