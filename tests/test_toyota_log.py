"""tests/toyota_log.py, the Toyota drive the find-signal tests use: its DBC without a message
loads and lacks it, its log reads back as written, SPEED carries the true speed, counters roll,
checksums follow Toyota's rule and every message comes at its cycle time."""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import can
import numpy as np
import pytest
import toyota_log as tl
from conftest import SHARED_DBC, SHARED_DBC_ORIGIN

pytestmark = pytest.mark.skipif(not tl.TOYOTA_DBC.is_file(),
                                reason=f"public DBCs not found at {SHARED_DBC}: "
                                       f"{SHARED_DBC_ORIGIN}")


@pytest.fixture(scope="module")
def drive() -> tl.ToyotaDrive:
    return tl.toyota_drive(60.0, seed=0)


@pytest.fixture(scope="module")
def db() -> tl.Database:
    return tl.load_toyota()


def frames_of(drive: tl.ToyotaDrive, frame_id: int) -> list[can.Message]:
    return [m for m in drive.frames if m.arbitration_id == frame_id]


@pytest.mark.parametrize("name", ["SPEED", "LKAS_HUD", "PCS_HUD"])
def test_dbc_without_a_message(tmp_path: Path, db: tl.Database, name: str) -> None:
    path = tl.dbc_without(name, tmp_path)
    assert path.parent == tmp_path
    left = tl.load_toyota(path)
    frame_id = db.get_message_by_name(name).frame_id
    assert {m.name for m in left.messages} == {m.name for m in db.messages} - {name}
    assert frame_id not in {m.frame_id for m in left.messages}
    for m in left.messages:  # the others as they were
        before = db.get_message_by_frame_id(m.frame_id)
        assert [(repr(s), s.choices) for s in m.signals] == \
            [(repr(s), s.choices) for s in before.signals]
    names_it = re.compile(rf"^(CM_ (BO_|SG_)|BA_ \"\w+\" (BO_|SG_)|VAL_) {frame_id}\b", re.M)
    assert not names_it.search(path.read_text(encoding="latin-1"))
    assert names_it.search(tl.TOYOTA_DBC.read_text(encoding="latin-1")) or name == "SPEED"


def test_dbc_without_speed_to_a_file(tmp_path: Path) -> None:
    path = tl.dbc_without("SPEED", tmp_path / "no_speed.dbc")
    assert path == tmp_path / "no_speed.dbc"
    with pytest.raises(KeyError):
        tl.load_toyota(path).get_message_by_name("SPEED")


@pytest.mark.slow
def test_every_message_at_its_cycle(drive: tl.ToyotaDrive, db: tl.Database) -> None:
    assert drive.frames[0].timestamp == tl.T0 == drive.start
    stamps = [m.timestamp for m in drive.frames]
    assert stamps == sorted(stamps) and stamps[-1] - stamps[0] < 60.0
    assert {m.channel for m in drive.frames} == {0}
    for message in db.messages:
        frames = frames_of(drive, message.frame_id)
        cycle = tl.cycle_time(message)
        assert len(frames) in (round(60 / cycle) - 1, round(60 / cycle)), message.name
        periods = np.diff([m.timestamp for m in frames])
        assert np.all(np.abs(periods - cycle) < 0.002), message.name
        assert all(len(m.data) == message.length for m in frames)


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".blf", ".log"])
def test_log_reads_back(tmp_path: Path, drive: tl.ToyotaDrive, suffix: str) -> None:
    path = tl.write_log(drive, tmp_path / f"toyota{suffix}")
    read = list(can.LogReader(path))
    assert len(read) == len(drive.frames)
    assert [(m.arbitration_id, bytes(m.data)) for m in read] == \
        [(m.arbitration_id, bytes(m.data)) for m in drive.frames]
    assert np.allclose([m.timestamp for m in read], [m.timestamp for m in drive.frames],
                       rtol=0, atol=1e-5)


