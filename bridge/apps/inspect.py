"""``tankviz inspect``: what a drive archive holds, readable in a terminal.

It prints the drive's times, marks, topics, attachments, decode statistics and what its
``tankviz`` metadata says; every list cut short ends with ``… and N more``. A file that cannot
be read is an :class:`~bridge.errors.InputError` saying why.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.reader import make_reader

from bridge.apps.options import Subparsers
from bridge.errors import InputError, check_input_path
from bridge.frame import format_time
from bridge.io.drives import BLOCK_SCHEMA, DriveMarks, by_number, parse_mark, read_marks
from bridge.io.issues import summarize_issues
from bridge.io.unreadable import why_unreadable
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline.marks import describe
from bridge.sinks.mcap import METADATA_NAME
from bridge.sinks.raw import WINDOW_NS
from bridge.topics import MARKS_TOPIC


@dataclass
class Topic:
    topic: str
    schema: str
    encoding: str
    messages: int


@dataclass
class DriveSummary:
    """Times, topics, metadata and attachments of one MCAP file."""

    start_ns: int
    end_ns: int
    messages: int
    topics: list[Topic]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: list[tuple[str, str, int]] = field(default_factory=list)
    marks: DriveMarks = field(default_factory=lambda: DriveMarks([], None))

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9 if self.messages else 0.0


def summarize(stream: IO[bytes]) -> DriveSummary:
    """Read the summary section (or, for a file without one, every message) of an MCAP."""
    reader = make_reader(stream)
    summary = reader.get_summary()
    if summary is not None and summary.statistics is not None:
        stats = summary.statistics
        counts = dict(stats.channel_message_counts)
        channels, schemas = summary.channels, summary.schemas
        start, end, total = stats.message_start_time, stats.message_end_time, stats.message_count
        marks, unreadable = read_marks(reader)
    else:
        counter: Counter[int] = Counter()
        start, end, total = 0, 0, 0
        channels, schemas = {}, {}
        found: list[Mark] = []
        unreadable = 0
        for schema, channel, message in reader.iter_messages():
            if channel.topic == MARKS_TOPIC:
                mark = parse_mark(message.data, message.log_time)
                if mark is None:
                    unreadable += 1
                else:
                    found.append(mark)
            counter[channel.id] += 1
            channels[channel.id] = channel
            if schema is not None:
                schemas[schema.id] = schema
            start = message.log_time if total == 0 else min(start, message.log_time)
            end = max(end, message.log_time)
            total += 1
        counts = dict(counter)
        marks = by_number(found)
    topics = [
        Topic(ch.topic, schemas[ch.schema_id].name if ch.schema_id in schemas else "",
              ch.message_encoding, counts.get(ch.id, 0))
        for ch in channels.values()
    ]
    topics.sort(key=lambda t: t.topic)
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    attachments = [(a.name, a.media_type, len(a.data)) for a in reader.iter_attachments()]
    return DriveSummary(start, end, total, topics, metadata, attachments,
                        DriveMarks(marks, start if total else None, unreadable))


def summarize_file(path: Path | str) -> DriveSummary:
    path = Path(path)
    check_input_path(path)
    try:
        with path.open("rb") as stream:
            return summarize(stream)
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, f"is a folder, not an MCAP file; name the drives in it "
                         f"({path / '*.mcap'})") from None
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    except (McapError, ValueError, struct.error, EOFError, RuntimeError) as exc:  # damaged files
        raise InputError(path, why_unreadable(path, exc)) from None


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


#: How many entries of a list are printed (the rest: ``… and N more``).
LIMIT = 20


def _cut(lines: list[str], total: int | None = None, limit: int = LIMIT,
         indent: str = "  ") -> list[str]:
    """The first ``limit`` of ``lines`` (of ``total``), and how many are left out."""
    left = (len(lines) if total is None else total) - min(limit, len(lines))
    return lines[:limit] + ([f"{indent}… and {left:,} more"] if left > 0 else [])


def _span(from_ns: int, to_ns: int | None) -> str:
    if to_ns is None:
        return f"{format_time(from_ns)} -> (not over)"
    return f"{format_time(from_ns)} -> {format_time(to_ns)} ({(to_ns - from_ns) / 1e9:,.1f} s)"


def _recording_gap(g: dict[str, Any], part: str) -> str:
    """One pause of the recording: when, why, and what it did not record."""
    if g.get("to_ns") is None:
        return (f"  {format_time(g['from_ns'])}: recording stopped: {g['reason']} (what it did "
                "not record is in the next part's metadata)")
    if "frames_not_recorded" in g:
        where = g.get("resumed_in")
        kept = "this part" if where in (None, part) else where
        lost = (f"{g['frames_not_recorded'] or 0:,} frames not recorded (backlog full), "
                f"{g.get('frames_kept') or 0:,} recorded at the start of {kept}, "
                f"{g.get('messages_not_recorded') or 0:,} decoded messages and scenes not "
                "recorded")
    else:  # recorded before these counts had their names
        lost = (f"{g.get('frames_dropped', 0):,} frames dropped, "
                f"{g.get('messages_lost', 0):,} messages not recorded")
    return f"  {_span(g['from_ns'], g['to_ns'])}: {g['reason']}: {lost}"


def _bus_gap(g: dict[str, Any]) -> str:
    return f"  {g.get('bus', '?')}: {_span(g['from_ns'], g.get('to_ns'))}: {g.get('reason', '')}"


def _entry(key: str, text: str) -> list[str]:
    """A metadata entry: one line, or a JSON map or list as a line per item."""
    value = _json(text)
    if isinstance(value, dict) and value:
        width = max(len(str(k)) for k in value)
        items = [f"    {k!s:<{width}}  {v:>12,}" if isinstance(v, int) and not isinstance(
            v, bool) else f"    {k!s:<{width}}  {v}" for k, v in value.items()]
        return [f"  {key} ({len(value)}):", *items]
    if isinstance(value, list) and value:
        return [f"  {key} ({len(value)}):", *_cut([f"    {v}" for v in value], indent="    ")]
    return [f"  {key}: {text}"]


def _marks(marks: DriveMarks) -> list[str]:
    """The drive's marks, a line each: seconds from its start, then as live said it."""
    if not marks.marks and not marks.unreadable:
        return []
    lines = ["", f"marks ({len(marks.marks)}; seconds from the drive's start):"]
    lines += _cut([f"  {marks.seconds(m):>10,.3f} s  {describe(m)}" for m in marks.marks],
                  limit=50)
    if marks.unreadable:
        lines.append(f"  ({marks.unreadable:,} {MARKS_TOPIC} messages are not a tankviz.Mark: "
                     "left out)")
    return lines


