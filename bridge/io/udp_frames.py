"""A udp_multicast bus read straight from its socket (:func:`udp_reader`: python-can's own bus,
as :data:`bridge.fences.PYTHON_CAN` checked it): each datagram queued by now gives what
python-can's ``recv(0)`` would, stamped with the kernel's receive time; one of the usual kind is
made its :class:`~bridge.frame.Frame` at once (no ``select``, no ``can.Message``), any other goes
through python-can's own code for one datagram (the same message, or the same error)."""

from __future__ import annotations

import socket
import struct
from collections.abc import Callable
from typing import Any

import can
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast import bus as udp_bus
from can.interfaces.udp_multicast import utils as udp_utils

from bridge.fences import PYTHON_CAN
from bridge.frame import NS, Frame

#: The last second a frame can be stamped with (int64 nanoseconds: 2262).
LAST_SECOND = ((1 << 63) - 1) // NS
#: Kinds of frame whose check is remembered, at most (then all are forgotten).
MAX_KINDS = 4096

_new_frame = tuple.__new__  # Frame's own __new__ is a Python function
_GENERAL = udp_bus.GeneralPurposeUdpMulticastBus
_MSGPACK: Any = getattr(udp_utils, "msgpack", None)  # (python-can's, if installed)
_OWN = (UdpMulticastBus._recv_internal, _GENERAL.recv, can.BusABC.recv,
        can.BusABC._matches_filters)


def udp_reader(bus: can.BusABC) -> UdpReader | None:
    """A reader of ``bus``'s socket, if ``bus`` is python-can's udp_multicast bus as checked:
    its own ``recv``, ``_recv_internal`` and filtering, no filters, the kernel's receive
    stamps (``SO_TIMESTAMPNS``), msgpack there; else None (read through python-can)."""
    multicast: Any = getattr(bus, "_multicast", None)
    if (type(bus) is not UdpMulticastBus or not PYTHON_CAN.holds() or _MSGPACK is None
            or (type(bus)._recv_internal, type(multicast).recv, type(bus).recv,
                type(bus)._matches_filters) != _OWN
            or type(multicast) is not _GENERAL or getattr(bus, "_filters", True) is not None
            or getattr(multicast, "timestamp_nanosecond", False) is not True
            or not isinstance(getattr(multicast, "_socket", None), socket.socket)):
        return None
    return UdpReader(bus)


