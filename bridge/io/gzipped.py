"""A gzip-compressed log unpacked up to where it is cut or damaged, every byte before kept.

:class:`GzipReader` gives every byte the compressed data holds (where :class:`gzip.GzipFile`
would lose a read's worth at a cut), then ends as a file ends; ``cut`` and ``problem`` say why it
ended early, ``failed_check`` that a member's data failed its check (its bytes are given all the
same). It never raises for what is in the file.
"""

from __future__ import annotations

import io
import zlib
from typing import IO, Any

#: The compressed bytes read from the file at a time.
_CHUNK = 1 << 16
_MAGIC = b"\x1f\x8b"
#: The header flags that add a field: FHCRC (2 bytes), FEXTRA (its length first), FNAME and
#: FCOMMENT (each up to a zero byte).
_FHCRC, _FEXTRA, _FNAME, _FCOMMENT = 2, 4, 8, 16


class GzipReader(io.RawIOBase):
    """The unpacked bytes of a gzip file (its members one after the other, as ``gzip`` reads
    them): read up to a cut or damage, never raising for either.

    ``unpacked`` counts the bytes given; ``cut`` tells the file ended inside a member (its
    header, its data or its 8-byte trailer); ``problem`` is why the data ended early otherwise,
    in a few words; ``failed_check`` the first member whose check failed, in a few words."""

    def __init__(self, file: IO[bytes]) -> None:
        super().__init__()
        self._file = file
        self._input = b""  # compressed bytes read from the file, not yet used
        self._inflate: Any = None  # the member being unpacked (a zlib decompressor)
        self._crc = 0
        self._length = 0
        self._members = 0
        self._ended = False
        self.unpacked = 0
        self.cut = False
        self.problem: str | None = None
        self.failed_check: str | None = None

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        while not self._ended and len(view):
            if self._inflate is not None and self._inflate.eof:
                self._trailer()
                continue
            if self._inflate is None:
                if not self._header():
                    self._ended = True
                    break
                self._inflate, self._crc, self._length = zlib.decompressobj(-zlib.MAX_WBITS), 0, 0
            if not self._input and not self._more():
                self._end(None)
                break
            try:
                data = self._inflate.decompress(self._input, len(view))
            except zlib.error as exc:
                self._end(f"its compressed data is damaged here (zlib: {exc})")
                break
            self._input = self._inflate.unused_data if self._inflate.eof else \
                self._inflate.unconsumed_tail
            if data:
                self._crc = zlib.crc32(data, self._crc)
                self._length += len(data)
                self.unpacked += len(data)
                view[:len(data)] = data
                return len(data)
        return 0

    def _end(self, why: str | None) -> None:
        """The data ends early: cut (``why`` None) or for the reason ``why``."""
        self._ended = True
        self.cut = why is None
        self.problem = why

    def _more(self) -> bool:
        chunk = self._file.read(_CHUNK)
        self._input += chunk
        return bool(chunk)

    def _has(self, size: int) -> bool:
        """Whether ``size`` compressed bytes are at hand (reading more if needed)."""
        while len(self._input) < size:
            if not self._more():
                return False
        return True

    def _header(self) -> bool:
        """Reads the header of the next member; False at the end of the file, or where it ends
        early (a cut, or bytes that are no gzip header: ``problem`` says)."""
        if self._members:
            while True:  # zeros may pad a file after a member, as gzip allows
                self._input = self._input.lstrip(b"\0")
                if self._input or not self._more():
                    break
        if not self._has(1):
            return False  # the end of the file (or an empty file)
        self._has(10)
        head = self._input[:10]
        if head[:2] != _MAGIC[:len(head[:2])] or (len(head) >= 3 and head[2] != 8):
            self._end(f"it is no gzip data (it begins {head[:4]!r})" if not self._members else
                      f"what follows its gzip member {self._members} is no gzip data")
            return False
        end = 10
        flags = head[3] if len(head) >= 4 else 0
        if flags & _FEXTRA and self._has(end + 2):
            end += 2 + int.from_bytes(self._input[end:end + 2], "little")
        for flag in (_FNAME, _FCOMMENT):
            if flags & flag:
                while (zero := self._input.find(b"\0", end)) < 0 and self._more():
                    pass
                end = zero + 1 if zero >= 0 else len(self._input) + 1
        end += 2 if flags & _FHCRC else 0
        if not self._has(end):
            self._end(None)
            return False
        self._input = self._input[end:]
        self._members += 1
        return True

    def _trailer(self) -> None:
        """Checks the member just unpacked against its trailer (CRC-32 and length)."""
        self._inflate = None
        if not self._has(8):
            self._end(None)
            return
        crc, length = int.from_bytes(self._input[:4], "little"), \
            int.from_bytes(self._input[4:8], "little")
        self._input = self._input[8:]
        if (crc, length) != (self._crc, self._length & 0xFFFFFFFF) and not self.failed_check:
            self.failed_check = (f"gzip member {self._members} fails its check (CRC-32 "
                                 f"{self._crc:08x} of {self._length:,} bytes, its trailer says "
                                 f"{crc:08x} of {length:,})")
