"""``tankviz batch``: many drives at once on Dask, each converted exactly as ``tankviz convert``
converts it.

The pure part (which files make one drive, what each output is called) is tested with made-up
time spans; the Dask part with eight simulated drives on a local cluster of two worker
processes, and with a real cluster (``dask scheduler`` and two ``dask worker`` processes started
here) running a non-ecocar profile.
"""

from __future__ import annotations

import io
import json
import os
import random
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import can
import cantools
import pytest
from conftest import T0, message, timeout_scale
from mcap.records import Attachment, AttachmentIndex, DataEnd, Footer, Metadata
from mcap.stream_reader import StreamReader
from waiting import wait_for

from bridge.cli import main
from bridge.errors import UsageError
from bridge.fleet.batch import (
    drive_stem,
    find_inputs,
    group_drives,
    plan_jobs,
    progress_line,
)
from bridge.frame import Frame
from bridge.io.can_logs import supported_suffixes
from bridge.pipeline.convert import convert
from bridge.sim.ecocar import simulate
from bridge.sinks.can_log_writer import write_log as write_sim_log

VENV_BIN = Path(sys.executable).parent
LOGS = tuple(supported_suffixes())
S = 10**9  # ns per second


# --- which files make one drive -----------------------------------------------------------------

@pytest.mark.parametrize(("name", "stem"), [
    ("drive.blf", "drive"),
    ("drive_can1.blf", "drive"),
    ("2026-10-02_morning-CAN2.asc.gz", "2026-10-02_morning"),
    ("logger_part002.log", "logger"),
    ("trip.001.asc", "trip"),
    ("trip_can0_part003.blf", "trip"),
    ("can1.blf", "can1"),            # nothing but a suffix: the name stays
    ("radar_front.blf", "radar_front"),
])
def test_a_drive_stem_is_the_name_without_its_bus_or_part_suffix(name: str, stem: str) -> None:
    assert drive_stem(Path(name), LOGS) == stem


def test_files_of_one_stem_are_one_drive_where_their_times_overlap_or_touch(
        tmp_path: Path) -> None:
    spans = {
        "a_can0.blf": (100 * S, 200 * S),
        "a_can1.blf": (101 * S, 199 * S),      # the other bus, same time: same drive
        "a_part002.blf": (230 * S, 300 * S),   # the logger's next part, 30 s later: same drive
        "a_can3.blf": (9000 * S, 9100 * S),    # same stem, hours later: another drive
        "b.blf": (150 * S, 250 * S),           # another stem: another drive
    }
    files = []
    for name in spans:
        (tmp_path / name).touch()
        files.append((tmp_path / name, tmp_path))
    drives = group_drives(files, LOGS, span=lambda p: spans[p.name])
    assert [(d.name, [p.name for p in d.inputs]) for d in drives] == [
        ("a", ["a_can0.blf", "a_can1.blf", "a_part002.blf"]),
        ("a_1970-01-01T02-30-00Z", ["a_can3.blf"]),
        ("b", ["b.blf"]),
    ]


def test_outputs_are_named_after_their_drive_and_keep_the_subfolders(tmp_path: Path) -> None:
    for rel in ("oct/d1.blf", "oct/d2_can0.asc", "oct/d2_can1.asc", "nov/d1.blf"):
        (tmp_path / "logs" / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "logs" / rel).touch()
    files = find_inputs([str(tmp_path / "logs")], LOGS)
    drives = group_drives(files, LOGS, span=lambda p: (0, S))
    jobs = plan_jobs(drives, tmp_path / "out")
    assert sorted((Path(j.output).relative_to(tmp_path / "out").as_posix(), len(j.inputs))
                  for j in jobs) == [("nov/d1.mcap", 1), ("oct/d1.mcap", 1), ("oct/d2.mcap", 2)]
    assert all(Path(p).is_absolute() for j in jobs for p in (*j.inputs, j.output))


def test_globs_find_logs_and_a_name_that_finds_nothing_is_one_line(tmp_path: Path) -> None:
    for name in ("x.blf", "y.asc", "notes.txt"):
        (tmp_path / name).touch()
    found = find_inputs([str(tmp_path / "*")], LOGS)
    assert sorted(p.name for p, _ in found) == ["x.blf", "y.asc"]
    with pytest.raises(UsageError, match=r"nothing\*\.blf: matches no file"):
        find_inputs([str(tmp_path / "nothing*.blf")], LOGS)
    with pytest.raises(UsageError, match=r"missing\.blf: no such file or folder"):
        find_inputs([str(tmp_path / "missing.blf")], LOGS)
    with pytest.raises(UsageError, match=r"holds no \.mcap"):
        find_inputs([str(tmp_path)], (".mcap",))


