"""Broken MCAP files say why they cannot be read, the same way in catalog, inspect and replay.

:func:`bridge.io.unreadable.why_unreadable` is the one place: an empty file, a file that is not
MCAP, one cut short (at which byte, and that ``tankviz recover`` salvages it), zeros where data
never reached the disk, damage inside a complete file. Then what ``inspect`` prints of the lists a
drive keeps: the bus gaps, the input issues (a stop first, repeats counted, a cut list says how
many are left out: :func:`bridge.io.issues.summarize_issues`).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from bridge.apps.inspect import DriveSummary, format_summary, summarize_file
from bridge.apps.replay import replay_mcap
from bridge.errors import InputError
from bridge.fleet.catalog import read_drive
from bridge.io.can_logs import SourceIssue
from bridge.io.issues import summarize_issues
from bridge.io.unreadable import why_unreadable
from bridge.pipeline.drive import Drive, load_stages
from bridge.sim.ecocar import simulate
from bridge.sinks.outputs import atomic_output
from bridge.sinks.server import ViewerServer


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("drive") / "drive.mcap"
    made = Drive(load_stages([], "ecocar"))
    with atomic_output(path) as stream:
        made.record(stream)
        made.run(simulate(duration_s=12.0, seed=3))
        made.finish()
    return path


def both(path: Path) -> tuple[str, str]:
    """What catalog and inspect say of ``path`` (and replay says as inspect does)."""
    with pytest.raises(InputError) as caught_catalog:
        read_drive(path)
    with pytest.raises(InputError) as caught_inspect:
        summarize_file(path)
    with ViewerServer(port=0) as server, pytest.raises(InputError) as caught_replay:
        replay_mcap(path, server, speed=1000)
    assert str(caught_replay.value) == str(caught_inspect.value)
    return str(caught_catalog.value), str(caught_inspect.value)


def salvage(path: Path) -> str:
    return f"(tankviz recover {path} -o FIXED.mcap salvages"


def test_an_empty_file(tmp_path: Path) -> None:
    (tmp_path / "empty.mcap").write_bytes(b"")
    path = (tmp_path / "empty.mcap").resolve()
    assert both(path) == (f"{path}: not a readable MCAP file: empty file",) * 2


def test_a_file_that_is_not_mcap(tmp_path: Path) -> None:
    path = (tmp_path / "notes.mcap").resolve()
    path.write_text("not a drive, a note\n")
    assert both(path) == (f"{path}: not a readable MCAP file: it starts with b'not a dr'…, "
                          "not with the MCAP magic",) * 2
    (tmp_path / "m.mcap").write_bytes(b"\x89MCA")
    assert why_unreadable(tmp_path / "m.mcap") == (
        "not a readable MCAP file: only 4 bytes, the start of the MCAP magic")


@pytest.mark.slow
@pytest.mark.parametrize("size", [1, 4, 7])
def test_a_file_cut_right_after_it_was_created(drive: Path, tmp_path: Path, size: int) -> None:
    """#33 item 10: a drive of 1 to 7 bytes (cut inside its magic) was a traceback (struct.error)
    in inspect and replay, and inspect showed none of the files after it."""
    path = (tmp_path / "cut.mcap").resolve()
    path.write_bytes(drive.read_bytes()[:size])
    said = f"{path}: not a readable MCAP file: only {size} bytes, the start of the MCAP magic"
    assert both(path) == (said, said)


@pytest.mark.slow
def test_replay_refuses_a_file_of_a_few_bytes_before_it_prints(
        drive: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from bridge.cli import main

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(drive.read_bytes()[:3])
    assert main(["replay", str(cut), "--port", "0"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.strip() == (f"error: {cut}: not a readable MCAP file: only 3 bytes, "
                                         "the start of the MCAP magic")


def test_inspect_goes_on_after_a_file_it_cannot_read(drive: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    from bridge.cli import main

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(drive.read_bytes()[:5])
    assert main(["inspect", str(cut), str(drive)]) == 1
    out, err = capsys.readouterr()
    assert f"file:      {drive}" in out
    assert "not a readable MCAP file: only 5 bytes" in err and "Traceback" not in err


def test_a_file_cut_short_says_where_and_how_to_salvage_it(drive: Path, tmp_path: Path) -> None:
    data = drive.read_bytes()
    with drive.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    last = max(c.chunk_start_offset for c in summary.chunk_indexes)
    path = (tmp_path / "cut.mcap").resolve()
    path.write_bytes(data[:last + 1000])  # inside the last chunk
    expected = (f"{path}: not a readable MCAP file: cut at byte {last:,} of {last + 1000:,} "
                f"{salvage(path)} it)")
    catalog_says, inspect_says = both(path)
    assert catalog_says == expected
    assert inspect_says == expected


def test_zeros_where_the_data_never_reached_the_disk(drive: Path, tmp_path: Path) -> None:
    data = drive.read_bytes()
    with drive.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    last = max(c.chunk_start_offset for c in summary.chunk_indexes)
    path = (tmp_path / "zeros.mcap").resolve()
    path.write_bytes(data[:last] + bytes(5000))
    assert why_unreadable(path) == (
        f"not a readable MCAP file: zero bytes from byte {last:,} of {last + 5000:,} (data that "
        f"never reached the disk) {salvage(path)} what comes before)")


def test_a_complete_file_damaged_inside_is_no_cryptic_mcap_error(drive: Path,
                                                                  tmp_path: Path) -> None:
    data = bytearray(drive.read_bytes())
    with drive.open("rb") as f:
        f.seek(-28, 2)  # the footer's summary start
        start = int.from_bytes(f.read(8), "little")
    data[start:start + 16] = b"\x6f" * 16  # the summary's first record: opcode 0x6f, huge length
    path = (tmp_path / "damaged.mcap").resolve()
    path.write_bytes(bytes(data))
    catalog_says, inspect_says = both(path)
    assert catalog_says == (f"{path}: not a readable MCAP file: damaged inside (its summary or "
                            f"indexes are damaged) {salvage(path)} what is intact)")
    assert "opcode" not in inspect_says and "\n" not in inspect_says


# --- inspect: the lists a drive keeps ----------------------------------------------------------

def summary_with(**entries: object) -> DriveSummary:
    return DriveSummary(0, 0, 0, [], {"tankviz": {k: json.dumps(v) for k, v in entries.items()}})


def test_inspect_shows_the_bus_gaps() -> None:
    t = 1_700_000_000_000_000_000
    text = format_summary("d.mcap", summary_with(bus_gaps=[
        {"bus": "can1", "from_ns": t, "to_ns": t + 2_500_000_000, "reason": "adapter unplugged"},
        {"bus": "can0", "from_ns": t + 10**10, "to_ns": None, "reason": "no frames for 2 s"}]))
    lines = text.splitlines()
    at = lines.index("bus gaps (2; a bus lost and back):")
    assert lines[at + 1].startswith("  can1: ") and lines[at + 1].endswith(
        "(2.5 s): adapter unplugged")
    assert lines[at + 2].startswith("  can0: ") and lines[at + 2].endswith(
        "-> (not over): no frames for 2 s")


def test_input_issues_a_stop_first_repeats_counted_and_a_cut_list_says_how_many_more() -> None:
    issues = [f"a.asc:line {n}: skipped a line python-can cannot parse: 'x{n}'"
              for n in range(3, 60)]
    issues.insert(20, "b.blf: reading stopped at byte 4,096: the file is cut short")
    issues += [f"c{n}.asc:line 1: skipped a line python-can cannot parse: 'y'" for n in range(30)]
    lines = summarize_issues(issues, total=len(issues) + 500, limit=5)
    assert lines == [
        "b.blf: reading stopped at byte 4,096: the file is cut short",
        "a.asc: skipped a line python-can cannot parse: … (57 times: line 3, line 4, line 5, …)",
        "c0.asc:line 1: skipped a line python-can cannot parse: 'y'",
        "c1.asc:line 1: skipped a line python-can cannot parse: 'y'",
        "c2.asc:line 1: skipped a line python-can cannot parse: 'y'",
        f"… and {27 + 500:,} more",
    ]
    text = format_summary("d.mcap", summary_with(input_issues={"count": len(issues) + 500,
                                                               "first": issues}))
    assert "  b.blf: reading stopped at byte 4,096: the file is cut short" in text.splitlines()
    assert text.index("reading stopped") < text.index("57 times")


def test_issue_objects_are_grouped_and_a_stop_told_in_words_comes_first() -> None:
    issues = [SourceIssue("a.blf", f"object {n}", "skipped an object") for n in (3, 8)]
    assert summarize_issues([*issues, "a.blf: the file is cut at byte 10"]) == [
        "a.blf: the file is cut at byte 10",
        "a.blf: skipped an object (2 times: object 3, object 8)"]
