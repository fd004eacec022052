"""``tankviz profile``: start a vehicle profile from the databases, and check one.

``profile new`` writes the commented starting profile :mod:`bridge.profile.draft` drafts and says
whether it loads; ``profile check`` loads one, prints what it maps and, given logs, what each
object group, sensor and mark rule made of them, then the warnings ``convert`` prints. Exit
status 0 when the profile is usable, 1 with the error otherwise.
"""

from __future__ import annotations

import argparse
import os
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridge.apps.options import Subparsers, dbc_option
from bridge.errors import FileError, UsageError
from bridge.frame import NS, Frame
from bridge.io.can_logs import LogSource, merge
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline.drive import Drive, Stages, load_stages
from bridge.pipeline.marks import describe
from bridge.pipeline.perception import Perception
from bridge.profile.draft import TODO, draft_profile
from bridge.profile.loader import load_profile
from bridge.profile.model import (
    Computed,
    ObjectGroup,
    Profile,
    ProfileError,
    Rule,
    SignalRef,
)
from bridge.resources import data_dir
from bridge.sinks.base import Serialized, Sink
from bridge.world.lateral import LateralVerdict
from bridge.world.observe import ObjectObservation
from bridge.world.pages import PageStats

# --- profile new --------------------------------------------------------------------------------


def new_profile(dbc_options: Sequence[str], output: Path, *, force: bool = False) -> str:
    """Draft a profile from the databases into ``output``; returns what to tell the user."""
    if output.exists() and not force:
        raise FileError(output, "exists (--force overwrites)")
    stages = load_stages(dbc_options, None)
    decoder = stages.decoder
    files = decoder.files
    if not files:
        raise UsageError("profile new", "name the databases with --dbc [BUS=]PATH")
    base = output.resolve().parent
    bundled = data_dir().resolve()
    # a bundled database by its bundled name, which the loader finds (never a path into the
    # installed package); any other relative to the profile
    named = [(f.path.name if f.path.resolve().parent == bundled
              else os.path.relpath(f.path.resolve(), base), f.db) for f in files]
    buses: dict[str, list[str]] = {}
    for (path, _), f in zip(named, files, strict=True):
        for bus in decoder.buses_for(f):
            buses.setdefault(bus, []).append(path)
    text = draft_profile(named, name=output.stem, buses=buses)
    try:
        output.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise FileError(output, f"cannot write: {exc.strerror or exc}") from None
    todos = [n for n, line in enumerate(text.splitlines(), 1) if line.startswith(TODO)]
    lines = [f"wrote {output}"]
    try:
        profile = load_profile(output, [f.db for f in files])
    except ProfileError as exc:
        lines.append(f"it does not load yet: {exc}")
        lines.append(f"fill in the '# TODO:' lines ({', '.join(map(str, todos))}), then: "
                     f"tankviz profile check {output}")
        return "\n".join(lines)
    groups = ", ".join(profile.groups) or "none"
    lines.append(f"it loads as written: object groups {groups}; read every guess and "
                 f"'# TODO (optional):' line, then: tankviz profile check {output} LOG")
    return "\n".join(lines)


# --- profile check ------------------------------------------------------------------------------


def _scaled(text: str, ref: SignalRef | Computed) -> str:
    if ref.scale != 1 or ref.offset != 0:
        text += f" (*{ref.scale:g}" + (f" {ref.offset:+g}" if ref.offset else "") + ")"
    return text


def _ref(ref: SignalRef | Computed | None) -> str:
    """An ego field: Message.Signal, or the expression, with its scale and offset."""
    if ref is None:
        return "-"
    if isinstance(ref, Computed):
        return _scaled(f"'{ref.text}'", ref)
    return _scaled(f"{ref.message}.{ref.signal}", ref)


def _field(ref: SignalRef | Computed) -> str:
    """An object field: the signal (a template), or the expression."""
    if isinstance(ref, Computed):
        return _scaled(f"'{ref.text}'", ref)
    return _scaled(ref.signal, ref)


