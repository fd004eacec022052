"""Marks from the car (#34): a profile's ``[marks]`` rule marks the drive on its rising edge, at
the time of the frame that makes it true, in convert, replay and live alike."""

from __future__ import annotations

import re
import threading
from collections.abc import Iterable
from functools import partial
from pathlib import Path
from typing import Any

import can
import pytest
from conftest import timeout_scale
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from waiting import wait_for

from bridge.cli import main
from bridge.frame import NS, Frame
from bridge.io.buses import BusSpec
from bridge.io.drives import ArchiveSource
from bridge.packed import PackedFrames
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline.drive import Drive, load_stages
from bridge.pipeline.live_engine import Live
from bridge.pipeline.marks import MarkAsked, MarkWatch
from bridge.pipeline.pipeline import Pipeline
from bridge.profile.expr import parse
from bridge.profile.model import MarkRule, ProfileError
from bridge.sim.highway import BUTTON_PRESSES, CAR_BUS, highway_database, simulate_highway
from bridge.sim.scenario import DEFAULT_START_NS
from bridge.sinks.base import Serialized, Sink
from bridge.topics import LOG_TOPIC, MARKS_TOPIC

T0 = 46_411_900_000_000  # a car's clock: seconds since it booted
MS = 1_000_000
STEER = highway_database("car").get_message_by_name("STEER_ANGLE_SENSOR")
SPEED = highway_database("car").get_message_by_name("SPEED")


def rule(when: str, reads: Iterable[tuple[str, str, str]], text: str = "",
         category: str = "") -> MarkRule:
    return MarkRule(parse(when), tuple(reads), text or when, category)


BUTTON = rule("STEER_BUTTON == 1", [("STEER_BUTTON", "STEER_ANGLE_SENSOR", "STEER_BUTTON")])


def presses(watch: MarkWatch, sequence: Iterable[tuple[str, dict[str, Any]]]) -> list[int]:
    """The frames (their index in ``sequence``) at which the watch asks for a mark."""
    return [i for i, (message, signals) in enumerate(sequence)
            if watch.on_message(message, signals)]


def steer(button: int) -> tuple[str, dict[str, Any]]:
    return "STEER_ANGLE_SENSOR", {"STEER_ANGLE": 1.5, "STEER_BUTTON": button}


# ---------------------------------------------------------------------------------------------
# The rising edge
# ---------------------------------------------------------------------------------------------


def test_a_held_button_marks_once_and_a_second_press_again() -> None:
    watch = MarkWatch([BUTTON])
    assert watch.messages == {"STEER_ANGLE_SENSOR"}
    held = [steer(b) for b in (0, 0, 1, 1, 1, 1, 0, 0, 1, 0, 1, 1)]
    assert presses(watch, held) == [2, 8, 10]


def test_the_first_frame_marks_when_the_rule_holds_at_once() -> None:
    """From no value yet to true is a rising edge: the button held as the drive starts."""
    assert presses(MarkWatch([BUTTON]), [steer(1), steer(1), steer(0)]) == [0]


def test_a_rule_whose_signal_never_comes_never_marks() -> None:
    watch = MarkWatch([BUTTON])
    assert presses(watch, [("STEER_ANGLE_SENSOR", {"STEER_ANGLE": 1.5})] * 5) == []
    # a frame without the signal (a short frame, another page) keeps its latest value: no
    # second mark while the button stays pressed
    assert presses(watch, [steer(1), ("STEER_ANGLE_SENSOR", {}), steer(1), steer(0),
                           ("STEER_ANGLE_SENSOR", {}), steer(1)]) == [0, 5]


def test_a_rule_over_two_messages_reads_the_latest_of_each() -> None:
    both = rule("STEER_ANGLE_SENSOR.STEER_BUTTON == 1 and SPEED.SPEED > 50",
                [("STEER_ANGLE_SENSOR.STEER_BUTTON", "STEER_ANGLE_SENSOR", "STEER_BUTTON"),
                 ("SPEED.SPEED", "SPEED", "SPEED")], text="pressed at speed", category="driver")
    watch = MarkWatch([both])
    sequence = [steer(1), ("SPEED", {"SPEED": 30.0}), ("SPEED", {"SPEED": 60.0}), steer(1),
                steer(0), ("SPEED", {"SPEED": 20.0}), steer(1), ("SPEED", {"SPEED": 70.0})]
    assert presses(watch, sequence) == [2, 7]
    watch = MarkWatch([both])
    assert watch.on_message("SPEED", {"SPEED": 60.0}) == []
    assert watch.on_message(*steer(1)) == [MarkAsked(
        "pressed at speed", "driver", "car",
        "STEER_ANGLE_SENSOR.STEER_BUTTON == 1 and SPEED.SPEED > 50")]


