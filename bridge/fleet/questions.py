"""The questions of ``tankviz catalog query``: SQL on a catalogue, read only, the canned
questions, and how to open each answer.

:func:`query` runs only :data:`READING_STATEMENTS`; :func:`alarm_query`, :func:`topic_query`,
:func:`mark_query` and :func:`between_query` are the canned questions; :func:`open_hints` gives
each answer row with a drive and a time or mark its ``tankviz replay`` command and MCAP time.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from bridge.errors import UsageError
from bridge.fleet.catalog import connect, drive_file
from bridge.frame import NS, format_time

Row = tuple[Any, ...]

@dataclass(frozen=True)
class Answer:
    """Columns and rows of a query, with the catalogue's drive start times (for open hints)."""

    columns: list[str]
    rows: list[Row]
    starts: dict[str, int]


def query(catalog: Path | str, sql: str, parameters: Sequence[Any] = ()) -> Answer:
    """Run ``sql`` on ``catalog``, read only: a query writes no file and no database."""
    import duckdb

    con = connect(catalog)
    try:
        try:
            _check_reads_only(con, sql)
            result = con.execute(sql, list(parameters))
        except duckdb.Error as exc:
            raise UsageError(str(catalog), " ".join(str(exc).split())) from None
        if result.description is None:
            return Answer([], [], {})
        columns = [d[0] for d in result.description]
        rows = result.fetchall()
        starts = dict(con.execute("SELECT path, start_ns FROM drives").fetchall())
    finally:
        con.close()
    return Answer(columns, rows, starts)


#: The statements a query may hold: they read. Every other kind may write a file or a database
#: (COPY, EXPORT, ATTACH, INSTALL and LOAD, SET, CREATE, ...), even on a read-only catalogue.
READING_STATEMENTS = ("SELECT", "EXPLAIN")


def _check_reads_only(con: Any, sql: str) -> None:
    """Refuse a query with no statement, or with one that is not a :data:`READING_STATEMENTS`."""
    statements = con.extract_statements(sql)
    shown = " ".join(sql.split())
    if not statements:
        raise UsageError("catalog query", f"no statement in the query {shown!r} "
                         '(e.g. "SELECT * FROM drives")')
    for statement in statements:
        kind = statement.type.name
        if kind not in READING_STATEMENTS:
            raise UsageError("catalog query only reads", f"a {kind} statement is refused (it may "
                             f"write files or databases): {_shown(shown)}")


def _shown(text: str, limit: int = 80) -> str:
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _check_name(catalog: Path | str, what: str, column: str, table: str, name: str) -> None:
    known = [r[0] for r in query(catalog, f"SELECT DISTINCT {column} FROM {table}").rows]
    if name not in known:
        close = difflib.get_close_matches(name, known, n=3, cutoff=0.5)
        hint = f"; closest: {', '.join(close)}" if close else ""
        raise UsageError(str(catalog), f"no {what} {name!r} in any drive of the catalogue{hint}")


def _between_sql(column: str, between: tuple[str, str] | None) -> tuple[str, list[Any]]:
    if between is None:
        return "", []
    return f" AND {column} >= ? AND {column} <= ?", [*_times(between)]


def _times(between: tuple[str, str]) -> tuple[datetime, datetime]:
    out = []
    for text in between:
        try:
            t = datetime.fromisoformat(text)
        except ValueError:
            raise UsageError("--between", "expected a date or time such as 2026-01-01 or "
                             "2026-01-01T12:00:00 (UTC)", value=text) from None
        if t.tzinfo is not None:
            t = t.astimezone(timezone.utc).replace(tzinfo=None)
        out.append(t)
    first, last = out
    if len(between[1]) == 10:  # a date alone: the whole day
        last = last.replace(hour=23, minute=59, second=59, microsecond=999999)
    if last < first:
        raise UsageError("--between", "the end is before the start",
                         value=f"{between[0]} {between[1]}")
    return first, last


def alarm_query(catalog: Path | str, alarm: str, between: tuple[str, str] | None = None
                ) -> Answer:
    """Every time ``alarm`` was raised, drive by drive in the order they were recorded."""
    _check_name(catalog, "alarm", "alarm", "alarms", alarm)
    where, params = _between_sql("a.raised", between)
    return query(catalog, "SELECT a.drive, a.alarm, a.raised, a.cleared, a.raised_ns, a.message "
                 "FROM alarms a JOIN drives d ON a.drive = d.path WHERE a.alarm = ?" + where
                 + " ORDER BY d.start_ns, a.raised_ns", [alarm, *params])


def topic_query(catalog: Path | str, topic: str, between: tuple[str, str] | None = None
                ) -> Answer:
    """Every drive with ``topic``: its count and rate, in the order they were recorded."""
    _check_name(catalog, "topic", "topic", "topics", topic)
    where, params = ("", []) if between is None else (
        " AND d.end_time >= ? AND d.start_time <= ?", list(_times(between)))
    return query(catalog, "SELECT t.drive, t.topic, t.schema, t.count, t.rate_hz, d.start_time, "
                 "d.start_ns FROM topics t JOIN drives d ON t.drive = d.path WHERE t.topic = ?"
                 + where + " ORDER BY d.start_ns", [topic, *params])


