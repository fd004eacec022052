"""Protobuf's wire format, the little tankviz writes by hand: a varint.

Hot paths build some messages from their wire bytes (the scene's, parsed in one call:
:mod:`bridge.scene.entities`, :mod:`bridge.scene.semantic`; the raw frames' blocks,
:mod:`bridge.sinks.raw`): the bytes of a field are its tag
(``number << 3 | wire type``, a varint), then a varint, a length-delimited payload or 8 bytes
of a double.
"""

from __future__ import annotations


def varint(n: int) -> bytes:
    """``n`` (≥ 0) as a protobuf varint: 7 bits a byte, low bits first, the high bit set on every
    byte but the last."""
    out = bytearray()
    while n >= 0x80:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)
