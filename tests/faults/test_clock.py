"""A car's clock steps (an NTP correction at boot, an adapter reset, a logger with a wrong date):
live and convert detect the step, re-base their scene ticks, health windows and lifetimes at
once, say so on ``/log``, and note it in the drive's metadata; every frame keeps its own stamp.

And a live pipeline that falls behind (a loaded machine) still records every scene tick of log
time; the end-of-run line says which viewers lost which topics.
"""

from __future__ import annotations

import itertools
import json
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
from harness import Viewer, assert_survived, start, steady
from mcap.reader import make_reader

from bridge.decode.codec import Decoded
from bridge.frame import NS, Frame
from bridge.pipeline.convert import convert
from bridge.pipeline.drive import Drive, load_stages
from bridge.sinks.base import Serialized, Sink
from bridge.topics import HEALTH_TOPIC, scene_topic

PROFILES = Path(__file__).resolve().parent.parent / "profiles"
T0 = 1_700_000_000.0  # an absolute start time, in python-can's float seconds
PERIOD_NS = NS // 20  # the default scene rate
MS_NS = 1_000_000
YEAR_NS = 365 * 24 * 3600 * NS


# --- what a recording holds --------------------------------------------------------------------

def log_times(drives: Path | Iterable[Path]) -> tuple[dict[str, list[int]], dict[str, Any]]:
    """The log time of every message by topic, and the ``tankviz`` metadata (of the last
    file), of every MCAP in ``drives`` (a folder or files)."""
    paths = sorted(drives.glob("*.mcap")) if isinstance(drives, Path) else list(drives)
    times: dict[str, list[int]] = {}
    metadata: dict[str, Any] = {}
    for path in paths:
        with path.open("rb") as f:
            reader = make_reader(f)
            for _, channel, msg in reader.iter_messages(log_time_order=False):
                times.setdefault(channel.topic, []).append(msg.log_time)
            for record in reader.iter_metadata():
                if record.name == "tankviz":
                    metadata = {k: _json(v) for k, v in record.metadata.items()}
    return times, metadata


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text  # a string value


def segments(stamps: Iterable[int], gap_ns: int = NS) -> list[tuple[int, int]]:
    """The runs of frame stamps without a gap of ``gap_ns``: the timelines of a stepped clock."""
    ordered = sorted(stamps)
    out = [[ordered[0], ordered[0]]]
    for t in ordered[1:]:
        if t - out[-1][1] > gap_ns:
            out.append([t, t])
        out[-1][1] = t
    return [(a, b) for a, b in out]