def test_speed_carries_the_truth(drive: tl.ToyotaDrive, db: tl.Database) -> None:
    speed = db.get_message_by_name("SPEED")
    frames = frames_of(drive, speed.frame_id)
    kmh = np.array([speed.decode(m.data)["SPEED"] for m in frames])
    t = np.array([m.timestamp - drive.start for m in frames])
    assert np.max(np.abs(kmh - drive.truth_at(t) * 3.6)) <= 0.02
    raw = [speed.decode(m.data, scaling=False)["SPEED"] for m in frames]
    assert min(raw) == 0 and max(raw) > 10_000  # 0.01 km/h a step: well over 8 bits
    assert drive.speed_mps[0] == 0 and 29 < drive.speed_mps.max() < 31
    assert drive.t[1] - drive.t[0] == pytest.approx(0.01)


def test_counters_step_by_one(drive: tl.ToyotaDrive, db: tl.Database) -> None:
    counters = [(m, s) for m in db.messages for s in m.signals if tl.is_counter(s)]
    assert {s.name for _, s in counters} >= {"SYNCID1", "SYNCID2", "S07CNT"}
    for message, signal in counters:
        lo, hi = tl.counter_range(signal)
        values = [message.decode(f.data, decode_choices=False)[signal.name]
                  for f in frames_of(drive, message.frame_id)]
        assert all(lo <= v <= hi for v in values)
        steps = [(b - a) % (hi - lo + 1) for a, b in itertools.pairwise(values)]
        assert set(steps) == {1}, signal.name
        assert len(set(values)) == hi - lo + 1  # it wraps within a minute


def test_checksums(drive: tl.ToyotaDrive, db: tl.Database) -> None:
    with_checksum = {m.frame_id: (m, s) for m in db.messages
                     if (s := tl.checksum_signal(m)) is not None}
    assert {m.name for m, _ in with_checksum.values()} >= {
        "SPEED", "STEER_TORQUE_SENSOR", "GEAR_PACKET_HYBRID", "PCM_CRUISE_2", "ACC_CONTROL"}
    checked = 0
    for f in drive.frames:
        if f.arbitration_id in with_checksum:
            # opendbc: length + the id's bytes + every byte before the checksum, & 0xFF
            expected = (len(f.data) + (f.arbitration_id & 0xFF) + (f.arbitration_id >> 8)
                        + sum(f.data[:-1])) & 0xFF
            message, checksum = with_checksum[f.arbitration_id]
            assert message.decode(f.data)[checksum.name] == expected
            checked += 1
    assert checked > 5000


def test_pack_places_bits_like_cantools(db: tl.Database) -> None:
    """The bit packer used for PCS_HUD (which cantools cannot encode) gives cantools' bytes for
    every other message."""
    rng = np.random.default_rng(1)
    for message in db.messages:
        if message.name == "PCS_HUD":
            continue
        for _ in range(20):
            raw = {s.name: int(rng.integers(*tl.raw_limits(s), endpoint=True))
                   for s in message.signals}
            assert tl.pack(message, raw) == message.encode(raw, scaling=False, strict=False)


def test_speed_csv(tmp_path: Path, drive: tl.ToyotaDrive) -> None:
    for clock, first in (("source", 0.0), ("log", tl.T0)):
        path = tl.write_speed_csv(drive, tmp_path / f"{clock}.csv", clock=clock)
        lines = path.read_text(encoding="utf-8").splitlines()
        assert lines[0] == "time,speed_mps" and len(lines) == len(drive.t) + 1
        rows = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
        assert rows[0, 0] == first
        assert np.allclose(rows[:, 0] - first, drive.t, atol=1e-6)
        assert np.allclose(rows[:, 1], drive.speed_mps, atol=1e-6)
    with pytest.raises(ValueError, match="clock"):
        tl.write_speed_csv(drive, tmp_path / "x.csv", clock="wall")


def test_same_seed_same_drive() -> None:
    a, b = tl.toyota_drive(3.0, seed=5), tl.toyota_drive(3.0, seed=5)
    assert [(m.timestamp, bytes(m.data)) for m in a.frames] == \
        [(m.timestamp, bytes(m.data)) for m in b.frames]
    c = tl.toyota_drive(3.0, seed=6)
    assert [m.timestamp for m in a.frames] != [m.timestamp for m in c.frames]
