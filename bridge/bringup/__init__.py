"""Bring-up: finding what a new car's buses say that no database names.

It counts each id's frames, periods, lengths and bit flips, finds bits that switch and fields that
follow a known quantity, and writes them as DBC lines. Bit ``i`` is byte ``i // 8``, bit
``i % 8``, the least significant first, as DBC start bits of little-endian signals are.
"""
