"""Bring-up: finding what a new car's buses say that no database names.

Frames come as the block columns every offline command reads (:mod:`bridge.block`); this package
turns them into numpy columns per (bus, id) (:mod:`~bridge.bringup.columns`), counts each id's
frames, periods, lengths and bit flips (:mod:`~bridge.bringup.census`), tells which bits a
database's signals cover (:mod:`~bridge.bringup.layout`), finds bits that switch between two
moments (:mod:`~bridge.bringup.compare`) and the field that follows a known quantity
(:mod:`~bridge.bringup.search`), and writes what was found as DBC lines
(:mod:`~bridge.bringup.dbc`). Every drive publishes what it counts as it goes, for Foxglove
(:mod:`~bridge.bringup.monitor`: the ids tables, the unknown ids' payloads,
:mod:`~bridge.bringup.payload`, and the bit-change map, :mod:`~bridge.bringup.bitmap`).

Bits are numbered as DBC start bits of little-endian signals are: bit ``i`` is byte ``i // 8``,
bit ``i % 8``, the least significant first.
"""
