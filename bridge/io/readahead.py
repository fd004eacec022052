"""Read ahead: the frames of several sources, read and merged in a second process.

:class:`ReadAhead` reads :func:`~bridge.io.can_logs.merge` of the sources in a forked child, which
sends them through a pipe as :class:`~bridge.packed.PackedFrames` packs of :data:`BATCH` frames
(:meth:`ReadAhead.packs`; iterating gives their frames), never more than two packs ahead, so
memory stays flat; :meth:`progress` tells the bytes read. The results are those of reading here:
each source's ``issues``, ``frames`` and ``backwards`` come back from the child; an
:class:`~bridge.errors.InputError` it meets is raised here after the frames before it; a bug in
the child is a :class:`RuntimeError` with its traceback, a child that dies without a word a
one-line :class:`~bridge.errors.HelperDied`. Stopped early, the child is ended with it (SIGTERM,
then SIGKILL). Where forking is not safe or not worth it (no ``fork``, other threads, a daemonic
process, inputs under :data:`MIN_BYTES`), the sources are read here, in the same order.

:func:`read_in_thread` reads in a daemon thread instead, for a consumer that must keep its stop
whatever the reading does: it waits at most :data:`POLL_S` at a time, and holds at most
:data:`THREAD_ITEMS` items ahead.
"""

from __future__ import annotations

import os
import pickle
import signal
import threading
import traceback
from array import array
from collections import deque
from collections.abc import Generator, Iterable, Iterator, Sequence
from itertools import islice
from typing import Any, Protocol, TypeVar

from bridge.errors import HelperDied, InputError
from bridge.frame import Frame
from bridge.io.can_logs import SourceIssue, merge
from bridge.packed import PackedFrames, packs

#: Frames per hand-over (per pack): large enough that a pack costs little per frame, small
#: enough that the pipeline starts at once.
BATCH = 4096
#: Inputs smaller than this (bytes, all sources) are read in this process.
MIN_BYTES = 256 * 1024

#: The signals that stop a conversion (blocked while the child is forked).
_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
#: Seconds a child stopped early has to end on SIGTERM before it is killed.
_GRACE_S = 1.0

#: Items :func:`read_in_thread` holds read ahead at most.
THREAD_ITEMS = 4096
#: Seconds :func:`read_in_thread`'s consumer waits at a time before it looks at its stop again.
POLL_S = 0.05

#: The first byte of a message from the child: a pack (after it, each source's bytes read so
#: far as ``array('q')``, then the pack's buffer) or anything else (a pickled tuple)
_BLOCK, _PICKLED = b"B", b"P"
_T = TypeVar("_T")


class Source(Protocol):
    """What :class:`ReadAhead` reads: a :class:`~bridge.io.can_logs.LogSource` or a
    :class:`~bridge.io.drives.ArchiveSource`."""

    issues: list[SourceIssue]
    frames: int
    backwards: int

    def __iter__(self) -> Iterator[Frame]: ...

    def progress(self) -> tuple[int, int]: ...


def can_fork() -> bool:
    """Whether a child process may be forked here and now (see the module's description)."""
    if not hasattr(os, "fork") or threading.active_count() > 1:
        return False
    import multiprocessing

    return not multiprocessing.current_process().daemon


