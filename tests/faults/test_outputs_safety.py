"""No command writes over one of its inputs, and two runs writing one output never mix their bytes
(issue #23, items 1, 2, 11 and 16).

- ``convert LOG -o LOG --force`` wrote an MCAP over the log. Now an output that is an input by
  any name (the same path, a symbolic link, a hard link) is refused whatever ``--force`` says,
  and convert's output must end in ``.mcap``; recover and batch are held to the same rule.
- Two conversions to one output shared one ``.OUT.mcap.partial``: the first to finish renamed
  the other's half-written file. Each run now writes a partial file of its own and publishes it
  whole: with ``--force`` the last to finish wins, without it the second keeps the first's file.
- ``convert a.blf a.blf`` recorded every frame twice; one log in two formats did too, unsaid.
- ``convert LOG --sample`` merged the bundled sample drive into the user's.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import T0, WriteLog, timeout_scale
from mcap.reader import make_reader

from bridge.apps.recover import recover_file
from bridge.cli import main
from bridge.errors import FileError, UsageError
from bridge.fleet.batch import find_inputs, group_drives, plan_jobs
from bridge.frame import Frame
from bridge.io.can_logs import LogSource
from bridge.pipeline.convert import convert, same_frames
from bridge.sim.ecocar import simulate
from bridge.sinks.can_log_writer import write_log as write_sim_log
from bridge.sinks.outputs import atomic_output

DRIVE_S = 2.0


def sim_log(path: Path, duration_s: float = DRIVE_S) -> Path:
    write_sim_log(simulate(duration_s=duration_s, seed=1), path, path.suffix)
    return path


@pytest.fixture
def log(tmp_path: Path) -> Path:
    return sim_log(tmp_path / "d.blf")


@pytest.fixture
def drive(tmp_path: Path, log: Path) -> Path:
    out = tmp_path / "d.mcap"
    convert([log], out, [])
    return out


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def link(kind: str, target: Path, name: Path) -> Path:
    """``name`` as a symbolic or hard link to ``target``, or ``target`` itself."""
    if kind == "symlink":
        name.symlink_to(target)
    elif kind == "hard link":
        os.link(target, name)
    else:
        return target
    return name


# --- item 1: nothing is written over an input ---------------------------------------------------

def test_convert_refuses_to_write_a_log_over_itself_even_with_force(
        log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = log.read_bytes()
    assert main(["convert", str(log), "-o", str(log), "--force", "--quiet"]) == 1
    assert one_error_line(capsys) == (
        f"error: {log}: is the same file as the input {log}: tankviz never writes over its "
        "inputs; name a new output file")
    assert log.read_bytes() == before


def test_convert_writes_only_an_mcap(log: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "d.asc"
    assert main(["convert", str(log), "-o", str(out), "--quiet"]) == 1
    assert one_error_line(capsys) == (f"error: {out}: convert writes an MCAP drive archive: "
                                      "the output's name must end in .mcap")
    assert not out.exists()


@pytest.mark.parametrize("kind", ["same path", "symlink", "hard link"])
def test_convert_refuses_an_output_that_is_its_log_by_another_name(
        log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str) -> None:
    before = log.read_bytes()
    out = link(kind, log, tmp_path / "d_out.mcap") if kind != "same path" else log
    assert main(["convert", str(log), "-o", str(out), "--force", "--quiet"]) == 1
    assert f"is the same file as the input {log}" in one_error_line(capsys)
    assert log.read_bytes() == before


@pytest.mark.parametrize("kind", ["same path", "symlink", "hard link"])
def test_rederiving_a_drive_never_writes_over_it(
        drive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str) -> None:
    before = drive.read_bytes()
    out = link(kind, drive, tmp_path / "again.mcap")
    assert main(["convert", str(drive), "-o", str(out), "--force", "--quiet"]) == 1
    assert one_error_line(capsys).startswith(f"error: {out}: is the same file as the input")
    assert drive.read_bytes() == before


@pytest.mark.parametrize("kind", ["symlink", "hard link"])
def test_recover_never_writes_over_the_file_it_recovers(drive: Path, tmp_path: Path,
                                                        kind: str) -> None:
    before = drive.read_bytes()
    fixed = link(kind, drive, tmp_path / "fixed.mcap")
    with pytest.raises(FileError, match=r"is the (file to recover|same file as the input)"):
        recover_file(drive, fixed, force=True)
    assert drive.read_bytes() == before


def test_a_batch_whose_out_folder_is_its_input_folder_by_a_link_is_refused(
        drive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The output ``OUT/d.mcap`` is the input ``d.mcap`` when OUT links to the drives' folder."""
    before = drive.read_bytes()
    folder = tmp_path / "same"
    folder.symlink_to(tmp_path)
    assert main(["batch", "rederive", str(drive), "--out", str(folder), "--force"]) == 1
    line = one_error_line(capsys)
    assert line.startswith(f"error: {folder / 'd.mcap'}: is an input") and str(drive) in line
    assert drive.read_bytes() == before


