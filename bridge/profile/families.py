"""Numbered message families and their companions: the object slots a database sends.

A **family** (:func:`find_families`) is at least :data:`MIN_FAMILY` messages whose names differ
only by one number, the longest run of consecutive numbers, whose signals have the same names;
where two claim a message, the wider span keeps it. **Companions** (:func:`group_families`) are
families whose messages of one index are one object.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from cantools.database.can.message import Message
from cantools.database.can.signal import Signal

#: The smallest number of messages that make a family.
MIN_FAMILY = 3


@dataclass(frozen=True)
class Family:
    """Messages whose names differ only by one number, with the same signal names."""

    template: str
    prefix: str
    first: int
    last: int
    #: the first member's message, and its signal names as templates
    message: Message
    signals: tuple[tuple[str, Signal], ...]
    source: str


def _index_text(index: int, width: int) -> str:
    return f"{index:0{width}d}" if width else str(index)


def find_families(messages: Iterable[tuple[str, Message]]) -> list[Family]:
    """The message families among ``messages`` (source name, message), by template."""
    by_key: dict[tuple[str, str, int], dict[int, tuple[str, Message]]] = {}
    for source, m in messages:
        for match in re.finditer(r"\d+", m.name):
            text = match.group()
            width = len(text) if text.startswith("0") and len(text) > 1 else 0
            key = (m.name[:match.start()], m.name[match.end():], width)
            by_key.setdefault(key, {})[int(text)] = (source, m)
    candidates: list[Family] = []
    for (prefix, suffix, width), members in by_key.items():
        if len(members) < MIN_FAMILY:
            continue
        padded_width = width
        if width:
            # a zero-padded family also holds its unpadded members of the same width (10, 11)
            extra = by_key.get((prefix, suffix, 0), {})
            members = {**{i: sm for i, sm in extra.items() if len(str(i)) == width}, **members}
        # Signal names as they are, or with the index in them as {i} (FwdVsnRngTrk1Rev):
        # whichever makes more members alike (as they are, on a tie: Index2 is no index).
        best: tuple[int, bool, list[int]] = (0, False, [])
        for numbered in (False, True):
            templates: dict[int, tuple[str, ...]] = {}
            for i, (_, m) in members.items():
                text = _index_text(i, padded_width)
                templates[i] = tuple(sorted(_signal_template(s.name, text, padded_width)
                                            if numbered else s.name for s in m.signals))
            counts: dict[tuple[str, ...], int] = {}
            for names in templates.values():
                counts[names] = counts.get(names, 0) + 1
            signature = max(counts, key=lambda k: counts[k])
            alike = sorted(i for i, names in templates.items() if names == signature)
            if signature and len(alike) > best[0]:
                best = (len(alike), numbered, alike)
        _, numbered, same = best
        run = _longest_run(same)
        if len(run) < MIN_FAMILY:
            continue
        source, first = members[run[0]]
        placeholder = f"{{i:0{padded_width}d}}" if padded_width else "{i}"
        text = _index_text(run[0], padded_width)
        signals = tuple((_signal_template(s.name, text, padded_width) if numbered else s.name, s)
                        for s in first.signals)
        candidates.append(Family(f"{prefix}{placeholder}{suffix}", prefix, run[0], run[-1],
                                 first, signals, source))
    candidates.sort(key=lambda f: (-(f.last - f.first), f.template))
    taken: set[str] = set()
    families = []
    for f in candidates:
        expanded = {expand(f.template, i) for i in range(f.first, f.last + 1)}
        if expanded & taken:
            continue
        taken |= expanded
        families.append(f)
    families.sort(key=lambda f: f.template)
    return families


def expand(template: str, index: int) -> str:
    """The message name of ``template`` at ``index``: ``Object_{i:02d}``, 3 -> ``Object_03``."""
    return re.sub(r"\{i(?::0(\d)d)?\}",
                  lambda m: _index_text(index, int(m.group(1) or 0)), template)


def _signal_template(name: str, text: str, width: int) -> str:
    placeholder = f"{{i:0{width}d}}" if width else "{i}"
    return re.sub(r"\d+", lambda m: placeholder if m.group() == text else m.group(), name)


def _longest_run(numbers: Sequence[int]) -> list[int]:
    best: list[int] = []
    run: list[int] = []
    for n in numbers:
        run = [*run, n] if run and n == run[-1] + 1 else [n]
        if len(run) > len(best):
            best = run
    return best


def stem(prefix: str) -> str:
    """The name before the index without a one-letter part that only tells companions apart:
    ``TRACK_A_`` and ``TRACK_B_`` -> ``TRACK_`` (``RadarPoint`` stays)."""
    return re.sub(r"(?:(?<=_)|^)[A-Z]_$", "", prefix)


def group_families(families: Sequence[Family]) -> list[list[Family]]:
    """Companion families as one group each: the same numbers, and names that differ only after
    the index (``Obj{i}_A``, ``Obj{i}_B``) or in a one-letter part before it (``TRACK_A_{i}``,
    ``TRACK_B_{i}``, :func:`stem`): the messages of one index are one object."""
    groups: dict[tuple[str, int, int], list[Family]] = {}
    for f in families:
        groups.setdefault((stem(f.prefix), f.first, f.last), []).append(f)
    return list(groups.values())