def test_urls_are_refused_with_what_works_instead() -> None:
    with pytest.raises(UsageError, match=r"^s3://bucket/d\.blf: .*local or shared-disk paths"):
        find_inputs(["s3://bucket/d.blf"], LOGS)


def test_two_drives_with_one_output_name_are_refused(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "d.blf").touch()
    (tmp_path / "d.asc").touch()
    files = find_inputs([str(tmp_path / "a" / "d.blf"), str(tmp_path / "d.asc")], LOGS)
    drives = group_drives(files, LOGS, span=lambda p: (0, S) if p.suffix == ".blf" else (S, 2 * S))
    # adjacent times and one stem, but different folders: two drives, and one output name
    with pytest.raises(UsageError, match=r"d\.mcap.*both"):
        plan_jobs(drives, tmp_path / "out")


def test_the_progress_line_says_drives_frames_per_second_and_eta() -> None:
    line = progress_line(done=2, failed=1, total=8, frames=300_000, elapsed=10.0,
                         fraction=0.25)
    assert "2/8 drives" in line and "1 failed" in line
    assert "30,000 frames/s" in line and "ETA 00:30" in line


def test_without_dask_batch_says_what_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "d.blf"
    log.touch()
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed: ImportError
    assert main(["batch", "convert", str(log), "--out", str(tmp_path / "out"),
                 "--dbc", "ecocar"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: tankviz batch: runs on Dask, which is not installed: "
                   "pip install 'tankviz[fleet]'"]


# --- eight simulated drives on a local cluster of two workers -----------------------------------

SIMULATED = [  # (name, seed, scenario)
    ("monday", 1, "drive"), ("tuesday", 2, "clean"), ("wednesday", 3, "radar_yaw"),
    ("thursday", 4, "radar_dropout"), ("friday", 5, "lane_loss"), ("saturday", 6, "babbling"),
]
DURATION_S = 3.0


def _bus_split(frames: Iterator[Frame]) -> tuple[list[Frame], list[Frame]]:
    radar: list[Frame] = []
    other: list[Frame] = []
    for frame in frames:
        (radar if frame.arbitration_id < 0x300 else other).append(frame)
    return radar, other


@pytest.fixture(scope="module")
def sim_logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Eight drives in ``logs/``: six simulated ones, one more split into two bus files, and a
    corrupt one."""
    logs = tmp_path_factory.mktemp("batch") / "logs"
    (logs / "week").mkdir(parents=True)
    for name, seed, scenario in SIMULATED:
        write_sim_log(simulate(duration_s=DURATION_S, seed=seed, scenario=scenario),
                      logs / "week" / f"{name}.blf", ".blf")
    radar, other = _bus_split(simulate(duration_s=DURATION_S, seed=7, scenario="drive"))
    write_sim_log(iter(radar), logs / "sunday_can0.blf", ".blf")
    write_sim_log(iter(other), logs / "sunday_can1.blf", ".blf")
    (logs / "broken.blf").write_bytes(b"LOGG" + random.Random(8).randbytes(3000))
    return logs


def _records(path: Path) -> list[object]:
    """Every record of an MCAP, chunks unpacked, with the time of the conversion taken out
    (``tankviz convert`` stamps the attachments' create time and the metadata's ``created``
    with the wall clock: the one thing two conversions of the same input differ by)."""
    out: list[object] = []
    with path.open("rb") as f:
        for record in StreamReader(f, emit_chunks=False).records:
            if isinstance(record, (Attachment, AttachmentIndex)):
                record.create_time = 0
            if isinstance(record, Attachment):
                record.crc = 0
            if isinstance(record, Metadata):
                record.metadata = {k: v for k, v in record.metadata.items() if k != "created"}
            if isinstance(record, DataEnd):
                record.data_section_crc = 0
            if isinstance(record, Footer):
                record.summary_crc = 0
            out.append(record)
    return out


def _reference(inputs: list[Path], output: Path, dbcs: list[str],
               profile: str | None) -> list[object]:
    convert(inputs, output, dbcs, profile=profile)
    return _records(output)


@pytest.mark.slow
def test_a_batch_converts_every_drive_as_convert_does_and_a_bad_one_fails_alone(
        sim_logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    args = ["batch", "convert", str(sim_logs), "--out", str(out), "--profile", "ecocar",
            "--workers", "2"]
    assert main(args) == 1
    captured = capsys.readouterr()
    assert "error: 1 of 8 drives failed" in captured.err
    failed = [line for line in captured.out.splitlines() if line.startswith("failed")]
    assert len(failed) == 1 and "broken.blf" in failed[0], captured.out

    written = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.mcap"))
    assert written == sorted([f"week/{n}.mcap" for n, _, _ in SIMULATED] + ["sunday.mcap"])
    assert not list(out.rglob("*.partial")) and not list(out.rglob(".*"))

    # Convert is deterministic but for the time it ran, and each output is what it writes for
    # the drive, record for record.
    ref = tmp_path / "ref"
    ref.mkdir()
    once = _reference([sim_logs / "week" / "monday.blf"], ref / "a.mcap", [], "ecocar")
    again = _reference([sim_logs / "week" / "monday.blf"], ref / "b.mcap", [], "ecocar")
    assert once == again
    for name, _, _ in SIMULATED:
        expected = _reference([sim_logs / "week" / f"{name}.blf"], ref / f"{name}.mcap", [],
                              "ecocar")
        assert _records(out / "week" / f"{name}.mcap") == expected, name
    # the drive in two bus files is one output, merged as convert merges them
    both = [sim_logs / "sunday_can0.blf", sim_logs / "sunday_can1.blf"]
    assert _records(out / "sunday.mcap") == _reference(both, ref / "sunday.mcap", [],
                                                              "ecocar")

    # A re-run skips what is finished: an interrupted batch resumes where it stopped.
    (out / "week" / "friday.mcap").unlink()
    (out / "week" / ".friday.mcap.partial").write_bytes(b"cut short")
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.mcap")}
    assert main(args) == 1
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert sum(line.startswith("skipped") for line in lines) == 6
    assert sorted(line.split()[0] for line in lines
                  if line.startswith(("wrote", "failed"))) == ["failed", "wrote"]
    assert {p: p.stat().st_mtime_ns for p in before} == before
    assert _records(out / "week" / "friday.mcap") == _records(ref / "friday.mcap")
    assert not (out / "week" / ".friday.mcap.partial").exists()

    # --force redoes a finished drive
    monday = out / "week" / "monday.mcap"
    os.utime(monday, ns=(0, 0))
    assert main(["batch", "convert", str(sim_logs / "week" / "monday.blf"), "--out",
                 str(out / "week"), "--profile", "ecocar", "--workers", "1", "--force"]) == 0
    assert monday.stat().st_mtime_ns > 0
    assert _records(monday) == _records(ref / "monday.mcap")

    # rederive: the drives converted again, each exactly as `tankviz convert DRIVE.mcap` does
    # (which gives the same bytes for the same drive); part files are not merged
    tuesday = (out / "week" / "tuesday.mcap").read_bytes()
    (out / "week" / "tuesday_part002.mcap").write_bytes(tuesday)
    again_out = tmp_path / "again"
    assert main(["batch", "rederive", str(out / "week" / "mon*.mcap"),
                 str(out / "week" / "tuesday*.mcap"), "--out", str(again_out),
                 "--workers", "2"]) == 0
    assert sorted(p.name for p in again_out.iterdir()) == [
        "monday.mcap", "tuesday.mcap", "tuesday_part002.mcap"]
    for name in ("monday", "tuesday_part002"):
        convert([out / "week" / f"{name}.mcap"], ref / f"re-{name}.mcap", [])
        assert (again_out / f"{name}.mcap").read_bytes() == (ref / f"re-{name}.mcap").read_bytes()


# --- a real cluster: a scheduler and two workers in their own processes -------------------------

def _workers_connected(address: str) -> int:
    from distributed import Client

    with Client(address, timeout=5) as client:
        return len(client.scheduler_info()["workers"])


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[str]:
    """``dask scheduler`` and two ``dask worker`` processes; yields the scheduler's address."""
    dask = shutil.which("dask", path=str(VENV_BIN)) or shutil.which("dask")
    if dask is None:
        pytest.skip("the dask command line (tankviz[fleet]) is not installed")
    # The scheduler takes a port the system gives it and writes its address to a file, which
    # the workers read: a port picked here and freed before the scheduler binds it can be taken
    # by another process meanwhile ("Address already in use", seen in CI).
    scheduler_file = tmp_path / "scheduler.json"
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    processes: list[subprocess.Popen[bytes]] = []

    def start(name: str, *command: str) -> None:
        with (logs / f"{name}.log").open("wb") as log:
            processes.append(subprocess.Popen([dask, *command], stdout=log, stderr=log,
                                              cwd=tmp_path))

    try:
        start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", "0",
              "--scheduler-file", str(scheduler_file), "--dashboard-address", ":0")
        for i in range(2):
            start(f"worker{i}", "worker", "--scheduler-file", str(scheduler_file),
                  "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                  "--dashboard-address", ":0", "--name", f"w{i}")
        address = ""
        connected = 0

        def up_or_ended() -> bool:
            nonlocal address, connected
            if any(p.poll() is not None for p in processes):
                return True
            try:
                address = address or json.loads(scheduler_file.read_text())["address"]
                connected = _workers_connected(address)
            except (OSError, ValueError, KeyError):
                connected = 0
            return connected == 2

        wait_for(up_or_ended, 60 * timeout_scale(), step=0.2)
        if connected != 2:
            text = "\n".join(f.read_text() for f in sorted(logs.iterdir()))
            pytest.fail(f"the Dask cluster did not come up ({connected} workers):\n{text}")
        yield address
    finally:
        for p in processes:
            p.terminate()
        for p in processes:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def _radar_frames(db: cantools.database.can.Database, t0: float, n: int,
                  channel: int) -> list[can.Message]:
    out = []
    for k in range(n):
        t = t0 + k * 0.05
        for i in range(2):
            out.append(message(db, f"RadarPoint{i}_A", t + i * 1e-4, channel=channel,
                               LongDist=20.0 + i + k * 0.1, LatDist=1.5 - i, Valid=1,
                               ProbExist=90))
            out.append(message(db, f"RadarPoint{i}_B", t + i * 1e-4 + 5e-5, channel=channel,
                               LatSpeed=0.0, Class=1))
    return out


@pytest.mark.slow
def test_a_real_dask_cluster_converts_a_non_ecocar_fleet(
        dask_cluster: str, shared_dbc: Path, tmp_path: Path) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    profile = Path(__file__).parent / "profiles" / "bosch_radar.toml"
    db = cantools.database.load_file(dbc)
    logs = tmp_path / "radar logs"
    logs.mkdir()

    def write(name: str, messages: list[can.Message]) -> Path:
        with can.Logger(logs / name) as logger:
            for m in messages:
                logger.on_message_received(m)
        return logs / name

    write("track_day.asc", _radar_frames(db, T0, 40, 0))
    # a logger's split parts: the second starts where the first ends
    write("long_run_part001.blf", _radar_frames(db, T0 + 100, 40, 0))
    write("long_run_part002.blf", _radar_frames(db, T0 + 102, 40, 0))
    out = tmp_path / "drives"
    result = subprocess.run(
        [str(VENV_BIN / "tankviz"), "batch", "convert", str(logs), "--out", str(out),
         "--dbc", str(dbc), "--profile", str(profile), "--scheduler", dask_cluster],
        capture_output=True, text=True, timeout=300 * timeout_scale())
    assert result.returncode == 0, result.stderr + result.stdout
    assert f"scheduler {dask_cluster}" in result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["long_run.mcap", "track_day.mcap"]
    ref = tmp_path / "ref.mcap"
    convert([logs / "long_run_part001.blf", logs / "long_run_part002.blf"], ref, [str(dbc)],
            profile=str(profile))
    assert _records(out / "long_run.mcap") == _records(ref)
    assert "2 drives: 2 written" in result.stdout


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_batch_line_counts_drives_under_way_and_ignores_late_events(tmp_path: Path) -> None:
    from bridge.apps.batch import _BatchProgress
    from bridge.fleet.batch import ConvertJob, JobResult

    logs = []
    for name in ("a.blf", "b.blf"):
        (tmp_path / name).write_bytes(b"x" * 1000)
        logs.append(str(tmp_path / name))
    a, b = (ConvertJob(n, (log,), str(tmp_path / f"{n}.mcap"))
            for n, log in zip("ab", logs, strict=True))
    terminal = _Terminal()
    bar = _BatchProgress([a, b], terminal, hz=1e9)
    bar.progress(b.output, 500, 0.5)
    assert terminal.getvalue().rsplit("\r", 1)[-1].startswith("\033[K[#####.....")
    assert "0/2 drives  500 frames" in terminal.getvalue()
    bar.result(JobResult(a, frames=2000, seconds=1.0, worker="w1"))
    bar.progress(a.output, 1500, 0.9)  # an event sent before the result, received after it
    line = terminal.getvalue().rsplit("\r", 1)[-1]
    assert "1/2 drives  2,500 frames" in line and "[###############.....]" in line
