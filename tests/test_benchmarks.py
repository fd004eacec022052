"""The benchmarks of issue #15 run and report every row (behaviour only: no timing is asserted).

tools/bench_convert.py and tools/bench_report.py are reports, not tests; here they run in a tiny
mode so that a change that breaks them (a renamed topic, a moved module) shows at once.
"""

from __future__ import annotations

import importlib.util
import inspect
import itertools
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import cantools
import pytest

TOOLS = Path(__file__).resolve().parents[1] / "tools"

#: Every row of issue #15's table that bench_convert measures.
CONVERT_ROWS = (
    "convert with the scene, tankviz / naive (BLF, simulated)",
    "convert with the scene, tankviz / naive (ASC, simulated)",
    "convert raw + decoded, tankviz / naive (BLF, simulated)",
    "convert raw + decoded, tankviz / naive (ASC, simulated)",
    "convert raw + decoded, tankviz / naive (candump, real-format log)",
    "convert raw + decoded, tankviz / bare LogReader (BLF)",
    "convert raw + decoded, tankviz / bare LogReader (ASC)",
    "archive size / BLF size, raw only",
    "archive size / BLF size, raw + decoded",
    "archive size / BLF size, with scene",
    "share of a 1 s log's convert (with scene) spent importing",
)

#: The start of every row of issue #36's budgets that bench_report measures.
BUDGET_ROWS = (
    *(f"archive, {kind} / log: {drive}"
      for drive in ("simulated ecocar BLF", "highway car BLF", "Toyota candump")
      for kind in ("full (raw + decoded + scene)", "raw")),
    *(f"reading, LogSource's own CPU / python-can's reader: {fmt}"
      for fmt in ("BLF", "ASC", "candump")),
    "start, a short convert",
    "start, tankviz --help",
)
#: The revision issue #36 starts from: the budgets' before.
BUDGETS_BEFORE = "304ae15"


