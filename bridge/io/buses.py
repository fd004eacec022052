"""Live CAN buses: how one is named and opened (python-can's own bus creation: any interface,
several at once), kept open, and read.

Each bus has a thread that opens it (:class:`BusLink`). A bus that cannot work at all (an
interface python-can does not have, a ``NAME`` without configuration, options it refuses:
:func:`configuration_error`) is a :class:`~bridge.errors.UsageError` at its first opening, never
retried. Any other failure to open (a socketcand server that is down, an address that is not one,
an interface that is not there) is retried with backoff; live waits at most :data:`OPEN_WAIT_S`
seconds (15) for every bus to open once, and a bus that has never opened by then is an error too
(:class:`bridge.pipeline.live_engine.Live`). Only a bus that opened once and then fails
(adapter unplugged, interface down) is a lost bus: the link says so, retries with backoff for as
long as the run goes on and says when it is back. Every reason is one line (:func:`one_line`:
the exception's type and the first line of its message, never a traceback).

The pipeline's thread reads every bus itself, without waiting, a few times per scene period
(:class:`ReadSchedule`): just after each scene tick and between; the frames of several buses are
merged in time order (:func:`merge_batches`). A read takes what python-can has received as
``recv(0)`` would, with less work per frame (:func:`_received`): a bus whose ``recv`` is
python-can's own is read through ``_recv_internal``, the method ``recv`` calls, with the same
filters. A frame whose stamp is not a time (NaN, infinite, before 1970 or after 2262) is not a
failure of the bus: it is stamped with the time it was read (on the bus's own clock, as its last
frames tell it), kept, and counted; something that is not a frame at all is skipped and counted,
and so is a datagram that a udp_multicast bus cannot unpack (another program's on the group: the
bus reads on, :func:`one_datagram`) (:class:`ReceiveCounts`, which :mod:`bridge.health.receive`
tells on ``/log`` and ``/health``). A udp_multicast bus hears only its own group
(:func:`own_group_only`: python-can binds every such socket to one port, and Linux gives each
socket every group the host joined).
Where python-can exposes the socket (socketcan, udp_multicast), its receive buffer is raised to
:data:`RECEIVE_BUFFER_BYTES` (as far as the OS allows: :func:`raise_receive_buffer`) and the
kernel's count of the frames it dropped for want of room is read at each read
(:func:`kernel_drops`).

python-can's own log lines (a warning per connection attempt: hundreds of thousands a second
from socketcand) go through :class:`CanLogLimiter`: each cause is said once, then at most every
10 s with how often it repeated (what is still counted when the run ends is said then).
"""

from __future__ import annotations

import contextlib
import difflib
import logging
import operator
import queue
import re
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from typing import Any

import can
from can.interfaces.udp_multicast import UdpMulticastBus

from bridge.errors import UsageError
from bridge.fences import PYTHON_CAN
from bridge.frame import NS, Frame

#: Seconds live waits for every bus to open once before a bus that never opened is an error
#: (longer than python-can's socketcand spends on one connection attempt, 10 s).
OPEN_WAIT_S = 15.0
#: The receive buffer asked for a bus's socket (the OS may allow less: ``net.core.rmem_max``).
RECEIVE_BUFFER_BYTES = 8 << 20
#: The last second a frame can be stamped with (int64 nanoseconds: 2262).
LAST_SECOND = ((1 << 63) - 1) // NS

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
            raise UsageError("--bus", "expected NAME=INTERFACE:CHANNEL[@BITRATE] "
                             "(e.g. radar=socketcan:can0) or the NAME of a python-can config "
                             "section", value=text)
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
                "--bus", f"python-can's configuration has no interface for "
                f"{spec.name} (no [{spec.name}] section with an interface in "
                f"{', '.join(can.util.CONFIG_FILES)}); give --bus {spec.name}=INTERFACE:CHANNEL",
                value=spec.name)
        known = sorted(can.interfaces.VALID_INTERFACES)
        if spec.interface not in known:
            close = difflib.get_close_matches(spec.interface, known, n=1)
            hint = f"did you mean {close[0]}?" if close else "one of " + ", ".join(known)
            return UsageError("--bus", f'python-can has no interface "{spec.interface}" '
                              f"({hint})", value=spec)
    text = str(exc).strip().splitlines()
    return UsageError("--bus", f"cannot work: {type(exc).__name__}"
                      + (f": {text[0]}" if text else ""), value=spec)