def test_each_rule_has_its_own_edge() -> None:
    speeding = rule("SPEED > 100", [("SPEED", "SPEED", "SPEED")])
    watch = MarkWatch([BUTTON, speeding])
    assert watch.on_message("SPEED", {"SPEED": 120.0}) == [
        MarkAsked("SPEED > 100", "", "car", "SPEED > 100")]
    assert watch.on_message(*steer(1)) == [
        MarkAsked("STEER_BUTTON == 1", "", "car", "STEER_BUTTON == 1")]
    assert watch.on_message("SPEED", {"SPEED": 130.0}) == []


# ---------------------------------------------------------------------------------------------
# The pipeline: every frame of the messages a rule reads, whichever way frames come
# ---------------------------------------------------------------------------------------------


class Collect(Sink):
    def __init__(self) -> None:
        self.messages: list[Serialized] = []

    def on_messages(self, messages: Iterable[Serialized], /) -> None:
        self.messages.extend(messages)

    def marks(self) -> list[tuple[int, Mark]]:
        return [(m.t_ns, Mark.FromString(m.payload)) for m in self.messages
                if m.topic == MARKS_TOPIC]


def button_frames(pattern: str, *, every_ms: int = 10, start_ns: int = T0) -> list[Frame]:
    """STEER_ANGLE_SENSOR every ``every_ms`` (the button: each character of ``pattern``, "-"
    released, "X" pressed), with SPEED frames between them (messages no rule reads)."""
    frames = []
    for k, c in enumerate(pattern):
        t = start_ns + k * every_ms * MS
        data = STEER.encode({"STEER_ANGLE": 0, "STEER_FRACTION": 0, "STEER_RATE": 0,
                             "STEER_BUTTON": int(c == "X")})
        frames.append(Frame(t, CAR_BUS, STEER.frame_id, data, dlc=8))
        frames.append(Frame(t + 3 * MS, CAR_BUS, SPEED.frame_id,
                            SPEED.encode({"SPEED": 100.0, "CHECKSUM": 0}), dlc=8))
    return frames


def through(frames: list[Frame], how: str, profile: str = "highway") -> list[tuple[int, Mark]]:
    stages = load_stages([], profile)
    collect = Collect()
    drive = Drive(stages, [collect])
    pipeline = drive.pipeline
    if how == "process":
        for frame in frames:
            pipeline.process(frame)
    elif how == "process_many":
        for k in range(0, len(frames), 7):
            pipeline.process_many(frames[k:k + 7])
    else:
        for k in range(0, len(frames), 50):
            pipeline.process_packed(PackedFrames.from_frames(frames[k:k + 50]))
    drive.finish()
    return collect.marks()


@pytest.mark.parametrize("how", ["process", "process_many", "process_packed"])
def test_the_pipeline_marks_at_the_frame_that_makes_the_rule_true(how: str) -> None:
    # a 20 ms press between two scene ticks (50 ms apart) marks too
    pattern = "---XXXXXX----XX---------X"
    marks = through(button_frames(pattern), how)
    expected = [T0 + k * 10 * MS for k in (3, 13, 24)]
    assert [t for t, _ in marks] == expected
    assert [m.timestamp.ToNanoseconds() for _, m in marks] == expected
    assert [(m.number, m.text, m.source, m.by) for _, m in marks] == [
        (n, "STEER_BUTTON == 1", "car", "STEER_BUTTON == 1") for n in (1, 2, 3)]


