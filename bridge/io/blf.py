"""BLF logs read past damage: python-can's object parser, fed only intact objects.

python-can's BLF reader stops at the first damaged object (losing the rest of the file), loops
forever on an object of size 0, or makes frames of garbage. :class:`BlfReader` walks the objects
first and gives python-can's object parser only intact ones: a damaged log container is skipped
whole, a damaged object up to the next object signature (``LOBJ``), and each damage is reported
with its byte offset; the frames before and after it are kept. It uses python-can's private
names (:data:`bridge.fences.PYTHON_CAN`): on a release not checked, logs are read by python-can's
own reader instead (:class:`~bridge.io.can_logs.LogSource`).
"""

from __future__ import annotations

import io
import re
import zlib
from collections.abc import Callable, Generator, Iterator
from typing import IO, Literal

import can
from can.io import blf

#: What a damage did to the reading (as :data:`bridge.io.can_logs.IssueKind` says it).
DamageKind = Literal["stop", "damage"]


class Bytes:
    """The binary stream python-can's BLF reader consumes, noticing where the file is cut short."""

    def __init__(self, stream: IO[bytes]) -> None:
        self._stream = stream
        self.offset = 0
        self.cut_at: int | None = None

    def read(self, size: int = -1) -> bytes:
        data = self._stream.read(size)
        if size > 0 and 0 < len(data) < size and self.cut_at is None:
            self.cut_at = self.offset
        self.offset += len(data)
        return data

    def close(self) -> None:
        """The underlying file is closed by :class:`~bridge.io.can_logs.LogSource`."""


_OBJ = blf.OBJ_HEADER_BASE_STRUCT
_CONTAINER = blf.LOG_CONTAINER_STRUCT
#: The size of the file header python-can and Vector write (python-can reads the first 72 bytes).
_FILE_HEADER_SIZE = blf.FILE_HEADER_SIZE
#: The largest log container believed (writers use about 128 KiB); a larger size is damage.
_MAX_CONTAINER = 16 << 20
#: The largest object inside a container believed; a larger size is damage.
_MAX_OBJECT = 1 << 20
#: The size of the object header of each version python-can reads.
_HEADER_SIZES = {1: _OBJ.size + blf.OBJ_HEADER_V1_STRUCT.size,
                 2: _OBJ.size + blf.OBJ_HEADER_V2_STRUCT.size}
#: The body python-can unpacks for each object type it reads as a frame.
_BODY_SIZES = {blf.CAN_MESSAGE: blf.CAN_MSG_STRUCT.size, blf.CAN_MESSAGE2: blf.CAN_MSG_STRUCT.size,
               blf.CAN_ERROR_EXT: blf.CAN_ERROR_EXT_STRUCT.size,
               blf.CAN_FD_MESSAGE: blf.CAN_FD_MSG_STRUCT.size,
               blf.CAN_FD_MESSAGE_64: blf.CAN_FD_MSG_64_STRUCT.size}


def _object_size(data: bytes | bytearray, at: int, largest: int) -> int | None:
    """The size of the BLF object whose header is at ``at`` (its whole header is in ``data``),
    or None when that header cannot be right: python-can would loop forever on a size 0, read
    past the object for a size too small for its type, or wait for a size beyond ``largest``."""
    signature, header_size, version, size, kind = _OBJ.unpack_from(data, at)
    size = int(size)
    if signature != b"LOBJ" or not _OBJ.size <= header_size <= size <= largest:
        return None
    if kind == blf.LOG_CONTAINER:
        return size if size >= _OBJ.size + _CONTAINER.size else None
    body = _BODY_SIZES.get(kind)
    if body is not None and version in _HEADER_SIZES and size < _HEADER_SIZES[version] + body:
        return None
    return size


#: The object headers (their first 16 bytes, which alone decide :func:`_object_size` inside a
#: container) found intact, and their sizes: a header met again is known at one dict look-up.
_INTACT: dict[bytes, int] = {}
#: The most headers remembered (a log has a few kinds of objects; damaged data may make more).
_MAX_INTACT = 4096
#: The pattern of a run of objects of each header of :data:`_INTACT` met twice in a row.
_KINDS: dict[bytes, re.Pattern[bytes]] = {}


def _kind(header: bytes, size: int) -> re.Pattern[bytes]:
    """The pattern of objects of ``size`` bytes beginning with ``header`` one after the other:
    its match from an object on ends after the last of them that is whole."""
    kind = _KINDS.get(header)
    if kind is None:
        kind = _KINDS[header] = re.compile(b"(?:%s(?s:.){%d})*" % (re.escape(header),
                                                                   size - _OBJ.size))
    return kind


