"""``tankviz recover`` on damage it can step over, on a file that is no MCAP, and on a drive cut
before its end, which still has its databases and profile.

(issue #13, item 12: one damaged message index record stopped recover at 58 % of the data with
"the file ends inside a message index record of 18,446,744,073,709,550,722 bytes", while mcap's
reader read every message of that file with CRCs on; an empty file gave an empty MCAP; a drive
cut before its end had lost its databases and profile, which were written last.)

(Named ``test_recover_damage.py``: a second ``test_recover.py`` beside tests/test_recover.py
stops pytest collecting either, the test folders having no ``__init__.py``.)
"""

from __future__ import annotations

import io
import shutil
import struct
from collections.abc import Callable
from pathlib import Path

import pytest
from mcap.reader import make_reader

from bridge.apps.recover import format_report, recover, recover_file
from bridge.cli import main
from bridge.frame import Frame
from bridge.io.drives import ArchiveSource
from bridge.pipeline.drive import Drive, load_stages
from bridge.sinks.mcap import Recorder
from bridge.sinks.raw import cut

T0 = 1_700_000_000_000_000_000
PROFILES = Path(__file__).resolve().parents[1] / "profiles"
#: A car that is not ecocar: two buses, its own database.
DBC = (b'VERSION ""\n\nBU_: ECU\n\nBO_ 256 Wheels: 8 ECU\n'
       b' SG_ FrontLeft : 0|16@1+ (0.01,0) [0|655] "km/h" ECU\n')


def drive() -> bytes:
    """A drive of small chunks, each followed by its message indexes, complete with summary."""
    out = io.BytesIO()
    recorder = Recorder(out, chunk_size=2048)
    recorder.add_attachment("wheels.dbc", DBC)
    for i in range(1200):
        bus = "chassis" if i % 3 else "body"
        recorder.on_raw(cut([Frame(T0 + i * 1_000_000, bus, 0x100 + i % 5,
                                   bytes([i % 256] * (i % 9)), dlc=i % 9)]))
    recorder.add_metadata({"driver": "test"}, name="notes")
    recorder.finish()
    return out.getvalue()


def records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of each record after the magic, up to the footer."""
    found, at = [], 8
    while at < len(data) - 8:
        opcode, length = struct.unpack_from("<BQ", data, at)
        found.append((at, opcode, length))
        at += 9 + length
    return found


def read_all(data: bytes) -> list[tuple[str, int, bytes]]:
    """Every message as mcap's reader reads it, CRCs checked."""
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    return [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages(log_time_order=False)]


def middle_message_index(data: bytes) -> tuple[int, int]:
    indexes = [(at, length) for at, opcode, length in records(data) if opcode == 0x07]
    return indexes[len(indexes) // 2]


def overwrite(data: bytes, at: int, new: bytes) -> bytes:
    return data[:at] + new + data[at + len(new):]


DAMAGES: dict[str, Callable[[bytes, int], bytes]] = {
    # The file: the length field of a message index record became huge.
    "length far past the end": lambda d, at: overwrite(d, at + 1, b"\xff" * 8),
    "length a little off": lambda d, at: overwrite(d, at + 1, bytes([d[at + 1] ^ 0x55])),
    "opcode": lambda d, at: overwrite(d, at, b"\x55"),
    "zeros over the record": lambda d, at: overwrite(d, at, bytes(20)),
}


@pytest.mark.parametrize("how", DAMAGES)
def test_one_damaged_message_index_record_loses_no_message(how: str) -> None:
    data = drive()
    at, _ = middle_message_index(data)
    damaged = DAMAGES[how](data, at)
    assert read_all(damaged) == read_all(data)  # mcap's reader does not need it either

    fixed = io.BytesIO()
    report = recover(io.BytesIO(damaged), fixed, source_name="drive.mcap")
    assert read_all(fixed.getvalue()) == read_all(data)
    assert report.stopped is None and report.dropped == 0
    assert (report.metadata, report.attachments) == (1, 1)
    (line,) = report.skipped
    assert line.startswith(f"message index record at byte {at:,}: ")
    assert "the file ends" not in line  # it does not: the record is damaged
    assert "18,446,744" not in line or "its length field says" in line
    text = format_report(report, "drive.mcap", "fixed.mcap")
    assert f"skipped the damaged message index record at byte {at:,}: " in text
    assert "the file was complete, but damaged inside" in text


def test_a_huge_length_is_reported_as_damage_not_as_the_end_of_the_file() -> None:
    data = drive()
    at, _ = middle_message_index(data)
    report = recover(io.BytesIO(DAMAGES["length far past the end"](data, at)), io.BytesIO())
    (line,) = report.skipped
    assert line == (f"message index record at byte {at:,}: its length field says "
                    f"{0xFFFF_FFFF_FFFF_FFFF:,} bytes, more than the {len(data) - at - 9:,} left "
                    "in the file; no message lost (message indexes are not needed)")


def test_damaged_message_indexes_of_a_cut_drive_are_stepped_over() -> None:
    """No summary to say where the next record starts: the next chunk is found by its CRC."""
    data = drive()
    at, _ = middle_message_index(data)
    chunks = [a for a, opcode, _ in records(data) if opcode == 0x06]
    cut = chunks[-2]  # in the data section, far after the damage
    damaged = DAMAGES["length far past the end"](data, at)[:cut]
    fixed = io.BytesIO()
    report = recover(io.BytesIO(damaged), fixed)
    complete = recover(io.BytesIO(data[:cut]), io.BytesIO())
    assert report.messages == complete.messages
    assert read_all(fixed.getvalue()) == read_all(data)[:report.messages]
    (line,) = report.skipped
    assert line.startswith(f"message index record at byte {at:,}: its length field says ")
    assert report.stopped_at == cut


@pytest.mark.parametrize("content", [b"", b"\x89MCA", b"hello, not a drive\n"])
def test_a_file_that_is_not_an_mcap_is_one_line_and_writes_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes) -> None:
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(content)
    assert main(["recover", str(broken), "-o", str(tmp_path / "fixed.mcap")]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"error: {broken}: not an MCAP file (")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.mcap"]


