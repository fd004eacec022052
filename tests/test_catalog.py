"""``tankviz catalog``: an archive of drives indexed into one DuckDB file, and its answers.

The archive is five simulated ecocar drives on five days (``tankviz simulate`` for the scripted
drive, whose radar is misaligned for a while; the simulation's own API for the others, to give
them their own start time and fault), plus, where the public DBCs are there, a drive of a Bosch
radar retrofit converted with a profile whose sensor, group and database names are not ecocar's.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import can
import cantools
import duckdb
import pytest
from conftest import T0, message
from mcap.reader import make_reader
from mcap.writer import Writer

from bridge.cli import main
from bridge.errors import UsageError
from bridge.fleet import catalog, questions
from bridge.fleet.catalog import DriveRows, index, read_here
from bridge.frame import NS
from bridge.io.drives import ArchiveSource
from bridge.pb import health_pb2
from bridge.pipeline.convert import convert
from bridge.pipeline.drive import Drive, load_stages
from bridge.sim.ecocar import simulate
from bridge.sim.scenario import DEFAULT_START_NS
from bridge.sinks.outputs import atomic_output

VENV_BIN = Path(sys.executable).parent
DAY_NS = 86_400 * NS
MISALIGNED = "radar-camera.misaligned"

#: The example queries of docs/commands.md (`tankviz catalog`; the 10 minutes of the second one
#: are a parameter here: the simulated drives are seconds long).
FIRST_MISALIGNED_AND_SINCE = """
    SELECT d.path AS drive, d.start_time, a.raised, a.raised_ns
    FROM drives d LEFT JOIN alarms a ON a.drive = d.path AND a.alarm = 'radar-camera.misaligned'
    WHERE d.start_ns >= (SELECT min(d2.start_ns) FROM drives d2 JOIN alarms a2
                         ON a2.drive = d2.path WHERE a2.alarm = 'radar-camera.misaligned')
    ORDER BY d.start_ns, a.raised_ns
"""
LONG_WITH_CLOSE_LEAD = """
    SELECT d.path AS drive, d.duration_s, o.min_distance_m, o.min_distance_ns
    FROM drives d JOIN objects_summary o ON o.drive = d.path
    WHERE o.object_group = 'lead' AND d.duration_s > ? AND o.min_distance_m < 20
    ORDER BY d.start_ns
"""
DATABASE_CHANGED = """
    SELECT DISTINCT b.drive, b.name, b.sha256
    FROM databases b
    WHERE b.name = ? AND b.sha256 <> (SELECT sha256(content) FROM read_blob(?))
    ORDER BY b.drive
"""


def simulated(path: Path, *, seed: int, day: int, scenario: str = "clean",
              duration_s: float = 16.0) -> Path:
    """A simulated ecocar drive written as ``tankviz simulate`` writes it, ``day`` days after
    the simulation's default start."""
    drive = Drive(load_stages([], "ecocar"),
                  extra={"simulated": {"seed": seed, "duration_s": duration_s}})
    with atomic_output(path) as stream:
        drive.record(stream)
        drive.run(simulate(duration_s=duration_s, seed=seed, scenario=scenario,
                           start_ns=DEFAULT_START_NS + day * DAY_NS))
        drive.finish()
    return path


