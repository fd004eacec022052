"""Marks (bridge.pipeline.marks): asked from any thread, made in the pipeline's, numbered, stamped
on the drive's clock, and three messages each: /marks, a /log line, a text in the scene."""

from __future__ import annotations

import threading

import pytest
from foxglove_schemas_protobuf.Log_pb2 import Log

from bridge.pipeline.marks import SHOWN_S, MarkAsked, Marks, describe
from bridge.topics import LOG_TOPIC, MARKS_TOPIC

T0 = 46_411_900_000_000  # a car's clock: seconds since it booted


def test_marks_are_numbered_and_stamped_when_the_pipeline_takes_them() -> None:
    marks = Marks()
    assert marks.take(T0) == []
    marks.ask(MarkAsked("mark"))
    marks.ask(MarkAsked("ghost target here", "radar", "viewer", "192.168.1.4:53211"))
    made = marks.take(T0 + 5)
    assert [m.topic for m in made] == [MARKS_TOPIC, LOG_TOPIC, "/scene/marks"] * 2
    first, second = made[0].message, made[3].message
    assert (first.number, first.text, first.category, first.source) == (1, "mark", "", "viewer")
    assert (second.number, second.text, second.category, second.by) == (
        2, "ghost target here", "radar", "192.168.1.4:53211")
    assert all(m.t_ns == T0 + 5 for m in made)
    assert first.timestamp.ToNanoseconds() == T0 + 5
    assert marks.take(T0 + 10) == []
    assert [m.number for m in marks.made] == [1, 2]


def test_a_mark_is_a_log_line_and_a_text_in_the_scene_for_a_few_seconds() -> None:
    marks = Marks()
    marks.ask(MarkAsked("lanes jumped", "lanes", "car", "LANE_BTN == 1"))
    _, log, scene = marks.make(MarkAsked("lanes jumped", "lanes", "car", "LANE_BTN == 1"), T0)
    assert log.message.level == Log.INFO
    assert log.message.message == "MARK 1: lanes jumped [lanes] (car LANE_BTN == 1)"
    assert describe(marks.made[0]) == log.message.message
    (shown,) = scene.message.entities
    assert shown.id == "mark-1" and shown.texts[0].text == log.message.message
    assert shown.lifetime.ToNanoseconds() == SHOWN_S * 1e9
    assert shown.texts[0].font_size > 0 and shown.texts[0].color.a > 0


def test_marks_asked_from_many_threads_are_all_made_once() -> None:
    marks = Marks()
    threads = [threading.Thread(target=lambda i=i: [marks.ask(MarkAsked(f"{i}-{k}"))
                                                     for k in range(100)]) for i in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    made = [m.message for m in marks.take(T0) if m.topic == MARKS_TOPIC]
    assert sorted(m.text for m in made) == sorted(f"{i}-{k}" for i in range(4)
                                                   for k in range(100))
    assert [m.number for m in made] == list(range(1, 401))


def test_a_mark_from_nowhere_is_refused() -> None:
    with pytest.raises(ValueError, match="source"):
        Marks().ask(MarkAsked("x", source="email"))
