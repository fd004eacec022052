"""Why an MCAP file cannot be read, in words a user can act on.

:func:`why_unreadable` says what ``catalog``, ``inspect`` and ``replay`` print after the path of
a file mcap cannot read (empty, not MCAP, cut at byte N, damaged from byte N or inside), with the
``tankviz recover`` advice where it helps. It only reads the file.
"""

from __future__ import annotations

import shlex
import struct
from pathlib import Path
from typing import BinaryIO

from mcap.opcode import Opcode

MAGIC = b"\x89MCAP0\r\n"
PREFIX = "not a readable MCAP file: "
_HEADER = struct.Struct("<BQ")
_FOOTER = _HEADER.size + 20  # a footer record: summary start, summary offset start, CRC
_OPCODES = {int(op) for op in Opcode}


def _start(head: bytes) -> str:
    return repr(head[:8]) + ("…" if len(head) > 8 else "")


def _error(error: BaseException | None) -> str:
    if error is None:
        return ""
    name = type(error).__name__
    if "CRC" in name:
        return "a CRC does not match its content"
    if "Zstd" in name or "LZ4" in name.upper():
        return "a chunk does not decompress"
    text = " ".join(str(error).split())
    if not text or len(text) > 80 or "opcode" in text or "length" in text:
        return "its summary or indexes are damaged"
    return text


def why_unreadable(path: Path | str, error: BaseException | None = None) -> str:
    """Why the MCAP file ``path`` cannot be read, one line (module docstring); ``error``: what
    mcap's reader raised, if anything."""
    path = Path(path)
    salvage = f"(tankviz recover {shlex.quote(str(path))} -o FIXED.mcap salvages"
    try:
        with path.open("rb") as f:
            size = f.seek(0, 2)
            f.seek(0)
            head = f.read(len(MAGIC) + 1)
            if size == 0:
                return PREFIX + "empty file"
            if head[:len(MAGIC)] != MAGIC[:min(len(head), len(MAGIC))]:
                return PREFIX + f"it starts with {_start(head)}, not with the MCAP magic"
            if size < len(MAGIC):
                return PREFIX + f"only {size} bytes, the start of the MCAP magic"
            if size >= 2 * len(MAGIC) + _FOOTER:
                f.seek(size - _FOOTER - len(MAGIC))
                tail = f.read(_FOOTER + len(MAGIC))
                if tail[:_HEADER.size] == _HEADER.pack(Opcode.FOOTER, 20) and (
                        tail[-len(MAGIC):] == MAGIC):
                    if error is None:
                        return PREFIX + f"it has no summary {salvage} it into one that has)"
                    return PREFIX + f"damaged inside ({_error(error)}) {salvage} what is intact)"
            return PREFIX + _walk(f, size, salvage)
    except OSError as exc:
        return f"cannot read: {exc.strerror or exc}"


def _walk(stream: BinaryIO, size: int, salvage: str) -> str:
    """Where the records of a file without its footer end, and why."""
    at = len(MAGIC)
    while True:
        stream.seek(at)
        head = stream.read(_HEADER.size)
        if len(head) < _HEADER.size:
            return f"cut at byte {at:,} of {size:,} {salvage} it)"
        opcode, length = _HEADER.unpack(head)
        if not any(head):
            return (f"zero bytes from byte {at:,} of {size:,} (data that never reached the "
                    f"disk) {salvage} what comes before)")
        if opcode not in _OPCODES and opcode < 0x80:
            return (f"damaged at byte {at:,} of {size:,}: no MCAP record starts there "
                    f"{salvage} what is intact)")
        if _HEADER.size + length > size - at:
            return f"cut at byte {at:,} of {size:,} {salvage} it)"
        at += _HEADER.size + length
        if opcode == Opcode.FOOTER:
            return (f"its closing magic is missing or damaged at byte {at:,} of {size:,} "
                    f"{salvage} it)")