def mark_query(catalog: Path | str, text: str, between: tuple[str, str] | None = None
               ) -> Answer:
    """Every mark whose text contains ``text`` (in any case), in the order they were made."""
    where, params = _between_sql("m.time", between)
    return query(catalog, "SELECT m.drive, m.mark, m.time, m.t_s, m.text, m.category, m.source, "
                 "m.marked_by, m.t_ns FROM marks m JOIN drives d ON m.drive = d.path "
                 "WHERE contains(lower(m.text), lower(?))" + where
                 + " ORDER BY d.start_ns, m.mark", [text, *params])


def between_query(catalog: Path | str, between: tuple[str, str]) -> Answer:
    """Every drive recorded (in part) between two times."""
    return query(catalog, "SELECT path AS drive, start_time, end_time, duration_s, profile, "
                 "start_ns FROM drives WHERE end_time >= ? AND start_time <= ? "
                 "ORDER BY start_ns", list(_times(between)))


@dataclass(frozen=True)
class OpenHint:
    """How to open one answer: the drive, seconds into it or the mark (its number) to start a
    few seconds before, the log time (None: not in the answer)."""

    drive: str
    start_s: float
    t_ns: int | None
    mark: int | None = None

    def command(self) -> str:
        start = f"mark:{self.mark}" if self.mark is not None else f"{self.start_s:.3f}"
        return f"tankviz replay {_quote(self.drive)} --start {start}"

    def line(self) -> str:
        if self.t_ns is None:
            return self.command()
        return (f"{self.command()}    # Foxglove: jump to {format_time(self.t_ns)} "
                f"(log time {self.t_ns // NS}.{self.t_ns % NS:09d})")


def _quote(path: str) -> str:
    """A drive's path as a shell reads it back: a name with bytes that are not UTF-8 (shown as
    ``\\xNN``) in bash's ``$'...'``."""
    import shlex

    file = drive_file(path)
    if file is None or str(file) == path:
        return shlex.quote(path)
    escaped = {"\\": "\\\\", "'": "\\'"}
    return "$'" + "".join(f"\\x{ord(c) - 0xDC00:02x}" if "\udc80" <= c <= "\udcff"
                          else escaped.get(c, c) for c in str(file)) + "'"


def open_hints(answer: Answer) -> list[OpenHint | None]:
    """For each row with a drive (column ``drive`` or ``path``, a catalogued drive) and a log
    time (its first ``*_ns`` column) or a mark (column ``mark``, its number: ``--start mark:N``):
    how to open it there; None for the other rows."""
    columns = answer.columns
    drive_col = next((i for i, c in enumerate(columns) if c in ("drive", "path")), None)
    time_col = next((i for i, c in enumerate(columns) if c.endswith("_ns")), None)
    mark_col = columns.index("mark") if "mark" in columns else None
    hints: list[OpenHint | None] = []
    for row in answer.rows:
        drive = row[drive_col] if drive_col is not None else None
        t_ns = row[time_col] if time_col is not None else None
        t_ns = t_ns if isinstance(t_ns, int) else None
        mark = row[mark_col] if mark_col is not None else None
        mark = mark if isinstance(mark, int) else None
        if isinstance(drive, str) and drive in answer.starts and (t_ns, mark) != (None, None):
            start = answer.starts[drive]
            seconds = 0.0 if t_ns is None else max(0.0, (t_ns - start) // 1_000_000 / 1000)
            hints.append(OpenHint(drive, seconds, t_ns, mark))
        else:
            hints.append(None)
    return hints


def _cell(value: Any) -> str:
    if value is None:
        return "NULL"
    if isinstance(value, float):
        return f"{value:.3f}"
    if isinstance(value, datetime):
        return value.isoformat(sep=" ", timespec="milliseconds")
    if isinstance(value, list):
        return ", ".join(str(v) for v in value)
    return str(value)


def format_answer(answer: Answer) -> str:
    """The answer as a table, then how to open each row that names a drive and a time."""
    if not answer.columns:
        return "(no result)"
    cells = [[_cell(v) for v in row] for row in answer.rows]
    widths = [max([len(c), *(len(r[i]) for r in cells)]) for i, c in enumerate(answer.columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(answer.columns, widths, strict=True)).rstrip(),
             "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
              for r in cells]
    lines.append(f"({len(answer.rows)} row{'s' if len(answer.rows) != 1 else ''})")
    hints = [h for h in open_hints(answer) if h is not None]
    if hints:
        lines += ["", "open:"]
        lines += [f"  {h.line()}" for h in hints]
    return "\n".join(lines)
