"""Marks from a viewer (#34): what a live server takes on ``/marks`` and what it refuses, and
that a replay takes none. (The live runs: tests/faults/test_marks_live.py and
test_marks_hostile.py.)"""

from __future__ import annotations

import asyncio
import json
import struct
from typing import Any

import pytest
import websockets

from bridge.sinks.server import ViewerMark, ViewerServer
from bridge.sinks.server.viewer_input import (
    CHANNELS_PER_VIEWER,
    MARK_BYTES,
    MARKS_AT_ONCE,
    REFUSALS_LOGGED,
    STATUSES_AT_ONCE,
    TooManyMarks,
    ViewerInput,
    ViewerInputError,
    mark_content,
)

SUBPROTOCOL = websockets.Subprotocol("foxglove.websocket.v1")
#: What Foxglove Studio's Publish panel fills in for the schema tankviz.Mark (its sample message).
PUBLISH_PANEL_TEMPLATE = {"timestamp": {"sec": 0, "nsec": 0}, "number": 0, "text": "",
                          "category": "", "source": "", "by": ""}


def data(channel: int, content: Any) -> bytes:
    payload = content if isinstance(content, bytes) else json.dumps(content).encode()
    return struct.pack("<BI", 1, channel) + payload


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def viewer(clock: Clock | None = None, *, marks: bool = True) -> ViewerInput:
    return ViewerInput("10.0.0.7:5555", marks, clock or Clock())


def advertised(clock: Clock | None = None) -> ViewerInput:
    v = viewer(clock)
    assert v.text(json.dumps({"op": "advertise", "channels": [
        {"id": 1, "topic": "/marks", "encoding": "json", "schemaName": "tankviz.Mark"}]})) is None
    return v


# --- what a mark holds -------------------------------------------------------------------------

@pytest.mark.parametrize(("content", "taken"), [
    ({"text": "ghost", "category": "radar"}, ("ghost", "radar")),
    ({"text": "  lane lost  "}, ("lane lost", "")),
    ({}, ("mark", "")),  # nothing named: "mark", as Enter in the terminal
    (PUBLISH_PANEL_TEMPLATE, ("mark", "")),  # the fields the server sets are ignored
    ({**PUBLISH_PANEL_TEMPLATE, "text": "Geisterziel ü 🚗", "number": 7}, ("Geisterziel ü 🚗", "")),
    ({"text": "x" * 200, "category": "c" * 40}, ("x" * 200, "c" * 40)),
])
def test_a_mark_is_a_json_object_with_a_text_and_maybe_a_category(
        content: dict[str, Any], taken: tuple[str, str]) -> None:
    assert mark_content(json.dumps(content).encode()) == taken


@pytest.mark.parametrize(("payload", "said"), [
    (b"mark!", "not JSON"),
    (b"\xff\xfe{}", "UTF-8"),
    (b"[1, 2]", "a JSON object"),
    (b'"ghost"', "a JSON object"),
    (b'{"txt": "typo"}', 'not "txt"'),
    (b'{"text": 3}', "text is a string, not int"),
    (b'{"category": ["a"]}', "category is a string"),
    (json.dumps({"text": "x" * 201}).encode(), "text of 201 characters: at most 200"),
    (json.dumps({"category": "c" * 41}).encode(), "category of 41 characters: at most 40"),
    (b'{"text": "two\\nlines"}', "control character (U+000A)"),
    (b'{"text": "x\\u2028y"}', "control character (U+2028)"),
    (b'{"text": "' + b"x" * MARK_BYTES + b'"}', f"bytes: at most {MARK_BYTES:,}"),
])
def test_anything_else_is_refused_saying_why_in_one_line(payload: bytes, said: str) -> None:
    with pytest.raises(ViewerInputError) as refused:
        mark_content(payload)
    assert said in str(refused.value) and "\n" not in str(refused.value)


def test_a_viewers_mark_is_taken_with_its_address() -> None:
    v = advertised()
    assert v.binary(data(1, {"text": "ghost", "category": "radar"})) == ViewerMark(
        "ghost", "radar", "10.0.0.7:5555")


# --- limits --------------------------------------------------------------------------------------