def format_summary(path: str, s: DriveSummary) -> str:
    """The report ``tankviz inspect`` prints."""
    lines = [
        f"file:      {path}",
        f"duration:  {s.duration_s:.3f} s",
        f"start:     {format_time(s.start_ns)}",
        f"end:       {format_time(s.end_ns)}",
        f"messages:  {s.messages:,}",
    ]
    lines += _marks(s.marks)
    lines += ["", f"topics ({len(s.topics)}):"]
    width = max((len(t.topic) for t in s.topics), default=10)
    for t in s.topics:
        lines.append(f"  {t.topic:<{width}}  {t.messages:>10,}  {t.schema} ({t.encoding})")
    if any(t.schema == BLOCK_SCHEMA for t in s.topics):
        lines.append(f"  (raw frames: a {BLOCK_SCHEMA} per bus per {WINDOW_NS // 1_000_000} ms; "
                     "frames are counted under decode statistics)")
    meta = dict(s.metadata)
    ours = meta.pop(METADATA_NAME, None)
    if ours is not None:
        lines += ["", "recorded by:"]
        lines.append(f"  tankviz {ours.get('tankviz_version', '?')}, {ours.get('created', '?')}")
        for entry in _json(ours.get("inputs", "[]")):
            lines.append(f"  input {entry['path']}: {entry['frames']:,} frames, "
                         f"{entry['skipped']} skipped, {entry.get('backwards_jumps', 0)} "
                         "backwards time jumps")
        for db in _json(ours.get("databases", "[]")):
            lines.append(f"  database {db['name']} (attachment {db['attachment']}) on buses "
                         f"{', '.join(db['buses'])}: sha256 {db['sha256']}")
        stats = _json(ours.get("statistics", "{}"))
        lines += ["", "decode statistics:"]
        for bus, n in stats.get("frames", {}).items():
            lines.append(f"  {bus}: {n:,} frames, {stats.get('error_frames', {}).get(bus, 0)} "
                         f"error frames, {stats.get('remote_frames', {}).get(bus, 0)} remote")
        for title, key in (("unknown ids", "unknown_ids"), ("decode errors", "decode_errors"),
                           ("short frames (decoded what fits)", "truncated")):
            entries = stats.get(key, {})
            total = sum(entries.values())
            top = sorted(entries.items(), key=lambda kv: -kv[1])
            more = f", … and {len(top) - 12:,} more" if len(top) > 12 else ""
            lines.append(f"  {title}: {total:,}" + ("" if not entries else " — " + ", ".join(
                f"{k} ({v})" for k, v in top[:12]) + more))
            if key == "decode_errors":  # each id's last error, under them
                last_errors = stats.get("last_decode_error", {})
                lines += _cut([f"    {k}: {text}" for k, text in last_errors.items()],
                              limit=12, indent="    ")
        longer = stats.get("longer", {})
        lines.append("  CAN FD frames longer than their message (decoded what it defines): "
                     f"{sum(v['frames'] for v in longer.values()):,}")
        lines += [f"    {topic}: {v['frames']:,} frames longer than its {v['message_bytes']} "
                  f"bytes (up to {v['longest']})" for topic, v in longer.items()]
        for title, key in (("non-finite values (kept out of the scene)", "non_finite"),
                           ("validity rules that could not be evaluated (objects left out)",
                            "rule_errors")):
            entries = stats.get(key, {})
            if entries:
                lines.append(f"  {title}: {sum(entries.values()):,} — " + ", ".join(
                    f"{k} ({v})" for k, v in sorted(entries.items(), key=lambda kv: -kv[1])))
        steps = _json(ours.get("clock_steps", "[]"))
        if steps:
            lines += ["", f"clock steps ({len(steps)}; frames recorded with their own stamps):"]
            lines += _cut([f"  {format_time(s['from_ns'])} -> {format_time(s['to_ns'])} "
                           f"({s['step_s']:+,.3f} s)" for s in steps])
        bus_gaps = _json(ours.get("bus_gaps", "[]"))
        if bus_gaps:
            lines += ["", f"bus gaps ({len(bus_gaps)}; a bus lost and back):"]
            lines += _cut([_bus_gap(g) for g in bus_gaps])
        gaps = _json(ours.get("recording_gaps", "[]"))
        if gaps:
            lines += ["", f"recording paused ({len(gaps)}):"]
            lines += _cut([_recording_gap(g, Path(path).name) for g in gaps])
        warnings = _json(ours.get("warnings", "[]"))
        if warnings:
            lines += ["", f"warnings ({len(warnings)}):"]
            lines += [f"  {text}" for text in warnings]
        alarms = _json(ours.get("alarms", "[]"))
        lines += ["", f"alarms ({sum(a['event'] == 'raised' for a in alarms)} raised):"]
        lines += _cut([f"  {format_time(a['t_ns'])}  {a['event']:<7} {a['alarm']}: "
                       f"{a['message']}" for a in alarms], limit=50)
        lateral = _json(ours.get("lateral_sign", "[]"))
        if lateral:  # each sensor's verdict: bridge.world.lateral
            lines += ["", "lateral sign (stationary objects against the turn, vehicles ahead "
                      "into the curves):"]
            lines += [f"  {v['verdict']:<7}  {v['message']}" for v in lateral]
        issues = _json(ours.get("input_issues", "{}"))
        if issues.get("count"):
            lines += ["", f"skipped in the inputs ({issues['count']:,}):"]
            lines += [f"  {text}" for text in summarize_issues(
                issues.get("first", []), total=issues["count"], limit=LIMIT)]
    for name, values in sorted(meta.items()):
        lines += ["", f"metadata {name}:"]
        for k, v in sorted(values.items()):
            lines += _entry(k, v)
    lines += ["", f"attachments ({len(s.attachments)}):"]
    lines += [f"  {name}  {media}  {size:,} bytes" for name, media, size in s.attachments]
    return "\n".join(lines)


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser("inspect", help="show what a drive archive (MCAP) holds",
                            description="Duration, start and end, topics with schemas and "
                            "counts, metadata, attachments and decode statistics of MCAP files.")
    parser.add_argument("files", nargs="+", type=Path, metavar="FILE.mcap",
                        help="drives to show (MCAP files), each in turn")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Each file in turn; one that cannot be read is one ``error:`` line, and the others are
    still shown (exit status 1 if any could not be)."""
    failed = 0
    for path in args.files:
        try:
            summary = summarize_file(path)
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr, flush=True)
            failed += 1
            continue
        print(format_summary(str(path), summary), flush=True)
    return 1 if failed else 0
