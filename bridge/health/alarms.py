"""Health alarms: the settings of the checks, what an alarm is about, and an alarm's hysteresis.

:func:`alarm_id` makes every alarm id, its subject and its kind (``tankviz.AlarmKind`` in
``/health``); this is the one table of them (:mod:`bridge.health.monitor` checks them; live's last
two, :mod:`bridge.health.receive`):

============================  ==================  ================================================
id                            kind                holds when
============================  ==================  ================================================
``<sensor>.silent``           ``SENSOR_SILENT``   no frame of one of the sensor's families for
                                                  ``gap_factor`` x its cycle time (``ego.silent``
                                                  for the ego signals)
``<sensor>.rate``             ``RATE_LOW``        a family's rate is below ``rate_threshold`` of
                                                  the expected rate (``ego.rate`` too)
``<sensor>.blind``            ``NO_OBJECTS``      frames but no valid object (for as long as makes
                                                  it silent), while another sensor sees objects
                                                  (not stationary ones) inside this sensor's field
                                                  of view
``<a>-<b>.misaligned``        ``MISALIGNED``      detections both sensors see (groups of role
                                                  detections, not tracks; greedy nearest
                                                  neighbour within ``bias_gate_m``) are offset on
                                                  average by more than ``bias_lateral_m`` or
                                                  ``bias_angle_deg``: one sensor is misaligned
``lanes.lost``                ``LANES_LOST``      no valid camera lanes (the steering fallback)
                                                  for ``lane_loss_s`` (only with camera lines:
                                                  steering-only lanes have none to lose)
``bus.<bus>.silent``          ``BUS_SILENT``      no traffic at all on the bus (a gap)
``bus.<bus>.babbling``        ``BABBLING``        one id far above its cycle time, or (without
                                                  one) most of the bus
``recorder.disk_full``        ``DISK_FULL``       live: the recorder stopped for want of disk
                                                  space (told to the monitor, which raises and
                                                  clears it at the next check, without waiting)
``bus.<bus>.frames_lost``     ``FRAMES_LOST``     live: the kernel dropped frames of the bus (its
                                                  receive buffer was full) within the last window
``bus.<bus>.bad_timestamps``  ``BAD_TIMESTAMPS``  live: frames stamped NaN (or another non-time)
                                                  came within the last window
============================  ==================  ================================================
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, fields
from enum import Enum

from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.errors import UsageError
from bridge.frame import timestamp
from bridge.pb import health_pb2


@dataclass(frozen=True)
class HealthSettings:
    """Thresholds and timing of the health checks (every time in seconds of log time); a value out
    of range is a :class:`~bridge.errors.UsageError`.
    """

    #: Rates and counts are over this window.
    window_s: float = 1.0
    #: /health messages per second (1-2 Hz is plenty to plot).
    publish_hz: float = 1.0
    #: Checks per second (alarms are raised and cleared on this grid).
    eval_hz: float = 10.0
    #: A condition raises its alarm once it has held this long ...
    raise_after_s: float = 1.0
    #: ... and clears it once it has been gone this long.
    clear_after_s: float = 2.0
    #: A family below this fraction of its expected rate is too slow ...
    rate_threshold: float = 0.5
    #: ... measured over this window (or five of the family's cycles, if longer): shorter than
    #: ``window_s`` so that a slow sensor is caught within two seconds.
    rate_window_s: float = 0.5
    #: No frame for this many expected periods is a gap (a silent sensor or bus).
    gap_factor: float = 5.0
    #: Families (and buses) without a cycle time in the databases learn their rate over this
    #: long after their first frame; families never seen are silent after this long.
    learning_s: float = 3.0
    #: Radar-camera association: nearest neighbours at most this far apart (m) ...
    bias_gate_m: float = 2.5
    #: ... at least this far from the first sensor (near objects make wild angles) ...
    bias_min_range_m: float = 10.0
    #: ... over this window: a mean lateral offset beyond this (m) ...
    bias_lateral_m: float = 1.0
    #: ... or a mean angular offset beyond this (degrees) means a misaligned sensor ...
    bias_angle_deg: float = 1.5
    #: ... once at least this many pairs were matched in the window.
    bias_min_matches: int = 8
    bias_window_s: float = 0.5
    #: Camera lanes lost (steering fallback) this long raise ``lanes.lost``.
    lane_loss_s: float = 1.0
    #: Babbling: an id at more than this many times its database rate ...
    babble_factor: float = 10.0
    #: ... or, without a cycle time, more than this share of its bus's frames ...
    babble_share: float = 0.5
    #: ... and at least this many frames per second.
    babble_min_hz: float = 200.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise UsageError(f"health setting {f.name}", "must be a positive number",
                                 value=repr(value))
        if self.rate_threshold >= 1 or self.babble_share > 1:
            raise UsageError("health settings", "rate_threshold must be below 1 and "
                             "babble_share at most 1")


class AlarmKind(str, Enum):
    """What an alarm is about; the value is the format of its ids, ``{}`` standing for the
    subject (:func:`alarm_id`)."""

    SENSOR_SILENT = "{}.silent"
    RATE_LOW = "{}.rate"
    NO_OBJECTS = "{}.blind"
    MISALIGNED = "{}.misaligned"
    LANES_LOST = "{}.lost"
    BUS_SILENT = "bus.{}.silent"
    BABBLING = "bus.{}.babbling"
    DISK_FULL = "{}.disk_full"
    FRAMES_LOST = "bus.{}.frames_lost"
    BAD_TIMESTAMPS = "bus.{}.bad_timestamps"


def alarm_id(kind: AlarmKind, subject: str) -> str:
    """The id of the alarm of ``kind`` about ``subject`` (the module's table): a sensor, a pair
    of sensors (``<a>-<b>``), ``lanes``, a bus or ``recorder``."""
    return kind.value.format(subject)


class Notice(str):
    """A line to tell on ``/log``, and its level there (``foxglove.Log``'s)."""

    level: int

    def __new__(cls, text: str, level: int = Log.WARNING) -> Notice:
        notice = super().__new__(cls, text)
        notice.level = level
        return notice


def alarm_notice(kind: AlarmKind, subject: str, what: str, *, cleared: bool = False) -> Notice:
    """A notice about an alarm: ``<id>: <what>``, a warning; or, once its condition is gone,
    ``<id> cleared: <what>``, info."""
    if cleared:
        return Notice(f"{alarm_id(kind, subject)} cleared: {what}", Log.INFO)
    return Notice(f"{alarm_id(kind, subject)}: {what}", Log.WARNING)


_PB_KINDS = {
    AlarmKind.SENSOR_SILENT: health_pb2.ALARM_KIND_SENSOR_SILENT,
    AlarmKind.RATE_LOW: health_pb2.ALARM_KIND_RATE_LOW,
    AlarmKind.NO_OBJECTS: health_pb2.ALARM_KIND_NO_OBJECTS,
    AlarmKind.MISALIGNED: health_pb2.ALARM_KIND_MISALIGNED,
    AlarmKind.LANES_LOST: health_pb2.ALARM_KIND_LANES_LOST,
    AlarmKind.BUS_SILENT: health_pb2.ALARM_KIND_BUS_SILENT,
    AlarmKind.BABBLING: health_pb2.ALARM_KIND_BABBLING,
    AlarmKind.DISK_FULL: health_pb2.ALARM_KIND_DISK_FULL,
    AlarmKind.FRAMES_LOST: health_pb2.ALARM_KIND_FRAMES_LOST,
    AlarmKind.BAD_TIMESTAMPS: health_pb2.ALARM_KIND_BAD_TIMESTAMPS,
}


@dataclass(frozen=True)
class AlarmInfo:
    """An active alarm, for the scene overlay."""

    id: str
    kind: AlarmKind
    #: the sensor, sensor pair, "lanes" or bus it is about
    subject: str
    message: str
    #: log time it was raised
    since_ns: int
    #: the profile sensors it concerns (their field-of-view outlines turn red)
    sensors: tuple[str, ...]


class Alarm:
    """One alarm and its hysteresis, in log time.

    Raised once its condition has held for ``raise_after_s`` (``lane_loss_s`` for ``lanes.lost``; at
    once for live's receive alarms), cleared once gone for ``clear_after_s``, either wait restarting
    when the condition flips back; as ``tankviz.Alarm`` (:meth:`to_pb`) and for the overlay
    (:meth:`info`). An alarm told outside the monitor's ``/log`` is a :class:`Notice`.
    """

    def __init__(self, alarm_id: str, kind: AlarmKind, subject: str, sensors: Iterable[str],
                 raise_ns: int, clear_ns: int) -> None:
        self.id = alarm_id
        self.kind = kind
        self.subject = subject
        self.sensors = tuple(sensors)
        self.raise_ns = raise_ns
        self.clear_ns = clear_ns
        self.active = False
        self.since_ns: int | None = None
        self.holding_since: int | None = None
        self.gone_since: int | None = None
        self.message = ""
        self.raised = 0

    def update(self, t_ns: int, holds: bool, message: str = "") -> str | None:
        """Feed the condition at ``t_ns``; returns "raised" or "cleared" when that happens."""
        if holds:
            self.gone_since = None
            self.message = message
            if self.holding_since is None:
                self.holding_since = t_ns
            if not self.active and t_ns - self.holding_since >= self.raise_ns:
                self.active, self.since_ns = True, t_ns
                self.raised += 1
                return "raised"
            return None
        self.holding_since = None
        if self.active:
            if self.gone_since is None:
                self.gone_since = t_ns
            if t_ns - self.gone_since >= self.clear_ns:
                self.active, self.since_ns = False, t_ns
                return "cleared"
        return None

    def info(self) -> AlarmInfo:
        return AlarmInfo(self.id, self.kind, self.subject, self.message, self.since_ns or 0,
                         self.sensors)

    def to_pb(self) -> health_pb2.Alarm:
        msg = health_pb2.Alarm(id=self.id, kind=_PB_KINDS[self.kind], subject=self.subject,
                               message=self.message, active=self.active,
                               raised_count=self.raised)
        if self.since_ns is not None:
            msg.since.CopyFrom(timestamp(self.since_ns))
        return msg