def one_line(exc: BaseException) -> str:
    """An exception as one line: its type and the first line of its message (python-can's
    socketcand puts a whole traceback into its errors' messages)."""
    text = _first_line(str(exc))
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _first_line(text: str) -> str:
    lines = text.strip().splitlines()
    first = lines[0] if lines else ""
    return first.split("Traceback (most recent call last)")[0].strip()


# --- the socket under a bus ---------------------------------------------------------------------

_SO_RCVBUFFORCE = 33  # Linux: SO_RCVBUF past net.core.rmem_max (needs CAP_NET_ADMIN)
_SO_MEMINFO = 55  # Linux: the socket's memory counters (u32 each), drops the ninth
_MEMINFO_DROPS = 8


def receive_socket(bus: can.BusABC) -> socket.socket | None:
    """The socket python-can reads the bus from, where it exposes one (socketcan: ``socket``;
    udp_multicast: its multicast bus's ``_socket``)."""
    for found in (getattr(bus, "socket", None),
                  getattr(getattr(bus, "_multicast", None), "_socket", None)):
        if isinstance(found, socket.socket):
            return found
    return None


def raise_receive_buffer(sock: socket.socket, size: int) -> int:
    """Ask for a receive buffer of ``size`` bytes (past the OS's limit where allowed, else up to
    it); returns the size the OS gives (Linux reports twice what is asked, for its overhead)."""
    for option in ((_SO_RCVBUFFORCE, socket.SO_RCVBUF) if sys.platform == "linux"
                   else (socket.SO_RCVBUF,)):
        try:
            if sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) >= size:
                break
            sock.setsockopt(socket.SOL_SOCKET, option, size)
            break
        except OSError:
            continue
    try:
        return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    except OSError:
        return 0


def meminfo_drops(raw: bytes) -> int | None:
    """The drop counter in ``SO_MEMINFO``'s answer (None if the kernel gives no such count)."""
    count = len(raw) // 4
    if count <= _MEMINFO_DROPS:
        return None
    return int(struct.unpack(f"{count}I", raw[:count * 4])[_MEMINFO_DROPS])


def kernel_drops(sock: socket.socket) -> int | None:
    """How many packets (frames) the kernel dropped on ``sock`` for want of room in its receive
    buffer: the counter ``SO_RXQ_OVFL`` reports (None where it cannot be read: not Linux, a
    closed socket)."""
    if sys.platform != "linux":
        return None
    try:
        return meminfo_drops(sock.getsockopt(socket.SOL_SOCKET, _SO_MEMINFO, 4 * 9))
    except OSError:
        return None


_IP_MULTICAST_ALL = 49  # Linux: 1 (default): every group the host joined; 0: the socket's own
_IPV6_MULTICAST_ALL = 29


def own_group_only(bus: can.BusABC) -> None:
    """A udp_multicast bus's socket gets only the group it joined.

    python-can binds every udp_multicast socket to the same port, and Linux delivers to each
    every group that any socket of the host joined (``IP_MULTICAST_ALL``): two buses would each
    get both groups' frames. Set off; what the socket had queued before (maybe another group's)
    is dropped: the bus is open from here. (Other systems deliver a socket its own groups only.)
    """
    sock = receive_socket(bus)
    if not isinstance(bus, UdpMulticastBus) or sock is None or sys.platform != "linux":
        return
    with contextlib.suppress(OSError):  # a kernel without it (IPv6 before Linux 4.20)
        if sock.family == socket.AF_INET:
            sock.setsockopt(socket.IPPROTO_IP, _IP_MULTICAST_ALL, 0)
        else:
            sock.setsockopt(socket.IPPROTO_IPV6, _IPV6_MULTICAST_ALL, 0)
    with contextlib.suppress(OSError):  # (BlockingIOError: nothing more queued)
        while True:
            sock.recv(1, socket.MSG_DONTWAIT)


def one_datagram(bus: can.BusABC, exc: Exception) -> bool:
    """Whether ``exc``, raised by reading ``bus``, is about one datagram python-can took off a
    udp_multicast bus and could not read (no msgpack frame: another program's on the group, an
    error frame with an id >= 2**29; a bad receive stamp), not about the bus: that datagram is
    skipped and counted, and the bus read on. A failure of the socket itself comes from an
    ``OSError``: the bus is lost."""
    return (isinstance(bus, UdpMulticastBus) and isinstance(exc, can.CanOperationError)
            and not isinstance(exc.__cause__, OSError))


def datagram_text(exc: BaseException) -> str:
    """Why a datagram could not be read, in one line: python-can's error and its cause."""
    cause = exc.__cause__
    return one_line(exc) + (f" ({one_line(cause)})" if cause is not None else "")