def test_a_pipeline_without_marks_rules_has_no_marks_and_no_marks_channels() -> None:
    decoder, profile = load_stages([], "ecocar")
    pipeline = Pipeline(decoder, profile=profile)
    assert pipeline.marks is None
    assert "/marks" not in {c.topic for c in pipeline.channels(["can0"])}
    decoder, profile = load_stages([], "highway")
    pipeline = Pipeline(decoder, profile=profile)
    assert pipeline.marks is not None
    assert {"/marks", "/scene/marks"} <= {c.topic for c in pipeline.channels(["can0"])}


def test_marks_from_the_car_and_from_elsewhere_share_the_numbers() -> None:
    stages = load_stages([], "highway")
    collect = Collect()
    drive = Drive(stages, [collect])
    pipeline = drive.pipeline
    assert pipeline.marks is not None
    frames = button_frames("--XX--XX")
    for frame in frames[:6]:
        pipeline.process(frame)
    pipeline.marks.ask(MarkAsked("ghost", "radar"))
    pipeline.emit(pipeline.marks.take(frames[5].timestamp_ns))
    for frame in frames[6:]:
        pipeline.process(frame)
    drive.finish()
    assert [(m.number, m.source) for _, m in collect.marks()] == [
        (1, "car"), (2, "viewer"), (3, "car")]


# ---------------------------------------------------------------------------------------------
# The simulated highway car: its wheel button, pressed at known times
# ---------------------------------------------------------------------------------------------


def first_pressed(frames: Iterable[Frame]) -> list[int]:
    """The time of each frame that says the button is pressed after one that says it is not."""
    out, before = [], False
    for f in frames:
        if f.bus == CAR_BUS and f.arbitration_id == STEER.frame_id:
            values: Any = STEER.decode(f.data)
            pressed = values["STEER_BUTTON"] == 1
            if pressed and not before:
                out.append(f.timestamp_ns)
            before = pressed
    return out


def read_marks(path: Path) -> tuple[list[tuple[int, Any]], list[str]]:
    with path.open("rb") as f:
        decoded = list(make_reader(f, decoder_factories=[DecoderFactory()])
                       .iter_decoded_messages(topics=[MARKS_TOPIC, LOG_TOPIC]))
    marks = [(m.log_time, p) for _, c, m, p in decoded if c.topic == MARKS_TOPIC]
    lines = [p.message for _, c, _, p in decoded
             if c.topic == LOG_TOPIC and p.message.startswith("MARK")]
    return marks, lines


@pytest.fixture(scope="module")
def highway_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """42 s of the simulated highway drive: both presses of the button."""
    log = tmp_path_factory.mktemp("highway") / "highway.blf"
    assert main(["simulate", "--car", "highway", "-o", str(log), "--duration", "42"]) == 0
    return log


