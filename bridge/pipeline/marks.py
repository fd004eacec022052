"""Marks: moments somebody marked during a drive, made into the drive's messages.

A mark is asked for from any thread (a viewer, the terminal) or by a profile's ``[marks]`` rule
and made in the pipeline's thread, stamped with the drive's clock, so it lands among the frames
of that moment. Each is numbered in the drive and becomes ``/marks`` (``tankviz.Mark``), a ``/log``
line and a text in the scene for :data:`SHOWN_S` seconds.
"""

from __future__ import annotations

import queue
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bridge.frame import timestamp
from bridge.pb.marks_pb2 import Mark
from bridge.topics import LOG_TOPIC, MARKS_CATEGORY, MARKS_TOPIC, TopicMessage, scene_topic

if TYPE_CHECKING:
    from bridge.profile.model import MarkRule

#: How long a mark's text stays in the scene (s of log time).
SHOWN_S = 5.0
#: Where a mark's text stands in the scene: above the ego vehicle, over the alarm overlay
#: (vehicle frame, m).
SHOWN_AT = (0.0, 0.0, 8.0)
#: The sources of marks (``Mark.source``).
SOURCES = ("viewer", "car", "terminal")


@dataclass(frozen=True)
class MarkAsked:
    """A mark somebody asked for: its text, an optional category, who asked (one of
    :data:`SOURCES`) and which one of them (``by``: a viewer's address, a rule's text)."""

    text: str
    category: str = ""
    source: str = "viewer"
    by: str = ""


class Marks:
    """The marks of one drive: asked from any thread, made in the pipeline's."""

    def __init__(self) -> None:
        self._asked: queue.SimpleQueue[MarkAsked] = queue.SimpleQueue()
        #: the marks made so far
        self.made: list[Mark] = []

    def ask(self, asked: MarkAsked) -> None:
        """Ask for a mark (thread-safe): it is made at the pipeline's next :meth:`take`."""
        if asked.source not in SOURCES:
            raise ValueError(f"a mark's source is one of {', '.join(SOURCES)}: {asked.source!r}")
        self._asked.put(asked)

    def take(self, t_ns: int) -> list[TopicMessage]:
        """Every mark asked since the last call, made at ``t_ns`` (the drive's clock now)."""
        out: list[TopicMessage] = []
        while True:
            try:
                asked = self._asked.get_nowait()
            except queue.Empty:
                return out
            out += self.make(asked, t_ns)

    def make(self, asked: MarkAsked, t_ns: int) -> list[TopicMessage]:
        """A mark at ``t_ns``, numbered next: its /marks, /log and scene messages."""
        mark = Mark(timestamp=timestamp(t_ns), number=len(self.made) + 1, text=asked.text,
                    category=asked.category, source=asked.source, by=asked.by)
        self.made.append(mark)
        return mark_messages(mark, t_ns)


class MarkWatch:
    """A profile's ``[marks]`` rules, each evaluated on every decoded frame of a message it
    reads, a signal keeping its latest value until its message brings another: a rule that
    becomes true (it was false, or could not be evaluated: a signal not there yet) asks for a
    mark, ``source`` "car", ``by`` the rule as written; while it stays true, nothing more."""

    def __init__(self, rules: Sequence[MarkRule]) -> None:
        self.rules = tuple(rules)
        #: every message a rule reads: only their frames are watched
        self.messages = frozenset(m for rule in self.rules for m in rule.messages)
        #: per message, each rule that reads it: (its index, (name, signal) of what it reads there)
        self._reads: dict[str, list[tuple[int, tuple[tuple[str, str], ...]]]] = {}
        for i, rule in enumerate(self.rules):
            for message in sorted(rule.messages):
                self._reads.setdefault(message, []).append(
                    (i, tuple((name, signal) for name, m, signal in rule.reads if m == message)))
        self._values: list[dict[str, Any]] = [{} for _ in self.rules]
        self._held = [False] * len(self.rules)
        self._asked = [MarkAsked(r.text, r.category, "car", r.when) for r in self.rules]

    def on_message(self, message: str, signals: Mapping[str, Any]) -> list[MarkAsked]:
        """The marks a decoded frame of ``message`` asks for: one per rule it makes true."""
        out: list[MarkAsked] = []
        for i, reads in self._reads[message]:
            values = self._values[i]
            for name, signal in reads:
                value = signals.get(signal)
                if value is not None:
                    values[name] = value
            holds = self.rules[i].expression.test(values)
            if holds and not self._held[i]:
                out.append(self._asked[i])
            self._held[i] = holds
        return out


def describe(mark: Mark) -> str:
    """A mark in one line: ``MARK 3: ghost [radar] (viewer 192.168.1.4)`` (who only once: ``MARK
    4: STEER_BUTTON == 1 (car)``, a car's rule that is its own text; ``MARK 5: mark
    (terminal)``)."""
    category = f" [{mark.category}]" if mark.category else ""
    by = f" {mark.by}" if mark.by and mark.by not in (mark.text, mark.source) else ""
    return f"MARK {mark.number}: {mark.text}{category} ({mark.source}{by})"


def mark_messages(mark: Mark, t_ns: int) -> list[TopicMessage]:
    """A mark's messages: itself on /marks, its line on /log, its text in the scene."""
    from bridge.scene.entities import add_text, entity  # (a drive may have marks, no scene)

    line = describe(mark)
    shown = entity(t_ns, f"mark-{mark.number}", SHOWN_S)
    add_text(shown, *SHOWN_AT, line)
    return [TopicMessage(MARKS_TOPIC, mark, t_ns),
            TopicMessage(LOG_TOPIC, Log(timestamp=timestamp(t_ns), level=Log.INFO, message=line,
                                        name="tankviz"), t_ns),
            TopicMessage(scene_topic(MARKS_CATEGORY), SceneUpdate(entities=[shown]), t_ns)]
