"""The catalogue's numbers: a split drive's parts, a recovered drive, one file named two ways.

- each part of a drive split by ``tankviz live`` counts its own frames (its ``statistics`` are
  the part's, not the drive's so far), so summing over the parts counts the drive once;
- a drive cut short and recovered has no ``tankviz`` record: its frames, buses, databases and
  profile come from what it holds;
- a drive named through ``..`` or a symbolic link is one drive.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from bridge.apps.recover import recover_file
from bridge.fleet import catalog, questions
from bridge.fleet.catalog import index, read_drive
from bridge.io.drives import ArchiveSource
from bridge.pipeline.drive import Drive, load_stages
from bridge.resources import data_dir
from bridge.sim.ecocar import simulate
from bridge.sinks.outputs import atomic_output


def frames_per_part(path: Path) -> int:
    return len(list(ArchiveSource(path)))


@pytest.mark.slow
def test_each_part_of_a_split_drive_counts_its_own_frames(tmp_path: Path) -> None:
    drive = Drive(load_stages([], "ecocar"))
    recorder = drive.record_parts(tmp_path / "drives", split_duration_s=1.0)
    now = [0.0]
    recorder.clock = lambda: now[0]
    total = 0
    for frame in simulate(duration_s=6.0, seed=1):
        drive.pipeline.process(frame)
        total += 1
        if total % 500 == 0:
            now[0] += 0.3
            recorder.tick()
    drive.finish()
    parts = recorder.files
    assert len(parts) >= 3
    rows = {r.path: r.tables["drives"][0] for r in map(read_drive, parts)}
    frames = {path: row[12] for path, row in rows.items()}  # the drives table's ``frames``
    assert frames == {str(p): frames_per_part(p) for p in parts}
    assert sum(frames.values()) == total


def recorded(path: Path, duration_s: float = 12.0) -> Path:
    drive = Drive(load_stages([], "ecocar"))
    with atomic_output(path) as stream:
        drive.record(stream)
        drive.run(simulate(duration_s=duration_s, seed=2))
        drive.finish()
    return path


@pytest.mark.slow
def test_a_recovered_drive_is_catalogued_with_what_it_holds(tmp_path: Path) -> None:
    whole = recorded(tmp_path / "whole.mcap")
    data = whole.read_bytes()
    with whole.open("rb") as f:
        reader = make_reader(f)
        (end,) = [m.offset for m in reader.get_summary().metadata_indexes]  # type: ignore[union-attr]
    (tmp_path / "cut.mcap").write_bytes(data[:end])  # cut before the tankviz record
    report = recover_file(tmp_path / "cut.mcap", tmp_path / "fixed.mcap")
    assert report.messages and not report.complete and report.metadata == 0

    (row,) = read_drive(tmp_path / "fixed.mcap").tables["drives"]
    columns = [name for name, _ in catalog.SCHEMA["drives"]]
    values = dict(zip(columns, row, strict=True))
    assert values["frames"] == frames_per_part(tmp_path / "fixed.mcap") > 1000
    assert values["buses"] == ["can0"]
    assert values["profile"] == "ecocar"
    sha = hashlib.sha256((data_dir() / "ecocar.dbc").read_bytes()).hexdigest()
    assert [(d["name"], d["sha256"]) for d in json.loads(values["databases"])] == [
        ("ecocar", sha)]
    recovered = json.loads(values["statistics"])["recovered"]
    assert recovered["complete"] is False and recovered["source"].endswith("cut.mcap")
    (database,) = read_drive(tmp_path / "fixed.mcap").tables["databases"]
    assert database[1:3] == ("ecocar", sha)


@pytest.mark.slow
def test_a_recovered_drive_with_its_tankviz_record_counts_the_frames_it_holds(
        tmp_path: Path) -> None:
    whole = recorded(tmp_path / "whole.mcap", duration_s=20.0)
    data = whole.read_bytes()
    with whole.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (meta,) = summary.metadata_indexes
    last_chunk = max(c.chunk_start_offset for c in summary.chunk_indexes)
    assert last_chunk > meta.offset  # the drive's last chunk is written after its record
    (tmp_path / "cut.mcap").write_bytes(data[:last_chunk + 100])
    recover_file(tmp_path / "cut.mcap", tmp_path / "fixed.mcap")
    (row,) = read_drive(tmp_path / "fixed.mcap").tables["drives"]
    assert row[12] == frames_per_part(tmp_path / "fixed.mcap")


@pytest.mark.slow
def test_one_drive_named_through_dotdot_or_a_link_is_indexed_once(tmp_path: Path) -> None:
    folder = tmp_path / "drives"
    folder.mkdir()
    recorded(folder / "drv.mcap", duration_s=3.0)
    (tmp_path / "link").symlink_to(folder)
    (tmp_path / "x").mkdir()
    out = tmp_path / "catalog.duckdb"
    report = index(out, [str(folder), str(tmp_path / "x" / ".." / "drives" / "drv.mcap"),
                         str(tmp_path / "link")])
    assert report.new == [str((folder / "drv.mcap").resolve())]
    assert questions.query(out, "SELECT path FROM drives").rows == [
        (str((folder / "drv.mcap").resolve()),)]
    again = index(out, [str(tmp_path / "link" / "drv.mcap")])
    assert again.unchanged == [str((folder / "drv.mcap").resolve())] and not again.new


def test_a_recovered_drive_names_its_profile_as_the_profile_says() -> None:
    """The attachment is named after the profile's file; the name is the one inside it."""
    from types import SimpleNamespace

    from bridge.fleet.held import held_metadata

    profile = SimpleNamespace(name="profile-mycar.toml",
                              data=b'[profile]\nname = "rav4"\ndatabases = []\n')
    reader = SimpleNamespace(iter_attachments=lambda: [profile])
    held = held_metadata(reader, {}, None)
    assert json.loads(held["profile"]) == {"name": "rav4", "attachment": "profile-mycar.toml"}
