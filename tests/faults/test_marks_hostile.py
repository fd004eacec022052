"""Hostile marking viewers cannot hurt the live bridge (#34 item 1's proof): a viewer that
publishes on another topic, 1,000 marks a second, marks of 1 MB or garbage gets a status and a
limit, one console line at most for its flood, and nothing of it is recorded beyond its limit;
the recording keeps every frame, the other viewers their scene, and a polite viewer's mark is
taken all the same.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from harness import Viewer, assert_survived
from marker import Marker, client_message, mark_json
from test_marks_live import drive_until_told, until_told

from bridge.sinks.server.viewer_input import MARKS_AT_ONCE, MARKS_PER_S

with contextlib.suppress(ImportError):  # (not in the car's process, livecar.py: it drives)
    from conftest import timeout_scale


def on_time() -> Iterator[tuple[float, Any]]:
    """The simulated ecocar on the laptop's clock, until told."""
    return until_told(0)


async def hostile(url: str) -> dict[str, Any]:
    """Every hostile viewer at once, then a polite one; what each got and was."""
    wait = 30.0 * timeout_scale()
    other, flood, big, junk, polite = [await Marker(url).open() for _ in range(5)]
    # another topic: told once, its messages ignored
    await other.advertise(7, topic="/cmd_vel", schema_name="geometry_msgs/Twist")
    for _ in range(50):
        await other.publish(7, b'{"linear": {"x": 1}}')
    # 1,000 marks a second, for two seconds
    await flood.advertise(1)
    began = time.monotonic()
    for i in range(2000):
        await flood.publish(1, mark_json(f"flood {i}"))
        await asyncio.sleep(max(0.0, began + (i + 1) / 1000 - time.monotonic()))
    flooded_s = time.monotonic() - began
    # marks of 1 MB
    await big.advertise(1)
    for _ in range(3):
        await big.publish(1, mark_json("x" * 1_000_000))
    # garbage: binary junk, a mark that is no JSON, a message on a channel never advertised
    await junk.advertise(2)
    for garbage in (b"\x01", b"\x02" + bytes(40), client_message(2, b"\xff not json"),
                    client_message(9, mark_json("nowhere")), bytes(range(256))):
        await junk.ws.send(garbage)
    await other.until(lambda: len(other.statuses) >= 1, wait)
    await big.until(lambda: len(big.statuses) >= 3, wait)
    await junk.until(lambda: len(junk.statuses) >= 5, wait)
    await flood.until(lambda: len(flood.statuses) >= 1, wait)
    # a polite viewer, marking while (and after) the others were at it
    await polite.subscribe("/log")
    await polite.advertise(1)
    await polite.publish(1, mark_json("polite", "test"))
    await polite.until(lambda: bool(polite.logged("polite [test]")), wait)
    for marker in (other, flood, big, junk, polite):
        assert not marker.closed, marker.address  # (no viewer was thrown out)
        await marker.close()
    return {"other": other, "flood": flood, "big": big, "junk": junk, "polite": polite,
            "flooded_s": flooded_s}


@pytest.mark.slow
def test_hostile_marking_viewers_get_a_status_and_a_limit_and_every_frame_is_recorded(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    car, stop = drive_until_told(tmp_path, monkeypatch, f"{__file__}:on_time")
    viewer = Viewer(car.url)
    try:
        car.when("Ctrl+C")
        got = asyncio.run(hostile(car.url))
        ended = time.time()
    finally:
        stop.touch()
    recording = assert_survived(car, viewer, fault_ended=ended, on_log="polite [test]")
    other, flood, big, junk, polite = (got[k] for k in ("other", "flood", "big", "junk",
                                                         "polite"))

    assert [s["message"] for s in other.statuses] == [
        '"/cmd_vel": only /marks is taken here (marks); this channel\'s messages are ignored']
    assert "/cmd_vel" not in recording
    size = len(mark_json("x" * 1_000_000))
    assert [s["message"] for s in big.statuses] == [
        f"a mark of {size:,} bytes: at most 4,096"] * 3
    said = [s["message"] for s in junk.statuses]
    assert len(said) == 5 and "a message on channel 9, which it did not advertise" in said
    assert any("not JSON" in text for text in said) and any("opcode 2" in text for text in said)
    # the flood: a limit, told once per run of refused marks
    flooded = [m for m in recording["/marks"] if m.by == flood.address]
    most = MARKS_AT_ONCE + MARKS_PER_S * got["flooded_s"] + 1
    assert MARKS_AT_ONCE <= len(flooded) <= most, (len(flooded), most)
    assert all(s["message"].startswith("too many marks") for s in flood.statuses)
    assert 1 <= len(flood.statuses) <= len(flooded) - MARKS_AT_ONCE + 1
    # one console line for the flood; one for each other refusal
    lines = [text for _, text in car.lines if f"viewer {flood.address}:" in text]
    assert len(lines) == 1 and "too many marks" in lines[0], lines
    for marker, count in ((other, 1), (big, 3), (junk, 5)):
        assert sum(f"viewer {marker.address}:" in text for _, text in car.lines) == count
    # nothing else was marked; the polite viewer's mark was taken
    assert {m.by for m in recording["/marks"]} == {flood.address, polite.address}
    assert [m.text for m in recording["/marks"] if m.by == polite.address] == ["polite"]
    assert [m.number for m in recording["/marks"]] == list(range(1, len(recording["/marks"]) + 1))