def _group_lines(name: str, g: ObjectGroup) -> list[str]:
    indices = sorted(m.index for m in g.members.values() if m.index is not None)
    where = (f"[{indices[0]}..{indices[-1]}] ({len(set(indices))} objects)" if indices
             else "one message, the object by its id")
    fields = []
    for label, ref in (("x", g.x), ("y", g.y), ("range", g.range), ("azimuth", g.azimuth),
                       ("vx", g.vx), ("vy", g.vy), ("probability", g.probability),
                       ("class", g.class_signal), ("id", g.id)):
        if ref is not None:
            fields.append(f"{label} {_field(ref)}")
    if g.classes:
        classes = ", ".join(f"{k} {v.value}" for k, v in sorted(g.classes.items()))
        fields.append(f"classes {classes}")
    rules = {r.text for r in g.valid.values()}
    rule = next(iter(rules)) if len(rules) == 1 else (f"{len(rules)} rules, one per object"
                                                      if rules else "none: every object valid")
    paged = {m.template: g.pages[message].multiplexors for message, m in g.members.items()
             if message in g.pages}
    return [f"  {name}: sensor {g.sensor.name} ({g.sensor.kind.value}), role "
            f"{'tracks' if g.is_tracks else 'detections'}, {' + '.join(g.templates)} {where}",
            f"    {', '.join(fields)}",
            f"    valid: {rule}; lifetime {g.lifetime_s:g} s",
            *(f"    pages of {template} (multiplexor {', '.join(by)}) merged per object "
              f"{'id' if g.id is not None and not indices else 'slot'} within a cycle"
              for template, by in paged.items())]


def format_mapping(profile: Profile, databases: Sequence[str]) -> str:
    """What a profile maps, for people (``tankviz profile check``)."""
    lines = [f"profile {profile.path} (name {profile.name!r}): loads against "
             f"{', '.join(databases) or 'no databases'}", f"sensors ({len(profile.sensors)}):"]
    for s in profile.sensors.values():
        m = s.mount
        lines.append(f"  {s.name}: {s.kind.value}, {s.coordinates}"
                     + (f" ({s.angle_unit})" if s.coordinates == "polar" else "")
                     + f", lateral {s.lateral}, mount x {m.x:g} y {m.y:g} z {m.z:g} "
                     f"yaw {m.yaw_deg:g} deg")
    lines.append(f"object groups ({len(profile.groups)}):")
    for name, g in profile.groups.items():
        lines += _group_lines(name, g)
    ego = profile.ego
    lines.append(f"ego: speed {_ref(ego.speed)}; yaw rate {_ref(ego.yaw_rate)}; steering wheel "
                 f"angle {_ref(ego.steering_wheel_angle)}")
    lanes = profile.lanes
    if lanes is None:
        lines.append("lanes: none")
    elif not lanes.lines:
        lines.append("lanes: from the steering angle only (no camera lines)")
    else:
        assert lanes.sensor is not None
        lines.append(f"lanes: camera lines {', '.join(lanes.lines)} from sensor "
                     f"{lanes.sensor.name}, steering fallback after {lanes.stale_after_s:g} s")
    lead = profile.lead
    if lead is None:
        lines.append("lead: none")
    elif lead.source == "tracks" or lead.group is None:
        lines.append("lead: chosen: the closest valid track inside the ego lane")
    else:
        lines += ["lead: from its own messages:", *_group_lines("lead", lead.group)]
    for rule in profile.marks:
        reads = ", ".join(f"{message}.{signal}" for _, message, signal in rule.reads)
        said = f", text {rule.text!r}" if rule.text != rule.when else ""
        lines.append(f"marks: when {rule.when} ({reads}){said}"
                     + (f" [{rule.category}]" if rule.category else ""))
    return "\n".join(lines)


#: How many marks ``profile check`` lists (a rule that is true too often makes many).
MARKS_LISTED = 10


def format_marks(made: Sequence[Mark], start_ns: int | None) -> list[str]:
    """The marks the ``[marks]`` rules made in the logs, each with its time after the first
    frame (``start_ns``)."""
    if not made:
        return ["marks: none made: no rule became true"]
    lines = [f"marks: {len(made):,} made (s after the first frame):"]
    for mark in made[:MARKS_LISTED]:
        at = (mark.timestamp.ToNanoseconds() - (start_ns or 0)) / NS
        lines.append(f"  {describe(mark)} at {at:.3f} s")
    if len(made) > MARKS_LISTED:
        lines.append(f"  … {len(made) - MARKS_LISTED:,} more")
    return lines