class ReadAhead:
    """The frames of ``sources`` in time order, read by a child process when ``ahead`` allows
    it (and :func:`can_fork`, and the inputs are at least :data:`MIN_BYTES`). Iterate once, or
    take its :meth:`packs` once."""

    def __init__(self, sources: Sequence[Source], *, ahead: bool = True) -> None:
        self.sources = list(sources)
        self._total = sum(s.progress()[1] for s in self.sources)
        self._done: list[int] | None = None  # bytes read per source, as the child last said
        #: whether the frames come from a child process
        self.ahead = ahead and self._total >= MIN_BYTES and can_fork()

    def progress(self) -> tuple[int, int]:
        """Bytes of all sources read so far, and their total."""
        if self._done is None:
            return sum(s.progress()[0] for s in self.sources), self._total
        return sum(self._done), self._total

    def __iter__(self) -> Iterator[Frame]:
        if not self.ahead:
            return iter(merge(self.sources))
        return self._frames()

    def packs(self) -> Iterator[PackedFrames]:
        """The frames as :class:`~bridge.packed.PackedFrames` s of at most :data:`BATCH` frames, in
        order (instead of iterating: one or the other, once)."""
        if not self.ahead:
            return self._packs_here()
        return self._from_child()

    def _frames(self) -> Iterator[Frame]:
        from_child = self._from_child()
        try:
            for pack in from_child:
                yield from pack
        finally:
            from_child.close()  # the child is ended at once, not when this is collected

    def _packs_here(self) -> Iterator[PackedFrames]:
        frames = iter(merge(self.sources))
        while batch := list(islice(frames, BATCH)):
            yield from packs(batch)

    def _from_child(self) -> Generator[PackedFrames, None, None]:
        import multiprocessing

        context = multiprocessing.get_context("fork")
        receive, send = context.Pipe(duplex=False)
        child = context.Process(target=_read, args=(self.sources, send, receive), daemon=True,
                                name="tankviz-read-ahead")
        # The child must never run this process's signal handlers (convert's raise Stopped, and
        # through it this process's clean-up): the stop signals wait until it has its own.
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        try:
            child.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        finished = False
        try:
            send.close()
            sources = len(self.sources)
            while True:
                try:
                    message = receive.recv_bytes()
                except EOFError:
                    child.join()
                    code = child.exitcode or 0
                    how = (f"killed by {signal.Signals(-code).name}" if code < 0
                           else f"exit code {code}")
                    raise HelperDied("reading the inputs ahead", f"{how}; out of memory?",
                                     "--no-read-ahead reads them in this process") from None
                if message[:1] == _BLOCK:
                    done = array("q")
                    done.frombytes(message[1:1 + 8 * sources])
                    self._done = done.tolist()
                    yield PackedFrames.from_bytes(memoryview(message)[1 + 8 * sources:])
                    continue
                kind, *body = pickle.loads(message[1:])
                self._settle(body[0])
                if kind == "end":
                    finished = True
                    return
                if kind == "input_error":
                    path, reason, where = body[1]
                    raise InputError(path, reason, where=where)
                raise RuntimeError(f"the read-ahead process failed:\n{body[1]}")
        finally:
            receive.close()  # the last read end: a child still writing gets EPIPE
            if not finished:
                child.terminate()
                child.join(_GRACE_S)
                if child.is_alive():  # it outlived SIGTERM (busy in C code, handlers not set)
                    child.kill()
            child.join()

    def _settle(self, states: list[tuple[list[SourceIssue], int, int, tuple[int, int]]]) -> None:
        """The sources as the child left them."""
        self._done = []
        for source, (issues, frames, backwards, (done, _)) in zip(self.sources, states,
                                                                  strict=True):
            source.issues[:] = issues
            source.frames, source.backwards = frames, backwards
            self._done.append(done)


def _read(sources: list[Source], send: Any, receive: Any) -> None:
    """The child: every frame, in packs, then how each source ended."""
    receive.close()  # the parent's end: once the parent closes it, a write here fails at once
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl+C stops the parent, which ends this
    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)  # blocked by the parent's fork

    def states() -> list[tuple[list[SourceIssue], int, int, tuple[int, int]]]:
        return [(s.issues, s.frames, s.backwards, s.progress()) for s in sources]

    def put(*message: Any) -> None:
        send.send_bytes(_PICKLED + pickle.dumps(message, pickle.HIGHEST_PROTOCOL))

    batch: list[Frame] = []

    def flush() -> None:
        if batch:
            done = array("q", [s.progress()[0] for s in sources]).tobytes()
            for pack in packs(batch):
                send.send_bytes(b"".join((_BLOCK, done, pack.to_bytes())))
            batch.clear()

    try:
        try:
            for frame in merge(sources):
                batch.append(frame)
                if len(batch) >= BATCH:
                    flush()
            flush()
            put("end", states())
        except InputError as exc:
            flush()
            put("input_error", states(), (exc.path, exc.reason, exc.where))
        except Exception:
            flush()
            put("failed", states(), traceback.format_exc())
    except BrokenPipeError:
        pass  # the parent stopped reading: nothing to tell
    finally:
        send.close()


class _Failed:
    """The exception that ended the reading of :func:`read_in_thread`."""

    def __init__(self, error: BaseException) -> None:
        self.error = error


_END = object()


def read_in_thread(items: Iterable[_T], stopping: threading.Event, *,
                   name: str = "tankviz-read") -> Iterator[_T]:
    """``items``, read by a daemon thread; ends when ``stopping`` is set, within :data:`POLL_S`
    even while a read packs. An exception of the reading is raised here after the items before
    it. Once this iterator ends (or is closed), the thread stops at its next item."""
    buffer: deque[Any] = deque()
    ready, room, gone = threading.Event(), threading.Event(), threading.Event()

    def hand(item: Any) -> bool:
        """Hands ``item`` over when there is room; False once the consumer is gone."""
        while len(buffer) >= THREAD_ITEMS:
            room.clear()
            if gone.is_set():
                return False
            if len(buffer) >= THREAD_ITEMS:
                room.wait(POLL_S)
        buffer.append(item)
        if not ready.is_set():
            ready.set()
        return not gone.is_set()

    def read() -> None:
        try:
            for item in items:
                if not hand(item):
                    return
            hand(_END)
        except BaseException as exc:  # raised to the consumer
            hand(_Failed(exc))

    threading.Thread(target=read, name=name, daemon=True).start()
    try:
        while not stopping.is_set():
            if not buffer:
                room.set()
                ready.clear()  # (then looked at again: an item handed meanwhile sets it)
                if not buffer:
                    ready.wait(POLL_S)
                continue
            item = buffer.popleft()
            if item is _END:
                return
            if isinstance(item, _Failed):
                raise item.error
            yield item
    finally:
        gone.set()
        room.set()
