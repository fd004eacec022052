"""The one CAN frame type that flows through the bridge."""

from __future__ import annotations

from typing import NamedTuple


class Frame(NamedTuple):
    """One CAN frame as it was seen on a bus.

    ``timestamp_ns`` is integer nanoseconds (since the Unix epoch for logs and buses with absolute
    time, since the log's own start otherwise). Float seconds from python-can are converted once,
    at the source (:func:`bridge.io.logs.to_ns`).
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

