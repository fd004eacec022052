"""Finding marks (#34): inspect lists a drive's marks, the catalogue indexes them, replay starts a
few seconds before one, recover keeps those of a cut drive, and a re-derived drive keeps them.

One drive is recorded for real (``tankviz live`` on python-can's virtual bus, three marks asked
between bursts of frames); another is written with the recorder (marks far apart in time).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can
import pytest
from conftest import timeout_scale
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from waiting import wait_for

from bridge.cli import main
from bridge.frame import NS, Frame, timestamp
from bridge.io.buses import BusSpec
from bridge.io.drives import drive_marks, mark_time
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline.drive import load_stages
from bridge.pipeline.live_engine import Live
from bridge.pipeline.marks import MarkAsked, describe
from bridge.sim.ecocar import simulate
from bridge.sinks.base import Serialized, Sink
from bridge.sinks.mcap import Recorder
from bridge.topics import LOG_TOPIC, MARKS_TOPIC

#: The marks asked for during the recorded drive, in order.
ASKED = [MarkAsked("ghost on the left", "radar", "viewer", "192.168.1.4:53211"),
         MarkAsked("lanes jumped", "lanes", "terminal", "terminal"),
         MarkAsked("Ghost again", "", "car", "MARK_BTN == 1")]


def send(bus: can.BusABC, frames: list[Frame]) -> None:
    for frame in frames:
        bus.send(can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                             is_fd=frame.is_fd, dlc=frame.dlc))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Mark]]:
    """A drive recorded live with :data:`ASKED`, each between two bursts of frames (a chunk
    flushed at every tick, so that the drive has many), and the marks live made."""
    folder = tmp_path_factory.mktemp("marked")
    channel = f"marks-{os.getpid()}"
    live = Live([BusSpec("can0", "virtual", channel)], load_stages([], "ecocar"), drives=folder,
                say=lambda _: None)
    assert live.recorder is not None
    live.recorder.flush_interval_s = 0.0
    live.start()
    runner = threading.Thread(target=live.run)
    runner.start()
    frames = list(simulate(duration_s=1.0))
    bursts = [frames[i::4] for i in range(4)]  # (each covers the whole simulated second)
    sent = 0
    wait = 10 * timeout_scale()
    try:
        with can.Bus(interface="virtual", channel=channel) as bus:
            for i, burst in enumerate(bursts):
                send(bus, burst)
                sent += len(burst)
                assert wait_for(lambda n=sent: live.pipeline.frames >= n, wait)
                if i < len(ASKED):
                    live.marks.ask(ASKED[i])
                    assert wait_for(lambda n=i: len(live.marks.made) > n, wait)
    finally:
        live.stop()
        runner.join(wait)
    (drive,) = folder.glob("*.mcap")
    return drive, list(live.marks.made)


T0 = 1_767_268_800_000_000_000  # 2026-01-01T12:00:00Z


def mark(number: int, at_s: float, text: str, category: str = "",
         source: str = "viewer", by: str = "") -> Mark:
    return Mark(timestamp=timestamp(T0 + round(at_s * NS)), number=number, text=text,
                category=category, source=source, by=by)


def write_drive(path: Path, marks: list[Mark], *, seconds: int = 40,
                extra: list[Serialized] = ()) -> Path:  # type: ignore[assignment]
    """An MCAP of ``seconds`` with a /log line a second and ``marks`` on /marks."""
    with path.open("wb") as stream:
        recorder = Recorder(stream)
        recorder.on_messages([Serialized(LOG_TOPIC, Log, Log(message=f"{s}").SerializeToString(),
                                         T0 + s * NS) for s in range(seconds + 1)])
        recorder.on_messages([Serialized(MARKS_TOPIC, Mark, m.SerializeToString(),
                                         mark_time(m)) for m in marks])
        recorder.on_messages(list(extra))
        recorder.add_metadata({"tankviz_version": "test", "alarms": []})
        recorder.finish()
    return path


FAR = [mark(1, 12.5, "ghost target here", "radar", "viewer", "192.168.1.4:53211"),
       mark(2, 30.0, "lanes jumped", "lanes", "terminal", "terminal"),
       mark(3, 31.0, "Ghost again")]


# --- inspect ------------------------------------------------------------------------------------

@pytest.mark.slow
def test_inspect_lists_each_mark_with_its_seconds_from_the_drives_start(
        recorded: tuple[Path, list[Mark]], capsys: pytest.CaptureFixture[str]) -> None:
    drive, made = recorded
    assert [m.text for m in made] == [a.text for a in ASKED]
    assert main(["inspect", str(drive)]) == 0
    out = capsys.readouterr().out
    with drive.open("rb") as f:
        stats = make_reader(f).get_summary().statistics  # type: ignore[union-attr]
    assert stats is not None
    lines = out.splitlines()
    at = lines.index("marks (3; seconds from the drive's start):")
    expected = [f"  {(mark_time(m) - stats.message_start_time) / NS:>10,.3f} s  {describe(m)}"
                for m in made]
    assert lines[at + 1:at + 4] == expected
    assert "MARK 1: ghost on the left [radar] (viewer 192.168.1.4:53211)" in expected[0]
    assert "MARK 2: lanes jumped [lanes] (terminal)" in expected[1]
    assert "MARK 3: Ghost again (car MARK_BTN == 1)" in expected[2]
    assert 0 < mark_time(made[0]) - stats.message_start_time < mark_time(made[2]) - \
        stats.message_start_time


def test_inspect_reads_only_the_chunks_that_hold_marks(
        recorded: tuple[Path, list[Mark]], monkeypatch: pytest.MonkeyPatch) -> None:
    """A drive of hours is not read through to list its marks: only the chunks with /marks."""
    import mcap.reader

    from bridge.apps.inspect import summarize_file

    drive, _ = recorded
    with drive.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (marks_id,) = [c.id for c in summary.channels.values() if c.topic == MARKS_TOPIC]
    holding = [c for c in summary.chunk_indexes if marks_id in c.message_index_offsets]
    assert len(holding) < len(summary.chunk_indexes)
    read: list[Any] = []
    breakup = mcap.reader.breakup_chunk
    monkeypatch.setattr(mcap.reader, "breakup_chunk",
                        lambda chunk, **kw: read.append(chunk) or breakup(chunk, **kw))
    assert len(summarize_file(drive).marks.marks) == 3
    assert len(read) == len(holding)


def test_inspect_of_a_drive_without_marks_says_nothing_of_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["inspect", str(write_drive(tmp_path / "none.mcap", []))]) == 0
    assert "marks" not in capsys.readouterr().out


def test_a_marks_message_that_is_no_mark_is_counted_and_the_others_listed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = Serialized(MARKS_TOPIC, Mark, b"\xff\xff\xff", T0 + 5 * NS)
    drive = write_drive(tmp_path / "bad.mcap", FAR, extra=[bad])
    assert main(["inspect", str(drive)]) == 0
    out = capsys.readouterr().out
    assert "marks (3;" in out
    assert "      12.500 s  MARK 1: ghost target here [radar] (viewer 192.168.1.4:53211)" in out
    assert "(1 /marks messages are not a tankviz.Mark: left out)" in out


# --- replay --start mark:N ----------------------------------------------------------------------

@pytest.mark.parametrize(("spec", "start_s"), [
    ("mark:1", 7.5), ("mark:2", 25.0), ("mark:3", 26.0),  # MARK_LEAD_S before each
    ("mark:ghost", 7.5), ("mark:GHOST AGAIN", 26.0), ("mark:jump", 25.0)])
def test_replay_starts_a_few_seconds_before_the_mark_named_by_number_or_text(
        tmp_path: Path, spec: str, start_s: float) -> None:
    from bridge.apps.replay import MARK_LEAD_S, mark_start_s

    assert MARK_LEAD_S == 5.0
    drive = write_drive(tmp_path / "far.mcap", FAR)
    start, chosen = mark_start_s(drive, spec)
    assert start == pytest.approx(start_s)
    assert chosen.text.lower().find(spec[5:].lower()) >= 0 or str(chosen.number) == spec[5:]


def test_a_mark_in_the_first_seconds_starts_the_replay_at_the_drives_start(
        tmp_path: Path) -> None:
    from bridge.apps.replay import mark_start_s

    drive = write_drive(tmp_path / "early.mcap", [mark(1, 2.0, "early")])
    assert mark_start_s(drive, "mark:1")[0] == 0.0


@pytest.mark.parametrize(("marks", "spec", "says"), [
    (FAR, "mark:7", "error: --start mark:7: far.mcap has no mark 7; its marks: 1 ghost target "
     "here (12.5 s), 2 lanes jumped (30.0 s), 3 Ghost again (31.0 s)"),
    (FAR, "mark:fog", "error: --start mark:fog: far.mcap has no mark whose text contains 'fog'; "
     "its marks: 1 ghost target here (12.5 s), 2 lanes jumped (30.0 s), 3 Ghost again (31.0 s)"),
    ([], "mark:1", "error: --start mark:1: far.mcap has no marks"),
    (FAR, "mark:", "error: --start mark:: name a mark: mark:N (its number) or mark:TEXT (the "
     "first whose text contains TEXT)"),
    (FAR, "soon", "error: --start soon: expected SECONDS, mark:N or mark:TEXT")])
def test_a_mark_that_is_not_there_is_one_line_naming_the_drives_marks(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], marks: list[Mark], spec: str,
        says: str) -> None:
    drive = write_drive(tmp_path / "far.mcap", marks)
    assert main(["replay", str(drive), "--port", "0", "--start", spec]) == 1
    assert capsys.readouterr() == ("", says + "\n")


def test_replay_serves_the_drive_from_a_few_seconds_before_the_mark(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drive = write_drive(tmp_path / "far.mcap", FAR)
    assert main(["replay", str(drive), "--port", "0", "--speed", "100", "--start",
                 "mark:ghost again"]) == 0
    out = capsys.readouterr().out
    assert "starting 5 s before MARK 3: Ghost again (viewer), at 26.000 s" in out
    # from 26 s: the /log lines of 26 to 40 s and marks 2 and 3
    assert "replayed 17 messages (1 pass)" in out


def test_many_marks_are_listed_cut_short(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    drive = write_drive(tmp_path / "many.mcap", [mark(n, n, f"m{n}") for n in range(1, 31)])
    assert main(["replay", str(drive), "--port", "0", "--start", "mark:99"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.endswith("10 m10 (10.0 s), … and 20 more") and len(err.splitlines()) == 1


def test_can_logs_have_no_marks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "drive.asc"
    log.write_text("date Thu Jan 1 12:00:00.000 am 2026\nbase hex timestamps absolute\n"
                   "   0.001000 1  123             Rx   d 1 00\n")
    assert main(["replay", str(log), "--dbc", "ecocar", "--port", "0", "--start",
                 "mark:1"]) == 1
    assert capsys.readouterr().err.strip() == (
        "error: --start mark:1: CAN logs have no marks (a drive tankviz recorded, .mcap, has)")


def test_replay_of_a_recorded_drive_starts_before_its_mark(
        recorded: tuple[Path, list[Mark]]) -> None:
    """The live drive's marks come within a second of its start: replay starts at its start."""
    from bridge.apps.replay import mark_start_s

    drive, made = recorded
    start, chosen = mark_start_s(drive, "mark:lanes")
    assert (start, chosen.number) == (0.0, 2)
    assert chosen == made[1]


