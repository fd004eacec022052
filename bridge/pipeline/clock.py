"""Clock steps: a car's clocks jump (an NTP correction at boot, an adapter reset, a logger with a
wrong date), and log time comes from the frames.

At a step everything on log time re-bases at once, never waiting for the log to catch up; every
frame keeps its own stamp, and the step is said on ``/log`` and listed in the drive's metadata.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.frame import NS, format_time, timestamp
from bridge.topics import LOG_TOPIC, TopicMessage

#: A frame this far before log time is a step back (frames of several buses, merged, may be a
#: little out of order; a smaller step back only holds the scene for that long).
BACK_NS = NS
#: Live: a frame this far ahead of log time (which live also knows from the wall clock) is a step.
LIVE_FORWARD_NS = 2 * NS
#: A log: a frame this far after the one before is a step; a shorter silence is a gap, whose
#: scene ticks and health checks are made.
LOG_FORWARD_NS = 60 * NS


@dataclass(frozen=True)
class ClockStep:
    """Log time jumped from ``from_ns`` (the log time before) to ``to_ns`` (a frame's stamp)."""

    from_ns: int
    to_ns: int

    @property
    def shift_ns(self) -> int:
        """What log time moved by: what everything on log time is shifted by."""
        return self.to_ns - self.from_ns

    @property
    def step_s(self) -> float:
        return self.shift_ns / NS

    def describe(self) -> str:
        way = "back" if self.shift_ns < 0 else "ahead"
        return (f"clock step: frame stamps jumped {way} by {abs(self.step_s):,.3f} s "
                f"(from {format_time(self.from_ns)} to {format_time(self.to_ns)}); scene and "
                "health re-based, frames recorded with their own stamps")

    def log(self) -> TopicMessage:
        """The ``/log`` message saying so, at the new log time."""
        return TopicMessage(LOG_TOPIC, Log(timestamp=timestamp(max(self.to_ns, 0)),
                                           level=Log.WARNING, message=self.describe(),
                                           name="tankviz"), self.to_ns)

    def to_dict(self) -> dict[str, Any]:
        """For the drive's metadata (``clock_steps``)."""
        return {"from_ns": self.from_ns, "to_ns": self.to_ns, "step_s": self.step_s}


class StepDetector:
    """Tells clock steps from frame stamps, the one detector of convert and live.

    A frame stamped more than ``back_ns`` before log time, or more than ``forward_ns`` after it, is
    a step (:class:`ClockStep`); in a log, a jump ahead is a step only beyond
    :data:`LOG_FORWARD_NS`, shorter ones are gaps. Everything on log time re-bases by
    :attr:`ClockStep.shift_ns`.
    """

    def __init__(self, *, back_ns: int = BACK_NS, forward_ns: int = LOG_FORWARD_NS) -> None:
        self.back_ns = back_ns
        self.forward_ns = forward_ns
        #: log time so far: the newest stamp, or where the clock went without a frame
        self.now_ns: int | None = None

    def check(self, t_ns: int) -> ClockStep | None:
        """A frame stamped ``t_ns``: the step it makes, if it makes one."""
        now = self.now_ns
        if now is None:
            self.now_ns = t_ns
            return None
        if t_ns > now:
            self.now_ns = t_ns
            if t_ns - now > self.forward_ns:
                return ClockStep(now, t_ns)
        elif now - t_ns > self.back_ns:
            self.now_ns = t_ns
            return ClockStep(now, t_ns)
        return None

    def passed(self, t_ns: int) -> None:
        """Log time reached ``t_ns`` without a frame (live's clock, a quiet bus)."""
        if self.now_ns is None or t_ns > self.now_ns:
            self.now_ns = t_ns