@dataclass
class GroupStats:
    """What one object group's valid objects did over a drive."""

    ids: set[int] = field(default_factory=set)
    #: distinct (id, observation time) pairs the scene showed
    observations: set[tuple[int, int]] = field(default_factory=set)
    x: list[float] = field(default_factory=lambda: [float("inf"), float("-inf")])
    y: list[float] = field(default_factory=lambda: [float("inf"), float("-inf")])


@dataclass
class RuleStats:
    """How one group's objects fared when evaluated (each time their signals changed)."""

    #: evaluations without a position
    no_position: int = 0
    #: evaluations that judged the validity rule, and those where it held
    judged: int = 0
    held: int = 0
    rule: str = ""
    #: per name the rule reads: in how many judgements it was missing; the least and the most
    #: it was (numbers)
    missing: Counter[str] = field(default_factory=Counter)
    least: dict[str, float] = field(default_factory=dict)
    most: dict[str, float] = field(default_factory=dict)

    def note(self, made: ObjectObservation | None, rule: Rule | None,
             values: Mapping[str, Any]) -> None:
        """One evaluation of an object (:data:`~bridge.world.observe.Watcher`)."""
        if made is None:
            self.no_position += 1
            return
        if rule is None:
            return
        self.judged += 1
        self.held += made.valid
        self.rule = rule.text
        for name in sorted(rule.names):
            value = values.get(name)
            if value is None:
                self.missing[name] += 1
            elif isinstance(value, (int, float)):
                self.least[name] = min(self.least.get(name, value), value)
                self.most[name] = max(self.most.get(name, value), value)


class CheckSink(Sink):
    """A sink of a drive that watches the world at every scene tick for the object statistics of
    each group. Records nothing."""

    def __init__(self, perception: Perception) -> None:
        self.perception = perception
        self.groups = {name: GroupStats() for name in perception.profile.groups}
        self._last_tick: int | None = None

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        ticks = {m.t_ns for m in messages if m.topic.startswith("/perception/")}
        world = self.perception.world
        for t_ns in sorted(ticks):
            if t_ns == self._last_tick:
                continue
            self._last_tick = t_ns
            for name, stats in self.groups.items():
                for obs in world.objects.get(name, {}).values():
                    stats.ids.add(obs.object_id)
                    stats.observations.add((obs.object_id, obs.t_ns))
                    stats.x[0], stats.x[1] = min(stats.x[0], obs.x), max(stats.x[1], obs.x)
                    stats.y[0], stats.y[1] = min(stats.y[0], obs.y), max(stats.y[1], obs.y)


def _signals_in_order(group: ObjectGroup, names: Iterable[str]) -> list[str]:
    """``names`` in the order the group's fields read them (others after, by name)."""
    order = [signal for ref in (group.x, group.y, group.range, group.azimuth, group.vx,
                                group.vy, group.probability, group.class_signal, group.id)
             if ref is not None for _, signal in ref.signals]
    return sorted(names, key=lambda n: (order.index(n) if n in order else len(order), n))


def _counted(group: ObjectGroup, counts: Counter[str], of: int, what: str) -> str:
    """``A, B missing in 3 of 10 cycles``, or ``A missing in 3, B in 2 of 10 cycles``."""
    names = _signals_in_order(group, counts)
    if len({counts[n] for n in names}) == 1:
        return f"{', '.join(names)} missing in {counts[names[0]]:,} of {of:,} {what}"
    return ("missing: " + ", ".join(f"{n} in {counts[n]:,}" for n in names)
            + f" of {of:,} {what}")


def _pages_line(group: ObjectGroup, pages: PageStats) -> str:
    """What merging the group's pages lacked (``pages`` with incomplete cycles)."""
    messages = ", ".join(pages.messages)
    head = (f"no cycle of {messages} had every page" if pages.incomplete == pages.cycles
            else f"{pages.incomplete:,} of {pages.cycles:,} cycles of {messages} lacked a page")
    text = f"{head}: {_counted(group, pages.missing, pages.cycles, 'cycles')}"
    rule = _signals_in_order(group, pages.rule & set(pages.missing))
    if pages.unjudged:
        why = f"the rule reads {', '.join(rule)}" if rule else "no position"
        text += f" ({why}: not judged)"
    return text


