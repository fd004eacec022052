from google.protobuf import timestamp_pb2 as _timestamp_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from typing import ClassVar as _ClassVar, Iterable as _Iterable, Mapping as _Mapping, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class AlarmKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    ALARM_KIND_UNSPECIFIED: _ClassVar[AlarmKind]
    ALARM_KIND_SENSOR_SILENT: _ClassVar[AlarmKind]
    ALARM_KIND_RATE_LOW: _ClassVar[AlarmKind]
    ALARM_KIND_NO_OBJECTS: _ClassVar[AlarmKind]
    ALARM_KIND_MISALIGNED: _ClassVar[AlarmKind]
    ALARM_KIND_LANES_LOST: _ClassVar[AlarmKind]
    ALARM_KIND_BUS_SILENT: _ClassVar[AlarmKind]
    ALARM_KIND_BABBLING: _ClassVar[AlarmKind]
    ALARM_KIND_DISK_FULL: _ClassVar[AlarmKind]
    ALARM_KIND_FRAMES_LOST: _ClassVar[AlarmKind]
    ALARM_KIND_BAD_TIMESTAMPS: _ClassVar[AlarmKind]
ALARM_KIND_UNSPECIFIED: AlarmKind
ALARM_KIND_SENSOR_SILENT: AlarmKind
ALARM_KIND_RATE_LOW: AlarmKind
ALARM_KIND_NO_OBJECTS: AlarmKind
ALARM_KIND_MISALIGNED: AlarmKind
ALARM_KIND_LANES_LOST: AlarmKind
ALARM_KIND_BUS_SILENT: AlarmKind
ALARM_KIND_BABBLING: AlarmKind
ALARM_KIND_DISK_FULL: AlarmKind
ALARM_KIND_FRAMES_LOST: AlarmKind
ALARM_KIND_BAD_TIMESTAMPS: AlarmKind

class BusHealth(_message.Message):
    __slots__ = ("bus", "frames_per_s", "bits_per_s", "load", "bitrate", "data_bitrate", "error_frames", "error_frames_total", "unknown_ids", "unknown_ids_total", "decode_errors", "decode_errors_total", "silent_s", "gap", "gaps_total", "expected_period_s", "frames_total", "top_id", "top_id_hz", "top_id_share", "non_finite_total", "bad_timestamps_total", "receive_dropped_total")
    BUS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_PER_S_FIELD_NUMBER: _ClassVar[int]
    BITS_PER_S_FIELD_NUMBER: _ClassVar[int]
    LOAD_FIELD_NUMBER: _ClassVar[int]
    BITRATE_FIELD_NUMBER: _ClassVar[int]
    DATA_BITRATE_FIELD_NUMBER: _ClassVar[int]
    ERROR_FRAMES_FIELD_NUMBER: _ClassVar[int]
    ERROR_FRAMES_TOTAL_FIELD_NUMBER: _ClassVar[int]
    UNKNOWN_IDS_FIELD_NUMBER: _ClassVar[int]
    UNKNOWN_IDS_TOTAL_FIELD_NUMBER: _ClassVar[int]
    DECODE_ERRORS_FIELD_NUMBER: _ClassVar[int]
    DECODE_ERRORS_TOTAL_FIELD_NUMBER: _ClassVar[int]
    SILENT_S_FIELD_NUMBER: _ClassVar[int]
    GAP_FIELD_NUMBER: _ClassVar[int]
    GAPS_TOTAL_FIELD_NUMBER: _ClassVar[int]
    EXPECTED_PERIOD_S_FIELD_NUMBER: _ClassVar[int]
    FRAMES_TOTAL_FIELD_NUMBER: _ClassVar[int]
    TOP_ID_FIELD_NUMBER: _ClassVar[int]
    TOP_ID_HZ_FIELD_NUMBER: _ClassVar[int]
    TOP_ID_SHARE_FIELD_NUMBER: _ClassVar[int]
    NON_FINITE_TOTAL_FIELD_NUMBER: _ClassVar[int]
    BAD_TIMESTAMPS_TOTAL_FIELD_NUMBER: _ClassVar[int]
    RECEIVE_DROPPED_TOTAL_FIELD_NUMBER: _ClassVar[int]
    bus: str
    frames_per_s: float
    bits_per_s: float
    load: float
    bitrate: int
    data_bitrate: int
    error_frames: int
    error_frames_total: int
    unknown_ids: int
    unknown_ids_total: int
    decode_errors: int
    decode_errors_total: int
    silent_s: float
    gap: bool
    gaps_total: int
    expected_period_s: float
    frames_total: int
    top_id: int
    top_id_hz: float
    top_id_share: float
    non_finite_total: int
    bad_timestamps_total: int
    receive_dropped_total: int
    def __init__(self, bus: _Optional[str] = ..., frames_per_s: _Optional[float] = ..., bits_per_s: _Optional[float] = ..., load: _Optional[float] = ..., bitrate: _Optional[int] = ..., data_bitrate: _Optional[int] = ..., error_frames: _Optional[int] = ..., error_frames_total: _Optional[int] = ..., unknown_ids: _Optional[int] = ..., unknown_ids_total: _Optional[int] = ..., decode_errors: _Optional[int] = ..., decode_errors_total: _Optional[int] = ..., silent_s: _Optional[float] = ..., gap: bool = ..., gaps_total: _Optional[int] = ..., expected_period_s: _Optional[float] = ..., frames_total: _Optional[int] = ..., top_id: _Optional[int] = ..., top_id_hz: _Optional[float] = ..., top_id_share: _Optional[float] = ..., non_finite_total: _Optional[int] = ..., bad_timestamps_total: _Optional[int] = ..., receive_dropped_total: _Optional[int] = ...) -> None: ...