def test_marks_come_a_few_at_once_then_one_a_second() -> None:
    clock = Clock()
    v = advertised(clock)
    taken = [v.binary(data(1, {"text": str(i)})) for i in range(MARKS_AT_ONCE)]
    assert all(taken)
    with pytest.raises(TooManyMarks):
        v.binary(data(1, {}))
    clock.now += 0.5
    with pytest.raises(TooManyMarks):
        v.binary(data(1, {}))
    clock.now += 0.5
    assert v.binary(data(1, {"text": "again"})) is not None
    with pytest.raises(TooManyMarks):
        v.binary(data(1, {}))
    clock.now += 3600  # a quiet hour: a few at once again, no more
    assert all(v.binary(data(1, {})) for _ in range(MARKS_AT_ONCE))
    with pytest.raises(TooManyMarks):
        v.binary(data(1, {}))
    assert v.too_many == 4


def test_a_flood_of_marks_is_told_once_per_run_and_logged_once() -> None:
    clock = Clock()
    v = advertised(clock)
    told = []
    for _run in range(3):
        for _ in range(1000):
            try:
                v.binary(data(1, {}))
            except TooManyMarks as exc:
                told.append(v.refused(exc))
        clock.now += 1.0  # one mark taken now ends the run: the next one is told again
    statuses = [status for status, _ in told]
    lines = [line for _, line in told]
    assert sum(statuses) == 3 and statuses[0] and sum(lines) == 1 and lines[0]
    assert v.refusals == 0  # (the other refusals' lines are not used up)


def test_statuses_come_a_few_at_once_then_one_a_second_and_lines_are_counted() -> None:
    clock = Clock()
    v = viewer(clock)
    told = [v.refused(ViewerInputError("x")) for _ in range(100)]
    assert sum(status for status, _ in told) == STATUSES_AT_ONCE
    assert sum(line for _, line in told) == REFUSALS_LOGGED
    clock.now += 1.0
    assert v.refused(ViewerInputError("x")) == (True, False)


def test_a_mark_too_big_is_refused_before_it_is_read() -> None:
    v = advertised()
    with pytest.raises(ViewerInputError, match="a mark of 1,000,000 bytes: at most 4,096"):
        v.binary(struct.pack("<BI", 1, 1) + b"x" * 1_000_000)
    assert v.mark_budget.tokens == MARKS_AT_ONCE  # (not counted as a mark)


# --- channels ------------------------------------------------------------------------------------

def test_another_topic_is_refused_once_when_published_and_its_messages_ignored() -> None:
    """Advertising is not publishing: Foxglove Studio's 3D panel advertises its click topics
    (/clicked_point, /move_base_simple/goal, /initialpose) to every server that takes
    publishing, and the viewer must not see an error for that. The first message on such a
    channel is refused with one status; the next ones are ignored."""
    v = viewer()
    assert v.text(json.dumps({"op": "advertise", "channels": [
        {"id": 3, "topic": "/cmd_vel", "encoding": "json", "schemaName": "Twist"},
        {"id": 4, "topic": "/marks", "encoding": "cdr", "schemaName": "tankviz.Mark"},
        {"id": 5, "topic": "/marks", "encoding": "json"},  # (no schema name: taken)
        *({"id": 6 + i, "topic": topic, "encoding": "json", "schemaName": "x"}
          for i, topic in enumerate(("/clicked_point", "/move_base_simple/goal",
                                     "/initialpose")))]})) is None
    with pytest.raises(ViewerInputError, match='"/cmd_vel": only /marks is taken here'):
        v.binary(data(3, {"linear": 1}))
    assert v.binary(data(3, {"linear": 1})) is None
    with pytest.raises(ViewerInputError, match='/marks in "cdr": marks are \'json\''):
        v.binary(data(4, b"\x00"))
    assert v.binary(data(4, b"\x00")) is None
    assert v.ignored == 4
    assert v.binary(data(5, {"text": "ok"})) is not None


@pytest.mark.parametrize(("messages", "said"), [
    ([data(9, {})], "a message on channel 9, which it did not advertise"),
    ([b"\x01\x00"], "a binary message of 2 bytes"),
    ([struct.pack("<BIII", 2, 0, 1, 0)], "binary opcode 2: only 1"),
    (['{"op": "advertise", "channels": [{"id": 1, "topic": "/marks", "encoding": "json"}]}'],
     "channel 1 is advertised already"),
    (['{"op": "advertise", "channels": [{"id": "one"}]}'], '"channels" must be a list'),
    (['{"op": "unadvertise", "channelIds": [1]}', data(1, {})], "which it did not advertise"),
    (['{"op": "unadvertise", "channelIds": [8]}'], "channel 8 was not advertised"),
    (['{"op": "unadvertise", "channelIds": "all"}'], '"channelIds" must be a list'),
    (['{"op": "advertise", "channels": ['
      + ",".join(f'{{"id": {i}, "topic": "/x", "encoding": "json"}}' for i in range(2, 40))
      + "]}"], f"at most {CHANNELS_PER_VIEWER} channels"),
    (['{"op": "getParameters", "parameterNames": []}'], '"getParameters" is not taken'),
])
def test_what_is_not_a_mark_on_an_advertised_channel_is_refused(
        messages: list[str | bytes], said: str) -> None:
    v = advertised()
    with pytest.raises(ViewerInputError) as refused:
        for message in messages:
            v.text(message) if isinstance(message, str) else v.binary(message)
    assert said in str(refused.value)