def intact_objects(data: bytes, lost: bool = False,
                   ) -> tuple[list[tuple[int, int]], int, int, bool]:
    """Where the intact objects are in the data of a BLF log container: ``(runs, rest, damaged,
    lost)``.

    ``runs`` are the (start, end) of runs of consecutive intact objects, as python-can steps from
    one to the next (an object's signature up to 4 bytes of padding after the one before); data
    from ``rest`` on is the start of an object that goes on in the next container. A header that
    cannot be right is damage: the walk goes on at the next object signature (``LOBJ``) and
    counts the ``damaged`` bytes it skips. ``lost`` on entry says the data begins with the rest
    of an object whose start was lost (skipped to the first signature, not counted as damage); on
    return, that no signature was found after damage until the end.
    """
    runs: list[tuple[int, int]] = []
    damaged = 0
    n = len(data)
    pos = 0
    start = 0
    if lost:
        first = data.find(b"LOBJ")
        if first < 0:
            return [], max(0, n - 3), 0, True
        pos = start = first
        lost = False
    intact, head = _INTACT.get, _OBJ.size
    before = b""  # the header of the object before
    while pos + head <= n:
        header = data[pos:pos + head]
        size = intact(header)
        if size is not None:  # a header found intact before: the step below, in short
            if pos + size > n:
                break  # goes on in the next container
            if header == before:  # objects of one kind in a row: up to the last at once
                run = _kind(header, size).match(data, pos)  # (at least the one at pos)
                pos = run.end() if run is not None else pos + size
            else:
                pos += size
                before = header
            continue
        at = data.find(b"LOBJ", pos, pos + 8)
        if 0 <= at <= n - _OBJ.size:
            size = _object_size(data, at, _MAX_OBJECT)
            if size is not None:
                if len(_INTACT) >= _MAX_INTACT:
                    _INTACT.clear()
                    _KINDS.clear()
                _INTACT[data[at:at + _OBJ.size]] = size
                if at + size > n:
                    break  # goes on in the next container
                pos = at + size
                continue
        elif at >= 0:
            break  # the header goes on in the next container
        # damage: the objects so far are one run; the walk goes on at the next signature
        if pos > start:
            runs.append((start, pos))
        after = data.find(b"LOBJ", (pos if at < 0 else at) + 1)
        if after < 0:
            damaged += max(0, n - 3 - pos)
            return runs, max(pos, n - 3), damaged, True
        damaged += after - pos
        pos = start = after
    if pos > start:
        runs.append((start, pos))
    return runs, pos, damaged, lost