def why_none(group: ObjectGroup, rules: RuleStats | None, pages: PageStats | None,
             decoded: set[str]) -> str:
    """Why a group had no valid object: its messages never came, its pages never made a
    whole cycle, no position, or its rule never held (with what it read)."""
    if decoded.isdisjoint(group.members):
        return f"none of its messages ({' + '.join(group.templates)}) decoded"
    reasons = []
    if pages is not None and pages.incomplete:
        reasons.append(_pages_line(group, pages))
    if rules is not None and rules.judged and not rules.held:
        text = f"rule '{rules.rule}' held in 0 of {rules.judged:,} judgements"
        if rules.missing:
            text += "; " + _counted(group, rules.missing, rules.judged, "judgements")
        ranges = [f"{n} was {rules.least[n]:g}..{rules.most[n]:g}"
                  for n in _signals_in_order(group, rules.least)]
        reasons.append("; ".join([text, *ranges]))
    elif rules is not None and rules.no_position and not rules.judged:
        fields = [f"{label} {_field(ref)}" for label, ref in (
            ("x", group.x), ("y", group.y), ("range", group.range), ("azimuth", group.azimuth))
            if ref is not None]
        reasons.append(f"no position in {rules.no_position:,} evaluations ({', '.join(fields)}"
                       " missing or not finite)")
    return "; ".join(reasons)


def format_stats(frames: int, stats: dict[str, GroupStats], verdicts: Sequence[LateralVerdict],
                 profile: Profile, *, decoded: int | None = None,
                 why: Mapping[str, str] | None = None,
                 pages: Mapping[str, PageStats] | None = None,
                 marks: Sequence[str] = ()) -> str:
    """Per group: valid objects and their x/y ranges (none: ``why``; pages that lacked some:
    ``pages``); the lines of the ``marks`` made; per sensor: the lateral sign verdict. A log
    none of whose frames ``decoded`` says so: the wrong log, or the wrong bus."""
    head = f"log: {frames:,} frames"
    if decoded == 0 and frames:
        head += (", 0 decoded: none of their ids is in the databases (the wrong log, or the "
                 "wrong bus?)")
    lines = [f"{head}; valid objects per group (vehicle frame, m):"]
    for name, s in stats.items():
        if not s.ids:
            reason = (why or {}).get(name, "")
            lines.append(f"  {name}: no valid object" + (f": {reason}" if reason else ""))
            continue
        lines.append(f"  {name}: {len(s.ids)} objects (ids/slots), {len(s.observations):,} "
                     f"observations; x {s.x[0]:.1f}..{s.x[1]:.1f}, y {s.y[0]:.1f}..{s.y[1]:.1f}")
        paged = (pages or {}).get(name)
        if paged is not None and paged.incomplete:
            lines.append(f"    {_pages_line(profile.groups[name], paged)}")
    lines += marks
    lines.append("lateral sign:")
    lines += [f"  {v.message}" for v in verdicts]
    if not verdicts:
        lines.append(f"  no object groups in {profile.path.name}")
    return "\n".join(lines)


