"""A DBC message whose topic would be one of tankviz's own (#33 item 1): a message named
``frames``, ``ids`` or ``unknown`` would take ``/can/<bus>/frames`` (the raw frames),
``/can/<bus>/ids`` or ``/can/<bus>/unknown`` (bring-up); on a bus named ``bits`` a message
``labels`` would take ``/can/bits/labels``. Its signals go to ``/can/<bus>/msg/<Message>``
instead, said in one warning at the start and kept in the drive's warnings; convert, re-derive
and live all write both. Topics are case-sensitive: ``Frames`` is no clash.

Two buses whose names make one topic segment (``can.0`` and ``can_0``) would share their topics:
convert says so in a warning, live refuses to start.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest
from harness import recorded, start
from mcap.reader import make_reader

from bridge.cli import main
from bridge.decode.codec import Decoded
from bridge.decode.database import load_database
from bridge.decode.decoder import Decoder
from bridge.frame import Frame
from bridge.topics import (
    BITS_LABELS_TOPIC,
    BITS_TOPIC,
    frames_topic,
    ids_topic,
    message_topic,
    unknown_topic,
)

T0 = 1_700_000_000.0
CLASH_DBC = """VERSION ""
BS_:
BU_: Door
BO_ 1056 frames: 8 Door
 SG_ Open : 0|8@1+ (1,0) [0|255] "" Door
BO_ 1057 ids: 8 Door
 SG_ Pos : 0|8@1+ (1,0) [0|255] "" Door
BO_ 1058 unknown: 8 Door
 SG_ Angle : 0|8@1+ (1,0) [0|255] "" Door
BO_ 1059 Frames: 8 Door
 SG_ Tilt : 0|8@1+ (1,0) [0|255] "" Door
BO_ 1060 labels: 8 Door
 SG_ Text : 0|8@1+ (1,0) [0|255] "" Door
