from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from typing import ClassVar as _ClassVar, Optional as _Optional

DESCRIPTOR: _descriptor.FileDescriptor

class CanFrame(_message.Message):
    __slots__ = ("bus", "id", "extended", "fd", "bitrate_switch", "error_state_indicator", "error", "remote", "dlc", "data")
    BUS_FIELD_NUMBER: _ClassVar[int]
    ID_FIELD_NUMBER: _ClassVar[int]
    EXTENDED_FIELD_NUMBER: _ClassVar[int]
    FD_FIELD_NUMBER: _ClassVar[int]
    BITRATE_SWITCH_FIELD_NUMBER: _ClassVar[int]
    ERROR_STATE_INDICATOR_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    REMOTE_FIELD_NUMBER: _ClassVar[int]
    DLC_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    bus: str
    id: int
    extended: bool
    fd: bool
    bitrate_switch: bool
    error_state_indicator: bool
    error: bool
    remote: bool
    dlc: int
    data: bytes
    def __init__(self, bus: _Optional[str] = ..., id: _Optional[int] = ..., extended: bool = ..., fd: bool = ..., bitrate_switch: bool = ..., error_state_indicator: bool = ..., error: bool = ..., remote: bool = ..., dlc: _Optional[int] = ..., data: _Optional[bytes] = ...) -> None: ...
