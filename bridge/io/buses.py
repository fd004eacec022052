"""Live CAN buses: how one is named and opened (python-can's own bus creation: any interface,
several at once), kept open, and read.

Each bus has a thread that opens it (:class:`BusLink`): when the bus fails (adapter unplugged,
interface down) it says so, retries with backoff and says when it is back. A bus that cannot
work at all (an interface python-can does not have, a ``NAME`` without configuration, options it
refuses: :func:`configuration_error`) is a :class:`~bridge.errors.UsageError` at its first
opening, never retried. The pipeline's thread
reads every bus itself, without waiting, a few times per scene period (:class:`ReadSchedule`):
just after each scene tick and between; the frames of several buses are merged in time order
(:func:`merge_batches`).
"""

from __future__ import annotations

import contextlib
import difflib
import operator
import queue
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

from bridge.errors import UsageError
from bridge.frame import NS, Frame, to_ns

_BUS = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_.-]*)(=(?P<interface>[A-Za-z0-9_]+):"
                  r"(?P<channel>[^@]+)(@(?P<bitrate>\d+))?)?$")


@dataclass(frozen=True)
class BusSpec:
    """One bus: a name for the topics, and how python-can opens it.

    ``NAME=INTERFACE:CHANNEL[@BITRATE]`` (``radar=socketcan:can0``,
    ``car=pcan:PCAN_USBBUS1@500000``) or just ``NAME``: the section of that name in python-can's
    configuration file.
    """

    name: str
    interface: str | None = None
    channel: str | None = None
    bitrate: int | None = None

    @classmethod
    def parse(cls, text: str) -> BusSpec:
        match = _BUS.match(text.strip())
        if match is None:
            raise UsageError(f"--bus {text}: expected NAME=INTERFACE:CHANNEL[@BITRATE] "
                             "(e.g. radar=socketcan:can0) or the NAME of a python-can config "
                             "section")
        bitrate = match.group("bitrate")
        return cls(match.group("name"), match.group("interface"), match.group("channel"),
                   int(bitrate) if bitrate else None)

    def open(self) -> can.BusABC:
        """The bus, as python-can creates it."""
        if self.interface is None:
            return can.Bus(config_context=self.name)
        kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.bitrate is not None:
            kwargs["bitrate"] = self.bitrate
        return can.Bus(**kwargs)

    def __str__(self) -> str:
        if self.interface is None:
            return f"{self.name} (python-can config)"
        rate = f"@{self.bitrate}" if self.bitrate else ""
        return f"{self.name}={self.interface}:{self.channel}{rate}"


#: What python-can raises for a bus that cannot work however long one waits: no such interface
#: (also what a NAME without configuration gives), a driver module missing, options refused.
#: An ``OSError`` or other ``CanError`` may pass (an adapter not plugged in yet): retried.
CONFIGURATION_ERRORS = (can.CanInterfaceNotImplementedError, ImportError, ValueError, TypeError,
                        LookupError, NameError)


def configuration_error(spec: BusSpec, exc: Exception) -> UsageError | None:
    """The one-line error for a bus that cannot work (see :data:`CONFIGURATION_ERRORS`), or None
    for a failure that waiting may cure."""
    if not isinstance(exc, CONFIGURATION_ERRORS):
        return None
    if isinstance(exc, can.CanInterfaceNotImplementedError):
        if spec.interface is None:
            return UsageError(
                f"--bus {spec.name}: python-can's configuration has no interface for "
                f"{spec.name} (no [{spec.name}] section with an interface in "
                f"{', '.join(can.util.CONFIG_FILES)}); give --bus {spec.name}=INTERFACE:CHANNEL")
        known = sorted(can.interfaces.VALID_INTERFACES)
        if spec.interface not in known:
            close = difflib.get_close_matches(spec.interface, known, n=1)
            hint = f"did you mean {close[0]}?" if close else "one of " + ", ".join(known)
            return UsageError(f'--bus {spec}: python-can has no interface "{spec.interface}" '
                              f"({hint})")
    text = str(exc).strip().splitlines()
    return UsageError(f"--bus {spec}: cannot work: {type(exc).__name__}"
                      + (f": {text[0]}" if text else ""))


@dataclass(frozen=True)
class BusEvent:
    """A bus went away or came back."""

    bus: str
    up: bool
    t_ns: int
    reason: str = ""