def frames(n: int) -> list[Frame]:
    return [Frame(T0 + i * 1_000_000, "radar", 0x300 + i % 4, bytes(8)) for i in range(n)]


@pytest.mark.slow
def test_a_drive_cut_before_its_end_keeps_its_databases_and_profile(
        tmp_path: Path, shared_dbc: Path) -> None:
    """A car that is not ecocar, recorded as ``tankviz live`` records: the file as a power cut
    leaves it after a flush (no metadata, no summary) still has its database and profile."""
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    profile = PROFILES / "bosch_radar.toml"
    car = Drive(load_stages([f"radar={dbc}"], profile))
    clock = [0.0]
    parts = car.record_parts(tmp_path / "drives", split_duration_s=100.0)
    parts.clock = lambda: clock[0]
    car.run(frames(500))
    clock[0] = 5.0
    parts.tick()  # flushed: on the disk now
    (path,) = parts.files
    cut = tmp_path / "cut.mcap"
    shutil.copyfile(path, cut)  # the power goes off here
    car.finish()

    report = recover_file(cut, tmp_path / "fixed.mcap")
    assert report.stopped is not None
    # every frame but those of the window still open (20 ms: 20 frames) when it was flushed
    assert 480 <= len(list(ArchiveSource(tmp_path / "fixed.mcap"))) < 500
    with (tmp_path / "fixed.mcap").open("rb") as f:
        attached = {a.name: a.data for a in make_reader(f).iter_attachments()}
    assert attached == {"tesla_radar_bosch.dbc": dbc.read_bytes(),
                        "profile-bosch_radar.toml": profile.read_bytes()}


def test_every_part_of_a_drive_starts_with_its_databases_and_profile(
        tmp_path: Path, shared_dbc: Path) -> None:
    dbc = shared_dbc / "tesla_radar_bosch.dbc"
    car = Drive(load_stages([f"radar={dbc}"], PROFILES / "bosch_radar.toml"))
    clock = [0.0]
    parts = car.record_parts(tmp_path / "drives", split_duration_s=2.0)
    parts.clock = lambda: clock[0]
    for _ in range(6):  # each part: frames, flushed after 1.2 s; more frames, split after 2.4 s
        car.run(frames(50))
        clock[0] += 1.2
        parts.tick()
    car.finish()
    assert len(parts.files) >= 3
    for path in parts.files:
        data = path.read_bytes()
        kinds = [opcode for _, opcode, _ in records(data)]
        # after the header: the two attachments, before the first chunk; never again later
        assert kinds[1:3] == [0x09, 0x09] and 0x09 not in kinds[3:], path
        with path.open("rb") as f:
            reader = make_reader(f)
            assert sorted(a.name for a in reader.iter_attachments()) == [
                "profile-bosch_radar.toml", "tesla_radar_bosch.dbc"]
            assert [m.name for m in reader.iter_metadata()] == ["tankviz"]  # still at the end