# --- convert DRIVE.mcap (re-derive) and recover ------------------------------------------------

def recorded_messages(path: Path, topic: str) -> list[tuple[int, bytes]]:
    with path.open("rb") as f:
        return [(m.log_time, m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


def check_marks_kept(path: Path, made: list[Mark]) -> None:
    """``path`` holds ``made`` on /marks (the same numbers, texts and times), each once, with
    its /log line and its text in the scene at its time."""
    marks = [Mark.FromString(data) for _, data in recorded_messages(path, MARKS_TOPIC)]
    assert marks == made
    assert [t for t, _ in recorded_messages(path, MARKS_TOPIC)] == [mark_time(m) for m in made]
    said = [(t, Log.FromString(data).message) for t, data in recorded_messages(path, LOG_TOPIC)]
    assert [s for s in said if s[1].startswith("MARK ")] == [(mark_time(m), describe(m))
                                                             for m in made]
    shown = [(t, [(e.id, [x.text for x in e.texts]) for e in SceneUpdate.FromString(data).entities])
             for t, data in recorded_messages(path, "/scene/marks")]
    assert shown == [(mark_time(m), [(f"mark-{m.number}", [describe(m)])]) for m in made]


def test_a_rederived_drive_keeps_its_marks(recorded: tuple[Path, list[Mark]],
                                           tmp_path: Path) -> None:
    drive, made = recorded
    check_marks_kept(drive, made)  # (as live recorded them)
    again = tmp_path / "again.mcap"
    assert main(["convert", str(drive), "-o", str(again), "--quiet"]) == 0
    check_marks_kept(again, made)
    # and once more, without the second process reading ahead: the same bytes
    once_more = tmp_path / "once_more.mcap"
    assert main(["convert", str(again), "-o", str(once_more), "--quiet",
                 "--no-read-ahead"]) == 0
    check_marks_kept(once_more, made)


def test_a_rederived_drive_without_marks_has_no_marks_topics(tmp_path: Path) -> None:
    drive = tmp_path / "sim.mcap"
    assert main(["simulate", "-o", str(drive), "--duration", "0.5"]) == 0
    again = tmp_path / "again.mcap"
    assert main(["convert", str(drive), "-o", str(again), "--quiet"]) == 0
    with again.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert not {MARKS_TOPIC, "/scene/marks"} & {c.topic for c in summary.channels.values()}


def cut_after_the_marks(drive: Path, to: Path) -> Path:
    """``drive`` cut as a power loss cuts it: in the middle of its last chunk, which holds no
    mark (the chunks before it all come whole)."""
    with drive.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (marks_id,) = [c.id for c in summary.channels.values() if c.topic == MARKS_TOPIC]
    last = max(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert marks_id not in last.message_index_offsets
    data = drive.read_bytes()
    to.write_bytes(data[:last.chunk_start_offset + last.chunk_length // 2])
    return to


def test_recover_keeps_the_marks_of_a_cut_drive(recorded: tuple[Path, list[Mark]],
                                                 tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    drive, made = recorded
    cut = cut_after_the_marks(drive, tmp_path / "cut.mcap")
    fixed = tmp_path / "fixed.mcap"
    assert main(["recover", str(cut), "-o", str(fixed), "--quiet"]) == 0
    check_marks_kept(fixed, made)
    capsys.readouterr()
    assert main(["inspect", str(fixed)]) == 0
    assert "marks (3; seconds from the drive's start):" in capsys.readouterr().out


def test_a_cut_drive_rederived_keeps_its_marks(recorded: tuple[Path, list[Mark]],
                                               tmp_path: Path) -> None:
    drive, made = recorded
    cut = cut_after_the_marks(drive, tmp_path / "cut.mcap")
    assert [m.number for m in drive_marks(cut).marks] == [1, 2, 3]
    again = tmp_path / "again.mcap"
    assert main(["convert", str(cut), "-o", str(again), "--quiet"]) == 0
    check_marks_kept(again, made)


class Collected(Sink):
    """A sink that keeps what it is given in order: decoded frames' times, and messages; with
    what a replay asks of its server."""

    def __init__(self) -> None:
        self.events: list[tuple[str, int]] = []

    def on_decoded_many(self, run: Sequence[tuple[int, Any]], /) -> None:
        self.events += [("frame", t) for t, _ in run]

    def on_decoded(self, t_ns: int, decoded: Any, /) -> None:
        self.events.append(("frame", t_ns))

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        self.events += [(m.topic, m.t_ns) for m in messages if m.topic == MARKS_TOPIC]

    def flush(self) -> None:
        pass

    def broadcast_time(self, t_ns: int) -> None:
        pass


def check_between_their_frames(events: list[tuple[str, int]], made: list[Mark]) -> None:
    """Each mark comes after every frame stamped before it and before every frame after it."""
    at = [i for i, (what, _) in enumerate(events) if what == MARKS_TOPIC]
    assert [events[i][1] for i in at] == [mark_time(m) for m in made]
    for i in at:
        t = events[i][1]
        assert all(u < t for what, u in events[:i] if what == "frame")
        assert all(u >= t for what, u in events[i + 1:] if what == "frame")


def test_carried_marks_come_between_the_frames_before_and_after_them() -> None:
    from bridge.packed import packs
    from bridge.pipeline.drive import Drive
    from bridge.pipeline.rederive import CarriedMarks

    frames = list(simulate(duration_s=1.0))
    start, end = frames[0].timestamp_ns, frames[-1].timestamp_ns
    made = [Mark(timestamp=timestamp(t), number=n, text=f"m{n}") for n, t in enumerate(
        [start, start + 1, (start + end) // 2, (start + end) // 2, end, end + NS], 1)]
    for cut in (64, 4096):  # marks inside packs, and at their edges
        sink = Collected()
        drive = Drive(load_stages([], "ecocar"), [sink])
        carried = CarriedMarks(made, drive.pipeline)
        assert drive.run_packed(carried.packs(
            b for i in range(0, len(frames), cut) for b in packs(frames[i:i + cut]))) == len(
            frames)
        carried.finish()
        check_between_their_frames(sink.events, made)
        assert drive.pipeline.marks is not None
        assert drive.pipeline.marks.made == made


def test_a_drive_replayed_rederived_makes_its_marks_again(
        recorded: tuple[Path, list[Mark]], tmp_path: Path) -> None:
    from bridge.apps.replay import replay_drive
    from bridge.io.drives import read_drive
    from bridge.pipeline.rederive import rederive_stages

    drive, made = recorded
    stages = rederive_stages(read_drive(drive), [], None, tmp_path)
    served = Collected()
    replay_drive(drive, stages, served, speed=50)  # type: ignore[arg-type]
    check_between_their_frames(served.events, made)


# --- catalog ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def catalogued(recorded: tuple[Path, list[Mark]], tmp_path_factory: pytest.TempPathFactory
               ) -> tuple[Path, Path, Path]:
    """A catalogue of the recorded drive and of one with marks far apart: (it, them)."""
    pytest.importorskip("duckdb")
    folder = tmp_path_factory.mktemp("fleet")
    live = folder / "live.mcap"
    live.write_bytes(recorded[0].read_bytes())
    far = write_drive(folder / "far.mcap", FAR)
    out = folder / "catalog.duckdb"
    assert main(["catalog", str(live), str(far), "-o", str(out)]) == 0
    return out, live, far


def test_the_catalogue_has_every_mark_of_every_drive(
        catalogued: tuple[Path, Path, Path], recorded: tuple[Path, list[Mark]]) -> None:
    from bridge.fleet.catalog import SCHEMA
    from bridge.fleet.questions import query

    out, live, far = catalogued
    assert [c for c, _ in SCHEMA["marks"]] == [
        "drive", "mark", "time", "t_ns", "t_s", "text", "category", "source", "marked_by"]
    rows = query(out, "SELECT * FROM marks ORDER BY drive, mark").rows
    start = query(out, "SELECT start_ns FROM drives WHERE path = ?", [str(live)]).rows[0][0]
    assert [r[:2] + r[3:] for r in rows] == [
        (str(far), 1, T0 + 12_500_000_000, 12.5, "ghost target here", "radar", "viewer",
         "192.168.1.4:53211"),
        (str(far), 2, T0 + 30 * NS, 30.0, "lanes jumped", "lanes", "terminal", "terminal"),
        (str(far), 3, T0 + 31 * NS, 31.0, "Ghost again", "", "viewer", ""),
        *[(str(live), m.number, mark_time(m), (mark_time(m) - start) / NS, m.text, m.category,
           m.source, m.by) for m in recorded[1]]]
    assert str(rows[0][2]) == "2026-01-01 12:00:12.500000"


def test_every_mark_with_ghost_in_the_fleet(catalogued: tuple[Path, Path, Path],
                                            capsys: pytest.CaptureFixture[str]) -> None:
    out, live, far = catalogued
    capsys.readouterr()
    assert main(["catalog", "query", str(out), "SELECT drive, mark, t_s, text FROM marks "
                 "WHERE text ILIKE '%ghost%' ORDER BY drive, mark"]) == 0
    printed = capsys.readouterr().out
    assert "(4 rows)" in printed
    hints = printed.split("open:\n")[1].splitlines()
    assert [h.split("    #")[0].strip() for h in hints] == [
        f"tankviz replay {far} --start mark:1", f"tankviz replay {far} --start mark:3",
        f"tankviz replay {live} --start mark:1", f"tankviz replay {live} --start mark:3"]
    # with its time, the hint says where to jump in Foxglove too
    assert main(["catalog", "query", str(out), "SELECT drive, mark, t_ns FROM marks "
                 f"WHERE drive = '{far}' AND mark = 2"]) == 0
    assert (f"  tankviz replay {far} --start mark:2    # Foxglove: jump to "
            "2026-01-01T12:00:30.000+00:00 (log time 1767268830.000000000)"
            ) in capsys.readouterr().out


def test_the_mark_question_finds_marks_by_their_text(catalogued: tuple[Path, Path, Path],
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = catalogued[0]
    capsys.readouterr()
    assert main(["catalog", "query", str(out), "--mark", "GHOST"]) == 0
    printed = capsys.readouterr().out
    assert "(4 rows)" in printed and "lanes jumped" not in printed
    assert main(["catalog", "query", str(out), "--mark", "fog"]) == 0
    assert "(0 rows)" in capsys.readouterr().out
    assert main(["catalog", "query", str(out), "--mark", "ghost", "--between", "2026-01-01",
                 "2026-01-01"]) == 0
    assert "(2 rows)" in capsys.readouterr().out  # the far drive's alone


def test_a_catalogue_made_before_marks_gets_them_at_its_next_index(
        recorded: tuple[Path, list[Mark]], tmp_path: Path) -> None:
    """A catalogue an older tankviz made (no marks table) re-reads the drives that have marks,
    once; the others stay unchanged."""
    duckdb = pytest.importorskip("duckdb")
    from bridge.fleet.catalog import index
    from bridge.fleet.questions import query

    live = tmp_path / "live.mcap"
    live.write_bytes(recorded[0].read_bytes())
    plain = write_drive(tmp_path / "plain.mcap", [])
    out = tmp_path / "catalog.duckdb"
    index(out, [str(live), str(plain)])
    con = duckdb.connect(str(out))
    con.execute("DROP TABLE marks")
    con.close()
    report = index(out, [str(live), str(plain)])
    assert (report.changed, report.unchanged) == ([str(live)], [str(plain)])
    assert len(query(out, "SELECT * FROM marks").rows) == 3
    again = index(out, [str(live), str(plain)])
    assert again.changed == [] and len(again.unchanged) == 2


@pytest.fixture(scope="module")
def highway_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """11 s of the simulated highway car: its wheel button pressed once (at 10 s)."""
    log = tmp_path_factory.mktemp("highway") / "highway.blf"
    assert main(["simulate", "--car", "highway", "-o", str(log), "--duration", "11"]) == 0
    return log


@pytest.mark.slow
def test_a_drive_with_the_cars_marks_rederived_has_each_once(highway_log: Path,
                                                             tmp_path: Path) -> None:
    """The profile's [marks] rule marked the drive when it was recorded: re-derived, the drive
    keeps those marks, and the rule does not make them again."""
    drive, again = tmp_path / "drive.mcap", tmp_path / "again.mcap"
    assert main(["convert", str(highway_log), "-o", str(drive), "--profile", "highway",
                 "--quiet"]) == 0
    made = [Mark.FromString(data) for _, data in recorded_messages(drive, MARKS_TOPIC)]
    assert [(m.number, m.source) for m in made] == [(1, "car")]
    assert main(["convert", str(drive), "-o", str(again), "--quiet"]) == 0
    check_marks_kept(again, made)


@pytest.mark.slow
def test_a_drive_without_marks_rederived_with_a_marking_profile_gets_its_marks(
        highway_log: Path, tmp_path: Path) -> None:
    """A drive recorded before its profile had a [marks] rule (or without a profile): re-derived
    with one, the rule marks it as it would mark the log."""
    from bridge.resources import data_dir

    drive, again, direct = (tmp_path / n for n in ("drive.mcap", "again.mcap", "direct.mcap"))
    assert main(["convert", str(highway_log), "-o", str(drive), "--quiet",
                 "--dbc", f"can0={data_dir() / 'highway_car.dbc'}",
                 "--dbc", f"can1={data_dir() / 'highway_radar.dbc'}"]) == 0
    assert recorded_messages(drive, MARKS_TOPIC) == []
    assert main(["convert", str(drive), "-o", str(again), "--profile", "highway", "--quiet"]) == 0
    assert main(["convert", str(highway_log), "-o", str(direct), "--profile", "highway",
                 "--quiet"]) == 0
    assert recorded_messages(again, MARKS_TOPIC) == recorded_messages(direct, MARKS_TOPIC) != []
