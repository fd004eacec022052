"""The one CAN frame type that flows through the bridge, and its time base.

Log time is integer nanoseconds (:data:`NS` a second), since the Unix epoch for sources with
absolute time, else since the log's start; :func:`frame_key` makes an id's number and format one
int, the key of every per-id table.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import NamedTuple

from google.protobuf.timestamp_pb2 import Timestamp

#: Nanoseconds per second: the unit of every time in the bridge.
NS = 1_000_000_000
#: A log time before every frame's (nothing happened yet), and one after every frame's (nothing
#: is due): integer markers, so that every time held is an int (no float infinities).
NEVER_NS = -(1 << 62)
END_NS = 1 << 62


#: The bit of a frame key (:func:`frame_key`) that marks a 29-bit id (no CAN id reaches it).
EXTENDED_KEY = 1 << 31


def frame_key(arbitration_id: int, extended: bool) -> int:
    """One int for a CAN id and its format: ``arbitration_id``, with :data:`EXTENDED_KEY` set for
    a 29-bit (extended) id. The per-frame paths (the decoder's and the health monitor's) write
    it out inline, saying so: the call would cost them about 25 ns a frame."""
    return arbitration_id | EXTENDED_KEY if extended else arbitration_id


def key_id(key: int) -> int:
    """The arbitration id of a frame key (:func:`frame_key`), without its format."""
    return key & ~EXTENDED_KEY


def to_ns(seconds: float) -> int:
    """python-can's float seconds to integer nanoseconds, rounded to the microsecond."""
    return round(seconds * 1_000_000) * 1000


def timestamp(t_ns: int) -> Timestamp:
    """A log time as a protobuf Timestamp (the stamp of every message tankviz makes)."""
    return Timestamp(seconds=t_ns // NS, nanos=t_ns % NS)


def format_time(ns: int) -> str:
    """A log time for people: UTC with milliseconds when absolute (after 1973), else seconds
    since the log's start, marked relative."""
    if ns >= 10**17:
        return datetime.fromtimestamp(ns / NS, tz=timezone.utc).isoformat(timespec="milliseconds")
    return f"{ns / NS:.3f} s (relative)"


class Frame(NamedTuple):
    """One CAN frame as it was seen on a bus.

    ``timestamp_ns`` is integer nanoseconds (since the Unix epoch for logs and buses with absolute
    time, since the log's own start otherwise). Float seconds from python-can are converted once,
    at the source (:func:`to_ns`).
    """

    timestamp_ns: int
    bus: str
    arbitration_id: int
    data: bytes
    is_extended: bool = False
    is_fd: bool = False
    is_error: bool = False
    is_remote: bool = False
    bitrate_switch: bool = False
    error_state_indicator: bool = False
    dlc: int = 0