def tool(name: str) -> ModuleType:
    if str(TOOLS) not in sys.path:
        sys.path.insert(0, str(TOOLS))  # the tools import benchlib, as they do run as scripts
    spec = importlib.util.spec_from_file_location(f"tools_{name}", TOOLS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


#: The code before issue #26: raw frames one message each (2.45x the BLF), not in blocks.
BEFORE_BLOCKS = "a6fe390"


def has_commit(rev: str) -> bool:
    return subprocess.run(["git", "-C", str(TOOLS.parent), "cat-file", "-e", f"{rev}^{{commit}}"],
                          capture_output=True).returncode == 0


def table_of(text: str) -> dict[str, list[str]]:
    """A markdown report's table rows: the first cell, then the others."""
    return {cells[0]: cells[1:] for line in text.splitlines() if line.startswith("| ")
            for cells in [[c.strip() for c in line.strip("|").split(" | ")]]}


@pytest.mark.slow
def test_bench_report_writes_the_whole_table_before_and_now_with_numeric_ratios(
        tmp_path: Path, shared_dbc: Path) -> None:
    """The whole report in one tiny run: issue #15's table and issue #36's budgets, each with a
    before column measured in the same run by the same tools (``--before REV``: a worktree of
    REV, its ``bridge``, not this checkout's; the budgets' before is 304ae15)."""
    before = has_commit(BEFORE_BLOCKS)  # (not in a shallow clone)
    report = tmp_path / "report.md"
    run = subprocess.run(
        [sys.executable, str(TOOLS / "bench_report.py"), "--out", str(report),
         *(["--before", BEFORE_BLOCKS, "--ab-seconds", "2", "--ab-runs", "1"] if before else []),
         "--frames", "5000", "--frames2", "10000", "--real-frames", "5000", "--runs", "1",
         "--budget-frames", "3000", "--budget-seconds", "3", "--budget-runs", "1",
         "--workdir", str(tmp_path / "bench"),
         "--real-dbc", str(shared_dbc / "gm_global_a_object.dbc")],
        capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    # bench_convert prints the ratios first, then the details
    printed = run.stdout
    assert printed.index("convert with the scene, tankviz / naive") < printed.index(
        "bare can.LogReader iteration")
    assert "WARNING" not in printed  # naive and tankviz wrote the same messages per topic

    text = report.read_text()
    table = table_of(text)
    for measure in CONVERT_ROWS:
        *ratios, goal, _ok = table[measure]
        assert len(ratios) == 1 + before, (measure, ratios)
        # a speed ratio shows the other clock's beside it: "2.31x (1.71x cpu)"
        aside = r" \(\d+\.\d\dx cpu\)" if measure.startswith("convert") else ""
        for ratio in ratios:
            assert re.fullmatch(r"\d+\.\d\dx?" + aside, ratio), (measure, ratio)
        assert goal.startswith(("≥", "≤")), (measure, goal)
    rss = next(v for k, v in table.items() if k.startswith("peak RSS, with scene"))
    hour = next(v for k, v in table.items() if k.startswith("1 hour of the 3-bus drive"))
    for cell in range(1 + before):
        assert re.fullmatch(r"\d+ → \d+ MB \([+-]\d+ MB\)", rss[cell]), rss
        assert re.fullmatch(r"\d+\.\d min", hour[cell]), hour
    for field in ("date", "machine", "git commit", "load average (1 min)", "runs", "commands"):
        assert f"- **{field}:**" in text
    assert "## Details: tools/bench_convert.py" in text
    assert "of which message indexes" in text
    assert "real-format log real-gm_global_a_object-5000f" in text
    if before:
        assert "| measure (same run, same machine) | before | now | goal | ok |" in text
        assert f"- **before:** {BEFORE_BLOCKS}" in text
        assert "## Details: tools/bench_convert.py on the code before" in text
        raw = table["archive size / BLF size, raw only"]
        old, now = (float(cell.rstrip("x")) for cell in raw[:2])
        # the before column measured the old code: a message per frame, 1.7x the blocks on this
        # short drive of benchlib's (varied payloads), 3x and more on a long one
        assert old > 1.4 * now, (old, now)
        (ab,) = [line for line in text.splitlines()
                 if line.startswith("| tankviz convert raw + decoded, 2 s simulated")]
        pair = r"\d+\.\d\d, \d+\.\d\d"
        assert re.search(rf"\| {pair} \| {pair} \(\d+\.\d\dx cpu", ab), ab

    # issue #36's budgets, before (the code at 304ae15, when this clone has it) and now
    old_budgets = has_commit(BUDGETS_BEFORE)
    if old_budgets:
        assert f"## Issue #36's budgets: before (the code at {BUDGETS_BEFORE}) and now" in text
    number = r"-?\d+\.\d\dx|\d+\.\d{3} s \(\d+\.\d{3} s wall\)"
    for start in BUDGET_ROWS:
        (row,) = [cells for measure, cells in table.items() if measure.startswith(start)]
        budget_before, budget_now, goal, met = row
        assert re.fullmatch(number, budget_now), (start, row)
        assert re.fullmatch(number, budget_before) if old_budgets else budget_before == "—", (
            start, row)
        assert goal.startswith(("≤", "<")) and met in ("ok", "**missed**"), (start, row)
    assert "Issue #36's budgets" in printed  # the table is printed too


def test_real_format_log_rolls_counters_and_checks_its_sums(shared_dbc: Path) -> None:
    bench = tool("bench_convert")
    db = cantools.database.load_file(shared_dbc / "gm_global_a_object.dbc", strict=False)
    assert isinstance(db, cantools.database.can.Database)
    frames = []
    for n, msg in enumerate(bench.real_frames(db, seed=3)):
        if n == 3000:
            break
        frames.append(msg)
    stamps = [m.timestamp for m in frames]
    assert stamps == sorted(stamps)
    assert {m.channel for m in frames} == {"can0"}
    known = {m.frame_id for m in db.messages}
    assert {m.arbitration_id for m in frames} <= known | set(bench.REAL_UNKNOWN_IDS)
    steering = db.get_message_by_name("ASCMSteeringStatus")
    sent = [m for m in frames if m.arbitration_id == steering.frame_id]
    decoded: list[dict[str, Any]] = [steering.decode(bytes(m.data), decode_choices=False)
                                     for m in sent]
    counters = [d["RollingCounter"] for d in decoded]
    assert len(counters) > 5
    assert all((b - a) % 4 == 1 for a, b in itertools.pairwise(counters))
    for m, d in zip(sent, decoded, strict=True):
        without = steering.encode(d | {"ASCMSterringStatusChecksum": 0}, scaling=False,
                                  padding=False, strict=False)
        assert d["ASCMSterringStatusChecksum"] == sum(without) % 2**16, m
    # mostly repeating: many frames carry the payload their id carried last time
    last: dict[int, bytes] = {}
    repeats = 0
    for m in frames:
        repeats += last.get(m.arbitration_id) == bytes(m.data)
        last[m.arbitration_id] = bytes(m.data)
    assert repeats > len(frames) // 4


def test_naive_scene_draws_only_what_is_valid(ecocar: cantools.database.can.Database) -> None:
    bench = tool("bench_convert")
    latest = {
        "CamLaneLeft": {"Source": 1, "Quality": 3, "C0_Offset": -1.7, "C1_Heading": 0.0,
                        "C2_Curvature": 0.001, "C3_CurvatureDerivative": 0.0},
        "CamLaneRight": {"Source": 1, "Quality": 0, "C0_Offset": 1.8, "C1_Heading": 0.0,
                         "C2_Curvature": 0.0, "C3_CurvatureDerivative": 0.0},
        "RadarObj0_A": {"Valid": 1, "ProbExist": 90.0, "LongDist": 30.0, "LatDist": 1.0,
                        "LongSpeed": -2.0},
        "RadarObj0_B": {"Length": 4.5, "Width": 1.8},
        "RadarObj1_A": {"Valid": 1, "ProbExist": 40.0, "LongDist": 60.0, "LatDist": 0.0,
                        "LongSpeed": 0.0},
        "LeadVehicle": {"Valid": 0, "PosX": 30.0, "PosY": 1.0, "TimeGap": 1.5},
    }
    scene = dict(bench.naive_scene(latest, 1_700_000_000_050_000_000))
    assert list(scene) == list(bench.NAIVE_SCENE_CATEGORIES)
    assert len(scene["ego"].entities) == 1
    (lane,) = scene["lanes"].entities  # the right lane has quality 0
    points = lane.lines[0].points
    assert len(points) == 100
    assert (points[0].x, points[0].y) == (0.0, 1.7)  # the camera counts y to the right
    assert points[-1].x == pytest.approx(100.0)
    (radar,) = scene["radar"].entities  # object 1 is below the existence threshold
    assert (radar.cubes[0].pose.position.x, radar.cubes[0].pose.position.y) == (30.0, 1.0)
    assert radar.timestamp.seconds == 1_700_000_000 and radar.timestamp.nanos == 50_000_000
    assert not scene["lead"].entities and not scene["camera"].entities
    assert not scene["tracks"].entities


def test_live_table_is_read_by_its_columns() -> None:
    report = tool("bench_report")
    printed = "\n".join([
        "window 10.2 s (senders started → every frame processed)",
        "metric                          value                  target     ok?",
        "----------------------------------------------------------------------",
        "bridge CPU (process - senders)  38.5 % of one core     < 20 %     MISSED",
        "  reference: the pipeline alone 30.1 % (25.0 µs/frame)",
        "latency frame → scene p99       31.0 ms                < 25 ms    MISSED",
        "",
        "CPU by thread over the window:",
    ])
    rows = report.live_table(printed)
    assert rows == [
        ("bridge CPU (process - senders)", "38.5 % of one core", "< 20 %", "MISSED"),
        ("reference: the pipeline alone", "30.1 % (25.0 µs/frame)", "", ""),
        ("latency frame → scene p99", "31.0 ms", "< 25 ms", "MISSED"),
    ]
    assert report.live_table("no table here") == []


@pytest.mark.slow
def test_live_stages_run_every_stage_from_bare_decoding_on() -> None:
    """``bench_live.py --stages`` adds the stages one by one, from a pipeline with no sink at all
    (decoding only) to the server: every row is a cost."""
    bench = tool("bench_live")
    frames = bench.pipeline_frames(bench.traffic(0.5), 600)
    for stages in itertools.product((False, True), repeat=4):
        record, health, profile, serve = stages
        cost = bench.pipeline_cost(frames, record=record, health=health, profile=profile,
                                   serve=serve)
        assert cost > 0, stages


@pytest.mark.slow
def test_index_bytes_are_16_per_message_plus_each_index_records_header(tmp_path: Path) -> None:
    from mcap.records import MessageIndex
    from mcap.stream_reader import StreamReader

    from bridge.pipeline.convert import convert
    from bridge.resources import data_dir

    drive = tmp_path / "sample.mcap"
    report = convert([data_dir() / "ecocar_sample.blf"], drive, [], profile="ecocar")
    with drive.open("rb") as f:
        indexes = [r for r in StreamReader(f).records if isinstance(r, MessageIndex)]

    # opcode (1) + record length (8) + channel id (2) + array length (4), then (time, offset)s
    assert tool("bench_convert").index_bytes(drive) == 15 * len(indexes) + 16 * report.messages
    assert sum(len(r.records) for r in indexes) == report.messages


@pytest.mark.slow
def test_bench_health_tick_replays_every_frame_on_both_monitors_with_the_same_bytes() -> None:
    """tools/bench_health_tick.py in a tiny run: the convert's frames reach the monitors (the
    block engine counts frames without ``on_frame``: the recording must still see each), and
    the reference (this checkout's HEAD) makes what the working tree makes."""
    run = subprocess.run([sys.executable, str(TOOLS / "bench_health_tick.py"), "--duration", "3",
                          "--repeat", "1"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.count("same bytes (every /health and /log message") == 2, run.stdout
    assert re.search(r"ecocar \(\d+ scene ticks", run.stdout), run.stdout


def test_the_health_tick_reference_takes_the_lateral_check_from_its_revision() -> None:
    """``also=("bridge.world.lateral",)``: the reference monitor's LateralSignCheck is the module
    of the revision (its worktree), not the working tree's, which stays the one imported."""
    from bridge.world.lateral import LateralSignCheck

    modules = tool("bench_health").reference_package("HEAD", also=("bridge.world.lateral",))
    check = modules["monitor"].LateralSignCheck
    method = next(f for f in vars(check).values() if inspect.isfunction(f))
    tree = sys.modules["benchlib"].worktree("HEAD")  # the one bench_health made
    assert method.__code__.co_filename == str(tree / "bridge" / "world" / "lateral.py")
    assert check is not LateralSignCheck
    assert sys.modules[LateralSignCheck.__module__].LateralSignCheck is LateralSignCheck


@pytest.mark.slow
def test_bench_bringup_cli_times_every_command_against_python_can() -> None:
    """tools/bench_bringup_cli.py on a few seconds of the RAV4-sized drive: every command runs
    and gets its row (the find-signal goal line too)."""
    run = subprocess.run([sys.executable, str(TOOLS / "bench_bringup_cli.py"), "--runs", "1",
                          "--minutes", "0.1"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    for row in ("python-can reads the log (reference)", "tankviz ids", "tankviz bits --id",
                "tankviz bits --compare", "tankviz find-signal"):
        assert re.search(rf"^{re.escape(row)}\s+[\d.]+\s+[\d.]+\s+\d+$", run.stdout, re.M), (
            row, run.stdout)
    assert "find-signal goal" in run.stdout


@pytest.mark.slow
def test_bench_bringup_measures_size_cpu_and_live_with_and_without_bring_up(
        shared_dbc: Path) -> None:
    """tools/bench_bringup.py on a few seconds of the Toyota and the highway car: every row with
    its ratio, each bring-up topic's share of the archive."""
    run = subprocess.run([sys.executable, str(TOOLS / "bench_bringup.py"), "--seconds", "4",
                          "--runs", "1"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    for car in ("toyota", "highway"):
        for measure in ("archive size", "convert CPU"):
            assert re.search(rf"^{measure} with / without bring-up, {car}.*  [+-]\d+\.\d%",
                             run.stdout, re.M), (measure, car, run.stdout)
    for sinks in ("a viewer and a recorder", "a recorder alone"):
        assert re.search(rf"^live per frame .*{sinks}\s+[+-]\d+\.\d% \(", run.stdout, re.M)
    assert "/can/can0/unknown" in run.stdout and "kB of the archive" in run.stdout


def test_bench_reading_reports_the_overhead_of_every_format(tmp_path: Path) -> None:
    """tools/bench_reading.py in a tiny run (no timing is checked): every contender and the
    overhead of each format."""
    out = subprocess.run(
        [sys.executable, str(TOOLS / "bench_reading.py"), "--frames", "3000", "--runs", "1",
         "--workdir", str(tmp_path)],
        capture_output=True, text=True, timeout=600, check=True).stdout
    for fmt in ("blf", "asc", "log"):
        assert re.search(rf"overhead of LogSource \({fmt}\): -?\d+\.\d\dx", out), out
    assert out.count("python-can ") == 3 and out.count("+ packing") == 3, out


@pytest.mark.slow
def test_bench_batch_prints_one_row_per_worker_count(tmp_path: Path) -> None:
    """tools/bench_batch.py on two 2 s drives, 1 worker vs 2, two rounds (benchlib's
    interleaved, the fastest kept): the speed-up line and a row per worker count."""
    run = subprocess.run([sys.executable, str(TOOLS / "bench_batch.py"), "--drives", "2",
                          "--duration", "2", "--workers", "2", "--runs", "2",
                          "--workdir", str(tmp_path)], capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr
    assert re.search(r"^speed-up per added core: -?\d+\.\d\d \(2 workers vs 1", run.stdout, re.M)
    for workers in (1, 2):
        assert re.search(rf"^\s+{workers}\s+2\s+[\d.]+\s+[\d.]+\s+[\d.]+\s+[\d,]+\s+[\d,]+$",
                         run.stdout, re.M), run.stdout


@pytest.mark.slow
def test_bench_live_car_measures_live_with_the_car_in_another_process() -> None:
    run = subprocess.run([sys.executable, str(TOOLS / "bench_live_car.py"), "--rates", "2000",
                          "--seconds", "2", "--readers", "process,here"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    reference, split, here = [line for line in run.stdout.splitlines() if "frames/s " in line]
    assert re.search(r"reference: .* [\d.]+% \([\d.]+ µs/frame\)  received \d+/\d+$",
                     reference), reference
    # the buses read in a process of their own, then in the pipeline's
    assert re.search(r"live \d+ +[\d.]+% \([\d.]+ µs/frame\)  reader \d+ +[\d.]+%", split), split
    assert "reader" not in here.split("read here")[1], here
    for line in (split, here):
        assert re.search(r"live \d+ +[\d.]+% \([\d.]+ µs/frame\)", line), line
        assert re.search(r"p50 [\d.]+ ms  p99 [\d.]+ ms", line), line
        recorded, sent = map(int, re.search(r"recorded (\d+)/(\d+)", line).groups())  # type: ignore[union-attr]
        assert recorded == sent > 0, line
    assert len(re.findall(r"busiest process / reference [\d.]+x, all of live [\d.]+x",
                          run.stdout)) == 2, run.stdout
