"""J1939: a database's parameter groups matched by PGN, as J1939 tools match them.

A message is J1939 where cantools says so (``VFrameFormat`` ``J1939PG``) or where its database
says ``ProtocolType "J1939"`` and its id is extended. Its 29-bit id is priority (3 bits), PGN
(18 bits: EDP, DP, PF, PS) and source address (8 bits); in a PDU1 group (PF < 240) PS is the
destination address, not part of the group. :func:`pgn_key` is what a frame and a message are
matched by: a frame of any priority and source, to any destination, is the group's.

The decoded message of a J1939 message keeps what the match leaves out: a ``source_address``
field after the signals and, for a PDU1 group, a ``destination_address``
(:func:`address_fields`, :func:`address_suffix`: the bytes of both, appended to the signals'
as protobuf writes fields in number order).
"""

from __future__ import annotations

from cantools.database.can.database import Database
from cantools.database.can.message import Message as DbcMessage

from bridge.protowire import varint

#: PF from which a group is PDU2 (PS is part of the PGN, a group extension)
_PDU2 = 240
#: the field names of the addresses, before any clash with a signal's
SOURCE, DESTINATION = "source_address", "destination_address"


def is_j1939(message: DbcMessage, db: Database) -> bool:
    """Whether ``message`` of ``db`` is a J1939 parameter group."""
    if message.protocol == "j1939":
        return True
    if not message.is_extended_frame:
        return False
    attribute = (db.dbc.attributes.get("ProtocolType") if db.dbc is not None else None)
    return attribute is not None and str(attribute.value).upper() == "J1939"


def is_pdu1(frame_id: int) -> bool:
    """Whether the 29-bit ``frame_id`` is of a PDU1 group (PS: the destination address)."""
    return (frame_id >> 16) & 0xFF < _PDU2


def pgn_key(frame_id: int) -> int:
    """The PGN of a 29-bit id, its destination address masked for a PDU1 group: cantools'
    ``j1939.pgn_from_frame_id`` (a test holds them equal) in bit operations, for the per-frame
    path."""
    pgn = (frame_id >> 8) & 0x3FFFF
    return pgn & 0x3FF00 if is_pdu1(frame_id) else pgn


def address_fields(message: DbcMessage) -> tuple[str, ...]:
    """The addresses a J1939 message's decoded message keeps, in field order."""
    return (SOURCE, DESTINATION) if is_pdu1(message.frame_id) else (SOURCE,)


def address_suffix(frame_id: int, numbers: tuple[int, ...], *, implicit: bool = True) -> bytes:
    """The protobuf bytes of a frame's addresses: field ``numbers[0]`` the source address and,
    for a PDU1 group, ``numbers[1]`` the destination address (``uint32``, in every frame: of
    implicit presence, so address 0 is not written, unless not ``implicit``)."""
    values = (frame_id & 0xFF, (frame_id >> 8) & 0xFF)
    return b"".join(varint(number << 3) + varint(value)
                    for number, value in zip(numbers, values, strict=False)
                    if value or not implicit)