class BlfReader(can.BLFReader):
    """python-can's BLF reader, going on after damage.

    python-can stops at the first damaged object and loses the rest of the file, loops forever on
    an object of size 0, or makes frames of any bytes after a damaged one. This reader walks the
    objects first: a log container whose header or compressed data is damaged is skipped whole
    (its frames are lost); a damaged object inside a container is skipped to the next object
    signature (``LOBJ``); python-can's own parser (``_parse_data``) gets only runs of intact
    objects. ``damaged(byte offset, reason, kind, group)`` is told of each damage (the kind and
    group of :class:`SourceIssue`).
    """

    def __init__(self, stream: Bytes,
                 damaged: Callable[[int, str, DamageKind, str], None]) -> None:
        head = stream.read(_FILE_HEADER_SIZE)
        super().__init__(io.BytesIO(head))  # python-can reads the file header
        self.file = stream  # type: ignore[assignment]
        self._stream = stream
        self._damaged = damaged
        self._buffer = bytearray()
        declared = blf.FILE_HEADER_STRUCT.unpack_from(head)[1]
        if blf.FILE_HEADER_STRUCT.size <= declared <= _FILE_HEADER_SIZE:
            self._buffer += head[declared:]
        elif _FILE_HEADER_SIZE < declared <= 1 << 16:
            stream.read(declared - _FILE_HEADER_SIZE)
        else:
            damaged(4, f"the file header gives its own size as {declared} bytes (damaged); "
                    f"reading on after {_FILE_HEADER_SIZE}", "damage", "damaged file header")
        self._at = stream.offset - len(self._buffer)  # the file offset of the buffer's start
        self._lost = False  # the data of the next container begins inside a lost object

    def _fill(self, size: int) -> bool:
        while len(self._buffer) < size:
            chunk = self._stream.read(max(size - len(self._buffer), 1 << 16))
            if not chunk:
                return False
            self._buffer += chunk
        return True

    def _drop(self, size: int) -> None:
        del self._buffer[:size]
        self._at += size

    def _skip_to_signature(self) -> int:
        """Drops bytes up to the next object signature after the first byte; how many."""
        skipped = 0
        while True:
            found = self._buffer.find(b"LOBJ", 1)
            if found > 0:
                self._drop(found)
                return skipped + found
            keep = min(len(self._buffer), 3)  # a signature may begin in the last 3 bytes
            skipped += len(self._buffer) - keep
            self._drop(len(self._buffer) - keep)
            if not self._fill(len(self._buffer) + 1):
                skipped += len(self._buffer)
                self._drop(len(self._buffer))
                return skipped

    def __iter__(self) -> Generator[can.Message, None, None]:
        for run in self.runs():
            yield from self._parse_data(run)

    def runs(self) -> Generator[bytes, None, None]:
        """The runs of consecutive intact objects, in file order, for python-can's parser
        (``_parse_data``): what :meth:`__iter__` parses. ``damaged`` is told of each damage
        after the runs before it are taken."""
        damage_at: int | None = None  # where the damaged bytes being skipped began
        skipped = 0
        while True:
            if not self._fill(_OBJ.size):
                if damage_at is not None:
                    self._damaged(damage_at, f"damaged data: the rest of the file "
                                  f"({skipped + len(self._buffer)} bytes) holds no object",
                                  "stop", "damaged data up to the end")
                elif self._buffer.strip(b"\0"):
                    self._damaged(self._at, "the file ends in the middle of an object; frames "
                                  "in it are lost", "stop", "file cut short")
                break
            padding = self._buffer.find(b"LOBJ", 0, 8)  # python-can pads objects to 4 bytes
            if padding > 0 and damage_at is None:
                self._drop(padding)
                continue
            size = _object_size(self._buffer, 0, _MAX_CONTAINER) if padding == 0 else None
            if size is None:
                if damage_at is None:
                    damage_at, skipped = self._at, 0
                skipped += self._skip_to_signature()
                continue
            if damage_at is not None:
                self._damaged(damage_at, f"damaged data: {skipped} bytes skipped to the next "
                              f"object at byte {self._at}; frames in them are lost", "damage",
                              "damaged data skipped")
                damage_at = None
                self._lost, self._tail = True, b""
            at = self._at
            if not self._fill(size):  # the file is cut: the buffer holds the rest of it
                kind = _OBJ.unpack_from(self._buffer)[4]
                if kind == blf.LOG_CONTAINER and len(self._buffer) > _OBJ.size + _CONTAINER.size:
                    yield from self._container(bytes(self._buffer), at, cut=True)
                    self._damaged(at, "the file ends in the middle of an object (a log "
                                  "container: its frames before the cut are kept); frames in it "
                                  "after the cut are lost", "stop", "file cut short")
                else:
                    self._damaged(at, "the file ends in the middle of an object; frames in it "
                                  "are lost", "stop", "file cut short")
                self._tail = b""
                break
            obj = bytes(self._buffer[:size])
            self._drop(size)
            padding = size % 4  # python-can's writer pads objects to 4 bytes
            if self._fill(padding) and not self._buffer[:padding].strip(b"\0"):
                self._drop(padding)
            kind = _OBJ.unpack_from(obj)[4]
            if kind == blf.LOG_CONTAINER:
                yield from self._container(obj, at)
            elif kind in _BODY_SIZES:  # a frame outside a container (python-can skips those)
                yield obj
        if self._tail.find(b"LOBJ") >= 0:
            self._damaged(self._at, "the file ends in the middle of an object; frames in it "
                          "are lost", "stop", "file cut short")
        self.stop()

    def _container(self, obj: bytes, at: int, cut: bool = False) -> Iterator[bytes]:
        """The runs of intact objects of the log container ``obj`` found at byte ``at`` of the
        file (``cut``: its start only, the file ends in it)."""
        method, _ = _CONTAINER.unpack_from(obj, _OBJ.size)
        packed = obj[_OBJ.size + _CONTAINER.size:]
        if method == blf.NO_COMPRESSION:
            data = packed
        elif method == blf.ZLIB_DEFLATE:
            unpack = zlib.decompressobj()
            try:
                data = unpack.decompress(packed, _MAX_CONTAINER)
                if not unpack.eof and not cut:
                    raise zlib.error("the compressed data ends early" if not
                                     unpack.unconsumed_tail else "too much data")
            except zlib.error as exc:
                self._damaged(at, f"damaged log container ({exc}): the frames in it are lost",
                              "damage", "damaged log container")
                self._lost, self._tail = True, b""
                return
        else:
            self._damaged(at, f"log container with unknown compression method {method} "
                          "(damaged?): the frames in it are lost", "damage",
                          "damaged log container")
            self._lost, self._tail = True, b""
            return
        data = self._tail + data
        runs, rest, damaged, self._lost = intact_objects(data, self._lost)
        for start, end in runs:
            yield data[start:end]
        if damaged:
            self._damaged(at, f"damaged objects in the log container here: {damaged} bytes "
                          "skipped to the next object; frames in them are lost", "damage",
                          "damaged objects")
        self._tail = data[rest:]
