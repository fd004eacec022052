from google.protobuf import timestamp_pb2 as _timestamp_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from typing import ClassVar as _ClassVar, Iterable as _Iterable, Mapping as _Mapping, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class ObjectClass(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    OBJECT_CLASS_UNKNOWN: _ClassVar[ObjectClass]
    OBJECT_CLASS_CAR: _ClassVar[ObjectClass]
    OBJECT_CLASS_TWO_WHEELER: _ClassVar[ObjectClass]
    OBJECT_CLASS_PEDESTRIAN: _ClassVar[ObjectClass]
    OBJECT_CLASS_STATIONARY: _ClassVar[ObjectClass]
OBJECT_CLASS_UNKNOWN: ObjectClass
OBJECT_CLASS_CAR: ObjectClass
OBJECT_CLASS_TWO_WHEELER: ObjectClass
OBJECT_CLASS_PEDESTRIAN: ObjectClass
OBJECT_CLASS_STATIONARY: ObjectClass

class PerceivedObject(_message.Message):
    __slots__ = ("id", "x", "y", "vx", "vy", "probability", "object_class", "distance", "age", "twins")
    ID_FIELD_NUMBER: _ClassVar[int]
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    VX_FIELD_NUMBER: _ClassVar[int]
    VY_FIELD_NUMBER: _ClassVar[int]
    PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    OBJECT_CLASS_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_FIELD_NUMBER: _ClassVar[int]
    AGE_FIELD_NUMBER: _ClassVar[int]
    TWINS_FIELD_NUMBER: _ClassVar[int]
    id: int
    x: float
    y: float
    vx: float
    vy: float
    probability: float
    object_class: ObjectClass
    distance: float
    age: float
    twins: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, id: _Optional[int] = ..., x: _Optional[float] = ..., y: _Optional[float] = ..., vx: _Optional[float] = ..., vy: _Optional[float] = ..., probability: _Optional[float] = ..., object_class: _Optional[_Union[ObjectClass, str]] = ..., distance: _Optional[float] = ..., age: _Optional[float] = ..., twins: _Optional[_Iterable[int]] = ...) -> None: ...

class PerceivedObjects(_message.Message):
    __slots__ = ("timestamp", "frame_id", "group", "sensor", "count", "objects")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    GROUP_FIELD_NUMBER: _ClassVar[int]
    SENSOR_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    group: str
    sensor: str
    count: int
    objects: _containers.RepeatedCompositeFieldContainer[PerceivedObject]
    def __init__(self, timestamp: _Optional[_Union[_timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., group: _Optional[str] = ..., sensor: _Optional[str] = ..., count: _Optional[int] = ..., objects: _Optional[_Iterable[_Union[PerceivedObject, _Mapping]]] = ...) -> None: ...

class LeadVehicle(_message.Message):
    __slots__ = ("timestamp", "frame_id", "present", "object", "expected_present", "expected", "mio_ok", "mio_reason", "lead_number", "change")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    PRESENT_FIELD_NUMBER: _ClassVar[int]
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    EXPECTED_PRESENT_FIELD_NUMBER: _ClassVar[int]
    EXPECTED_FIELD_NUMBER: _ClassVar[int]
    MIO_OK_FIELD_NUMBER: _ClassVar[int]
    MIO_REASON_FIELD_NUMBER: _ClassVar[int]
    LEAD_NUMBER_FIELD_NUMBER: _ClassVar[int]
    CHANGE_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    present: bool
    object: PerceivedObject
    expected_present: bool
    expected: PerceivedObject
    mio_ok: bool
    mio_reason: str
    lead_number: int
    change: str
    def __init__(self, timestamp: _Optional[_Union[_timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., present: bool = ..., object: _Optional[_Union[PerceivedObject, _Mapping]] = ..., expected_present: bool = ..., expected: _Optional[_Union[PerceivedObject, _Mapping]] = ..., mio_ok: bool = ..., mio_reason: _Optional[str] = ..., lead_number: _Optional[int] = ..., change: _Optional[str] = ...) -> None: ...

class LaneLine(_message.Message):
    __slots__ = ("name", "c0", "c1", "c2", "c3")
    NAME_FIELD_NUMBER: _ClassVar[int]
    C0_FIELD_NUMBER: _ClassVar[int]
    C1_FIELD_NUMBER: _ClassVar[int]
    C2_FIELD_NUMBER: _ClassVar[int]
    C3_FIELD_NUMBER: _ClassVar[int]
    name: str
    c0: float
    c1: float
    c2: float
    c3: float
    def __init__(self, name: _Optional[str] = ..., c0: _Optional[float] = ..., c1: _Optional[float] = ..., c2: _Optional[float] = ..., c3: _Optional[float] = ...) -> None: ...

class Lanes(_message.Message):
    __slots__ = ("timestamp", "frame_id", "source", "lines", "camera_age")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    FRAME_ID_FIELD_NUMBER: _ClassVar[int]
    SOURCE_FIELD_NUMBER: _ClassVar[int]
    LINES_FIELD_NUMBER: _ClassVar[int]
    CAMERA_AGE_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    frame_id: str
    source: str
    lines: _containers.RepeatedCompositeFieldContainer[LaneLine]
    camera_age: float
    def __init__(self, timestamp: _Optional[_Union[_timestamp_pb2.Timestamp, _Mapping]] = ..., frame_id: _Optional[str] = ..., source: _Optional[str] = ..., lines: _Optional[_Iterable[_Union[LaneLine, _Mapping]]] = ..., camera_age: _Optional[float] = ...) -> None: ...

class EgoState(_message.Message):
    __slots__ = ("timestamp", "speed", "yaw_rate", "steering_wheel_angle", "curvature")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    SPEED_FIELD_NUMBER: _ClassVar[int]
    YAW_RATE_FIELD_NUMBER: _ClassVar[int]
    STEERING_WHEEL_ANGLE_FIELD_NUMBER: _ClassVar[int]
    CURVATURE_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    speed: float
    yaw_rate: float
    steering_wheel_angle: float
    curvature: float
    def __init__(self, timestamp: _Optional[_Union[_timestamp_pb2.Timestamp, _Mapping]] = ..., speed: _Optional[float] = ..., yaw_rate: _Optional[float] = ..., steering_wheel_angle: _Optional[float] = ..., curvature: _Optional[float] = ...) -> None: ...
