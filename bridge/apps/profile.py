"""``tankviz profile``: start a vehicle profile from the databases, and check one.

- ``tankviz profile new --dbc [BUS=]PATH [--dbc ...] -o car.toml`` writes the commented starting
  profile that :func:`bridge.profile.draft.draft_profile` drafts from the databases (loaded with
  cantools as :mod:`bridge.decode` loads them, each on its bus: an id defined differently on two
  buses is no conflict), naming them in ``[profile] databases`` relative to the output file (a
  table per bus, ``{ can0 = [...], can1 = [...] }``, when buses are given; a list otherwise),
  and says whether it loads as written or which ``# TODO:`` line stops it. An existing file is
  not overwritten unless ``--force``.
- ``tankviz profile check car.toml [--dbc ...] [LOG ...]`` loads the profile against the
  databases (``--dbc``, else the profile's own; a bad name is the loader's one-line error with
  the closest names) and prints what it maps (:func:`format_mapping`: sensors, object groups
  with sensor, role, messages, index range and fields, ego, lanes, lead). Given logs (any format
  ``tankviz convert`` reads), it runs them through the one drive assembly,
  :class:`~bridge.pipeline.drive.Drive`, with no recording sink, and prints per object group
  how many objects were valid (distinct ids and observations), their x and y ranges in the
  vehicle frame, and per sensor the lateral-sign verdict of the drive's health monitor
  (:class:`~bridge.world.lateral.LateralSignCheck`; :class:`GroupStats`, :func:`format_stats`).
  Last come the warnings ``tankviz convert`` prints
  (:meth:`~bridge.decode.decoder.Decoder.warnings`: a message cantools cannot decode; given logs,
  a ``--dbc BUS=`` for a bus no log has), one ``warning: …`` line each, so that check is the one
  place to see everything.

Exit status 0 when the profile is usable, 1 with the error otherwise.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from bridge.apps.options import Subparsers, dbc_option
from bridge.errors import BridgeError
from bridge.io.logs import LogSource, merge
from bridge.pipeline.drive import Drive, Stages, load_stages
from bridge.pipeline.perception import Perception
from bridge.profile.draft import TODO, draft_profile
from bridge.profile.loader import load_profile
from bridge.profile.model import Computed, ObjectGroup, Profile, ProfileError, SignalRef
from bridge.sinks.base import Serialized, Sink
from bridge.world.lateral import LateralVerdict

# --- profile new --------------------------------------------------------------------------------


def new_profile(dbc_options: Sequence[str], output: Path, *, force: bool = False) -> str:
    """Draft a profile from the databases into ``output``; returns what to tell the user."""
    if output.exists() and not force:
        raise BridgeError(f"{output}: exists (--force overwrites)")
    stages = load_stages(dbc_options, None)
    decoder = stages.decoder
    files = decoder.files
    if not files:
        raise BridgeError("profile new: name the databases with --dbc [BUS=]PATH")
    base = output.resolve().parent
    named = [(os.path.relpath(f.path.resolve(), base), f.db) for f in files]
    buses: dict[str, list[str]] = {}
    for (path, _), f in zip(named, files, strict=True):
        for bus in decoder.buses_for(f):
            buses.setdefault(bus, []).append(path)
    text = draft_profile(named, name=output.stem, buses=buses)
    try:
        output.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise BridgeError(f"{output}: cannot write: {exc.strerror or exc}") from None
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
    return [f"  {name}: sensor {g.sensor.name} ({g.sensor.kind.value}), role "
            f"{'tracks' if g.is_tracks else 'detections'}, {' + '.join(g.templates)} {where}",
            f"    {', '.join(fields)}",
            f"    valid: {rule}; lifetime {g.lifetime_s:g} s"]


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
    return "\n".join(lines)


@dataclass
class GroupStats:
    """What one object group's valid objects did over a drive."""

    ids: set[int] = field(default_factory=set)
    #: distinct (id, observation time) pairs the scene showed
    observations: set[tuple[int, int]] = field(default_factory=set)
    x: list[float] = field(default_factory=lambda: [float("inf"), float("-inf")])
    y: list[float] = field(default_factory=lambda: [float("inf"), float("-inf")])


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


def format_stats(frames: int, stats: dict[str, GroupStats], verdicts: Sequence[LateralVerdict],
                 profile: Profile) -> str:
    """Per group: valid objects and their x/y ranges; per sensor: the lateral sign verdict."""
    lines = [f"log: {frames:,} frames; valid objects per group (vehicle frame, m):"]
    for name, s in stats.items():
        if not s.ids:
            lines.append(f"  {name}: no valid object")
            continue
        lines.append(f"  {name}: {len(s.ids)} objects (ids/slots), {len(s.observations):,} "
                     f"observations; x {s.x[0]:.1f}..{s.x[1]:.1f}, y {s.y[0]:.1f}..{s.y[1]:.1f}")
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
    assert drive.pipeline.perception is not None
    sink = CheckSink(drive.pipeline.perception)
    drive.add(sink)
    frames = drive.run(merge(sources))
    drive.finish()
    # the health monitor runs the lateral sign check of every drive (bridge.world.lateral)
    lateral = drive.health.lateral
    verdicts = lateral.verdicts() if lateral is not None else []
    return _with_warnings(out + "\n" + format_stats(frames, sink.groups, verdicts, profile),
                          stages.decoder.warnings())


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