# --- python-can's log lines ---------------------------------------------------------------------

_DIGITS = re.compile(r"\d+")


class CanLogLimiter(logging.Handler):
    """python-can's log lines (warnings and worse), one per cause: the first at once, then the
    latest at most every ``every_s`` seconds with how many came since
    (``python-can: TEXT (repeated N times in the last S s)``); :meth:`close` says what is still
    counted. A cause is the logger and the first line of the message, its numbers left out; a
    traceback is never said."""

    def __init__(self, say: Callable[[str], None], *,
                 clock: Callable[[], float] = time.monotonic, every_s: float = 10.0) -> None:
        super().__init__(logging.WARNING)
        self.say = say
        self.clock = clock
        self.every_s = every_s
        self._causes: dict[str, tuple[float, int, str]] = {}  # since, repeats, latest text
        self._finished = False

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = _first_line(record.getMessage())
        except Exception:  # a message that does not format
            text = _first_line(str(record.msg))
        key = f"{record.name} {record.levelno} {_DIGITS.sub('#', text)}"
        now = self.clock()
        cause = self._causes.get(key)
        if cause is not None and self._finished:
            return
        if cause is not None and now - cause[0] < self.every_s:
            self._causes[key] = (cause[0], cause[1] + 1, text)
            return
        self._causes[key] = (now, 0, text)
        if cause is not None and cause[1]:
            self._say(text, cause[1] + 1, now - cause[0])
        else:
            self.say(f"python-can: {text}")

    def _say(self, text: str, times: int, seconds: float) -> None:
        self.say(f"python-can: {text} (repeated {times:,} time{'' if times == 1 else 's'} in "
                 f"the last {seconds:.0f} s)")

    def flush_counts(self) -> None:
        """Say the repeats counted and not yet said."""
        with self.lock or contextlib.nullcontext():
            now = self.clock()
            for key, (since, repeats, text) in list(self._causes.items()):
                if repeats:
                    self._say(text, repeats, now - since)
                    self._causes[key] = (now, 0, text)

    def finish(self) -> None:
        """Say the repeats counted, and from now on only new causes (the run's last line is
        its own: an opener thread python-can keeps busy may log on until the process ends)."""
        self.flush_counts()
        self._finished = True

    def close(self) -> None:
        self.flush_counts()
        super().close()


def limit_can_logs(say: Callable[[str], None]) -> CanLogLimiter:
    """Route python-can's log lines (logger ``can``) through a :class:`CanLogLimiter` that
    passes them to ``say``, instead of Python's last-resort printing of every one."""
    limiter = CanLogLimiter(say)
    logger = logging.getLogger("can")
    logger.addHandler(limiter)
    logger.propagate = False
    return limiter


@dataclass
class ReceiveCounts:
    """What one bus's reading mended or lost since the run began (:mod:`bridge.health.receive`
    says what each count is)."""

    bad_timestamps: int = 0
    last_bad_timestamp: str = ""
    unreadable: int = 0
    last_unreadable: str = ""
    kernel_drops: int = 0
    receive_buffer_bytes: int = 0
    missed_estimate: int = 0

    def to_dict(self) -> dict[str, Any]:
        """For the drive's metadata (``bus_receive``)."""
        return asdict(self)


@dataclass(frozen=True)
class BusEvent:
    """A bus that had opened went away, or came back (then, where its rate was known, about
    how many frames it missed while it was down: ``missed``, from ``rate`` frames per second)."""

    bus: str
    up: bool
    t_ns: int
    reason: str = ""
    missed: int | None = None
    rate: float | None = None