class FamilyHealth(_message.Message):
    __slots__ = ("name", "sensor", "expected_hz", "expected_source", "actual_hz", "rate_ratio", "age_s", "valid_objects", "silent", "frames_total", "rule_errors_total", "last_rule_error")
    NAME_FIELD_NUMBER: _ClassVar[int]
    SENSOR_FIELD_NUMBER: _ClassVar[int]
    EXPECTED_HZ_FIELD_NUMBER: _ClassVar[int]
    EXPECTED_SOURCE_FIELD_NUMBER: _ClassVar[int]
    ACTUAL_HZ_FIELD_NUMBER: _ClassVar[int]
    RATE_RATIO_FIELD_NUMBER: _ClassVar[int]
    AGE_S_FIELD_NUMBER: _ClassVar[int]
    VALID_OBJECTS_FIELD_NUMBER: _ClassVar[int]
    SILENT_FIELD_NUMBER: _ClassVar[int]
    FRAMES_TOTAL_FIELD_NUMBER: _ClassVar[int]
    RULE_ERRORS_TOTAL_FIELD_NUMBER: _ClassVar[int]
    LAST_RULE_ERROR_FIELD_NUMBER: _ClassVar[int]
    name: str
    sensor: str
    expected_hz: float
    expected_source: str
    actual_hz: float
    rate_ratio: float
    age_s: float
    valid_objects: int
    silent: bool
    frames_total: int
    rule_errors_total: int
    last_rule_error: str
    def __init__(self, name: _Optional[str] = ..., sensor: _Optional[str] = ..., expected_hz: _Optional[float] = ..., expected_source: _Optional[str] = ..., actual_hz: _Optional[float] = ..., rate_ratio: _Optional[float] = ..., age_s: _Optional[float] = ..., valid_objects: _Optional[int] = ..., silent: bool = ..., frames_total: _Optional[int] = ..., rule_errors_total: _Optional[int] = ..., last_rule_error: _Optional[str] = ...) -> None: ...

class SensorBias(_message.Message):
    __slots__ = ("pair", "sensor_a", "sensor_b", "matches", "lateral_offset_m", "angular_offset_deg")
    PAIR_FIELD_NUMBER: _ClassVar[int]
    SENSOR_A_FIELD_NUMBER: _ClassVar[int]
    SENSOR_B_FIELD_NUMBER: _ClassVar[int]
    MATCHES_FIELD_NUMBER: _ClassVar[int]
    LATERAL_OFFSET_M_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_OFFSET_DEG_FIELD_NUMBER: _ClassVar[int]
    pair: str
    sensor_a: str
    sensor_b: str
    matches: int
    lateral_offset_m: float
    angular_offset_deg: float
    def __init__(self, pair: _Optional[str] = ..., sensor_a: _Optional[str] = ..., sensor_b: _Optional[str] = ..., matches: _Optional[int] = ..., lateral_offset_m: _Optional[float] = ..., angular_offset_deg: _Optional[float] = ...) -> None: ...

class Alarm(_message.Message):
    __slots__ = ("id", "kind", "subject", "message", "since", "active", "raised_count")
    ID_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    SUBJECT_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    SINCE_FIELD_NUMBER: _ClassVar[int]
    ACTIVE_FIELD_NUMBER: _ClassVar[int]
    RAISED_COUNT_FIELD_NUMBER: _ClassVar[int]
    id: str
    kind: AlarmKind
    subject: str
    message: str
    since: _timestamp_pb2.Timestamp
    active: bool
    raised_count: int
    def __init__(self, id: _Optional[str] = ..., kind: _Optional[_Union[AlarmKind, str]] = ..., subject: _Optional[str] = ..., message: _Optional[str] = ..., since: _Optional[_Union[_timestamp_pb2.Timestamp, _Mapping]] = ..., active: bool = ..., raised_count: _Optional[int] = ...) -> None: ...

class Health(_message.Message):
    __slots__ = ("timestamp", "window_s", "buses", "families", "biases", "alarms", "active_alarms")
    TIMESTAMP_FIELD_NUMBER: _ClassVar[int]
    WINDOW_S_FIELD_NUMBER: _ClassVar[int]
    BUSES_FIELD_NUMBER: _ClassVar[int]
    FAMILIES_FIELD_NUMBER: _ClassVar[int]
    BIASES_FIELD_NUMBER: _ClassVar[int]
    ALARMS_FIELD_NUMBER: _ClassVar[int]
    ACTIVE_ALARMS_FIELD_NUMBER: _ClassVar[int]
    timestamp: _timestamp_pb2.Timestamp
    window_s: float
    buses: _containers.RepeatedCompositeFieldContainer[BusHealth]
    families: _containers.RepeatedCompositeFieldContainer[FamilyHealth]
    biases: _containers.RepeatedCompositeFieldContainer[SensorBias]
    alarms: _containers.RepeatedCompositeFieldContainer[Alarm]
    active_alarms: int
    def __init__(self, timestamp: _Optional[_Union[_timestamp_pb2.Timestamp, _Mapping]] = ..., window_s: _Optional[float] = ..., buses: _Optional[_Iterable[_Union[BusHealth, _Mapping]]] = ..., families: _Optional[_Iterable[_Union[FamilyHealth, _Mapping]]] = ..., biases: _Optional[_Iterable[_Union[SensorBias, _Mapping]]] = ..., alarms: _Optional[_Iterable[_Union[Alarm, _Mapping]]] = ..., active_alarms: _Optional[int] = ...) -> None: ...
