"""Bring-up: finding what a new car's buses say that no database names.

From the block columns offline commands read (:mod:`bridge.packed`) it counts each id's frames,
periods, lengths and bit flips (:mod:`~bridge.bringup.census`), finds bits that switch and fields
that follow a known quantity (:mod:`~bridge.bringup.compare`, :mod:`~bridge.bringup.search`) and
writes them as DBC lines (:mod:`~bridge.bringup.dbc`); every drive publishes its counts
(:mod:`~bridge.bringup.monitor`). Bit ``i`` is byte ``i // 8``, bit ``i % 8``, the least
significant first, as DBC start bits of little-endian signals are.
"""
