from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from typing import ClassVar as _ClassVar, Iterable as _Iterable, Mapping as _Mapping, Optional as _Optional, Union as _Union

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

class CanFrameBlock(_message.Message):
    __slots__ = ("bus", "frames")
    class Frame(_message.Message):
        __slots__ = ("id", "data", "offset_ns", "extended", "fd", "bitrate_switch", "error_state_indicator", "error", "remote", "dlc")
        ID_FIELD_NUMBER: _ClassVar[int]
        DATA_FIELD_NUMBER: _ClassVar[int]
        OFFSET_NS_FIELD_NUMBER: _ClassVar[int]
        EXTENDED_FIELD_NUMBER: _ClassVar[int]
        FD_FIELD_NUMBER: _ClassVar[int]
        BITRATE_SWITCH_FIELD_NUMBER: _ClassVar[int]
        ERROR_STATE_INDICATOR_FIELD_NUMBER: _ClassVar[int]
        ERROR_FIELD_NUMBER: _ClassVar[int]
        REMOTE_FIELD_NUMBER: _ClassVar[int]
        DLC_FIELD_NUMBER: _ClassVar[int]
        id: int
        data: bytes
        offset_ns: int
        extended: bool
        fd: bool
        bitrate_switch: bool
        error_state_indicator: bool
        error: bool
        remote: bool
        dlc: int
        def __init__(self, id: _Optional[int] = ..., data: _Optional[bytes] = ..., offset_ns: _Optional[int] = ..., extended: bool = ..., fd: bool = ..., bitrate_switch: bool = ..., error_state_indicator: bool = ..., error: bool = ..., remote: bool = ..., dlc: _Optional[int] = ...) -> None: ...
    BUS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    bus: str
    frames: _containers.RepeatedCompositeFieldContainer[CanFrameBlock.Frame]
    def __init__(self, bus: _Optional[str] = ..., frames: _Optional[_Iterable[_Union[CanFrameBlock.Frame, _Mapping]]] = ...) -> None: ...
