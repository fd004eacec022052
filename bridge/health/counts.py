"""What the health monitor counts per bus and per message family, and the figures of ``/health``
it makes of those counts.

:class:`BusCounts` becomes ``tankviz.BusHealth`` (:func:`bus_figures`) and the bus alarms that
hold (:func:`bus_conditions`), :class:`FamilyCounts` ``tankviz.FamilyHealth``
(:func:`family_figures`); rates over a window are the counts now less a :class:`Snapshot`'s.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from bridge.frame import NEVER_NS, NS, key_id
from bridge.health.alarms import AlarmKind, HealthSettings, alarm_id
from bridge.health.bus_bits import FrameKind, KindKey
from bridge.pb import health_pb2

if TYPE_CHECKING:  # (a drive without a profile has no families: it never loads them)
    from bridge.profile.model import Profile, Sensor

NEVER = NEVER_NS  # a time before everything
UNKNOWN = 1 << 62  # a gap threshold that is never exceeded


def seconds(ns: int) -> float:
    return ns / NS


class BusCounts:
    """One bus, counted since its first frame (the monitor's hot path updates it in place)."""

    __slots__ = ("bitrate", "bits", "brs_bits", "cycles", "data_bitrate", "decode_errors",
                 "error_frames", "families", "first_ns", "frames", "gap_ns", "gaps", "ids",
                 "kinds", "last_ns", "name", "non_finite", "unknown")

    def __init__(self, name: str, t_ns: int, bitrate: int | None,
                 data_bitrate: int | None) -> None:
        self.name = name
        self.first_ns = t_ns
        self.last_ns = t_ns
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate
        self.frames = 0
        self.bits = 0.0  # arbitration-phase bits (every bit of frames without bit rate switch)
        self.brs_bits = 0.0  # data-phase bits of CAN FD frames with bit rate switch
        self.error_frames = 0
        self.unknown = 0
        self.decode_errors = 0
        self.non_finite = 0
        self.gaps = 0
        self.gap_ns = UNKNOWN
        self.ids: Counter[int] = Counter()  # frames per frame key (bridge.frame.frame_key)
        self.cycles: dict[int, float] = {}  # frame key -> database cycle time (s)
        self.families: set[str] = set()
        #: the bits of each kind of frame (exact for a sample, else its mean: health.bus_bits)
        self.kinds: dict[KindKey, FrameKind] = {}


class FamilyCounts:
    """One message family of the profile."""

    __slots__ = ("buses", "expected_hz", "first_ns", "frames", "gap_ns", "group", "kind",
                 "last_ns", "last_valid_ns", "messages", "name", "rate_window_ns", "resumed_ns",
                 "rule_errors", "seen_messages", "sensor", "source", "subject",
                 "valid_objects", "why_rule", "witnessed_ns")

    def __init__(self, name: str, kind: str, sensor: Sensor | None, messages: Iterable[str],
                 group: str | None) -> None:
        self.name = name
        self.kind = kind  # "objects", "lead", "lanes" or "ego"
        self.sensor = sensor
        self.subject = sensor.name if sensor is not None else name
        self.messages = frozenset(messages)
        self.group = group  # the world's object group, for object families
        self.expected_hz: float | None = None
        self.source = "learning"
        self.gap_ns = UNKNOWN
        self.rate_window_ns = UNKNOWN
        self.frames = 0
        self.first_ns = NEVER
        self.last_ns = NEVER
        self.resumed_ns = NEVER
        self.last_valid_ns = NEVER
        self.witnessed_ns = NEVER
        self.valid_objects = 0
        self.seen_messages: set[str] = set()
        self.buses: set[str] = set()
        self.rule_errors = 0  # validity rule evaluations that failed, since the start
        self.why_rule = ""  # the latest reason


def make_families(profile: Profile, cycles: Mapping[str, float], settings: HealthSettings
                  ) -> list[FamilyCounts]:
    """The profile's message families: each object group, the lead, the lane lines (not
    steering-only lanes) and the ego signals; a family whose every message has a cycle time
    (``cycles``: message name -> seconds, from the databases) expects its rate from them."""
    from bridge.world.observe import LEAD_GROUP

    families = [FamilyCounts(name, "objects", g.sensor, g.members, name)
                for name, g in profile.groups.items()]
    if profile.lead is not None and profile.lead.group is not None:
        lead = profile.lead.group
        families.append(FamilyCounts("lead", "lead", lead.sensor, lead.members, LEAD_GROUP))
    if profile.lanes is not None and profile.lanes.lines:  # not for steering-only lanes
        families.append(FamilyCounts("lanes", "lanes", profile.lanes.sensor,
                                     (line.message for line in profile.lanes.lines.values()),
                                     None))
    ego = profile.ego
    messages = {ref.message for ref in (ego.speed, ego.yaw_rate, ego.steering_wheel_angle)
                if ref is not None}
    if messages:
        families.append(FamilyCounts("ego", "ego", None, messages, None))
    for family in families:
        found = [cycles.get(m) for m in family.messages]
        if found and all(c is not None for c in found):
            known = [c for c in found if c is not None]
            family.expected_hz = sum(1.0 / c for c in known)
            family.gap_ns = round(settings.gap_factor * min(known) * NS)
            family.rate_window_ns = rate_window(settings, max(known))
            family.source = "dbc"
    return families


def rate_window(settings: HealthSettings, period_s: float) -> int:
    """The window a family's rate is judged over: ``rate_window_s``, or five of its periods."""
    return round(max(settings.rate_window_s, 5 * period_s) * NS)


@dataclass(frozen=True)
class Pair:
    """Two sensors whose objects are compared for the misalignment check."""

    name: str
    a: FamilyCounts
    b: FamilyCounts


@dataclass
class Snapshot:
    """Every count at one check: per bus (frames, bits, data-phase bits, error frames, unknown
    ids, decode errors, frames per id), and frames per family."""

    t_ns: int
    buses: dict[str, tuple[int, float, float, int, int, int, dict[int, int]]]
    families: dict[str, int]

    @classmethod
    def take(cls, t_ns: int, buses: Iterable[BusCounts],
             families: Iterable[FamilyCounts]) -> Snapshot:
        return cls(t_ns, {b.name: (b.frames, b.bits, b.brs_bits, b.error_frames, b.unknown,
                                   b.decode_errors, dict(b.ids)) for b in buses},
                   {f.name: f.frames for f in families})


def bus_figures(buses: Mapping[str, BusCounts], base: Snapshot, t_ns: int, gap_factor: float
                ) -> tuple[dict[str, health_pb2.BusHealth], dict[str, int]]:
    """Every bus's ``BusHealth`` at log time ``t_ns``, its window counts since ``base``; and the
    key of each bus's busiest id in that window."""
    elapsed = seconds(t_ns - base.t_ns)
    top_keys = {}
    out = {}
    for name, bus in buses.items():
        frames, bits, brs_bits, errors, unknown, decode_errors, ids = base.buses.get(
            name, (0, 0.0, 0.0, 0, 0, 0, {}))
        msg = health_pb2.BusHealth(
            bus=name, bitrate=bus.bitrate or 0, data_bitrate=bus.data_bitrate or 0,
            error_frames=bus.error_frames - errors, error_frames_total=bus.error_frames,
            unknown_ids=bus.unknown - unknown, unknown_ids_total=bus.unknown,
            decode_errors=bus.decode_errors - decode_errors,
            decode_errors_total=bus.decode_errors, silent_s=seconds(t_ns - bus.last_ns),
            gap=t_ns - bus.last_ns > bus.gap_ns,
            expected_period_s=(seconds(bus.gap_ns) / gap_factor
                               if bus.gap_ns != UNKNOWN else 0.0),
            frames_total=bus.frames, non_finite_total=bus.non_finite)
        msg.gaps_total = bus.gaps + int(msg.gap)
        if elapsed > 0:
            window_frames = bus.frames - frames
            msg.frames_per_s = window_frames / elapsed
            nominal, data_phase = bus.bits - bits, bus.brs_bits - brs_bits
            if bus.bitrate and (not data_phase or bus.data_bitrate):
                time_s = nominal / bus.bitrate + (
                    data_phase / bus.data_bitrate if bus.data_bitrate else 0.0)
                msg.load = time_s / elapsed
                msg.bits_per_s = time_s * bus.bitrate / elapsed
            else:
                msg.bits_per_s = (nominal + data_phase) / elapsed
            top, top_count = 0, 0
            for key, count in bus.ids.items():
                delta = count - ids.get(key, 0)
                if delta > top_count:
                    top, top_count = key, delta
            if top_count:
                msg.top_id = key_id(top)
                msg.top_id_hz = top_count / elapsed
                msg.top_id_share = top_count / window_frames
                top_keys[name] = top
        out[name] = msg
    return out, top_keys


def bus_conditions(buses: Mapping[str, BusCounts], figures: Mapping[str, health_pb2.BusHealth],
                   top_keys: Mapping[str, int], settings: HealthSettings
                   ) -> Iterator[tuple[str, str]]:
    """The bus alarms whose condition holds, as (alarm id, why): a bus in a gap is silent; its
    busiest id far above its cycle time (or, without one, most of the bus) is babbling."""
    s = settings
    for name, msg in figures.items():
        if msg.gap:
            yield (alarm_id(AlarmKind.BUS_SILENT, name),
                   f"bus {name}: no frame for {msg.silent_s:.1f} s")
        key = top_keys.get(name)
        if key is None or msg.top_id_hz < s.babble_min_hz:
            continue
        cycle = buses[name].cycles.get(key)
        ident = f"0x{key_id(key):X}"
        if cycle is not None and msg.top_id_hz > s.babble_factor / cycle:
            yield (alarm_id(AlarmKind.BABBLING, name), f"bus {name}: id {ident} at "
                   f"{msg.top_id_hz:.0f} frames/s, its cycle time is {cycle * 1000:g} ms")
        elif cycle is None and msg.top_id_share > s.babble_share:
            yield (alarm_id(AlarmKind.BABBLING, name), f"bus {name}: id {ident} is "
                   f"{msg.top_id_share:.0%} of the frames ({msg.top_id_hz:.0f}/s)")


def family_figures(families: Iterable[FamilyCounts], base: Snapshot, t_ns: int
                   ) -> dict[str, health_pb2.FamilyHealth]:
    """Every family's ``FamilyHealth`` at log time ``t_ns``, its rate since ``base``."""
    elapsed = seconds(t_ns - base.t_ns)
    out = {}
    for family in families:
        msg = health_pb2.FamilyHealth(
            name=family.name, sensor=family.sensor.name if family.sensor else "",
            expected_hz=family.expected_hz or 0.0, expected_source=family.source,
            age_s=seconds(t_ns - family.last_ns) if family.last_ns != NEVER else -1.0,
            valid_objects=family.valid_objects,
            silent=family.last_ns != NEVER and t_ns - family.last_ns > family.gap_ns,
            frames_total=family.frames, rule_errors_total=family.rule_errors,
            last_rule_error=family.why_rule)
        if elapsed > 0:
            msg.actual_hz = (family.frames - base.families.get(family.name, 0)) / elapsed
            if family.expected_hz:
                msg.rate_ratio = msg.actual_hz / family.expected_hz
        out[family.name] = msg
    return out
