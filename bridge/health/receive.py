"""What a live bus's reading mended or lost before its frames reached the pipeline, and how the
health monitor says so.

:class:`ReceiveWatch` says live's receive counts (bad timestamps, unreadable frames, kernel
drops, frames missed while a bus was down) in log time: a ``/log`` warning when a count first
grows, then at most every ``REPORT_S`` seconds, and the alarms ``bus.<bus>.bad_timestamps`` and
``bus.<bus>.frames_lost``, raised at once and cleared after the clear time.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.frame import NS, timestamp
from bridge.health.alarms import AlarmKind, alarm_id
from bridge.topics import LOG_TOPIC, TopicMessage

if TYPE_CHECKING:  # (live's buses and python-can's interfaces: a convert never needs them)
    from bridge.io.buses import ReceiveCounts

#: seconds of log time between two /log warnings of the same count
REPORT_S = 10.0


def _plural(n: int, word: str) -> str:
    return f"{n:,} {word}" + ("" if n == 1 else "s")


def warning_text(bus: str, what: str, counts: ReceiveCounts) -> str:
    """The ``/log`` line of one count (``what``: a field of :class:`ReceiveCounts`)."""
    if what == "bad_timestamps":
        return (f"bus {bus}: {_plural(counts.bad_timestamps, 'frame')} stamped "
                f"{counts.last_bad_timestamp} s so far: each stamped with the time it was "
                "received instead, and recorded")
    if what == "kernel_drops":
        return (f"bus {bus}: {_plural(counts.kernel_drops, 'frame')} lost in the receive buffer "
                "so far (the kernel dropped them: tankviz read too late; receive buffer "
                f"{counts.receive_buffer_bytes // 1024:,} KB)")
    return (f"bus {bus}: {_plural(counts.unreadable, 'message')} from python-can that "
            f"{'is' if counts.unreadable == 1 else 'are'} not a CAN frame so far (the latest: "
            f"{counts.last_unreadable}): skipped")


#: the alarm of a count: (its kind, the reason it holds)
ALARMS: dict[str, tuple[AlarmKind, Callable[[str, ReceiveCounts], str]]] = {
    "bad_timestamps": (AlarmKind.BAD_TIMESTAMPS, lambda bus, c: (
        f"bus {bus}: frames stamped {c.last_bad_timestamp} s ({c.bad_timestamps:,} since the "
        "start): stamped with the time they were received")),
    "kernel_drops": (AlarmKind.FRAMES_LOST, lambda bus, c: (
        f"bus {bus}: frames lost in the receive buffer ({c.kernel_drops:,} since the start)")),
}


class ReceiveWatch:
    """The receive counts of every bus, as the monitor is told them, and what it says of them."""

    def __init__(self) -> None:
        self.counts: dict[str, ReceiveCounts] = {}
        #: (bus, count name) -> (the count at the last check, log time it last grew)
        self._grew: dict[tuple[str, str], tuple[int, int]] = {}
        #: (bus, count name) -> (the count said on /log, log time said)
        self._said: dict[tuple[str, str], tuple[int, int]] = {}

    def note(self, bus: str, counts: ReceiveCounts) -> list[AlarmKind]:
        """A bus's counts now; returns the kinds of the bus's alarms it may need from now on."""
        self.counts[bus] = counts
        return [kind for what, (kind, _) in ALARMS.items() if getattr(counts, what)]

    def conditions(self, t_ns: int, window_ns: int) -> Iterator[tuple[str, str]]:
        """The alarms whose count grew within ``window_ns`` before ``t_ns``, as (alarm id,
        why)."""
        for bus, counts in self.counts.items():
            for what, (kind, why) in ALARMS.items():
                n = getattr(counts, what)
                before, grew_ns = self._grew.get((bus, what), (0, -(1 << 62)))
                if n > before:
                    grew_ns = t_ns
                self._grew[bus, what] = (n, grew_ns)
                if t_ns - grew_ns < window_ns:
                    yield alarm_id(kind, bus), why(bus, counts)

    def rebase(self, shift_ns: int) -> None:
        """The clock stepped by ``shift_ns``: the times held move with it."""
        self._grew = {key: (n, t + shift_ns) for key, (n, t) in self._grew.items()}
        self._said = {key: (n, t + shift_ns) for key, (n, t) in self._said.items()}

    def warnings(self, t_ns: int) -> list[TopicMessage]:
        """``/log`` warnings of counts that grew: at once the first time, then at most every
        :data:`REPORT_S` seconds."""
        out = []
        for bus, counts in self.counts.items():
            for what in ("bad_timestamps", "kernel_drops", "unreadable"):
                n = getattr(counts, what)
                said, at = self._said.get((bus, what), (0, -(1 << 62)))
                if n > said and abs(t_ns - at) >= REPORT_S * NS:
                    self._said[bus, what] = (n, t_ns)
                    out.append(TopicMessage(LOG_TOPIC, Log(
                        timestamp=timestamp(t_ns), level=Log.WARNING,
                        message=warning_text(bus, what, counts), name="tankviz.buses"), t_ns))
        return out
