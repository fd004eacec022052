"""What the inputs of a drive could not give, as a short list to print.

:func:`summarize_issues` is a pure function from a drive's input issues (objects, or their texts
as the ``input_issues`` metadata keeps them) to at most ``limit`` lines, the gravest first.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Protocol

#: The kinds of issue, gravest first (as :data:`bridge.io.can_logs.ISSUE_KINDS`).
KINDS = ("stop", "damage", "skip", "note")
_STOP_WORDS = re.compile(r"stopped|\bcut\b|truncat", re.IGNORECASE)
_DAMAGE_WORDS = re.compile(r"\bdamaged\b", re.IGNORECASE)
_VARYING = re.compile(r"'[^']*'|\"[^\"]*\"|0x[0-9a-fA-F]+|\d[\d,.]*")
_WHERE = re.compile(r"(?:line|frame|byte|record|row|object|message|offset)s? [\d,]+.*|[\d,]+")
#: How many places a grouped line names.
PLACES = 3


class Issue(Protocol):
    """What :func:`summarize_issues` reads of an issue object (:class:`SourceIssue`; its
    ``kind`` and ``group`` too, where it has them)."""

    @property
    def path(self) -> str: ...

    @property
    def where(self) -> str: ...

    @property
    def reason(self) -> str: ...


@dataclass
class _Group:
    path: str
    family: str
    kind: str
    first: str
    places: list[str] = field(default_factory=list)
    count: int = 0


def _parts(issue: Issue | str) -> tuple[str, str, str, str, str]:
    """(path, where, reason, kind, group) of an issue or of its text."""
    if isinstance(issue, str):
        head, sep, reason = issue.partition(": ")
        if not sep:
            path, where, reason = "", "", issue
        else:
            path, colon, where = head.rpartition(":")
            if not colon or not _WHERE.fullmatch(where):
                path, where = head, ""
        kind, group = "", ""
    else:
        path, where, reason = issue.path, issue.where, issue.reason
        kind, group = str(getattr(issue, "kind", "")), str(getattr(issue, "group", ""))
    if kind not in KINDS:
        kind = ("stop" if _STOP_WORDS.search(reason) else
                "damage" if _DAMAGE_WORDS.search(reason) else "skip")
    return path, where, reason, kind, group or _VARYING.sub("…", reason)


def summarize_issues(issues: Iterable[Issue | str], *, total: int | None = None,
                     limit: int = 20) -> list[str]:
    """The lines that tell ``issues`` (:class:`~bridge.io.can_logs.SourceIssue` objects, or their
    texts as the ``input_issues`` metadata keeps them); ``total``: how many there were, when
    ``issues`` holds only the first of them.

    At most ``limit`` lines: the gravest first (a stop, then damage skipped, then a line or frame
    skipped, then a note), the issues of one file, kind and family on one line with their count and
    first places (``log.asc: skipped a line …: … (120 times: line 3, …)``), and a cut list ending
    with ``… and N more``.
    """
    groups: dict[tuple[str, str, str], _Group] = {}
    given = 0
    for issue in issues:
        given += 1
        path, where, _, kind, family = _parts(issue)
        group = groups.get((path, kind, family))
        if group is None:
            group = groups[path, kind, family] = _Group(path, family, kind, str(issue))
        group.count += 1
        if where and len(group.places) < PLACES:
            group.places.append(where)
    ordered = sorted(groups.values(), key=lambda g: KINDS.index(g.kind))  # stable: file order
    lines: list[str] = []
    shown = 0
    for group in ordered[:limit]:
        if group.count == 1:
            lines.append(group.first)
        else:
            more = ", …" if group.count > len(group.places) else ""
            places = f": {', '.join(group.places)}{more}" if group.places else ""
            prefix = f"{group.path}: " if group.path else ""
            lines.append(f"{prefix}{group.family} ({group.count:,} times{places})")
        shown += group.count
    left = max(total or 0, given) - shown
    if left > 0:
        lines.append(f"… and {left:,} more")
    return lines
