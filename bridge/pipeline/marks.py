"""Marks: moments somebody marked during a drive, made into the drive's messages.

A mark is asked for from any thread (:meth:`Marks.ask`: the server's, for a viewer's Publish
panel; the terminal's; the pipeline's own, for a profile's ``[marks]`` rule) and made in the
pipeline's thread (:meth:`Marks.take`), stamped with the drive's clock at that moment, so that
it lands where the frames of that moment are whatever the computer's clock says. Each mark is
numbered (1, 2, … in the drive) and becomes three messages: ``/marks`` (``tankviz.Mark``, what
inspect, catalog and replay find), a line on ``/log`` and a text in the scene
(``/scene/marks``) for :data:`SHOWN_S` seconds.
"""

from __future__ import annotations

import queue
from dataclasses import dataclass

from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bridge.frame import timestamp
from bridge.pb.marks_pb2 import Mark
from bridge.scene.entities import add_text, entity
from bridge.topics import LOG_TOPIC, MARKS_CATEGORY, MARKS_TOPIC, TopicMessage, scene_topic

#: How long a mark's text stays in the scene (s of log time).
SHOWN_S = 5.0
#: Where a mark's text stands in the scene: ahead of and above the ego vehicle (vehicle frame, m).
SHOWN_AT = (12.0, 0.0, 4.0)
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


def describe(mark: Mark) -> str:
    """A mark in one line: ``MARK 3: ghost [radar] (viewer 192.168.1.4)``."""
    category = f" [{mark.category}]" if mark.category else ""
    by = f" {mark.by}" if mark.by else ""
    return f"MARK {mark.number}: {mark.text}{category} ({mark.source}{by})"


def mark_messages(mark: Mark, t_ns: int) -> list[TopicMessage]:
    """A mark's messages: itself on /marks, its line on /log, its text in the scene."""
    line = describe(mark)
    shown = entity(t_ns, f"mark-{mark.number}", SHOWN_S)
    add_text(shown, *SHOWN_AT, line)
    return [TopicMessage(MARKS_TOPIC, mark, t_ns),
            TopicMessage(LOG_TOPIC, Log(timestamp=timestamp(t_ns), level=Log.INFO, message=line,
                                        name="tankviz"), t_ns),
            TopicMessage(scene_topic(MARKS_CATEGORY), SceneUpdate(entities=[shown]), t_ns)]