class UdpReader:
    """Reads one udp_multicast bus's datagrams from its socket (see the module)."""

    def __init__(self, bus: UdpMulticastBus) -> None:
        self.bus = bus
        multicast = bus._multicast
        self._socket: socket.socket = multicast._socket
        self._size: int = multicast.max_buffer
        self._ancillary: int = multicast.received_ancillary_buffer_size
        self._stamp = struct.Struct(multicast.received_timestamp_struct)
        self._fd = bus._can_protocol is can.CanProtocol.CAN_FD
        #: (id, extended, remote, error, fd, brs, esi, dlc, data length) -> whether such a frame
        #: is read at once (python-can's check takes it; not an FD frame of a bus without FD)
        self._kinds: dict[tuple[Any, ...], bool] = {}

    def read(self, bus_name: str, limit: int, frames: list[Frame],
             message: Callable[[can.Message], None],
             failed: Callable[[Exception], None]) -> None:
        """Every datagram queued by now (at most ``limit``) onto ``frames`` as ``bus_name``'s
        frames: those of the usual kind at once, the others python-can's way, its message to
        ``message``, its exception to ``failed`` (which raises it, or counts the datagram
        skipped: it counts in ``limit``); where python-can's ``recv`` gives None, the read ends.
        An ``OSError`` of the socket is raised."""
        receive, size, ancillary = self._socket.recvmsg, self._size, self._ancillary
        unstamp, stamp_size = self._stamp.unpack, self._stamp.size
        unpackb, kinds, append = _MSGPACK.unpackb, self._kinds, frames.append
        level, kind_of_stamp, last = socket.SOL_SOCKET, udp_bus.SO_TIMESTAMPNS, LAST_SECOND
        dontwait = socket.MSG_DONTWAIT
        for _ in range(limit):
            try:
                raw, extra, _, _ = receive(size, ancillary, dontwait)
            except BlockingIOError:
                return
            try:  # the usual datagram: any surprise goes python-can's way below
                ((cmsg_level, cmsg_type, cmsg_data),) = extra
                d = unpackb(raw, raw=False)
                data, ident, extended, remote = (d["data"], d["arbitration_id"],
                                                 d["is_extended_id"], d["is_remote_frame"])
                error, fd, brs, esi, dlc = (d["is_error_frame"], d["is_fd"],
                                            d["bitrate_switch"], d["error_state_indicator"],
                                            d["dlc"])
                kind = (ident, extended, remote, error, fd, brs, esi, dlc, len(data))
                usual = (cmsg_level == level and cmsg_type == kind_of_stamp
                         and len(cmsg_data) == stamp_size and type(data) is bytes
                         and len(d) == 11 and "timestamp" in d and "channel" in d
                         and (kinds.get(kind) or self._check(kind)))
            except Exception:
                usual = False
            if usual:
                seconds, nanoseconds = unstamp(cmsg_data)
                stamp = seconds + nanoseconds * 1.0e-9
                if nanoseconds < 1e9 and 0.0 <= stamp < last:
                    append(_new_frame(Frame, (
                        round(stamp * 1_000_000) * 1000, bus_name, ident, data, extended, fd,
                        error, remote, brs, esi, dlc)))
                    continue
            try:
                unpacked = self.unpacked(raw, extra)
            except Exception as exc:
                failed(exc)
                continue
            if unpacked is None:
                return
            message(unpacked)

    def _check(self, kind: tuple[Any, ...]) -> bool:
        """Whether frames of ``kind`` are read at once: python-can's ``Message(check=True)``
        takes them, they are not remote frames (whose data python-can drops) and not FD frames
        of a bus without FD (which end python-can's read). Remembered."""
        ident, extended, remote, error, fd, brs, esi, dlc, length = kind
        try:
            can.Message(arbitration_id=ident, is_extended_id=extended, is_remote_frame=remote,
                        is_error_frame=error, is_fd=fd, bitrate_switch=brs,
                        error_state_indicator=esi, dlc=dlc, data=bytes(length), check=True)
        except Exception:
            usual = False
        else:
            usual = dlc is not None and not remote and (self._fd or not fd)
        if len(self._kinds) >= MAX_KINDS:
            self._kinds.clear()
        self._kinds[kind] = usual
        return usual

    def unpacked(self, raw: bytes, extra: list[tuple[int, int, bytes]]) -> can.Message | None:
        """What python-can's ``recv(0)`` of this bus makes of one datagram received (``raw``,
        and ``extra``: its ancillary data): python-can's code of
        ``GeneralPurposeUdpMulticastBus.recv`` after its ``recvmsg`` (with the kernel's stamps)
        and of ``UdpMulticastBus._recv_internal``, as written (the same in 4.4, 4.5 and 4.6)."""
        if len(extra) != 1:
            raise can.CanOperationError(
                "Only requested a single extra field but got a different amount")
        cmsg_level, cmsg_type, cmsg_data = extra[0]
        if cmsg_level != socket.SOL_SOCKET or cmsg_type != udp_bus.SO_TIMESTAMPNS:
            raise can.CanOperationError("received control message type that was not requested")
        seconds, nanoseconds = struct.unpack(self.bus._multicast.received_timestamp_struct,
                                             cmsg_data)
        if nanoseconds >= 1e9:
            raise can.CanOperationError(
                f"Timestamp nanoseconds field was out of range: {nanoseconds} not less than 1e9")
        timestamp = seconds + nanoseconds * 1.0e-9
        try:
            message = udp_utils.unpack_message(raw, replace={"timestamp": timestamp},
                                               check=True)
        except Exception as exception:
            raise can.CanOperationError("could not unpack received message") from exception
        if not self._fd and message.is_fd:
            return None
        return message