def test_a_server_that_takes_no_marks_refuses_publishing_as_before() -> None:
    v = viewer(marks=False)
    with pytest.raises(ViewerInputError, match="op \"advertise\" is not taken here"):
        v.text('{"op": "advertise", "channels": []}')
    with pytest.raises(ViewerInputError, match="this server takes none"):
        v.binary(data(1, {}))


# --- the server -------------------------------------------------------------------------------

async def mark_once(url: str, content: Any) -> tuple[dict[str, Any], list[dict[str, Any]], str]:
    """Advertise /marks, publish one mark; the serverInfo, the statuses got within a moment
    after (none when it was taken: then the server closes the connection only after the
    mark), and this viewer's address."""
    statuses: list[dict[str, Any]] = []
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL]) as ws:
        info = json.loads(await ws.recv())
        await ws.send(json.dumps({"op": "advertise", "channels": [
            {"id": 1, "topic": "/marks", "encoding": "json", "schemaName": "tankviz.Mark"}]}))
        await ws.send(data(1, content))
        # a subscription to nothing: its status (a warning) says everything before was handled
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 1, "channelId": 999}]}))
        while True:
            message = json.loads(await asyncio.wait_for(ws.recv(), 10.0))
            if message["op"] == "status":
                if "999" in message["message"]:
                    break
                statuses.append(message)
        host, port = ws.local_address[:2]
    return info, statuses, f"{host}:{port}"


def test_a_live_server_hands_each_mark_to_the_drive_with_the_viewers_address() -> None:
    with ViewerServer(port=0) as server:
        marks: list[ViewerMark] = []
        server.on_mark = marks.append
        info, statuses, address = asyncio.run(mark_once(server.url, {"text": "ghost",
                                                                      "category": "radar"}))
    assert "clientPublish" in info["capabilities"] and info["supportedEncodings"] == ["json"]
    assert statuses == []
    assert marks == [ViewerMark("ghost", "radar", address)]


def test_before_the_drive_takes_marks_a_mark_is_refused_with_a_status() -> None:
    with ViewerServer(port=0) as server:
        _, statuses, _ = asyncio.run(mark_once(server.url, {"text": "early"}))
    assert [s["message"] for s in statuses] == ["no drive is taking marks now"]


def test_a_replay_takes_no_marks() -> None:
    with ViewerServer(port=0, server_time=True, mode="replay") as server:
        marks: list[ViewerMark] = []
        server.on_mark = marks.append
        info, statuses, _ = asyncio.run(mark_once(server.url, {"text": "ghost"}))
    assert "clientPublish" not in info["capabilities"] and not info["supportedEncodings"]
    assert ['op "advertise" is not taken here' in statuses[0]["message"],
            "this server takes none" in statuses[1]["message"]] == [True, True]
    assert marks == []


@pytest.mark.slow
def test_a_message_over_a_mebibyte_closes_its_viewers_connection_only() -> None:
    from bridge.sinks.server.viewer_server import VIEWER_MESSAGE_BYTES

    async def too_big(url: str) -> int | None:
        async with websockets.connect(url, subprotocols=[SUBPROTOCOL]) as ws:
            await ws.recv()
            await ws.send(data(1, b"x" * VIEWER_MESSAGE_BYTES))
            try:
                while True:
                    await asyncio.wait_for(ws.recv(), 10.0)
            except websockets.ConnectionClosed as closed:
                return closed.rcvd.code if closed.rcvd else None

    with ViewerServer(port=0) as server:
        marks: list[ViewerMark] = []
        server.on_mark = marks.append
        assert asyncio.run(too_big(server.url)) == 1009  # (websockets: message too big)
        asyncio.run(mark_once(server.url, {"text": "still here"}))
    assert [m.text for m in marks] == ["still here"]