def test_a_batch_output_that_is_a_hard_link_to_an_input_is_refused(drive: Path,
                                                                   tmp_path: Path) -> None:
    (tmp_path / "out").mkdir()
    os.link(drive, tmp_path / "out" / "d.mcap")
    drives = group_drives(find_inputs([str(drive)], [".mcap"]), [".mcap"], merge=False)
    with pytest.raises(UsageError, match=r"out/d\.mcap: is an input .*d\.mcap"):
        plan_jobs(drives, tmp_path / "out")


# --- item 2: two runs, one output ---------------------------------------------------------------

def stray(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.mark.parametrize("force", [False, True])
def test_two_runs_writing_one_output_leave_one_whole_file(tmp_path: Path, force: bool) -> None:
    """The first run is half way when the second writes the whole output; then the first ends.
    The output is one run's bytes, whole: the last's with force, else the first finisher's."""
    out = tmp_path / "o.mcap"
    first = atomic_output(out, force=force)
    stream = first.__enter__()
    stream.write(b"first " * 1000)
    with atomic_output(out, force=force) as other:
        other.write(b"second " * 1000)
    assert out.read_bytes() == b"second " * 1000
    stream.write(b"first " * 1000)
    with pytest.raises(FileError, match="another run") if not force else \
            contextlib.nullcontext():
        first.__exit__(None, None, None)
    assert out.read_bytes() == (b"first " * 2000 if force else b"second " * 1000)
    assert stray(tmp_path) == []


def test_two_simulations_writing_one_log_leave_one_whole_log(tmp_path: Path) -> None:
    """Half way through the first run, a second one writes the whole log: the first keeps it."""
    out = tmp_path / "d.blf"
    drive = list(simulate(duration_s=DRIVE_S, seed=1))

    def first_run() -> Iterator[Frame]:
        for i, frame in enumerate(drive):
            if i == len(drive) // 2:
                write_sim_log(iter(drive), out, ".blf")  # the second run, whole
            yield frame

    with pytest.raises(FileError, match="another run"):
        write_sim_log(first_run(), out, ".blf")
    assert [f.timestamp_ns for f in LogSource(out)] == [f.timestamp_ns for f in drive]
    assert stray(tmp_path) == []


def test_a_partial_output_left_by_a_killed_run_is_removed_and_a_live_one_kept(
        tmp_path: Path) -> None:
    out = tmp_path / "o.mcap"
    (tmp_path / ".o.mcap.partial").write_bytes(b"an older version's leftover")
    (tmp_path / ".o.mcap.4242-00c0ffee.partial").write_bytes(b"a killed run's")
    live = tmp_path / ".o.mcap.4343-0000beef.partial"
    live.write_bytes(b"being written")
    with live.open("rb") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        with atomic_output(out) as stream:
            stream.write(b"done")
    assert out.read_bytes() == b"done"
    assert stray(tmp_path) == [live.name]


def readable(path: Path) -> int:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    return summary.statistics.message_count


@pytest.mark.slow
@pytest.mark.parametrize("force", [False, True])
def test_two_conversions_at_once_to_one_output_leave_one_complete_drive(
        tmp_path: Path, force: bool) -> None:
    log = sim_log(tmp_path / "long.blf", 20.0)
    out = tmp_path / "o.mcap"
    if force:
        out.write_bytes(b"an old output")
    command = [sys.executable, "-m", "bridge", "convert", str(log), "-o", str(out), "--quiet",
               "--profile", "ecocar", "--no-read-ahead", *(["--force"] if force else [])]
    runs = [subprocess.Popen(command, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(r.wait(timeout=300 * timeout_scale()), r.stderr.read() if r.stderr else "")
               for r in runs]
    codes = sorted(code for code, _ in results)
    assert codes == ([0, 0] if force else [0, 1]), results
    for code, err in results:
        if code:
            (line,) = err.splitlines()
            assert line.startswith(f"error: {out}: ") and ("another run" in line
                                                           or "exists already" in line)
    assert readable(out) > 0
    assert stray(tmp_path) == []


# --- item 11: one log given twice ---------------------------------------------------------------

@pytest.mark.parametrize("kind", ["same path", "hard link"])
def test_one_log_given_twice_is_refused(log: Path, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str], kind: str) -> None:
    again = link(kind, log, tmp_path / "copy.blf")
    out = tmp_path / "o.mcap"
    assert main(["convert", str(log), str(again), "-o", str(out), "--quiet"]) == 1
    line = one_error_line(capsys)
    assert line.startswith(f"error: {again}: ") and "recorded twice" in line
    if kind == "hard link":
        assert f"same file as the input {log}" in line
    assert not out.exists()


@pytest.mark.slow
def test_one_log_in_two_formats_is_converted_with_a_warning_naming_both(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blf, asc = sim_log(tmp_path / "trip.blf"), sim_log(tmp_path / "trip.asc")
    out = tmp_path / "o.mcap"
    assert main(["convert", str(blf), str(asc), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    warning = (f"warning: {blf} and {asc} hold the same frames (their first 16 match in id, "
               "data and time): the drive records each of them twice; convert one of the two")
    assert warning in captured.err.splitlines()
    assert warning.removeprefix("warning: ") in captured.out  # and in the summary


def test_bus_files_of_one_drive_are_not_taken_for_one_log(
        tmp_path: Path, write_log: WriteLog, capsys: pytest.CaptureFixture[str]) -> None:
    import can

    def bus(channel: int) -> list[can.Message]:
        return [can.Message(timestamp=T0 + i * 0.01, arbitration_id=0x100 + channel,
                            data=bytes(8), channel=channel) for i in range(50)]

    logs = [write_log("trip_can0.blf", bus(0)), write_log("trip_can1.blf", bus(1))]
    assert main(["convert", *map(str, logs), "-o", str(tmp_path / "o.mcap")]) == 0
    assert "same frames" not in capsys.readouterr().err


def test_frames_match_within_a_millisecond_and_nothing_else_may_differ() -> None:
    head = [(T0_NS + i * 10**6, 0x100 + i, False, bytes([i]) * 8) for i in range(16)]
    rounded = [(t + 1000, *rest) for t, *rest in head]  # ASC's microseconds, rounded
    assert same_frames(head, rounded)
    assert not same_frames(head, head[:15])
    assert not same_frames(head, [*head[:15], (head[15][0], 0x7FF, False, head[15][3])])
    assert not same_frames(head, [(t + 2 * 10**6, *rest) for t, *rest in head])
    assert not same_frames([], [])


T0_NS = int(T0 * 1e9)


# --- item 16: --sample alone --------------------------------------------------------------------

def test_the_sample_is_not_merged_into_a_log(log: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "o.mcap"
    assert main(["convert", str(log), "--sample", "-o", str(out), "--quiet"]) == 1
    assert one_error_line(capsys) == (
        f"error: convert: --sample converts the bundled sample drive alone; it cannot be "
        f"merged into {log} (convert each on its own)")
    assert not out.exists()


def test_a_signal_the_moment_the_partial_file_is_made_leaves_nothing_behind(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Python runs a signal's handler between two bytecodes: right after the partial file was
    made and before its name was kept, a SIGHUP's Stopped left it behind (a convert stopped
    by a signal in CI, under load)."""
    from bridge.sinks import outputs

    made = outputs._create_partial

    def interrupted(*args: object) -> object:
        made(*args)  # made, then the signal's handler raises before the caller keeps it
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "_create_partial", interrupted)
    with pytest.raises(KeyboardInterrupt), outputs.atomic_output(tmp_path / "drive.mcap"):
        pass
    assert list(tmp_path.iterdir()) == []