class BusLink:
    """One bus: opened (and reopened after a failure, with backoff) by a thread of its own, and
    read without waiting by the pipeline's thread (:meth:`poll`).

    The pipeline reads every bus at once a few times per scene period, so a scene tick sees the
    frames of all buses before it, and no thread wakes up for each frame. Opening is what may
    block (an adapter that is being plugged in), so only the opener thread ever waits for it;
    it sleeps while the bus is up. Bus failures and returns are put on ``events``. A bus that
    cannot work (:func:`configuration_error`) at its first opening is not retried: the opener
    ends and :attr:`error` says why.
    """

    def __init__(self, spec: BusSpec, events: queue.SimpleQueue[BusEvent], *,
                 open_bus: Callable[[BusSpec], can.BusABC] = BusSpec.open,
                 backoff: tuple[float, float] = (0.2, 5.0)) -> None:
        self.spec = spec
        self.events = events
        self.open_bus = open_bus
        self.backoff = backoff
        self.stopping = threading.Event()
        #: set once the bus was opened, or failed to open, for the first time
        self.tried = threading.Event()
        #: why the bus cannot work at all (set, with ``tried``, by a failed first opening)
        self.error: UsageError | None = None
        self._opened = False  # once: later failures are a lost bus, retried
        self._bus: can.BusABC | None = None  # the open bus, handed over by the opener
        self._reopen = threading.Event()  # the opener is wanted
        self._reopen.set()
        self._down = False
        self._opener = threading.Thread(target=self._open_loop, daemon=True,
                                        name=f"tankviz-bus-{spec.name}")

    def start(self) -> None:
        if not self._opener.is_alive():
            self._opener.start()

    def stop(self) -> None:
        """Stops the opener; the bus stays readable until :meth:`close`."""
        self.stopping.set()
        self._reopen.set()
        if self._opener.is_alive():
            self._opener.join(2.0)

    def close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            with contextlib.suppress(Exception):  # a broken adapter may fail to close
                bus.shutdown()

    def _open_loop(self) -> None:
        delay = self.backoff[0]
        while not self.stopping.is_set():
            self._reopen.wait()
            if self.stopping.is_set():
                break
            try:
                try:
                    bus = self.open_bus(self.spec)
                except Exception as exc:
                    if not self._opened:
                        self.error = configuration_error(self.spec, exc)
                    raise
                finally:
                    self.tried.set()
            except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
                if self.error is not None:
                    break
                self._failed(exc)
                self.stopping.wait(delay)
                delay = min(delay * 2, self.backoff[1])
                continue
            delay = self.backoff[0]
            self._opened = True
            self._reopen.clear()
            if self._down:
                self._down = False
                self.events.put(BusEvent(self.spec.name, True, time.time_ns()))
            self._bus = bus
            if self.stopping.is_set():
                self.close()

    def _failed(self, exc: Exception) -> None:
        if not self._down:
            self._down = True
            self.events.put(BusEvent(self.spec.name, False, time.time_ns(),
                                     f"{type(exc).__name__}: {exc}".strip()))

    def poll(self, limit: int = 100_000) -> list[Frame]:
        """What the interface has received by now (at most ``limit`` frames), never waiting.

        When the bus fails, the frames read before are returned and the opener takes over.
        """
        bus = self._bus
        if bus is None:
            return []
        frames: list[Frame] = []
        name, to_frame = self.spec.name, _frame
        try:
            while len(frames) < limit and (message := bus.recv(0)) is not None:
                frames.append(to_frame(name, message))
        except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
            self.close()
            self._failed(exc)
            self._reopen.set()
        return frames


def _frame(bus: str, message: can.Message) -> Frame:
    return Frame(
        to_ns(message.timestamp), bus, message.arbitration_id, bytes(message.data),
        message.is_extended_id, message.is_fd, message.is_error_frame, message.is_remote_frame,
        message.bitrate_switch, message.error_state_indicator, message.dlc)


_timestamp = operator.itemgetter(0)  # of a Frame


def merge_batches(batches: list[list[Frame]]) -> list[Frame]:
    """The frames of several readers' batches in time order (each batch is in order; frames of
    one time keep their order): a scene tick then comes after every frame before it that had
    arrived, whichever bus brought it."""
    if len(batches) == 1:
        return batches[0]
    frames = [frame for batch in batches for frame in batch]
    frames.sort(key=_timestamp)  # stable, and fast on runs already in order
    return frames