"""
IDS = (0x420, 0x421, 0x422, 0x423, 0x424)
#: the messages that clash on every bus, and the file's warnings about them
MOVED = {"frames": "tankviz's raw frames", "ids": "bring-up's ids", "unknown":
         "bring-up's unknown ids"}


def expected_warnings(path: Path) -> list[str]:
    return [f"{path}: message {name} (0x{0x420 + i:X}) would take {what} topic "
            f"/can/<bus>/{name}: its signals go to /can/<bus>/msg/{name}"
            for i, (name, what) in enumerate(MOVED.items())]


def topics_of(path: Path) -> dict[str, str]:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}


def warnings_of(path: Path) -> list[str]:
    with path.open("rb") as f:
        for record in make_reader(f).iter_metadata():
            if record.name == "tankviz":
                found: list[str] = json.loads(record.metadata["warnings"])
                return found
    return []


def test_message_topic_never_is_one_of_tankviz_own() -> None:
    for bus in ("can0", "bits", "radar.front", "x"):
        own = {frames_topic(bus), ids_topic(bus), unknown_topic(bus), BITS_TOPIC,
               BITS_LABELS_TOPIC}
        for name in ("frames", "ids", "unknown", "labels", "bits", "msg", "Frames", "Speed"):
            assert message_topic(bus, name) not in own
    assert message_topic("can0", "frames") == "/can/can0/msg/frames"
    assert message_topic("can0", "Frames") == "/can/can0/Frames"  # topics are case-sensitive
    assert message_topic("can0", "labels") == "/can/can0/labels"
    assert message_topic("bits", "labels") == "/can/bits/msg/labels"
    assert message_topic("can0", "Speed") == "/can/can0/Speed"


def test_a_clashing_message_is_warned_about_when_its_database_loads(tmp_path: Path) -> None:
    path = tmp_path / "clash.dbc"
    path.write_text(CLASH_DBC)
    assert list(load_database(path).warnings) == expected_warnings(path)
    decoder = Decoder({None: [load_database(path)]})
    assert {c.message.name: c.topic for c in decoder.codecs_for("bits")}["labels"] == (
        "/can/bits/msg/labels")


def clash_frames(n: int = 10) -> list[can.Message]:
    return [can.Message(timestamp=T0 + i / 100, arbitration_id=id_, data=bytes([i] * 8),
                        channel=0, is_extended_id=False) for i in range(n) for id_ in IDS]


def test_convert_moves_the_message_and_keeps_every_raw_frame(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dbc = tmp_path / "clash.dbc"
    dbc.write_text(CLASH_DBC)
    log = tmp_path / "clash.blf"
    with can.Logger(str(log)) as writer:
        for m in clash_frames():
            writer.on_message_received(m)
    out = tmp_path / "clash.mcap"
    assert main(["convert", str(log), "-o", str(out), "--dbc", str(dbc)]) == 0
    err = capsys.readouterr().err
    assert [line for line in err.splitlines() if line.startswith("warning:")] == [
        f"warning: {text}" for text in expected_warnings(dbc)]
    topics = topics_of(out)
    assert topics["/can/can0/frames"] == "tankviz.CanFrameBlock"
    assert topics["/can/can0/ids"] == "tankviz.CanIds"
    assert topics["/can/can0/msg/frames"] == "tankviz.dbc.clash.frames"
    assert topics["/can/can0/msg/ids"] == "tankviz.dbc.clash.ids"
    assert topics["/can/can0/msg/unknown"] == "tankviz.dbc.clash.unknown"
    assert topics["/can/can0/Frames"] == "tankviz.dbc.clash.Frames"
    assert topics["/can/can0/labels"] == "tankviz.dbc.clash.labels"
    assert warnings_of(out) == expected_warnings(dbc)
    frames = recorded_frames(out)
    assert frames == 50
    # Re-derived from the drive: the same topics, the same warnings (the attached database's).
    again = tmp_path / "again.mcap"
    assert main(["convert", str(out), "-o", str(again)]) == 0
    assert topics_of(again) == topics
    assert recorded_frames(again) == 50


def recorded_frames(path: Path) -> int:
    from bridge.pb.can_frame_pb2 import CanFrameBlock

    with path.open("rb") as f:
        return sum(len(CanFrameBlock.FromString(m.data).frames)
                   for _, _, m in make_reader(f).iter_messages(topics=["/can/can0/frames"]))


def test_convert_warns_when_two_buses_share_a_topic_segment(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "two.log"
    log.write_text("(1700000000.000000) can.0 100#0011223344556677\n"
                   "(1700000000.010000) can_0 100#0011223344556677\n"
                   "(1700000000.020000) can-0 420#0011223344556677\n")
    dbc = tmp_path / "ok.dbc"
    dbc.write_text(CLASH_DBC.split("BO_ 1057")[0].replace("frames", "Door"))
    out = tmp_path / "two.mcap"
    assert main(["convert", str(log), "-o", str(out), "--dbc", str(dbc)]) == 0
    expected = ("buses can-0, can.0 and can_0 share the topics /can/can_0/...: their decoded "
                "messages are mixed there (each raw frame keeps its bus)")
    assert expected in capsys.readouterr().out
    assert expected in warnings_of(out)


def live_script() -> Iterator[tuple[float, Any]]:
    now = time.time_ns()
    for i in range(20):
        for id_ in IDS:
            yield i * 0.01, Frame(now + i * 10_000_000, "can0", id_, bytes([i] * 8))


@pytest.mark.slow
def test_live_moves_the_message_and_records_every_raw_frame(tmp_path: Path) -> None:
    dbc = tmp_path / "clash.dbc"
    dbc.write_text(CLASH_DBC)
    car = start(tmp_path, f"{__file__}:live_script", "--dbc", str(dbc), "--no-server",
                "--min-free", "0")
    assert car.wait() == 0, car.output
    assert "Traceback" not in car.output, car.output
    warned = [line for line in car.output.splitlines() if line.startswith("warning:")]
    assert warned == [f"warning: {text}" for text in expected_warnings(dbc)]
    recording = recorded(car.drives)
    assert sum(len(b.frames) for b in recording["/can/can0/frames"]) == 100
    assert len(recording["/can/can0/msg/frames"]) == 20
    assert len(recording["/can/can0/msg/ids"]) == 20
    assert len(recording["/can/can0/Frames"]) == 20
    drive = sorted(car.drives.glob("*.mcap"))[0]
    assert warnings_of(drive) == expected_warnings(dbc)


@pytest.mark.slow
def test_live_refuses_two_buses_that_share_a_topic_segment(tmp_path: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-m", "bridge", "live", "--bus", f"can.0=virtual:a-{tmp_path.name}",
         "--bus", f"can_0=virtual:b-{tmp_path.name}", "--no-server", "--drives",
         str(tmp_path / "drives"), "--min-free", "0", "--for", "0.5"],
        capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 1, run.stderr
    assert run.stderr.strip() == ("error: --bus can.0 and --bus can_0: would share the topics "
                                  "/can/can_0/...: rename one")


NAMES_KCD = """<NetworkDefinition xmlns="http://kayak.2codeornot2code.org/1.0">
  <Document/>
  <Bus name="b">
    <Message id="0x100" name="A-B" length="8"><Signal name="T" offset="0" length="8"/></Message>
    <Message id="0x101" name="A_B" length="8"><Signal name="S" offset="0" length="16"/></Message>
    <Message id="0x102" name="frames" length="8"><Signal name="S" offset="0" length="8"/></Message>
    <Message id="0x103" name="msg/frames" length="8"><Signal name="R" offset="8" length="8"/>
    </Message>
  </Bus>
</NetworkDefinition>
"""


def test_names_that_differ_only_by_characters_made_safe_keep_apart(tmp_path: Path) -> None:
    """A KCD may name messages A-B and A_B: their protobuf types were one (the second's never
    built: every frame of it a decode error); and a message msg/frames took the topic that
    frames moves to."""
    path = tmp_path / "names.kcd"
    path.write_text(NAMES_KCD)
    decoder = Decoder({None: [load_database(path)]})
    out = {}
    for id_ in (0x100, 0x101, 0x102, 0x103):
        decoded = decoder.decode(Frame(0, "can0", id_, bytes(range(1, 9))))
        assert isinstance(decoded, Decoded), decoder.stats.last_error
        out[decoded.codec.message.name] = (decoded.codec.topic, decoded.codec.schema.full_name,
                                           decoded.codec.schema.parse(decoded.payload))
    assert out == {
        "A-B": ("/can/can0/A-B", "tankviz.dbc.names.A_B", {"T": 1}),
        "A_B": ("/can/can0/A_B", "tankviz.dbc.names.A_B_101", {"S": 0x0201}),
        "frames": ("/can/can0/msg/frames", "tankviz.dbc.names.frames", {"S": 1}),
        "msg/frames": ("/can/can0/msg/msg/frames", "tankviz.dbc.names.msg_frames", {"R": 2}),
    }