class BusLink:
    """One bus: opened (and reopened after a failure, with backoff) by a thread of its own, and
    read without waiting by the pipeline's thread (:meth:`poll`).

    The pipeline reads every bus at once a few times per scene period, so a scene tick sees the
    frames of all buses before it, and no thread wakes up for each frame. Opening is what may
    block (an adapter that is being plugged in, a server that does not answer), so only the
    opener thread ever waits for it; it sleeps while the bus is up. A bus that cannot work
    (:func:`configuration_error`) at its first opening is not retried: the opener ends and
    :attr:`error` says why. Other failures to open are retried; until the bus first opened
    (:attr:`opened`) they are only noted (:attr:`failure`, :attr:`tries`), after that a failure
    and the return are put on ``events`` (a lost bus). :attr:`receive` counts what the reading
    mended or lost (bad stamps, what is not a frame, the kernel's drops, and an estimate of the
    frames missed while the bus was down: its frame rate while up, after a second of it, times
    how long it was down, on ``clock``).
    """

    def __init__(self, spec: BusSpec, events: queue.SimpleQueue[BusEvent], *,
                 open_bus: Callable[[BusSpec], can.BusABC] = BusSpec.open,
                 backoff: tuple[float, float] = (0.2, 5.0),
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.spec = spec
        self.clock = clock
        self.events = events
        self.open_bus = open_bus
        self.backoff = backoff
        self.stopping = threading.Event()
        #: set once the bus was opened, or failed to open, for the first time
        self.tried = threading.Event()
        #: set once the bus was opened for the first time
        self.opened = threading.Event()
        #: why the bus cannot work at all (set, with ``tried``, by a failed first opening)
        self.error: UsageError | None = None
        #: why the latest opening failed (one line), and how many were tried
        self.failure = ""
        self.tries = 0
        #: what the reading mended or lost so far
        self.receive = ReceiveCounts()
        self._bus: can.BusABC | None = None  # the open bus, handed over by the opener
        self._socket: socket.socket | None = None  # its socket, where python-can exposes it
        self._drops_before = 0  # the kernel's drops on the sockets of earlier openings
        self._lead_ns: int | None = None  # the bus's clock minus the wall clock, as last read
        self._reopen = threading.Event()  # the opener is wanted
        self._reopen.set()
        self._down = False
        #: frames read since the start
        self.frames_read = 0
        self._up_s = 0.0  # seconds the bus was up, before its latest opening
        self._up_since: float | None = None  # when it was last opened (clock)
        self._lost_at = 0.0  # when it was last lost (clock)
        self._opener = threading.Thread(target=self._open_loop, daemon=True,
                                        name=f"tankviz-bus-{spec.name}")

    def start(self) -> None:
        if self._opener.ident is None and not self.stopping.is_set():  # (a thread starts once)
            self._opener.start()

    def stop(self) -> None:
        """Stops the opener; the bus stays readable until :meth:`close`."""
        self.stopping.set()
        self._reopen.set()
        if self._opener.is_alive():
            self._opener.join(2.0)

    def close(self) -> None:
        bus, self._bus = self._bus, None
        sock, self._socket = self._socket, None
        if sock is not None:
            self._drops_before += kernel_drops(sock) or 0
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
                    if not self.opened.is_set():
                        self.error = configuration_error(self.spec, exc)
                    raise
                finally:
                    self.tries += 1
                    self.tried.set()
            except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
                if self.error is not None:
                    break
                self._failed(exc)
                self.stopping.wait(delay)
                delay = min(delay * 2, self.backoff[1])
                continue
            delay = self.backoff[0]
            self._reopen.clear()
            now = self.clock()
            if self._down:
                self._down = False
                self._back(now)
            self._up_since = now
            own_group_only(bus)
            sock = receive_socket(bus)
            if sock is not None:
                self.receive.receive_buffer_bytes = raise_receive_buffer(
                    sock, RECEIVE_BUFFER_BYTES)
            self._socket = sock
            self._bus = bus
            self.opened.set()
            if self.stopping.is_set():
                self.close()

    def _failed(self, exc: Exception) -> None:
        self.failure = one_line(exc)
        if self.opened.is_set() and not self._down:
            self._down = True
            self._lost_at = now = self.clock()
            if self._up_since is not None:
                self._up_s += now - self._up_since
                self._up_since = None
            self.events.put(BusEvent(self.spec.name, False, time.time_ns(), self.failure))

    def _back(self, now: float) -> None:
        """The bus is back: about how many frames it missed (its rate while up, once it was up
        a second, times how long it was down), counted and said."""
        rate = self.frames_read / self._up_s if self._up_s >= 1.0 else None
        missed = None if rate is None else round(rate * max(now - self._lost_at, 0.0))
        if missed is not None:
            self.receive.missed_estimate += missed
        self.events.put(BusEvent(self.spec.name, True, time.time_ns(), missed=missed, rate=rate))

    def poll(self, limit: int = 100_000) -> list[Frame]:
        """What the interface has received by now (at most ``limit`` frames), never waiting.

        When the bus fails, the frames read before are returned and the opener takes over. A
        frame whose stamp is not a time is stamped with the time it is read and kept; something
        that is not a frame, and a datagram python-can could not unpack (:func:`one_datagram`),
        are skipped; all are counted (:attr:`receive`).
        """
        bus = self._bus
        if bus is None:
            return []
        frames: list[Frame] = []
        name, to_frame, append = self.spec.name, _frame, frames.append
        failure = None
        try:
            for message in _received(bus, limit, self._skip):
                try:
                    append(to_frame(name, message))
                except Exception as exc:  # a stamp that is not a time, or not a frame at all
                    self._mend(message, exc, frames)
        except Exception as exc:  # python-can raises CanError, OSError, ValueError, ...
            failure = exc
        self.frames_read += len(frames)
        if failure is not None:
            self.close()
            self._failed(failure)
            self._reopen.set()
        if frames:
            self._lead_ns = frames[-1].timestamp_ns - time.time_ns()
        sock = self._socket
        if sock is not None:
            drops = kernel_drops(sock)
            if drops is not None:
                self.receive.kernel_drops = self._drops_before + drops
        return frames

    def _skip(self, exc: Exception) -> None:
        """A datagram python-can took and could not read: counted, skipped."""
        self.receive.unreadable += 1
        self.receive.last_unreadable = datagram_text(exc)

    def _mend(self, message: can.Message, exc: Exception, frames: list[Frame]) -> None:
        """A frame python-can gave that :func:`_frame` refused: kept, stamped with the time it
        is read on the bus's clock (never before the frame read just before it), if only its
        stamp is wrong; else skipped. Counted either way."""
        counts = self.receive
        if isinstance(exc, BadTimestamp) or not isinstance(message.timestamp, (int, float)):
            t = time.time_ns() + (self._lead_ns or 0)
            if frames:
                t = max(t, frames[-1].timestamp_ns)
            try:
                frames.append(_stamped(self.spec.name, message, t))
            except Exception as again:
                exc = again
            else:
                counts.bad_timestamps += 1
                counts.last_bad_timestamp = _stamp_text(message.timestamp)
                return
        counts.unreadable += 1
        counts.last_unreadable = one_line(exc)


class BadTimestamp(ValueError):
    """A frame stamped with something that is not a time tankviz can record."""


def _stamp_text(seconds: Any) -> str:
    return str(seconds) if isinstance(seconds, float) else repr(seconds)


def _received(bus: can.BusABC, limit: int,
              skip: Callable[[Exception], None] | None = None) -> Iterator[can.Message]:
    """What ``bus`` has received by now, at most ``limit`` messages, never waiting: what
    ``bus.recv(0)`` returns until it returns None. A datagram python-can could not read
    (:func:`one_datagram`) is given to ``skip`` and the read goes on (it counts in ``limit``).

    A bus that keeps python-can's own ``recv`` is read through the method ``recv`` calls,
    ``_recv_internal`` (every interface implements it), with the same filtering: ``recv``'s
    clock readings and its log call cost more than taking the frame (1.5 µs of 3.4 a frame on
    the virtual bus). One difference: ``recv(0)`` ends a read at a message its filters refuse,
    this goes on to the next. Behind :data:`bridge.fences.PYTHON_CAN`."""
    # an interface with a recv of its own, or a python-can release not checked: recv itself
    if type(bus).recv is not _BUS_RECV or not PYTHON_CAN.holds():
        recv = bus.recv
        for _ in range(limit):
            message = recv(0)
            if message is None:
                return
            yield message
        return
    receive, matches = bus._recv_internal, bus._matches_filters
    taken = 0
    while taken < limit:
        try:
            message, filtered = receive(0.0)
        except Exception as exc:
            if skip is None or not one_datagram(bus, exc):
                raise
            skip(exc)
            taken += 1
            continue
        if message is None:
            return
        if filtered or matches(message):
            taken += 1
            yield message


_BUS_RECV = can.BusABC.recv
_new_frame = tuple.__new__  # Frame's own __new__ is a Python function: 0.4 µs a frame more


def _frame(bus: str, message: can.Message, last: float = LAST_SECOND) -> Frame:
    seconds = message.timestamp
    if 0.0 <= seconds < last:  # (not NaN)
        return _new_frame(Frame, (
            round(seconds * 1_000_000) * 1000,  # to_ns(), inlined: this runs for every frame
            bus, message.arbitration_id, bytes(message.data),
            message.is_extended_id, message.is_fd, message.is_error_frame,
            message.is_remote_frame, message.bitrate_switch, message.error_state_indicator,
            message.dlc))
    raise BadTimestamp(seconds)


def _stamped(bus: str, message: can.Message, t_ns: int) -> Frame:
    """The frame of ``message`` stamped ``t_ns`` instead of its own stamp."""
    return Frame(
        t_ns, bus, message.arbitration_id, bytes(message.data),
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