def check_profile(profile_path: str, dbc_options: Sequence[str], logs: Sequence[Path]) -> str:
    """What ``tankviz profile check`` prints; a profile that cannot be used raises its error."""
    stages = load_stages(dbc_options, profile_path)
    assert stages.profile is not None
    profile = stages.profile
    databases = [str(f.path) for f in stages.decoder.files]
    out = format_mapping(profile, databases)
    if not logs:
        return _with_warnings(out, stages.decoder.warnings())
    sources = [LogSource(p) for p in logs]
    drive = Drive(Stages(stages.decoder, profile))
    perception = drive.pipeline.perception
    assert perception is not None
    sink = CheckSink(perception)
    drive.add(sink)
    observer = perception.observer
    rules: dict[str, RuleStats] = {}
    observer.watch(lambda group, made, rule, values: rules.setdefault(
        group.name, RuleStats()).note(made, rule, values))
    first: list[int] = []

    def noted(frames: Iterator[Frame]) -> Iterator[Frame]:  # (the first frame's time)
        for frame in frames:
            first.append(frame.timestamp_ns)
            yield frame
            break
        yield from frames

    frames = drive.run(noted(iter(merge(sources))))
    drive.finish()
    observer.close()
    pages = observer.page_stats()
    codecs = stages.decoder.codecs()
    decoded = {c.message.name for c in codecs if c.decoded}
    why = {name: why_none(g, rules.get(observer.aliases.get(name, name)), pages.get(name),
                          decoded)
           for name, g in profile.groups.items() if not sink.groups[name].ids}
    # the health monitor runs the lateral sign check of every drive (bridge.world.lateral)
    lateral = drive.health.lateral
    verdicts = lateral.verdicts() if lateral is not None else []
    made = drive.pipeline.marks.made if drive.pipeline.marks is not None else []
    marks = format_marks(made, first[0] if first else None) if profile.marks else []
    return _with_warnings(out + "\n" + format_stats(
        frames, sink.groups, verdicts, profile, decoded=sum(c.decoded for c in codecs),
        why=why, pages=pages, marks=marks), stages.decoder.warnings())


def _with_warnings(text: str, warnings: Sequence[str]) -> str:
    """The report, then the decoder's warnings as ``tankviz convert`` prints them."""
    return "\n".join([text, *(f"warning: {line}" for line in warnings)])


# --- the command --------------------------------------------------------------------------------


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "profile", help="start a vehicle profile from the databases, or check one",
        description="new: a commented starting profile drafted from the databases; check: "
        "load a profile against the databases, print what it maps and, given logs, what its "
        "object groups saw.")
    commands = parser.add_subparsers(dest="profile_command", required=True, metavar="SUBCOMMAND")
    new = commands.add_parser(
        "new", help="write a commented starting profile drafted from the databases",
        description="Find the object families (numbered messages; companions such as "
        "TRACK_A_{i} and TRACK_B_{i} are one object per index), their position, velocity, "
        "score or probability, validity, class and id signals, and the ego speed (the mean of "
        "four wheel speeds where there are), yaw rate and steering angle by name and unit; "
        "write them as a profile with a typical car's dimensions and a forward radar at its "
        "front, every guess commented, '# TODO:' where something needed was not found. Give "
        "each bus its database with --dbc BUS=PATH: [profile] databases is then a table per bus.")
    new.add_argument("--dbc", action="append", required=True, metavar="[BUS=]PATH",
                     help="signal database (DBC, KCD, SYM, ARXML) for BUS, or for every bus "
                     "without BUS=; repeatable: a database per bus is written as "
                     "[profile] databases = { BUS = [...] }")
    new.add_argument("-o", "--output", type=Path, required=True, metavar="car.toml",
                     help="the profile to write (an existing file only with --force)")
    new.add_argument("--force", action="store_true", help="overwrite an existing file")
    new.set_defaults(run=run_new)
    check = commands.add_parser(
        "check", help="load a profile, print what it maps and, given logs, what it saw",
        description="Load the profile against the databases (--dbc, else the profile's own) "
        "and print its sensors, object groups, ego, lanes and lead; given logs (any format "
        "tankviz convert reads), run them through and print per group the valid objects and "
        "their x/y ranges, and per sensor the lateral sign verdict.")
    check.add_argument("profile", metavar="NAME|PATH", help="the profile (TOML) or a bundled name")
    check.add_argument("logs", nargs="*", type=Path, metavar="LOG", help="CAN logs to run through")
    check.add_argument("--dbc", action="append", metavar="[BUS=]PATH",
                       help="signal database for BUS, or for every bus; repeatable")
    check.set_defaults(run=run_check)


def run_new(args: argparse.Namespace) -> int:
    print(new_profile([dbc_option(text) for text in args.dbc], args.output, force=args.force))
    return 0


def run_check(args: argparse.Namespace) -> int:
    print(check_profile(args.profile, [dbc_option(text) for text in args.dbc or []], args.logs))
    return 0