def tankviz(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(VENV_BIN / "tankviz"), *args], capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five drives in a folder tree: two clean ones before the misaligned drive, a radar yaw
    fault and a clean drive after it; the second clean drive is short (8 s)."""
    root = tmp_path_factory.mktemp("archive")
    (root / "2025-12").mkdir()
    (root / "2026-01").mkdir()
    simulated(root / "2025-12" / "a_clean.mcap", seed=1, day=-2)
    simulated(root / "2025-12" / "b_short.mcap", seed=2, day=-1, duration_s=8.0)
    made = tankviz("simulate", "-o", str(root / "2026-01" / "c_scripted.mcap"), "--duration",
                   "20", "--seed", "3")  # the scripted drive, radar misaligned from 75 % on
    assert made.returncode == 0, made.stderr
    simulated(root / "2026-01" / "d_yaw.mcap", seed=4, day=1, scenario="radar_yaw")
    simulated(root / "2026-01" / "e_clean.mcap", seed=5, day=2)
    return root


def drives(root: Path) -> dict[str, str]:
    return {p.stem: str(p) for p in sorted(root.rglob("*.mcap"))}


@pytest.fixture(scope="module")
def indexed(archive: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("catalogue") / "catalog.duckdb"
    report = index(out, [str(archive)])
    assert len(report.new) == 5 and not report.failed
    return out


def health_alarm_spans(path: str, alarm: str) -> tuple[list[tuple[int, int | None]], int]:
    """When ``alarm`` was active, as the drive's own ``/health`` messages say: (since, the first
    /health time at which it is no longer active), and the time of the last /health message."""
    spans: list[tuple[int, int | None]] = []
    active, last = False, 0
    with open(path, "rb") as f:
        for _, _, m in make_reader(f).iter_messages(topics=["/health"], log_time_order=True):
            health = health_pb2.Health.FromString(m.data)
            state = next((a for a in health.alarms if a.id == alarm), None)
            now = state is not None and state.active
            if now and not active:
                assert state is not None
                spans.append((state.since.seconds * NS + state.since.nanos, None))
            elif active and not now:
                spans[-1] = (spans[-1][0], m.log_time)
            active, last = now, m.log_time
    return spans, last


def rows(catalogue: Path, sql: str, *params: Any) -> list[tuple[Any, ...]]:
    return questions.query(catalogue, sql, params).rows


# --- the example queries of docs/commands.md ------------------------------------------------------

@pytest.mark.slow
def test_the_first_drive_with_a_misaligned_radar_and_every_drive_since(
        archive: Path, indexed: Path) -> None:
    d = drives(archive)
    answer = rows(indexed, FIRST_MISALIGNED_AND_SINCE)

    assert [r[0] for r in answer] == [d["c_scripted"], d["d_yaw"], d["e_clean"]]
    scripted, yaw, clean = answer
    assert scripted[2] is not None and yaw[2] is not None  # raised in both faulty drives
    assert clean[2] is None  # the drive since without the alarm is listed with none


@pytest.mark.slow
def test_the_misalignment_is_catalogued_with_the_times_its_health_messages_say(
        archive: Path, indexed: Path) -> None:
    for name in ("c_scripted", "d_yaw"):
        path = drives(archive)[name]
        spans, last_health = health_alarm_spans(path, MISALIGNED)
        catalogued = rows(indexed, "SELECT raised_ns, cleared_ns, message FROM alarms "
                          "WHERE drive = ? AND alarm = ? ORDER BY raised_ns", path, MISALIGNED)
        assert spans and len(catalogued) == len(spans)
        for (raised, cleared, text), (since, inactive_at) in zip(catalogued, spans, strict=True):
            assert raised == since
            if inactive_at is None:  # active in the last /health: cleared after it, or never
                assert cleared is None or cleared > last_health
            else:  # /health is published at intervals: the clear is at or before it says so
                assert cleared is not None and raised < cleared <= inactive_at
                assert inactive_at - cleared < 2 * NS
            assert "misaligned" in text
    assert rows(indexed, "SELECT count(*) FROM alarms WHERE alarm = ? AND drive IN (?, ?, ?)",
                MISALIGNED, *(drives(archive)[n] for n in ("a_clean", "b_short", "e_clean"))
                ) == [(0,)]


@pytest.mark.slow
def test_drives_longer_than_a_limit_with_a_lead_vehicle_under_20_m(
        archive: Path, indexed: Path) -> None:
    d = drives(archive)
    answer = rows(indexed, LONG_WITH_CLOSE_LEAD, 10.0)

    # every simulated drive has the cut-in ~10 m ahead; the 8 s drive is too short
    assert [r[0] for r in answer] == [d[n] for n in ("a_clean", "c_scripted", "d_yaw",
                                                     "e_clean")]
    assert all(r[1] > 10.0 and r[2] < 20.0 for r in answer)
    cut_ins = rows(indexed, "SELECT drive, distance_m, previous_distance_m FROM lead_changes "
                   "WHERE cut_in AND drive = ?", d["c_scripted"])
    assert len(cut_ins) == 1
    (_, distance, before), = cut_ins
    assert distance < 20.0 < before


@pytest.mark.slow
def test_the_drives_table_holds_what_the_drive_says_of_itself(archive: Path,
                                                              indexed: Path) -> None:
    path = drives(archive)["c_scripted"]
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    (row,) = rows(indexed, "SELECT size, start_ns, end_ns, duration_s, profile, buses, frames, "
                  "decode_errors, tankviz_version FROM drives WHERE path = ?", path)
    size, start, end, duration, profile, buses, frames, errors, version = row
    assert size == Path(path).stat().st_size
    assert (start, end) == (summary.statistics.message_start_time,
                            summary.statistics.message_end_time)
    assert duration == pytest.approx((end - start) / NS)
    assert (profile, buses, errors) == ("ecocar", ["can0"], 0)
    counts = {summary.channels[i].topic: n
              for i, n in summary.statistics.channel_message_counts.items()}
    assert frames == len(list(ArchiveSource(path))) > counts["/can/can0/frames"]  # in blocks
    assert version
    topics = dict((t, (n, rate)) for t, n, rate in rows(
        indexed, "SELECT topic, count, rate_hz FROM topics WHERE drive = ?", path))
    assert {t: n for t, (n, _) in topics.items()} == counts
    assert topics["/health"][1] == pytest.approx(counts["/health"] / duration)


# --- incremental indexing ------------------------------------------------------------------------

def counting(read: list[str]) -> catalog.Reader:
    def reader(paths: Sequence[str]) -> Iterator[DriveRows | str]:
        read.extend(paths)
        return read_here(paths)
    return reader


@pytest.mark.slow
def test_a_reindex_reads_only_new_and_changed_drives_and_forgets_removed_ones(
        archive: Path, tmp_path: Path) -> None:
    root = tmp_path / "drives"
    shutil.copytree(archive, root)
    out = tmp_path / "catalog.duckdb"
    read: list[str] = []
    index(out, [str(root)], reader=counting(read))
    assert len(read) == 5

    read.clear()
    again = index(out, [str(root)], reader=counting(read))
    assert read == [] and len(again.unchanged) == 5

    d = drives(root)
    # rewritten: another drive in the same file
    simulated(Path(d["e_clean"]), seed=6, day=3, duration_s=8.0)
    (root / "2026-01" / "d_yaw.mcap").unlink()
    new = simulated(root / "2026-01" / "f_new.mcap", seed=7, day=4, duration_s=8.0)
    read.clear()
    report = index(out, [str(root)], reader=counting(read))

    assert sorted(read) == sorted([d["e_clean"], str(new)])
    assert (report.new, report.changed, report.removed) == ([str(new)], [d["e_clean"]],
                                                             [d["d_yaw"]])
    assert rows(out, "SELECT count(*) FROM drives") == [(5,)]
    assert rows(out, "SELECT count(*) FROM alarms WHERE drive = ?", d["d_yaw"]) == [(0,)]
    (start,) = rows(out, "SELECT start_ns FROM drives WHERE path = ?", d["e_clean"])[0]
    assert start >= DEFAULT_START_NS + 3 * DAY_NS  # the rewritten drive's own times


# --- bad files -----------------------------------------------------------------------------------

@pytest.mark.slow
def test_a_file_that_is_not_a_tankviz_drive_is_reported_in_one_line_and_the_others_indexed(
        archive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "drives"
    shutil.copytree(archive / "2025-12", root)
    (root / "notes.mcap").write_text("not a drive\n")
    with (root / "foreign.mcap").open("wb") as f:  # a valid MCAP, not written by tankviz
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("Point", "jsonschema", b"{}")
        channel = writer.register_channel("/points", "json", schema)
        writer.add_message(channel, log_time=1, data=b"{}", publish_time=1)
        writer.finish()
    out = tmp_path / "catalog.duckdb"

    code = main(["catalog", str(root), "-o", str(out)])

    captured = capsys.readouterr()
    skipped = [line for line in captured.err.splitlines() if line.startswith("skipped: ")]
    assert code == 1
    assert len(skipped) == 2 and len(captured.err.splitlines()) == 2
    assert any(str(root / "notes.mcap") in s and "not a readable MCAP" in s for s in skipped)
    assert any(str(root / "foreign.mcap") in s and "not a tankviz drive" in s for s in skipped)
    assert "2 new, 0 changed, 0 unchanged, 0 removed, 2 not indexed" in captured.out
    assert rows(out, "SELECT count(*) FROM drives") == [(2,)]


def test_indexing_without_naming_the_catalogue_or_into_a_missing_one_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["catalog", str(tmp_path)]) == 1
    assert "-o catalog.duckdb" in capsys.readouterr().err
    assert main(["catalog", "query", str(tmp_path / "none.duckdb"), "SELECT 1"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "none.duckdb: no such catalogue" in err


# --- the command: canned questions and how to open each answer -----------------------------------

def test_alarm_query_prints_each_raise_with_the_replay_command_and_the_foxglove_time(
        archive: Path, indexed: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = drives(archive)
    assert main(["catalog", "query", str(indexed), "--alarm", MISALIGNED]) == 0
    out = capsys.readouterr().out

    raised = rows(indexed, "SELECT a.drive, a.raised_ns, d.start_ns FROM alarms a JOIN drives d "
                  "ON a.drive = d.path WHERE alarm = ? ORDER BY d.start_ns", MISALIGNED)
    assert [r[0] for r in raised] == [d["c_scripted"], d["d_yaw"]]
    for drive, raised_ns, start_ns in raised:
        start_s = (raised_ns - start_ns) // 1_000_000 / 1000
        assert f"tankviz replay {drive} --start {start_s:.3f}" in out
        assert f"log time {raised_ns // NS}.{raised_ns % NS:09d}" in out
    assert f"({len(raised)} rows)" in out
    # the start is the one replay takes: seconds after the drive's first message
    c_raised = raised[0][1] - raised[0][2]
    assert 0.7 * 20 * NS < c_raised < 20 * NS


def test_an_unknown_alarm_or_topic_names_the_closest_ones(
        indexed: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["catalog", "query", str(indexed), "--alarm", "radar-camera.misalign"]) == 1
    err = capsys.readouterr().err
    assert "no alarm 'radar-camera.misalign'" in err and MISALIGNED in err
    assert main(["catalog", "query", str(indexed), "--topic", "/perception/leed"]) == 1
    assert "closest: /perception/lead" in capsys.readouterr().err


def test_topic_and_between_queries(archive: Path, indexed: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    d = drives(archive)
    assert main(["catalog", "query", str(indexed), "--topic", "/perception/radar"]) == 0
    out = capsys.readouterr().out
    assert all(p in out for p in d.values()) and "(5 rows)" in out
    assert "tankviz replay" in out and "--start 0.000" in out  # each from its start

    assert main(["catalog", "query", str(indexed), "--between", "2025-12-31",
                 "2026-01-01T23:00:00"]) == 0
    out = capsys.readouterr().out
    listed = {name for name, p in d.items() if p in out}
    assert listed == {"b_short", "c_scripted"} and "(2 rows)" in out

    assert main(["catalog", "query", str(indexed), "--alarm", MISALIGNED, "--between",
                 "2026-01-02", "2026-01-09"]) == 0
    out = capsys.readouterr().out
    assert d["d_yaw"] in out and d["c_scripted"] not in out

    assert main(["catalog", "query", str(indexed), "--between", "2026-01-02", "soon"]) == 1
    assert "--between soon: expected a date or time" in capsys.readouterr().err


def test_sql_queries_print_a_table_and_bad_sql_is_one_line(
        indexed: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["catalog", "query", str(indexed),
                 "SELECT object_group, count(*) AS drives FROM objects_summary "
                 "GROUP BY object_group ORDER BY object_group"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["object_group", "drives"]
    assert [line.split() for line in out[2:6]] == [["camera", "5"], ["lead", "5"],
                                                   ["radar", "5"], ["tracks", "5"]]
    assert main(["catalog", "query", str(indexed), "SELECT nope FROM drives"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "nope" in err


# --- another car ---------------------------------------------------------------------------------

def retrofit_drive(shared_dbc: Path, tmp_path: Path) -> tuple[Path, Path]:
    """A Bosch MRR radar retrofit (opendbc's tesla_radar_bosch.dbc, copied) with a profile that
    calls the sensor ``front_mrr`` and its group ``mrr_points``: 10 s, the radar silent from 3 s
    to 6 s, the wheel speed at 20 Hz throughout. Returns the drive and the DBC copy."""
    dbc = tmp_path / "front_radar.dbc"
    shutil.copy(shared_dbc / "tesla_radar_bosch.dbc", dbc)
    text = (Path(__file__).parent / "profiles" / "bosch_radar.toml").read_text()
    for old, new in (("[sensors.radar]", "[sensors.front_mrr]"),
                     ('sensor = "radar"', 'sensor = "front_mrr"'),
                     ("[objects.radar]", "[objects.mrr_points]"),
                     ('name = "bosch_radar"', 'name = "retrofit_mrr"')):
        assert old in text
        text = text.replace(old, new)
    profile = tmp_path / "retrofit.toml"
    profile.write_text(text)
    db = cantools.database.load_file(dbc)
    assert isinstance(db, cantools.database.can.Database)
    frames: list[can.Message] = []
    for k in range(200):
        t = T0 + k * 0.05
        frames.append(message(db, "Msg169_ESP_wheelSpeeds", t, ESP_wheelSpeedReL_HS=50))
        if 3.0 <= k * 0.05 < 6.0:
            continue
        for i in range(2):
            frames.append(message(db, f"RadarPoint{i}_A", t + 0.001 + i * 0.01,
                                  LongDist=30.0 - k * 0.1 + 5 * i, LatDist=1.5 - i, Valid=1,
                                  ProbExist=90))
            frames.append(message(db, f"RadarPoint{i}_B", t + 0.002 + i * 0.01, Class=1))
    log = tmp_path / "retrofit.blf"
    with can.Logger(log) as logger:
        for m in frames:
            logger.on_message_received(m)
    drive = tmp_path / "drives" / "retrofit.mcap"
    drive.parent.mkdir()
    convert([log], drive, [str(dbc)], profile=str(profile))
    return drive, dbc


def test_a_drive_of_another_car_is_catalogued_with_its_own_names(
        shared_dbc: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drive, dbc = retrofit_drive(shared_dbc, tmp_path)
    out = tmp_path / "catalog.duckdb"
    assert main(["catalog", str(drive.parent), "-o", str(out)]) == 0
    capsys.readouterr()

    assert rows(out, "SELECT profile, buses FROM drives") == [("retrofit_mrr", ["can0"])]
    alarms = rows(out, "SELECT alarm, raised_s, cleared_s FROM alarms ORDER BY raised_ns")
    silent = [a for a in alarms if a[0] == "front_mrr.silent"]
    assert len(silent) == 1 and 3.0 < silent[0][1] < silent[0][2] < 10.0
    groups = rows(out, "SELECT object_group, valid_objects, max_count, min_distance_m "
                  "FROM objects_summary")
    assert [g[0] for g in groups] == ["mrr_points"]  # no lead, no camera: none made up
    assert groups[0][1] > 0 and groups[0][2] == 2
    assert groups[0][3] < 30.0 - 199 * 0.1 + 3.6 + 1.0  # the nearest point, from the mount
    assert rows(out, "SELECT count(*) FROM lead_changes") == [(0,)]

    # docs/commands.md's third question: recorded with a database whose hash differs from today's
    assert rows(out, DATABASE_CHANGED, "front_radar", str(dbc)) == []
    with dbc.open("a") as f:
        f.write('\nCM_ "today\'s edit";\n')
    changed = rows(out, DATABASE_CHANGED, "front_radar", str(dbc))
    assert [r[:2] for r in changed] == [(str(drive), "front_radar")]

    assert main(["catalog", "query", str(out), "--alarm", "front_mrr.silent"]) == 0
    assert f"tankviz replay {drive} --start {silent[0][1]:.3f}" in capsys.readouterr().out


def test_an_alarm_still_raised_at_the_end_has_no_clear_time(
        shared_dbc: Path, tmp_path: Path) -> None:
    drive, _ = retrofit_drive(shared_dbc, tmp_path)
    rows_ = catalog.read_drive(drive).tables["alarms"]
    with open(drive, "rb") as f:
        meta = next(dict(m.metadata) for m in make_reader(f).iter_metadata()
                    if m.name == "tankviz")
    events = json.loads(meta["alarms"])
    still = {e["alarm"] for e in events} - {e["alarm"] for e in events if e["event"] == "cleared"}
    assert still  # the 20 Hz wheel speed is below its expected rate to the end
    assert {r[1] for r in rows_ if r[3] is None} == still


def test_alarms_come_from_the_log_when_the_metadata_record_is_missing() -> None:
    t = DEFAULT_START_NS
    log = [(t + 1 * NS, "tankviz.health", "ALARM front_mrr.silent: mrr_points: no frame for 1.3 s"),
           (t + 2 * NS, "tankviz.values", "ALARM not.this: a warning of another kind"),
           (t + 4 * NS, "tankviz.health", "cleared front_mrr.silent (the condition ended 2.0 s "
            "ago): was mrr_points: no frame for 3.0 s"),
           (t + 5 * NS, "tankviz.health", "ALARM front_mrr.silent: mrr_points: again"),
           (t + 6 * NS, "tankviz.health", "ALARM bus.side can.silent: no traffic")]
    events = catalog.alarm_events_from_log(log)
    table = catalog.alarm_rows("x.mcap", t, events)
    assert [(r[1], r[6], r[7]) for r in table] == [("front_mrr.silent", 1.0, 4.0),
                                                   ("front_mrr.silent", 5.0, None),
                                                   ("bus.side can.silent", 6.0, None)]


# --- Dask ----------------------------------------------------------------------------------------

def tables(path: Path) -> dict[str, list[tuple[Any, ...]]]:
    con = duckdb.connect(str(path), read_only=True)
    try:
        return {t: sorted(con.execute(f"SELECT * FROM {t}").fetchall(), key=repr)
                for t in catalog.SCHEMA}
    finally:
        con.close()


@pytest.mark.slow
def test_two_local_dask_workers_make_the_same_catalogue_as_one_process(
        archive: Path, indexed: Path, tmp_path: Path) -> None:
    out = tmp_path / "dask.duckdb"
    result = tankviz("catalog", str(archive), "-o", str(out), "--workers", "2")
    assert result.returncode == 0, result.stderr
    assert "5 new, 0 changed, 0 unchanged, 0 removed, 0 not indexed" in result.stdout
    assert tables(out) == tables(indexed)


def test_without_dask_the_workers_option_says_what_to_install(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    with pytest.raises(UsageError, match=r"pip install 'tankviz\[fleet\]'"):
        catalog.dask_reader(workers=2)


def test_lead_changes_count_the_lead_number_and_old_drives_the_id() -> None:
    from bridge.fleet.catalog import _Lead

    def changes(seen: list[tuple[int, float, int]]) -> list[tuple[int | None, int, bool]]:
        lead = _Lead()
        for t, (lead_id, distance, number) in enumerate(seen):
            lead.see("d", 0, t, True, lead_id, distance, number)
        return [(row[4], row[5], row[8]) for row in lead.rows]

    # the lead's twins take turns in its slot (ids 2 and 8, lead_number 1), then a car cuts in
    twins = [(2, 50.0, 1), (8, 50.4, 1), (2, 50.1, 1), (8, 50.3, 1), (0, 31.0, 2)]
    assert changes(twins) == [(None, 2, False), (8, 0, True)]
    # a drive recorded before lead_number: every change of id
    assert len(changes([(i, d, 0) for i, d, _ in twins])) == 5


# --- the command line ---------------------------------------------------------------------------

def test_the_usage_says_both_forms_and_query_help_is_the_querys(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["catalog", "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(
        "usage: tankviz catalog DRIVES... -o CATALOG.duckdb [--workers N | --scheduler ADDRESS]\n"
        '       tankviz catalog query CATALOG.duckdb ["SQL" | --alarm ID | --topic T | --mark '
        "TEXT]\n                             [--between T1 T2]\n")
    assert "DRIVES | query" not in out and "--workers" in out
    # the examples, as written: every mark with 'ghost' in the fleet (#34)
    assert ("""\n      "SELECT drive, mark, t_s, text FROM marks WHERE text ILIKE '%ghost%'"\n"""
            in out)
    with pytest.raises(SystemExit) as done:
        main(["catalog", "query", "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith('usage: tankviz catalog query CATALOG.duckdb ["SQL" | --alarm ID | '
                          "--topic T | --mark TEXT] [--between T1 T2]\n")
    assert "every mark with 'ghost' in the fleet:" in out
    assert "--alarm ID" in out and "--workers" not in out and "-o CATALOG" not in out
