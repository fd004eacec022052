"""Live buses read in a process of their own: :class:`ReaderProcess` starts it and takes what it
read, in order, as the pipeline's process reads them.

The reading process (``multiprocessing``'s ``spawn``: a fresh interpreter, never a fork of a
process with threads) opens each bus as :class:`~bridge.io.buses.BusLink` does, reads them all on
:class:`~bridge.io.buses.ReadSchedule`'s schedule (following the frames' clock, and a clock that
steps back), and sends each read at once as one :class:`~bridge.packed.PackedFrames` (the frames of
every bus merged in time order, with the wall time of the read): a read with no frame is sent
too, so the pipeline knows every frame stamped before then has come. Its sending never waits for
the pipeline (a thread of its own sends, from a queue without bound), so a slow pipeline never
makes the kernel drop a frame. It also sends each link's opening state (:class:`LinkState`) when
it changes, every :class:`~bridge.io.buses.BusEvent` and each bus's
:class:`~bridge.io.buses.ReceiveCounts` when they change. It ignores SIGINT, SIGTERM and SIGHUP
(a terminal's or systemd's stop reaches the whole group: the pipeline's process decides): asked
to stop (:meth:`ReaderProcess.stop`) it reads what the interfaces still hold, for at most 0.25 s,
sends it and ends; it ends too when the pipeline's process is gone. A reading process that ends
any other way is a :class:`Died` item saying how.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import queue
import signal
import struct
import sys
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from bridge.errors import UsageError
from bridge.frame import NS, Frame
from bridge.io.buses import (
    BusEvent,
    BusLink,
    BusSpec,
    ReadSchedule,
    ReceiveCounts,
    limit_can_logs,
    merge_batches,
)
from bridge.packed import PackedFrames

#: A read's first bytes: the kind, the wall time of the read (ns); then its pack, if any.
_READ = struct.Struct("<cq")
_PACK, _EMPTY, _PICKLED = b"F", b"E", b"P"
#: Seconds the reading process reads what the interfaces still hold once asked to stop.
DRAIN_S = 0.25
#: How far back (ns) the frames' clock must go for the schedule to start again at once.
STEP_BACK_NS = NS


@dataclass
class LinkState:
    """A bus's opening as the reading process last told it (:class:`~bridge.io.buses.BusLink`'s
    ``opened``, ``error``, ``failure`` and ``tries``)."""

    spec: BusSpec
    opened: bool = False
    error: UsageError | None = None
    failure: str = ""
    tries: int = 0


@dataclass
class Read:
    """One read of every bus: its frames in time order (None: none), at ``read_ns`` (wall)."""

    read_ns: int
    pack: PackedFrames | None


@dataclass
class Died:
    """The reading process ended without being asked to: how (one line)."""

    reason: str


Item = Read | BusEvent | tuple[str, ReceiveCounts] | Died


class ReaderProcess:
    """The buses ``specs`` read in a process of their own, on a schedule of ``period_ns`` (the
    scene period). :meth:`take` gives what it sent, in order; :attr:`links` the opening state
    of each bus."""

    def __init__(self, specs: Sequence[BusSpec], period_ns: int, *,
                 open_bus: Callable[[BusSpec], Any] = BusSpec.open) -> None:
        context = multiprocessing.get_context("spawn")
        self._data, send = context.Pipe(duplex=False)
        control, self._control = context.Pipe(duplex=False)
        self.links = [LinkState(spec) for spec in specs]
        self.process = context.Process(
            target=_serve, args=(list(specs), period_ns, open_bus, send, control),
            daemon=True, name="tankviz-bus-reader")
        self.process.start()
        send.close()
        control.close()
        self.ended = False  # the process said its last, or died

    def take(self, timeout: float, limit: int = 64) -> list[Item]:
        """What the process sent: waits at most ``timeout`` seconds for the first item, then
        takes the rest already there (at most ``limit`` reads)."""
        out: list[Item] = []
        if self.ended:
            return out
        data = self._data
        reads = 0
        wait = timeout
        while reads < limit and data.poll(wait):
            wait = 0
            try:
                message = data.recv_bytes()
            except (EOFError, OSError):
                out.append(self._died())
                break
            kind = message[:1]
            if kind in (_PACK, _EMPTY):
                _, read_ns = _READ.unpack_from(message)
                pack = (PackedFrames.from_bytes(memoryview(message)[_READ.size:])
                        if kind == _PACK else None)
                out.append(Read(read_ns, pack))
                reads += 1
                continue
            what, *body = pickle.loads(message[1:])
            if what == "links":
                for link, (opened, error, failure, tries) in zip(self.links, body[0],
                                                                 strict=True):
                    link.opened, link.failure, link.tries = opened, failure, tries
                    if error is not None:
                        link.error = UsageError(error[0], error[1], value=error[2])
            elif what == "event":
                out.append(body[0])
            elif what == "receive":
                out.append((body[0], body[1]))
            elif what == "end":
                self.ended = True
                break
            else:  # "failed": a bug in the reading process
                out.append(Died(f"the process reading the buses failed:\n{body[0]}"))
                self.ended = True
                break
        return out

    def _died(self) -> Died:
        self.ended = True
        self.process.join(1.0)
        code = self.process.exitcode
        how = ("still running" if code is None else f"killed by {signal.Signals(-code).name}"
               if code < 0 else f"exit code {code}")
        return Died(f"the process reading the buses ended without a word ({how})")

    def stop(self) -> None:
        """Asks the process to read what the interfaces hold and end (:meth:`take` its last)."""
        with contextlib.suppress(OSError):
            self._control.send_bytes(b"stop")

    def close(self) -> None:
        """Ends the process (at once if it has not ended by itself) and closes the pipes."""
        self.process.join(2.0)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self._data.close()
        self._control.close()


def _serve(specs: list[BusSpec], period_ns: int, open_bus: Callable[[BusSpec], Any],
           send: Any, control: Any) -> None:
    """The reading process."""
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_IGN)  # the pipeline's process says when to stop
    outbox: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()

    def sending() -> None:
        try:
            while (message := outbox.get()) is not None:
                send.send_bytes(message)
        except OSError:  # the pipeline's process is gone: nothing to read for
            os._exit(0)
        finally:
            send.close()

    def put(*message: Any) -> None:
        outbox.put(_PICKLED + pickle.dumps(message, pickle.HIGHEST_PROTOCOL))

    sender = threading.Thread(target=sending, name="tankviz-bus-sender")
    sender.start()
    try:
        limiter = limit_can_logs(lambda text: print(text, file=sys.stderr, flush=True))
        try:
            _read_until_stopped(specs, period_ns, open_bus, outbox.put, put, control)
        finally:
            limiter.finish()
        put("end")
    except BaseException:
        put("failed", traceback.format_exc())
    finally:
        outbox.put(None)
        sender.join()


def _read_until_stopped(specs: list[BusSpec], period_ns: int,
                        open_bus: Callable[[BusSpec], Any], put_bytes: Callable[[bytes], None],
                        put: Callable[..., None], control: Any) -> None:
    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    links = [BusLink(spec, events, open_bus=open_bus) for spec in specs]
    for link in links:
        link.start()
    said_links: list[Any] = []
    said_receive: dict[str, ReceiveCounts] = {}

    def tell() -> None:
        """Events, links' states and receive counts, when they changed."""
        nonlocal said_links
        while True:
            try:
                put("event", events.get_nowait())
            except queue.Empty:
                break
        states = [(link.opened.is_set(), None if link.error is None else
                   (link.error.argument, link.error.reason, link.error.value),
                   link.failure, link.tries) for link in links]
        if states != said_links:
            said_links = states
            put("links", states)
        for link in links:
            if link.receive != said_receive.get(link.spec.name):
                said_receive[link.spec.name] = counts = ReceiveCounts(**link.receive.to_dict())
                put("receive", link.spec.name, counts)

    def read() -> list[Frame]:
        polled = [frames for link in links if (frames := link.poll())]
        return merge_batches(polled) if polled else []

    def hand(frames: list[Frame], read_ns: int) -> None:
        if frames:
            put_bytes(_READ.pack(_PACK, read_ns) + PackedFrames.from_frames(frames).to_bytes())
        else:
            put_bytes(_READ.pack(_EMPTY, read_ns))

    schedule = ReadSchedule(period_ns)
    try:
        while not control.poll():
            schedule.wait()
            tell()
            frames = read()
            read_ns = time.time_ns()
            if frames:
                newest = frames[-1].timestamp_ns
                offset = schedule.offset_ns
                if offset is not None and newest - read_ns < offset - STEP_BACK_NS:
                    schedule.restart(newest, read_ns)  # the frames' clock stepped back
                else:
                    schedule.saw(newest, read_ns)
            hand(frames, read_ns)
    finally:
        for link in links:
            link.stop()
        until = time.monotonic() + DRAIN_S
        while time.monotonic() < until and (frames := read()):
            hand(frames, time.time_ns())
        for link in links:
            link.close()
        tell()
