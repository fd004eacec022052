"""candump's error frames: SocketCAN marks one by the CAN_ERR_FLAG bit of its id, its class in
the low bits; python-can's reader makes an error frame of a bus error alone, so the others are
told from the line here.
"""

from __future__ import annotations

import can

#: candump's mark of an error frame in its id (SocketCAN's CAN_ERR_FLAG); its class is in the
#: low bits. python-can's reader makes an error frame of a bus error (0x80) alone.
CAN_ERR_FLAG = 0x20000000


def candump_error(line: str) -> bool:
    """Whether a candump line's id has :data:`CAN_ERR_FLAG`: an error frame of any class."""
    fields = line.split()
    ident = fields[2].partition("#")[0] if len(fields) >= 3 else ""
    try:
        return len(ident) == 8 and bool(int(ident, 16) & CAN_ERR_FLAG)
    except ValueError:
        return False


def error_frame(message: can.Message) -> can.Message:
    """A data frame python-can made of a candump error frame, as the error frame it is (its
    error class and data kept: the class in the id, the details in the data)."""
    return can.Message(timestamp=message.timestamp, arbitration_id=message.arbitration_id,
                       is_extended_id=True, is_error_frame=True, data=message.data,
                       dlc=message.dlc, channel=message.channel, is_rx=message.is_rx)