class ReadSchedule:
    """When the live pipeline reads the buses: just after each scene tick, and twice between.

    Scene ticks are multiples of the scene period in log time (the frames' timestamps). The read
    ``after_tick_ns`` after a tick takes in every frame stamped before it, so the scene is
    computed at once; the read ``before_tick_ns`` before the next tick leaves little for that
    one; one more halfway keeps a busy bus's backlog short. Frames are read in the same thread
    that processes them, so nothing wakes up for every frame.

    Log time is wall time plus an offset that the frames tell (:meth:`saw`): a frame is read
    after it was stamped, so the newest frame's stamp minus the time of reading is at most the
    offset, and the largest is close to it (0 for buses stamped with the wall clock, such as
    socketcan and virtual; something else for an adapter's own clock). A larger one counts at
    once, a smaller one (a clock that drifts) once a second, from the next read on: the read
    made just after a tick must still see that tick due. When the frames' clock steps, the
    pipeline re-bases and the offset starts again from the newest frame (:meth:`restart`).
    """

    def __init__(self, period_ns: int, *, after_tick_ns: int = 500_000,
                 before_tick_ns: int = 2_500_000) -> None:
        self.period_ns = period_ns
        self.after_tick_ns = min(after_tick_ns, period_ns // 4)
        self.phases = sorted({self.after_tick_ns, period_ns // 2,
                              max(period_ns - before_tick_ns, period_ns * 3 // 4)})
        self.offset_ns: int | None = None  # log time - wall time, once a frame was seen
        self._best: int | None = None
        self._window_end = 0
        self._next_offset: int | None = None  # the last second's best, from the next read on
        self._last_read_ns: int | None = None  # when the last read began

    def saw(self, newest_ns: int, now_ns: int) -> None:
        """The newest frame of a read (log time) and when it was read (wall time)."""
        if now_ns >= self._window_end:
            if self._best is not None:
                self._next_offset = self._best  # also if less (a drifting clock)
            self._best = None
            self._window_end = now_ns + NS
        lead = newest_ns - now_ns
        if self._best is None or lead > self._best:
            self._best = lead
        if self.offset_ns is None or lead > self.offset_ns:
            self.offset_ns = lead  # a better estimate counts at once

    def restart(self, newest_ns: int, now_ns: int) -> None:
        """The frames' clock stepped (:mod:`bridge.pipeline.clock`): forget the offset, and take
        the newest frame's (log time, after the step) and its reading's (wall time) at once."""
        self.offset_ns = newest_ns - now_ns
        self._best = None
        self._next_offset = None
        self._window_end = now_ns + NS

    def log_time(self, now_ns: int) -> int | None:
        """Log time now, minus the time frames may take to be read: every frame stamped
        before this has been read (None before the first frame)."""
        if self.offset_ns is None:
            return None
        return now_ns + self.offset_ns - self.after_tick_ns

    def reading(self, now_ns: int) -> None:
        """A read begins (wall time)."""
        self._last_read_ns = now_ns

    def wait(self, clock: Callable[[], int] = time.time_ns,
             sleep: Callable[[float], None] = time.sleep) -> None:
        """Sleep until the next read is due (again, if a sleep ends a hair early), then note
        that it begins."""
        read_at = self.next_read_ns(clock())
        while (pause := read_at - clock()) > 0:
            sleep(pause / NS)
        self.reading(clock())

    def next_read_ns(self, now_ns: int) -> int:
        """The wall time of the next read: the first after the last read began, so a read that
        ran past the next one's time is followed at once, never by skipping it (the read after a
        tick starts that scene); before any read, the first after ``now_ns``."""
        if self._last_read_ns is not None:
            now_ns = self._last_read_ns
        if self._next_offset is not None:
            best = self._best  # of this second so far
            self.offset_ns = (self._next_offset if best is None
                              else max(self._next_offset, best))
            self._next_offset = None
        offset = self.offset_ns or 0
        log_now = now_ns + offset
        tick = log_now - log_now % self.period_ns
        for phase in self.phases:
            if tick + phase > log_now:
                return tick + phase - offset
        return tick + self.period_ns + self.phases[0] - offset