def missing_ticks(ticks: Iterable[int], lo: int, hi: int) -> list[int]:
    """The scene ticks of log time between two frame stamps that are not in ``ticks``."""
    have = set(ticks)
    first = (lo // PERIOD_NS + 1) * PERIOD_NS
    return [t for t in range(first, hi - PERIOD_NS, PERIOD_NS) if t not in have]


def assert_every_tick_in_each_timeline(times: dict[str, list[int]]) -> None:
    """Scenes at every tick, and /health every second, of every run of frames."""
    runs = segments(times["/can/can0/frames"])
    health = sorted(times[HEALTH_TOPIC])
    for lo, hi in runs:
        if hi - lo < 4 * PERIOD_NS:
            continue  # a single stray frame
        assert missing_ticks(times["/scene/ego"], lo, hi) == [], (lo, hi, runs)
        inside = [t for t in health if lo <= t <= hi]
        edges = [lo, *inside, hi]
        assert max(b - a for a, b in itertools.pairwise(edges)) <= 1.2 * NS, (
            f"a gap in /health between {lo} and {hi}: {inside}")


def alarms_raised(metadata: dict[str, Any]) -> list[str]:
    return [a["alarm"] for a in metadata.get("alarms", []) if a["event"] == "raised"]


# --- the clock-step detector -------------------------------------------------------------------

def test_a_step_is_a_jump_back_or_far_ahead_of_the_frames_before() -> None:
    from bridge.pipeline.clock import ClockStep, StepDetector

    detector = StepDetector(back_ns=NS, forward_ns=2 * NS)
    assert [detector.check(t) for t in (100 * NS, 100 * NS + 5, 100 * NS + 3)] == [None] * 3
    assert detector.check(70 * NS) == ClockStep(100 * NS + 5, 70 * NS)  # 30 s back
    assert detector.check(70 * NS + 10) is None  # the new timeline goes on
    assert detector.check(YEAR_NS) == ClockStep(70 * NS + 10, YEAR_NS)  # a year ahead
    assert detector.check(70 * NS + 20) == ClockStep(YEAR_NS, 70 * NS + 20)  # and back
    detector.passed(71 * NS)  # live's clock went on without a frame (a quiet bus)
    assert detector.check(72 * NS) is None  # 1 s after the clock, not a step
    assert detector.check(75 * NS) == ClockStep(72 * NS, 75 * NS)
    assert ClockStep(100 * NS, 70 * NS).step_s == -30.0


# --- live --------------------------------------------------------------------------------------

def shifted(after_s: float, by_ns: int, duration_s: float = 4.0) -> Iterator[tuple[float, Any]]:
    said = False
    for at, frame in steady(duration_s):
        if at >= after_s:
            if not said:
                yield at, "clock step"
                said = True
            frame = frame._replace(timestamp_ns=frame.timestamp_ns + by_ns)
        yield at, frame


def back_30_s() -> Iterator[tuple[float, Any]]:
    yield from shifted(1.5, -30 * NS)


def ahead_3_s() -> Iterator[tuple[float, Any]]:
    yield from shifted(1.5, 3 * NS)


def one_frame_a_year_ahead() -> Iterator[tuple[float, Any]]:
    said = False
    for at, frame in steady(4.0):
        yield at, frame
        if at >= 1.5 and not said:
            said = True
            yield at, "clock step"
            yield at, frame._replace(timestamp_ns=frame.timestamp_ns + YEAR_NS)


def check_live_step(tmp_path: Path, script: str, steps: int) -> None:
    """Live through the car's clock step: a /health after it, every scene tick, no bus alarm and
    ``steps`` steps noted. Tried twice: the car is a thread of live's process (see
    harness.LiveCar.late_s), so a stall of that process on a loaded machine can hold its frames
    back for a second, a silence live rightly reports."""
    failed: list[str] = []
    for attempt in (1, 2):
        folder = tmp_path / f"attempt-{attempt}"
        folder.mkdir()
        car = start(folder, f"{__file__}:{script}")
        viewer = Viewer(car.url)
        stepped = car.when("car: clock step")
        assert_survived(car, viewer, fault_ended=stepped, on_log="clock step")
        try:
            after = [at for at, topic, _ in viewer.got if topic == HEALTH_TOPIC and at > stepped]
            assert after, "no /health after the step"
            times, metadata = log_times(car.drives)
            assert_every_tick_in_each_timeline(times)
            assert not [a for a in alarms_raised(metadata) if a.startswith("bus.")], (
                metadata["alarms"])
            assert len(metadata["clock_steps"]) == steps, metadata["clock_steps"]
            return
        except AssertionError as e:
            failed.append(f"attempt {attempt} (the car sent up to {car.late_s:.2f} s late): {e}")
    pytest.fail("\n".join(failed))


@pytest.mark.slow
def test_live_goes_on_through_a_30_s_step_back(tmp_path: Path) -> None:
    check_live_step(tmp_path, "back_30_s", 1)


@pytest.mark.slow
def test_live_goes_on_through_a_step_of_3_s_ahead(tmp_path: Path) -> None:
    check_live_step(tmp_path, "ahead_3_s", 1)


@pytest.mark.slow
def test_one_frame_stamped_a_year_ahead_does_not_stop_the_scene(tmp_path: Path) -> None:
    check_live_step(tmp_path, "one_frame_a_year_ahead", 2)


# --- convert, on a car that is not ecocar ------------------------------------------------------

def message(db: cantools.database.can.Database, name: str, t: float,
            **values: float) -> can.Message:
    m = db.get_message_by_name(name)
    signals = {s.name: 0 for s in m.signals}
    signals.update(values)
    data = m.encode(signals, strict=False)
    return can.Message(timestamp=t, arbitration_id=m.frame_id, data=data, channel="can0",
                       dlc=len(data))


def bosch_drive(db: cantools.database.can.Database, starts: Iterable[float],
                seconds: float) -> Iterator[can.Message]:
    """A Bosch radar seeing one object at 20 Hz, from each start on for ``seconds``."""
    for t0 in starts:
        for i in range(round(seconds * 20)):
            t = t0 + i * 0.05
            yield message(db, "RadarPoint1_A", t, LongDist=30.0, LatDist=1.0,
                          ProbExist=90, Valid=1)
            yield message(db, "RadarPoint1_B", t + 0.001, Class=1)


@pytest.mark.slow
def test_convert_goes_on_with_the_scene_after_a_step_back(shared_dbc: Path,
                                                           tmp_path: Path) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    db = cantools.database.load_file(dbc)
    log = tmp_path / "stepped.log"  # candump: 3 s of drive, then the clock 30 s back, 3 s more
    log.write_text("".join(f"({m.timestamp:.6f}) can0 {m.arbitration_id:03X}#{m.data.hex()}\n"
                           for m in bosch_drive(db, (T0, T0 + 3.0 - 30.0), 3.0)))
    out = tmp_path / "stepped.mcap"

    convert([log], out, [str(dbc)], profile=PROFILES / "bosch_radar.toml")

    times, metadata = log_times([out])
    assert len(segments(times["/can/can0/frames"])) == 2
    assert_every_tick_in_each_timeline(times)
    radar = times[scene_topic("radar")]
    assert len(radar) >= 2 * (3.0 * 20 - 2)
    (step,) = metadata["clock_steps"]
    assert step["step_s"] < -29.0
    from bridge.apps.inspect import format_summary, summarize_file

    assert "clock steps (1; frames recorded with their own stamps)" in format_summary(
        str(out), summarize_file(out))  # tankviz inspect says so
    assert not [a for a in alarms_raised(metadata) if a.startswith(("bus.", "radar."))]


# --- a pipeline that falls behind records every tick -------------------------------------------

class Ticks(Sink):
    """A sink that notes the log time of every scene it gets."""

    def __init__(self) -> None:
        self.ticks: list[int] = []

    def on_decoded(self, t_ns: int, decoded: Decoded, /) -> None:
        return None

    def on_messages(self, messages: Iterable[Serialized], /) -> None:
        self.ticks += [m.t_ns for m in messages if m.topic == scene_topic("radar")]


def test_a_pipeline_behind_the_bus_records_every_scene_tick(shared_dbc: Path) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    stages = load_stages([str(dbc)], PROFILES / "bosch_radar.toml")
    db = cantools.database.load_file(dbc)
    sink = Ticks()
    drive = Drive(stages, [sink])
    pipeline = drive.pipeline
    start_ns = round(T0 * NS)
    # Frames come in bursts of 100 ms, and live's clock runs 650 ms ahead between them (a read
    # made late on a loaded machine): the scenes of those 650 ms are made all the same.
    for burst in range(5):
        t0 = T0 + burst * 0.75
        for m in bosch_drive(db, (t0,), 0.1):
            pipeline.process(Frame(round(m.timestamp * NS), "can0", m.arbitration_id,
                                   bytes(m.data), False, False, False, False, False, False,
                                   m.dlc))
        pipeline.advance(round((t0 + 0.75) * NS))
    drive.finish()

    end_ns = start_ns + round(5 * 0.75 * NS)
    assert missing_ticks(sink.ticks, start_ns, end_ns) == []
    assert len(sink.ticks) == len(set(sink.ticks))


def test_a_viewer_gets_the_latest_scene_of_a_catch_up_and_the_recording_all(
        shared_dbc: Path) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    stages = load_stages([str(dbc)], PROFILES / "bosch_radar.toml")
    db = cantools.database.load_file(dbc)
    viewer, archive = Ticks(), Ticks()
    drive = Drive(stages)
    drive.pipeline.add_viewer(viewer)
    drive.add(archive)
    for m in bosch_drive(db, (T0,), 0.1):
        drive.pipeline.process(Frame(round(m.timestamp * NS), "can0", m.arbitration_id,
                                     bytes(m.data), dlc=m.dlc))
    before = len(archive.ticks)
    drive.pipeline.advance(round((T0 + 0.6) * NS))  # the ticks at 0.10, 0.15 ... 0.60 s at once

    assert archive.ticks[before:] == [round(T0 * NS) + i * PERIOD_NS for i in range(2, 13)]
    assert viewer.ticks[before:] == [archive.ticks[-1]]


# --- the end of a run names the viewers that lost messages, and what ---------------------------

def test_the_end_of_a_run_says_which_viewer_lost_which_topics() -> None:
    from bridge.apps.live import dropped_report
    from bridge.sinks.server import ClientStats

    stats = [ClientStats("10.0.0.5:51234", sent=900, dropped=120,
                         topics=Counter({"/can/can0/frames": 100, "/scene/ego": 20})),
             ClientStats("127.0.0.1:40000", sent=1000, dropped=0)]

    line = dropped_report(stats)

    assert line.startswith("120 messages dropped for slow viewers: ")
    assert "10.0.0.5:51234" in line and "/can/can0/frames 100" in line
    assert "/scene/ego 20" in line and "127.0.0.1" not in line
    assert dropped_report(stats[1:]) == "0 messages dropped for slow viewers"


def test_a_full_viewer_queue_counts_what_it_drops_per_channel() -> None:
    from bridge.sinks.server.client import ClientQueue as _Client
    from bridge.sinks.server.client import ClientStats

    stats = ClientStats("10.0.0.5:51234")
    client = _Client(None, stats, limit=3)
    client.put([(1, 0, b"a"), (1, 1, b"b")])
    client.put([(2, 2, b"c"), (2, 3, b"d"), (2, 4, b"e")])  # the two oldest go
    client.put([(3, 5, b"f")])

    assert stats.dropped == 3
    assert stats.channels == Counter({1: 2, 2: 1})
    assert [item[1] for item in client.queue] == [3, 4, 5]


def test_an_object_seen_before_a_step_is_placed_in_the_new_timeline(shared_dbc: Path) -> None:
    """The A frame (position) of a Bosch radar object came before a 30 s step back, its B frame
    after: the observation the B frame makes is stamped in the new timeline, where its lifetime
    goes on, not 30 s in the future."""
    from bridge.pipeline.perception import Perception

    _, profile = load_stages([str(shared_dbc / "tesla_radar_bosch.dbc")],
                             Path(__file__).resolve().parents[1] / "profiles" / "bosch_radar.toml")
    assert profile is not None
    perception = Perception(profile)
    a = {"LongDist": 20.0, "LatDist": 0.0, "LongSpeed": 0.0, "ProbExist": 90.0, "Valid": 1}
    perception.observer.observe("RadarPoint0_A", a, 100 * NS)
    perception.rebase(-30 * NS, 70 * NS)
    (seen,) = perception.observer.observe("RadarPoint0_B", {"LatSpeed": 0.0, "Class": 1},
                                          70 * NS + NS // 100)
    assert seen.t_ns == 70 * NS


@pytest.mark.parametrize("away_ms", [(1_040, 1_060), (995, 1_005)],
                         ids=["across a scene tick", "across a health check"])
def test_a_frame_stamped_a_year_off_and_back_leaves_no_tick_unmade(
        away_ms: tuple[int, int]) -> None:
    """The clock steps a year ahead for one frame, then back: every scene tick and health check
    of the drive's own timeline is still made, also the one that fell due while the clock was
    away (the frame after the stray one comes just after it)."""
    made: dict[str, list[int]] = {scene_topic("ego"): [], HEALTH_TOPIC: []}

    class Ticks(Sink):
        def on_messages(self, messages: Sequence[Serialized], /) -> None:
            for m in messages:
                made.get(m.topic, []).append(m.t_ns)

    drive = Drive(load_stages([], "ecocar"), [Ticks()])
    t0 = 1_800_000_000 * NS
    before, after = away_ms
    stamps = [t0 + ms * MS_NS for ms in range(0, before + 1, 10)]
    stamps += [t0 + 365 * 86_400 * NS, t0 + after * MS_NS]
    stamps += [t0 + ms * MS_NS for ms in range(after + 10, 3_001, 10)]
    drive.run(Frame(t, "can0", 0x7FF, b"") for t in stamps)
    drive.finish()
    own = {topic: sorted(t for t in times if t < t0 + 10 * NS) for topic, times in made.items()}
    assert missing_ticks(own[scene_topic("ego")], t0, t0 + 3 * NS) == []
    health = own[HEALTH_TOPIC]
    # /health about every second: the same bound as the live tests' (a step re-bases its clock)
    assert health and max(b - a for a, b in itertools.pairwise(health)) <= 1.2 * NS, health
    assert len(drive.pipeline.steps) == 2