@pytest.mark.slow
def test_converting_the_simulated_highway_drive_marks_each_press_of_the_wheel_button(
        tmp_path: Path, highway_log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    output = tmp_path / "highway.mcap"
    assert main(["convert", str(highway_log), "-o", str(output), "--profile", "highway"]) == 0
    capsys.readouterr()
    marks, lines = read_marks(output)
    pressed = first_pressed(simulate_highway(duration_s=42.0))
    assert [t for t, _ in marks] == pressed
    for (t, mark), (start, _) in zip(marks, BUTTON_PRESSES, strict=True):
        # the first STEER_ANGLE_SENSOR of the press: measured at its start, sent within 5.2 ms
        assert 0 <= t - DEFAULT_START_NS - round(start * NS) < 5.2 * MS
        assert mark.timestamp.ToNanoseconds() == t
    assert [(m.number, m.text, m.category, m.source, m.by) for _, m in marks] == [
        (n, "STEER_BUTTON == 1", "", "car", "STEER_BUTTON == 1") for n in (1, 2)]
    assert lines == ["MARK 1: STEER_BUTTON == 1 (car)", "MARK 2: STEER_BUTTON == 1 (car)"]


@pytest.mark.slow
def test_profile_check_says_what_the_rules_read_and_which_marks_a_log_made(
        highway_log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["profile", "check", "highway", str(highway_log)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "marks: when STEER_BUTTON == 1 (STEER_ANGLE_SENSOR.STEER_BUTTON)" in out
    first = min(f.timestamp_ns for f in simulate_highway(duration_s=0.1))
    at = [(t - first) / NS for t in first_pressed(simulate_highway(duration_s=42.0))]
    made = out.index("marks: 2 made (s after the first frame):")
    assert out[made + 1:made + 4] == [f"  MARK 1: STEER_BUTTON == 1 (car) at {at[0]:.3f} s",
                                      f"  MARK 2: STEER_BUTTON == 1 (car) at {at[1]:.3f} s",
                                      "lateral sign:"]


def test_profile_check_lists_the_first_marks_of_a_rule_true_too_often(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "highway.blf"
    assert main(["simulate", "--car", "highway", "-o", str(log), "--duration", "2"]) == 0
    profile = tmp_path / "car.toml"
    profile.write_text(HEAD + '[[marks]]\nwhen = "STEER_BUTTON == 1"\n'
                       '[[marks]]\nwhen = "KINEMATICS.YAW_RATE < 0"\ntext = "noise"\n'
                       'category = "yaw"\n')
    assert main(["profile", "check", str(profile)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[-2:] == ["marks: when STEER_BUTTON == 1 (STEER_ANGLE_SENSOR.STEER_BUTTON)",
                        "marks: when KINEMATICS.YAW_RATE < 0 (KINEMATICS.YAW_RATE), "
                        "text 'noise' [yaw]"]
    assert main(["profile", "check", str(profile), str(log)]) == 0
    out = capsys.readouterr().out.splitlines()
    made = next(i for i, line in enumerate(out) if line.startswith("marks: ") and "made" in line)
    assert re.fullmatch(r"marks: \d\d+ made \(s after the first frame\):", out[made])
    assert all(re.fullmatch(r"  MARK \d+: noise \[yaw\] \(car KINEMATICS.YAW_RATE < 0\) at "
                            r"[01]\.\d\d\d s", line) for line in out[made + 1:made + 11])
    assert re.fullmatch(r"  … \d+ more", out[made + 11])
    assert main(["profile", "check", "highway", str(log)]) == 0  # no press in 2 s
    assert "marks: none made: no rule became true" in capsys.readouterr().out.splitlines()


# ---------------------------------------------------------------------------------------------
# The profile: [marks] and [[marks]], checked against the databases
# ---------------------------------------------------------------------------------------------

HEAD = '[profile]\ndatabases = { can0 = ["highway_car.dbc"], can1 = ["highway_radar.dbc"] }\n'


def load(tmp_path: Path, body: str) -> Any:
    path = tmp_path / "car.toml"
    path.write_text(HEAD + body if body.startswith("[") else body + HEAD)  # (top-level keys first)
    return load_stages([], path)[1]


def test_one_rule_or_several_with_their_text_and_category(tmp_path: Path) -> None:
    profile = load(tmp_path, '[marks]\nwhen = "STEER_BUTTON == 1"\n')
    (mark,) = profile.marks
    assert (mark.when, mark.text, mark.category) == ("STEER_BUTTON == 1", "STEER_BUTTON == 1", "")
    assert mark.reads == (("STEER_BUTTON", "STEER_ANGLE_SENSOR", "STEER_BUTTON"),)
    profile = load(tmp_path, '[[marks]]\nwhen = "STEER_BUTTON == 1"\ntext = "look here"\n'
                             'category = "driver"\n[[marks]]\n'
                             'when = "TRACK_A_0.VALID == 1 and TRACK_A_0.LONG_DIST < 10"\n')
    first, second = profile.marks
    assert (first.text, first.category) == ("look here", "driver")
    assert second.messages == {"TRACK_A_0"}
    assert "STEER_ANGLE_SENSOR" in profile.message_names()


@pytest.mark.parametrize(("body", "error"), [
    ('[marks]\nwhen = "STEER_BUTON == 1"\n',
     "marks.when: rule 'STEER_BUTON == 1': column 1: no signal 'STEER_BUTON' in the databases; "
     "closest: STEER_BUTTON"),
    ('[marks]\nwhen = "VALID == 1 and LONG_DIST < 10"\n',
     "marks.when: rule 'VALID == 1 and LONG_DIST < 10': column 1: signal 'VALID' is in "
     "TRACK_A_0 and TRACK_A_1: write Message.Signal"),
    ('[marks]\nwhen = "STEER.STEER_BUTTON == 1"\n',
     "marks.when: rule 'STEER.STEER_BUTTON == 1': column 1: no message 'STEER' in the databases"),
    ('[marks]\nwhen = "STEER_ANGLE_SENSOR.BUTTON == 1"\n',
     "marks.when: rule 'STEER_ANGLE_SENSOR.BUTTON == 1': column 1: no signal 'BUTTON' in "
     "STEER_ANGLE_SENSOR"),
    ('[[marks]]\nwhen = "STEER_BUTTON == 1"\n[[marks]]\nwhen = "VALID = 1"\n',
     "marks[2].when: rule 'VALID = 1': column 7: "),
    ('[marks]\nwhen = "1 == 1"\n',
     "marks.when: rule '1 == 1' reads no signal: it would never mark"),
    ('[marks]\ntext = "x"\n', "marks: missing required key 'when'"),
    ('[marks]\nwhen = "STEER_BUTTON == 1"\ncolour = "red"\n', "marks.colour: unknown key"),
    ('[marks]\nwhen = 1\n', "marks.when: expected a string, got a number (1)"),
    ('marks = "STEER_BUTTON == 1"\n', "marks: expected a table, got a string"),
    ('marks = ["STEER_BUTTON == 1"]\n', "marks[1]: expected a table, got a string"),
])
def test_a_wrong_marks_rule_is_one_line_naming_it(tmp_path: Path, body: str, error: str) -> None:
    with pytest.raises(ProfileError) as caught:
        load(tmp_path, body)
    message = str(caught.value)
    assert message.startswith(f"{tmp_path / 'car.toml'}: {error}"), message
    assert "\n" not in message


def test_a_wrong_signal_in_marks_stops_convert_with_one_error_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    profile = tmp_path / "car.toml"
    profile.write_text(HEAD + '[marks]\nwhen = "STEER_BUTON == 1"\n')
    log = tmp_path / "highway.blf"
    assert main(["simulate", "--car", "highway", "-o", str(log), "--duration", "0.2"]) == 0
    capsys.readouterr()
    code = main(["convert", str(log), "-o", str(tmp_path / "o.mcap"), "--profile", str(profile)])
    err = capsys.readouterr().err
    assert code == 1
    assert err.splitlines() == [
        f"error: {profile}: marks.when: rule 'STEER_BUTON == 1': column 1: no signal "
        "'STEER_BUTON' in the databases; closest: STEER_BUTTON"]
    assert not (tmp_path / "o.mcap").exists()


# ---------------------------------------------------------------------------------------------
# Live: the button on a bus
# ---------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_live_marks_the_drive_when_the_button_is_pressed_on_the_bus(tmp_path: Path) -> None:
    channel = f"marks-car-{threading.get_ident()}"
    said: list[str] = []
    live = Live([BusSpec("can0", "virtual", channel)], load_stages([], "highway"),
                drives=tmp_path, say=said.append)
    live.start()
    runner = threading.Thread(target=live.run)
    runner.start()
    wait = timeout_scale() * 10
    try:
        with can.Bus(interface="virtual", channel=channel) as bus:
            def read(frames: int) -> bool:
                return live.pipeline.frames >= frames

            def send(button: int) -> None:
                bus.send(can.Message(arbitration_id=STEER.frame_id, is_extended_id=False,
                                     data=STEER.encode({"STEER_ANGLE": 0, "STEER_FRACTION": 0,
                                                        "STEER_RATE": 0,
                                                        "STEER_BUTTON": button})))

            for k, button in enumerate((0, 0, 1, 1, 1, 0), 1):
                send(button)  # each frame read before the next is sent
                assert wait_for(partial(read, k), wait)
            assert wait_for(lambda: len(live.marks.made) == 1, wait)
    finally:
        live.stop()
        runner.join(wait)
    (drive,) = tmp_path.glob("*.mcap")
    marks, lines = read_marks(drive)
    pressed = first_pressed(ArchiveSource(drive))
    assert len(pressed) == 1
    assert [t for t, _ in marks] == pressed
    ((_, mark),) = marks
    assert (mark.number, mark.source, mark.by) == (1, "car", "STEER_BUTTON == 1")
    assert lines == ["MARK 1: STEER_BUTTON == 1 (car)"]
    assert [line for line in said if "MARK" in line] == lines  # echoed on the console once
