"""The health monitor: sensor and CAN bus diagnostics, computed in log time for live, convert and
replay alike.

:class:`HealthMonitor` watches every bus and every message family of the profile, checks the
alarms of :mod:`bridge.health.alarms` at ticks of log time (a gap's ticks caught up, so a
conversion raises alarms when live would), and publishes ``/health`` and ``/log``. A silence
explains everything under it: one fault raises one alarm, not a cascade.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from itertools import chain
from typing import TYPE_CHECKING, Any

from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.decode.codec import MessageCodec
from bridge.decode.decoder import Decoder
from bridge.frame import NEVER_NS, NS, timestamp
from bridge.health.alarms import Alarm, AlarmInfo, AlarmKind, HealthSettings, alarm_id
from bridge.health.counts import (
    NEVER,
    UNKNOWN,
    BusCounts,
    FamilyCounts,
    Pair,
    Snapshot,
    bus_conditions,
    bus_figures,
    family_figures,
    make_families,
    rate_window,
    seconds,
)
from bridge.health.receive import ReceiveWatch
from bridge.health.sight import FieldOfView, associate, has_fov
from bridge.health.traffic import TrafficCounting
from bridge.pb import health_pb2
from bridge.topics import HEALTH_TOPIC, LOG_TOPIC, TopicMessage
from bridge.world.lateral import LateralSignCheck

if TYPE_CHECKING:  # (live's buses: a convert never needs them; a profile's stages: a drive
    # without one never loads them)
    from bridge.io.buses import ReceiveCounts
    from bridge.profile.model import Profile
    from bridge.world.model import LaneModel, World
    from bridge.world.observe import ObjectObservation

_REPORT_S = 10.0  # seconds of log time between two /log warnings of the same bad value or rule


class HealthMonitor(TrafficCounting):
    """Sensor and bus health of one drive.

    Per bus: frames/s, load (:mod:`bridge.health.bus_bits`), error frames, unknown ids, decode
    errors, non-finite values, gaps longer than ``gap_factor`` x the bus's shortest cycle time, the
    busiest id. Per family: expected rate (``GenMsgCycleTime`` or learned), actual rate, age of the
    newest frame, valid objects, validity rules that could not be evaluated. While a bus is in a
    gap, the sensor alarms of families only on it are not raised, nor ``lanes.lost`` for a silent
    lane family; a sensor's rate is judged only after a full window of traffic; without enough
    matched objects the misalignment alarm stays as it is. ``/health`` (``tankviz.Health``) comes at
    ``publish_hz``; ``foxglove.Log`` on ``/log`` when an alarm is raised or cleared, when a value is
    non-finite or a rule cannot be evaluated (the first time, then at most every ``_REPORT_S`` s
    with the count), and once per sensor whose lateral sign looks wrong.

    - ``profile``: the families and sensors to watch (None: buses only).
    - ``decoder``: the pipeline's decoder, for the databases' cycle times and which ids a bus
      knows.
    - ``bitrates`` and ``data_bitrates``: nominal and CAN FD data bitrate per bus (bit/s); a bus
      without a bitrate gets no load figure (nor one with bit-rate-switched frames but no data
      bitrate).
    - ``settings``: thresholds and timing (:class:`HealthSettings`).
    """

    def __init__(self, profile: Profile | None, decoder: Decoder, *,
                 bitrates: Mapping[str, int] | None = None,
                 data_bitrates: Mapping[str, int] | None = None,
                 settings: HealthSettings | None = None) -> None:
        self.profile = profile
        self.decoder = decoder
        self.bitrates = dict(bitrates or {})
        self.data_bitrates = dict(data_bitrates or {})
        self.settings = s = settings or HealthSettings()
        self.period_ns = round(NS / s.eval_hz)
        self.publish_ns = round(NS / s.publish_hz)
        self.window_ns = round(s.window_s * NS)
        self.learning_ns = round(s.learning_s * NS)
        self._raise_ns = round(s.raise_after_s * NS)
        self._clear_ns = round(s.clear_after_s * NS)
        #: log time of the next check; frames at or after it make it happen
        self.next_tick_ns = NEVER_NS  # (no frame yet)
        self._next_publish_ns: int | None = None
        self.first_ns: int | None = None
        self.last_tick_ns: int | None = None
        self._buses: dict[str, BusCounts] = {}
        self._families_of: dict[MessageCodec, tuple[FamilyCounts, ...]] = {}
        self._snapshots: deque[Snapshot] = deque()
        self._cycles = {m.name: m.cycle_time / 1000.0 for f in decoder.files
                        for m in f.db.messages if m.cycle_time}
        self.families = (make_families(profile, self._cycles, s) if profile is not None
                         else [])
        self._by_message: dict[str, list[FamilyCounts]] = {}
        for family in self.families:
            for name in family.messages:
                self._by_message.setdefault(name, []).append(family)
        self._pairs = self._make_pairs()
        #: the families whose blindness is checked (detections of a sensor with a field of view)
        self._blind = {id(f) for f in self.families if self._blind_checked(f)}
        #: per blindness-checked family: its sensor's field of view, the groups of the other
        #: sensors' detections (in the order of the families), and whether each object of
        #: theirs it was last asked about is a moving one in its view (by id, with the object:
        #: observations are values, so one is never asked twice while it stays in the world)
        self._witnesses: list[tuple[FamilyCounts, FieldOfView, list[str],
                                    dict[int, tuple[ObjectObservation, bool]]]] = [
            (family, FieldOfView(family.sensor),
             [other.group for other in self.families if self._detections(other)
              and other.sensor is not None and other.sensor.name != family.sensor.name
              and other.group is not None], {})
            for family in self.families
            if family.sensor is not None and self._detections(family) and has_fov(family.sensor)]
        #: the active alarms' infos, oldest first, until the next check (None: to be made)
        self._active: list[AlarmInfo] | None = None
        self._bias: dict[str, deque[tuple[int, float, float]]] = {
            p.name: deque() for p in self._pairs}
        self._bias_means: dict[str, tuple[int, float, float]] = {
            p.name: (0, 0.0, 0.0) for p in self._pairs}
        self._lane_source: str | None = None
        self._world_ns: int | None = None
        self._alarms: dict[str, Alarm] = {}
        #: the busiest id of each bus in the last window
        self._top_keys: dict[str, int] = {}
        for family in self.families:
            sensors = (family.subject,) if family.sensor is not None else ()
            for kind in (AlarmKind.SENSOR_SILENT, AlarmKind.RATE_LOW):
                self._alarm(kind, family.subject, sensors)
            if self._blind_checked(family):
                self._alarm(AlarmKind.NO_OBJECTS, family.subject, sensors)
        for pair in self._pairs:
            self._alarm(AlarmKind.MISALIGNED, pair.name, (pair.a.subject, pair.b.subject))
        if profile is not None and profile.lanes is not None and profile.lanes.sensor is not None:
            self._alarm(AlarmKind.LANES_LOST, "lanes", (profile.lanes.sensor.name,),
                        raise_ns=round(s.lane_loss_s * NS))
        #: (count, latest value) of every signal that had a non-finite value, by bus/Message.Signal
        self._bad_values: dict[str, tuple[int, str]] = {}
        #: (count, log time) of the latest /log warning, per value or rule
        self._reported: dict[str, tuple[int, int]] = {}
        #: (id, "raised"/"cleared", log time, message) of every alarm event so far
        self.events: list[tuple[str, str, int, str]] = []
        #: conditions told from outside (:meth:`hold`): alarm id -> why
        self._held: dict[str, str] = {}
        #: the lateral sign check of the sensors with object groups (:mod:`bridge.world.lateral`)
        self.lateral = (LateralSignCheck(profile) if profile is not None and profile.groups
                        else None)
        #: sensors whose "flipped" verdict was said on /log
        self._lateral_said: set[str] = set()
        #: what live's buses mended or lost before their frames came (:meth:`note_receive`)
        self.receive = ReceiveWatch()

    # --- set-up --------------------------------------------------------------------------

    def _make_pairs(self) -> list[Pair]:
        """Every two detection families of different sensors."""
        candidates = [f for f in self.families if self._detections(f)]
        pairs = []
        for i, a in enumerate(candidates):
            for b in candidates[i + 1:]:
                assert a.sensor is not None and b.sensor is not None
                if a.sensor.name != b.sensor.name:
                    pairs.append(Pair(f"{a.sensor.name}-{b.sensor.name}", a, b))
        return pairs

    def _detections(self, family: FamilyCounts) -> bool:
        """An object family whose group's role is detections (not tracks)."""
        if family.kind != "objects" or family.sensor is None or self.profile is None:
            return False
        group = self.profile.groups.get(family.group or "")
        return group is not None and not group.is_tracks

    def _blind_checked(self, family: FamilyCounts) -> bool:
        """A detection family of a sensor with a field of view (its ``no_objects`` alarm)."""
        return (self._detections(family) and family.sensor is not None
                and has_fov(family.sensor))

    def _alarm(self, kind: AlarmKind, subject: str, sensors: Iterable[str],
               raise_ns: int | None = None, clear_ns: int | None = None) -> Alarm:
        """The alarm of ``kind`` about ``subject``, made the first time (with the settings'
        raise and clear times unless given)."""
        ident = alarm_id(kind, subject)
        alarm = self._alarms.get(ident)
        if alarm is None:
            alarm = self._alarms[ident] = Alarm(
                ident, kind, subject, sensors, self._raise_ns if raise_ns is None else raise_ns,
                self._clear_ns if clear_ns is None else clear_ns)
        return alarm

    def _add_bus(self, name: str, t_ns: int) -> BusCounts:
        bus = self._buses[name] = BusCounts(name, t_ns, self.bitrates.get(name),
                                            self.data_bitrates.get(name))
        if self.first_ns is None:
            self.first_ns = t_ns
        self._alarm(AlarmKind.BUS_SILENT, name, ())
        self._alarm(AlarmKind.BABBLING, name, ())
        return bus

    def on_world(self, t_ns: int, world: World, lanes: LaneModel | None = None) -> None:
        """Look at the world of a scene tick (after :meth:`World.expire`): valid objects, who
        sees what in whose field of view, radar-camera offsets, camera lanes. Without ``lanes``
        the camera lanes are judged like :meth:`World.lane_model` does (fresh left and right)."""
        self._world_ns = t_ns
        if self.lateral is not None:
            self.lateral.update(t_ns, world)
        objects = world.objects
        for family in self.families:
            if family.group is not None:
                found = objects.get(family.group, {})
                family.valid_objects = len(found)
                if found:
                    family.last_valid_ns = t_ns
            rules = family.group if family.group is not None else family.kind
            family.rule_errors = world.rule_errors.get(rules, 0)
            family.why_rule = world.last_rule_error.get(rules, "")
        spec = world.profile.lanes
        if spec is not None:
            if lanes is not None:
                source = lanes.source
                count = len(lanes.lines) if source == "camera" else 0
            else:
                stale = round(spec.stale_after_s * NS)
                fresh = [name for name, o in world.lanes.items() if t_ns - o.t_ns <= stale]
                source = "camera" if "left" in fresh and "right" in fresh else "steering"
                count = len(fresh) if source == "camera" else 0
            self._lane_source = source
            for family in self.families:
                if family.kind == "lanes":
                    family.valid_objects = count
        from bridge.profile.model import ObjectClass

        stationary = ObjectClass.STATIONARY
        for family, view, groups, asked in self._witnesses:
            contains = view.contains
            now: dict[int, tuple[ObjectObservation, bool]] = {}
            for group in groups:
                for o in objects.get(group, {}).values():
                    known = asked.get(id(o))
                    if known is not None and known[0] is o:
                        moving_in_view = known[1]
                    else:
                        moving_in_view = (o.object_class is not stationary
                                          and contains(o.x, o.y))
                    now[id(o)] = (o, moving_in_view)
                    if moving_in_view:
                        family.witnessed_ns = t_ns
                        break
                else:
                    continue
                break
            asked.clear()
            asked.update(now)
        for pair in self._pairs:
            assert pair.a.group is not None and pair.b.group is not None
            matches = self._bias[pair.name]
            for lateral, angular in associate(
                    objects.get(pair.a.group, {}).values(), objects.get(pair.b.group, {}).values(),
                    pair.a.sensor, pair.b.sensor, t_ns, gate_m=self.settings.bias_gate_m,
                    min_range_m=self.settings.bias_min_range_m):
                matches.append((t_ns, lateral, angular))

    # --- checks ---------------------------------------------------------------------------

    def advance(self, t_ns: int) -> list[TopicMessage]:
        """The checks due before log time ``t_ns`` (call it before each frame's
        :meth:`on_frame`, and with the clock when no frame comes); cheap unless one is due."""
        if t_ns < self.next_tick_ns:
            return []
        if self.next_tick_ns == NEVER_NS:
            self.next_tick_ns = (t_ns // self.period_ns + 1) * self.period_ns
            if self.first_ns is None:
                self.first_ns = t_ns
            return []
        tick = self.next_tick_ns
        due = (t_ns - tick) // self.period_ns + 1
        out: list[TopicMessage] = []
        limit = 600  # a gap of more than a minute: the first minute, then the latest tick
        for _ in range(min(due, limit)):
            out += self.tick(tick)
            tick += self.period_ns
        if due > limit:
            tick += (due - limit - 1) * self.period_ns
            out += self.tick(tick)
            tick += self.period_ns
        self.next_tick_ns = tick
        return out

    def finish(self, t_ns: int) -> list[TopicMessage]:
        """The checks still due at the end of the drive (log time ``t_ns``)."""
        return self.advance(t_ns + 1) if self.next_tick_ns != NEVER_NS else []

    def rebase(self, shift_ns: int, t_ns: int) -> None:
        """The clock stepped by ``shift_ns`` to log time ``t_ns`` (a frame's stamp): every log
        time held (windows, last frames, alarm timers) moves with it, as if no time had passed,
        and the next check is the one of the grid at or just before ``t_ns``, made at once (a
        clock that steps away and back leaves no check unmade): nothing looks silent,
        nothing waits for the log to catch up."""
        def moved(t: int) -> int:
            return t if t == NEVER else t + shift_ns

        self._active = None
        if self.next_tick_ns != NEVER_NS:
            self.next_tick_ns = t_ns // self.period_ns * self.period_ns  # (made at once)
        if self._next_publish_ns is not None:
            self._next_publish_ns += shift_ns
        for name in ("first_ns", "last_tick_ns", "_world_ns"):
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, value + shift_ns)
        for bus in self._buses.values():
            bus.first_ns += shift_ns
            bus.last_ns += shift_ns
        for f in self.families:
            f.first_ns, f.last_ns, f.resumed_ns = (moved(f.first_ns), moved(f.last_ns),
                                                   moved(f.resumed_ns))
            f.last_valid_ns, f.witnessed_ns = moved(f.last_valid_ns), moved(f.witnessed_ns)
        for snap in self._snapshots:
            snap.t_ns += shift_ns
        self.receive.rebase(shift_ns)
        for name, matches in self._bias.items():
            self._bias[name] = deque((t + shift_ns, a, b) for t, a, b in matches)
        for alarm in self._alarms.values():
            for name in ("holding_since", "gone_since", "since_ns"):
                value = getattr(alarm, name)
                if value is not None:
                    setattr(alarm, name, value + shift_ns)

    def tick(self, t_ns: int) -> list[TopicMessage]:
        """Check everything at log time ``t_ns``: alarm events as ``/log`` messages, and the
        ``/health`` message when one is due."""
        if self.first_ns is None:
            self.first_ns = t_ns
        self.last_tick_ns = t_ns
        self._active = None
        self._snapshot(t_ns)
        self._learn(t_ns)
        out: list[TopicMessage] = []
        base = self._base(t_ns, self.window_ns)
        buses, self._top_keys = bus_figures(self._buses, base, t_ns, self.settings.gap_factor)
        for name, counts in self.receive.counts.items():
            if name in buses:
                buses[name].bad_timestamps_total = counts.bad_timestamps
                buses[name].receive_dropped_total = counts.kernel_drops
        families = family_figures(self.families, base, t_ns)
        self._update_bias(t_ns)
        events = self._check(t_ns, buses, families)
        for alarm, event in events:
            out.append(TopicMessage(LOG_TOPIC, self._log(alarm, event, t_ns), t_ns))
        out += self._value_warnings(t_ns)
        out += self.receive.warnings(t_ns)
        out += self._lateral_warnings(t_ns)
        if self._next_publish_ns is None or t_ns >= self._next_publish_ns:
            self._next_publish_ns = (t_ns // self.publish_ns + 1) * self.publish_ns
            out.append(TopicMessage(HEALTH_TOPIC, self._health(t_ns, buses, families), t_ns))
        return out

    def hold(self, kind: AlarmKind, subject: str, why: str | None) -> None:
        """A condition the monitor cannot see itself (``recorder.disk_full``): it holds for
        ``why`` (None: it does not), from the next check on; raised and cleared without delay."""
        ident = alarm_id(kind, subject)
        if why is None:
            self._held.pop(ident, None)
            return
        self._alarm(kind, subject, (), raise_ns=0, clear_ns=0)
        self._held[ident] = why

    def note_receive(self, bus: str, counts: ReceiveCounts) -> None:
        """What live's reading of ``bus`` mended or lost so far (:mod:`bridge.health.receive`):
        said on ``/log``, and its alarms (made when a count first grows) hold while it grows."""
        for kind in self.receive.note(bus, counts):
            self._alarm(kind, bus, (), raise_ns=0)

    def _lateral_warnings(self, t_ns: int) -> list[TopicMessage]:
        """A ``/log`` warning, once per sensor, when its lateral sign looks flipped."""
        if self.lateral is None:
            return []
        out = []
        for verdict in self.lateral.verdicts():
            if verdict.verdict == "flipped" and verdict.sensor not in self._lateral_said:
                self._lateral_said.add(verdict.sensor)
                out.append(TopicMessage(LOG_TOPIC, Log(
                    timestamp=timestamp(t_ns), level=Log.WARNING,
                    message=f"lateral sign of {verdict.message}", name="tankviz.health"), t_ns))
        return out

    def lateral_sign_records(self) -> list[dict[str, Any]]:
        """Each sensor's lateral sign verdict so far, for a drive's metadata (``tankviz
        inspect``)."""
        return ([v.to_dict() for v in self.lateral.verdicts()] if self.lateral is not None
                else [])

    def event_records(self) -> list[dict[str, Any]]:
        """Every alarm raised or cleared so far, for a drive's metadata (``tankviz inspect``)."""
        return [{"alarm": alarm, "event": event, "t_ns": t, "message": message}
                for alarm, event, t, message in self.events]

    def active_alarms(self) -> list[AlarmInfo]:
        """Every active alarm, oldest first (made once per check: only a check changes them)."""
        if self._active is None:
            active = [a for a in self._alarms.values() if a.active]
            self._active = [a.info() for a in sorted(active, key=lambda a: (a.since_ns or 0,
                                                                              a.id))]
        return list(self._active)

    def alarm_ids(self) -> list[str]:
        """Every alarm the monitor checks (so far: bus alarms appear with their bus)."""
        return list(self._alarms)

    def _snapshot(self, t_ns: int) -> None:
        snaps = self._snapshots
        snaps.append(Snapshot.take(t_ns, self._buses.values(), self.families))
        keep = max([self.window_ns, *(f.rate_window_ns for f in self.families
                                      if f.rate_window_ns != UNKNOWN)])
        while len(snaps) > 2 and snaps[1].t_ns <= t_ns - keep:
            snaps.popleft()

    def _base(self, t_ns: int, window_ns: int) -> Snapshot:
        """The newest snapshot at least ``window_ns`` old (or the oldest there is)."""
        found = self._snapshots[0]
        for snap in self._snapshots:
            if snap.t_ns > t_ns - window_ns:
                break
            found = snap
        return found

    def _learn(self, t_ns: int) -> None:
        gap_factor = self.settings.gap_factor
        for family in self.families:
            if (family.expected_hz is None and family.first_ns != NEVER
                    and t_ns - family.first_ns >= self.learning_ns):
                family.expected_hz = family.frames / seconds(t_ns - family.first_ns)
                family.source = "learned"
                per_message = max(1, len(family.seen_messages)) / family.expected_hz
                family.gap_ns = round(gap_factor * per_message * NS)
                family.rate_window_ns = rate_window(self.settings, per_message)
        for bus in self._buses.values():
            if (bus.gap_ns == UNKNOWN and bus.ids and t_ns - bus.first_ns >= self.learning_ns):
                fastest = max(bus.ids.values()) / seconds(t_ns - bus.first_ns)
                bus.gap_ns = round(gap_factor / fastest * NS)

    def _update_bias(self, t_ns: int) -> None:
        oldest = t_ns - round(self.settings.bias_window_s * NS)
        for name, matches in self._bias.items():
            while matches and matches[0][0] <= oldest:
                matches.popleft()
            n = len(matches)
            self._bias_means[name] = (
                (n, sum(m[1] for m in matches) / n, sum(m[2] for m in matches) / n) if n
                else (0, 0.0, 0.0))

    def _check(self, t_ns: int, buses: Mapping[str, health_pb2.BusHealth],
               families: Mapping[str, health_pb2.FamilyHealth]) -> list[tuple[Alarm, str]]:
        """Feed every alarm its condition at ``t_ns``: the raised and cleared ones."""
        conditions: dict[str, list[str]] = {}  # alarm id -> why (absent: does not hold)
        in_gap = {name: msg.gap for name, msg in buses.items()}
        for ident, why in chain(
                self._held.items(), self.receive.conditions(t_ns, self.window_ns),
                bus_conditions(self._buses, buses, self._top_keys, self.settings),
                self._family_conditions(t_ns, families, in_gap), self._pair_conditions(),
                self._lane_conditions(t_ns, families, in_gap)):
            conditions.setdefault(ident, []).append(why)
        no_evidence = {alarm_id(AlarmKind.MISALIGNED, pair.name) for pair in self._pairs
                       if self._bias_means[pair.name][0] < self.settings.bias_min_matches}
        events = []
        for ident, alarm in self._alarms.items():
            if ident in no_evidence:
                continue
            whys = conditions.get(ident)
            event = alarm.update(t_ns, whys is not None, "; ".join(whys or ()))
            if event is not None:
                if alarm.kind in (AlarmKind.BUS_SILENT, AlarmKind.BABBLING):
                    bus = self._buses.get(alarm.subject)
                    alarm.sensors = tuple(sorted(
                        {f.subject for f in self.families if bus is not None
                         and f.name in bus.families and f.sensor is not None}))
                events.append((alarm, event))
                self.events.append((alarm.id, event, t_ns, alarm.message))
        return events

    def _behind_silent_bus(self, family: FamilyCounts, in_gap: Mapping[str, bool]) -> bool:
        """Every bus the family came on is in a gap (or, before its first frame, every bus)."""
        return (all(in_gap.get(b, False) for b in family.buses) if family.buses
                else bool(in_gap) and all(in_gap.values()))

    def _family_conditions(self, t_ns: int, families: Mapping[str, health_pb2.FamilyHealth],
                           in_gap: Mapping[str, bool]) -> Iterator[tuple[str, str]]:
        """The sensors' alarms (of each family) whose condition holds, as (alarm id, why):
        silent, rate and blind; none for a family behind a silent bus."""
        s = self.settings
        started = self.first_ns is not None and t_ns - self.first_ns >= self.learning_ns
        for family in self.families:
            if self._behind_silent_bus(family, in_gap):
                continue
            fig = families[family.name]
            subject = family.subject
            never = family.last_ns == NEVER
            if fig.silent:
                yield (alarm_id(AlarmKind.SENSOR_SILENT, subject),
                       f"{family.name}: no frame for {fig.age_s:.1f} s")
            elif never and started:
                yield (alarm_id(AlarmKind.SENSOR_SILENT, subject),
                       f"{family.name}: no frame since the start")
            if never or fig.silent:
                continue
            window = family.rate_window_ns
            if family.expected_hz and t_ns - family.resumed_ns >= window:
                base = self._base(t_ns, window)
                elapsed = seconds(t_ns - base.t_ns)
                rate = (family.frames - base.families.get(family.name, 0)) / elapsed
                if rate < s.rate_threshold * family.expected_hz:
                    yield (alarm_id(AlarmKind.RATE_LOW, subject),
                           f"{family.name}: {rate:.0f} frames/s, "
                           f"{rate / family.expected_hz:.0%} of the expected "
                           f"{family.expected_hz:.0f}/s")
            nothing_since = max(family.last_valid_ns, family.resumed_ns)
            if (id(family) in self._blind and self._world_ns is not None
                    and t_ns - nothing_since > family.gap_ns
                    and t_ns - family.witnessed_ns < self.window_ns):
                yield (alarm_id(AlarmKind.NO_OBJECTS, subject),
                       f"{family.name}: frames but no valid object for "
                       f"{seconds(t_ns - nothing_since):.1f} s while another sensor sees "
                       "objects in its field of view" + (
                           f" (its validity rule failed {family.rule_errors} times: "
                           f"{family.why_rule})" if family.rule_errors else ""))

    def _pair_conditions(self) -> Iterator[tuple[str, str]]:
        """The misalignment alarms whose condition holds, as (alarm id, why) (a pair without
        enough matches has no evidence either way: :meth:`_check` leaves its alarm as it is)."""
        s = self.settings
        for pair in self._pairs:
            n, lateral, angular = self._bias_means[pair.name]
            if n >= s.bias_min_matches and (abs(lateral) > s.bias_lateral_m
                                            or abs(angular) > s.bias_angle_deg):
                a, b = pair.a.subject, pair.b.subject
                side = "right" if angular < 0 else "left"
                yield (alarm_id(AlarmKind.MISALIGNED, pair.name),
                       f"{a} sees objects {abs(angular):.1f} deg ({abs(lateral):.1f} m) to the "
                       f"{side} of where {b} sees them ({n} matches): one of them is misaligned")

    def _lane_conditions(self, t_ns: int, families: Mapping[str, health_pb2.FamilyHealth],
                         in_gap: Mapping[str, bool]) -> Iterator[tuple[str, str]]:
        """``lanes.lost`` as (alarm id, why) when it holds: the lanes are not the camera's, and
        the lane family is not silent (nor behind a silent bus, nor never seen once started)."""
        lanes = next((f for f in self.families if f.kind == "lanes"), None)
        if lanes is None or self._lane_source is None or self._lane_source == "camera":
            return
        started = self.first_ns is not None and t_ns - self.first_ns >= self.learning_ns
        if (self._behind_silent_bus(lanes, in_gap) or families[lanes.name].silent
                or (lanes.last_ns == NEVER and started)):
            return
        yield (alarm_id(AlarmKind.LANES_LOST, "lanes"),
               "no valid camera lanes: lanes extrapolated from the steering"
               if self._lane_source == "steering" else "no valid camera lanes and no steering "
               "angle: no lanes")

    def _value_warnings(self, t_ns: int) -> list[TopicMessage]:
        """``/log`` warnings of non-finite values and failing validity rules: new ones at once,
        ongoing ones at most every ``_REPORT_S`` seconds."""
        found = [(f"value {key}", count,
                  f"{key} = {value}: a non-finite value ({count} so far), kept out of the world; "
                  "the frame is recorded as it came")
                 for key, (count, value) in self._bad_values.items()]
        found += [(f"rule {f.name}", f.rule_errors,
                   f"{f.name}: validity {f.why_rule} ({f.rule_errors} times so far): "
                   f"{'those objects are' if f.group is not None else 'that is'} left out")
                  for f in self.families if f.rule_errors]
        out = []
        for key, count, words in found:
            reported, at = self._reported.get(key, (0, NEVER))
            if count > reported and abs(t_ns - at) >= _REPORT_S * NS:
                self._reported[key] = (count, t_ns)
                out.append(TopicMessage(LOG_TOPIC, Log(
                    timestamp=timestamp(t_ns), level=Log.WARNING, message=words,
                    name="tankviz.values"), t_ns))
        return out

    def _log(self, alarm: Alarm, event: str, t_ns: int) -> Log:
        if event == "raised":
            level, words = Log.WARNING, f"ALARM {alarm.id}: {alarm.message}"
        else:
            duration = ""
            if alarm.holding_since is None and alarm.gone_since is not None:
                duration = f" (the condition ended {seconds(t_ns - alarm.gone_since):.1f} s ago)"
            level, words = Log.INFO, f"cleared {alarm.id}{duration}: was {alarm.message}"
        return Log(timestamp=timestamp(t_ns), level=level, message=words, name="tankviz.health")

    def _health(self, t_ns: int, buses: Mapping[str, health_pb2.BusHealth],
                families: Mapping[str, health_pb2.FamilyHealth]) -> health_pb2.Health:
        msg = health_pb2.Health(timestamp=timestamp(t_ns), window_s=self.settings.window_s)
        msg.buses.extend(buses[name] for name in sorted(buses))
        msg.families.extend(families[f.name] for f in self.families)
        for pair in self._pairs:
            n, lateral, angular = self._bias_means[pair.name]
            msg.biases.add(pair=pair.name, sensor_a=pair.a.subject, sensor_b=pair.b.subject,
                           matches=n, lateral_offset_m=lateral, angular_offset_deg=angular)
        msg.alarms.extend(a.to_pb() for a in self._alarms.values())
        msg.active_alarms = sum(a.active for a in self._alarms.values())
        return msg

    def topics(self) -> list[tuple[str, Any]]:
        """The topics :meth:`tick` emits, with their message classes (to advertise them)."""
        return [(HEALTH_TOPIC, health_pb2.Health), (LOG_TOPIC, Log)]
