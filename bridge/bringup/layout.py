"""Which bits of a payload a database's signals cover, in bring-up's bit numbering.

Bit ``i`` is byte ``i // 8``, bit ``i % 8`` (least significant first): a little-endian signal
starting at DBC start bit ``s`` covers bits ``s`` to ``s + length - 1``; a big-endian (Motorola)
one starts at its most significant bit and runs down each byte, then on to the next byte's bit 7
(DBC's "sawtooth" numbering).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any


def field_bits(start: int, length: int, big_endian: bool) -> Iterator[int]:
    """The bits a field covers, from its DBC start bit, most significant first for big-endian
    fields, least significant first for little-endian ones."""
    if not big_endian:
        yield from range(start, start + length)
        return
    bit = start
    for _ in range(length):
        yield bit
        bit = bit + 15 if bit % 8 == 0 else bit - 1


def message_bits(message: Any) -> dict[int, list[str]]:
    """Bit → the names of the signals of a cantools message that cover it (several where
    multiplexed signals share bits)."""
    covered: dict[int, list[str]] = {}
    for signal in message.signals:
        big = signal.byte_order == "big_endian"
        for bit in field_bits(signal.start, signal.length, big):
            covered.setdefault(bit, []).append(signal.name)
    return covered
