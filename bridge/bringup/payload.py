"""``/can/<bus>/unknown``'s messages, ``tankviz.CanPayload`` (schemas/bringup.proto), written in
protobuf's wire format by hand: byte for byte what ``SerializeToString`` gives.

A message is its id field, then the payload's bytes, its big-endian and its little-endian 16-bit
words as packed fields of varints.
"""

from __future__ import annotations

import struct

from bridge.bringup.columns import id_text
from bridge.protowire import ONE_BYTE, string, varint

#: Payloads remembered per id (their messages), then forgotten all at once.
CACHE_SIZE = 512

#: a packed field's length (a payload of 64 bytes: at most 63 words of 3 bytes)
_LENGTHS = [varint(n) for n in range(256)]
class _Varints(dict[int, bytes]):
    """Value -> its varint, made when first asked for (a 16-bit word's at most: 65,536)."""

    def __missing__(self, value: int) -> bytes:
        made = self[value] = varint(value)
        return made


_VARINTS = _Varints(enumerate(ONE_BYTE))


def id_field(key: int) -> bytes:
    """The ``id`` field of a frame key's messages (``0x2C4``)."""
    return string(b"\x0a", id_text(key))


def encode(head: bytes, data: bytes) -> bytes:
    """The ``tankviz.CanPayload`` of a payload, after its id field ``head``."""
    n = len(data)
    if not n:
        return head
    v = _VARINTS.__getitem__
    length = _LENGTHS.__getitem__ if n <= 64 else varint  # (CAN FD: 64 bytes at most)
    values = data if data.isascii() else b"".join(map(v, data))  # (a byte < 128: itself)
    if n == 1:
        return head + b"\x12" + length(len(values)) + values
    words = _WORDS.get(n) or _words(n)
    even_be, odd_be, even_le, odd_le, w = words
    # the words at even offsets, then at odd ones, put in their order
    w[0::2] = even_be.unpack_from(data)
    w[1::2] = odd_be.unpack_from(data, 1)
    be = b"".join(map(v, w))
    w[0::2] = even_le.unpack_from(data)
    w[1::2] = odd_le.unpack_from(data, 1)
    le = b"".join(map(v, w))
    return b"".join((head, b"\x12", length(len(values)), values, b"\x1a", length(len(be)), be,
                     b'"', length(len(le)), le))


#: payload length -> the 16-bit words at even and at odd offsets, big- and little-endian, and
#: a list to put them in
_WORDS: dict[int, tuple[struct.Struct, struct.Struct, struct.Struct, struct.Struct, list[int]]] = {}


def _words(n: int) -> tuple[struct.Struct, struct.Struct, struct.Struct, struct.Struct, list[int]]:
    even, odd = n // 2, (n - 1) // 2
    made = _WORDS[n] = (struct.Struct(f">{even}H"), struct.Struct(f">{odd}H"),
                        struct.Struct(f"<{even}H"), struct.Struct(f"<{odd}H"), [0] * (n - 1))
    return made


class PayloadWriter:
    """One id's messages: its id field (made once), and the payloads it sent lately remembered
    (up to :data:`CACHE_SIZE`, then all forgotten at once).
    """

    __slots__ = ("_cache", "head")

    def __init__(self, key: int) -> None:
        self.head = id_field(key)
        self._cache: dict[bytes, bytes] = {}

    def __call__(self, data: bytes) -> bytes:
        message = self._cache.get(data)
        if message is None:
            if len(self._cache) >= CACHE_SIZE:
                self._cache.clear()
            message = self._cache[data] = encode(self.head, data)
        return message
