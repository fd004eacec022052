"""Protobuf's wire format, the little tankviz writes by hand: varints, length-delimited fields
and doubles, for the messages hot paths build from their bytes (parsed in one call, they are the
message that setting each field makes).

A field's bytes are its tag (``number << 3 | wire type``, a varint), then a varint (wire type
0), the 8 little-endian bytes of a double (1), or a length (a varint) and that many bytes (2).
"""

from __future__ import annotations

import struct


def varint(n: int) -> bytes:
    """``n`` (≥ 0) as a protobuf varint: 7 bits a byte, low bits first, the high bit set on every
    byte but the last."""
    out = bytearray()
    while n >= 0x80:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


#: The one-byte varints, 0 to 127 (``ONE_BYTE[n] == varint(n)``): most lengths, small ids.
ONE_BYTE = [bytes((n,)) for n in range(0x80)]


def tag(number: int, wire_type: int) -> bytes:
    """The tag of field ``number`` of ``wire_type`` (0 varint, 1 double, 2 length-delimited)."""
    return varint(number << 3 | wire_type)


def field(tag: bytes, data: bytes) -> bytes:
    """A length-delimited field (string, bytes, message): ``tag``, the length and ``data``."""
    n = len(data)
    return tag + (ONE_BYTE[n] if n < 0x80 else bytes((n & 0x7F | 0x80, n >> 7)) if n < 0x4000
                  else varint(n)) + data  # varint(n), its one or two bytes inline


def string(tag: bytes, words: str) -> bytes:
    """A string field: ``tag`` and ``words`` in UTF-8."""
    return field(tag, words.encode())


#: A double field: its one-byte tag, then the value (``DOUBLE.pack(tag, value)``).
DOUBLE = struct.Struct("<Bd")
