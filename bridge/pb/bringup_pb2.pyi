from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from typing import ClassVar as _ClassVar, Iterable as _Iterable, Mapping as _Mapping, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class CanIds(_message.Message):
    __slots__ = ("bus", "rows")
    class Row(_message.Message):
        __slots__ = ("id", "message", "frames", "period_ms", "jitter_ms", "dlc", "changing_bits", "unexplained_bits", "changed_last_s")
        ID_FIELD_NUMBER: _ClassVar[int]
        MESSAGE_FIELD_NUMBER: _ClassVar[int]
        FRAMES_FIELD_NUMBER: _ClassVar[int]
        PERIOD_MS_FIELD_NUMBER: _ClassVar[int]
        JITTER_MS_FIELD_NUMBER: _ClassVar[int]
        DLC_FIELD_NUMBER: _ClassVar[int]
        CHANGING_BITS_FIELD_NUMBER: _ClassVar[int]
        UNEXPLAINED_BITS_FIELD_NUMBER: _ClassVar[int]
        CHANGED_LAST_S_FIELD_NUMBER: _ClassVar[int]
        id: str
        message: str
        frames: int
        period_ms: float
        jitter_ms: float
        dlc: str
        changing_bits: int
        unexplained_bits: int
        changed_last_s: int
        def __init__(self, id: _Optional[str] = ..., message: _Optional[str] = ..., frames: _Optional[int] = ..., period_ms: _Optional[float] = ..., jitter_ms: _Optional[float] = ..., dlc: _Optional[str] = ..., changing_bits: _Optional[int] = ..., unexplained_bits: _Optional[int] = ..., changed_last_s: _Optional[int] = ...) -> None: ...
    BUS_FIELD_NUMBER: _ClassVar[int]
    ROWS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    rows: _containers.RepeatedCompositeFieldContainer[CanIds.Row]
    def __init__(self, bus: _Optional[str] = ..., rows: _Optional[_Iterable[_Union[CanIds.Row, _Mapping]]] = ...) -> None: ...

class CanPayload(_message.Message):
    __slots__ = ("id", "bytes", "be16", "le16")
    ID_FIELD_NUMBER: _ClassVar[int]
    BYTES_FIELD_NUMBER: _ClassVar[int]
    BE16_FIELD_NUMBER: _ClassVar[int]
    LE16_FIELD_NUMBER: _ClassVar[int]
    id: str
    bytes: _containers.RepeatedScalarFieldContainer[int]
    be16: _containers.RepeatedScalarFieldContainer[int]
    le16: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, id: _Optional[str] = ..., bytes: _Optional[_Iterable[int]] = ..., be16: _Optional[_Iterable[int]] = ..., le16: _Optional[_Iterable[int]] = ...) -> None: ...
