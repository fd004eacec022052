"""Bring-up on the command line: ``tankviz ids``, ``bits`` and ``find-signal`` on the simulated
highway car, whose buses carry ids its databases do not define (bridge/sim/highway_body.py), and
on a Toyota log whose DBC lost its SPEED message.

Every figure is checked against a count made here from the frames themselves."""

from __future__ import annotations

import itertools
import json
import statistics
from collections import defaultdict
from pathlib import Path

import cantools
import numpy as np
import pytest
from conftest import SHARED_DBC, SHARED_DBC_ORIGIN

from bridge.cli import main
from bridge.frame import NS
from bridge.resources import data_dir
from bridge.sim.highway import SPEEDOMETER_GAIN, ego_at, simulate_highway
from bridge.sim.highway_body import BRAKE_BIT, BRAKE_ID, HEARTBEAT_ID, SPEED_FIELD, UNKNOWN_IDS

CAR = f"can0={data_dir() / 'highway_car.dbc'}"
RADAR = f"can1={data_dir() / 'highway_radar.dbc'}"


@pytest.fixture(scope="module")
def frames() -> list:
    return list(simulate_highway())


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("highway") / "highway.blf"
    assert main(["simulate", "--car", "highway", "-o", str(path)]) == 0
    return path


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    capsys.readouterr()
    assert main([*argv, "--quiet"]) == 0
    return capsys.readouterr().out


def fails(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    capsys.readouterr()
    assert main([*argv, "--quiet"]) == 1
    return capsys.readouterr().err.strip()


@pytest.mark.slow
def test_ids_counts_periods_and_lengths_are_exact(capsys, frames, log) -> None:
    times = defaultdict(list)
    lengths = defaultdict(set)
    for f in frames:
        times[(f.bus, f.arbitration_id)].append(f.timestamp_ns)
        lengths[(f.bus, f.arbitration_id)].add(len(f.data))
    rows = [json.loads(line) for line in
            run(capsys, "ids", str(log), "--dbc", CAR, "--dbc", RADAR, "--json").splitlines()]
    assert [(r["bus"], int(r["id"], 16)) for r in rows] == sorted(times)
    for r in rows:
        ts = times[(r["bus"], int(r["id"], 16))]
        gaps = np.diff(ts)
        assert r["frames"] == len(ts)
        assert r["period_ms"] == pytest.approx(statistics.median(gaps) / 1e6, abs=1e-9)
        assert r["gap_p5_ms"] == pytest.approx(np.percentile(gaps, 5) / 1e6, abs=1e-9)
        assert r["dlcs"] == sorted(lengths[(r["bus"], int(r["id"], 16))])
    unknown = {(r["bus"], int(r["id"], 16)) for r in rows if r["message"] is None}
    assert unknown == {("can0", i) for i in (0x2C4, 0x3B7, 0x4C8)} | {("can1", 0x2E0)}
    assert {r["message"] for r in rows if r["id"] == "0x0B4"} == {"SPEED"}
    assert all(r["unexplained_bits"] == 0 for r in rows if r["message"] is not None)
    assert next(r for r in rows if r["id"] == "0x4C8")["changing_bits"] == 0


@pytest.mark.slow
def test_ids_prints_a_table_that_names_unknown_ids(capsys, log) -> None:
    out = run(capsys, "ids", str(log), "--dbc", CAR, "--dbc", RADAR)
    assert "0x2C4" in out and "unknown" in out and "KINEMATICS" in out
    assert out.splitlines()[-1].startswith("40 ids, ")
    assert "4 ids" in out.splitlines()[-1]


@pytest.mark.slow
def test_bits_counts_every_flip_of_one_id_exactly(capsys, frames, log) -> None:
    payloads = [f.data for f in frames if f.bus == "can0" and f.arbitration_id == BRAKE_ID]
    expected = [0] * 64
    for before, after in itertools.pairwise(payloads):
        changed = int.from_bytes(before, "little") ^ int.from_bytes(after, "little")
        for bit in range(64):
            expected[bit] += changed >> bit & 1
    got = json.loads(run(capsys, "bits", str(log), "--id", "can0/0x2C4", "--json"))
    assert got["flips"] == expected
    assert got["frames"] == len(payloads)
    assert got["message"] is None
    assert expected[8] == len(payloads) - 1  # the counter's lowest bit flips every frame
    assert expected[0] == 0  # byte 0 is constant


@pytest.mark.slow
def test_bits_window_and_decimal_id(capsys, frames, log) -> None:
    t0 = frames[0].timestamp_ns
    inside = [f.data for f in frames if f.bus == "can0" and f.arbitration_id == HEARTBEAT_ID
              and t0 + 10 * NS <= f.timestamp_ns < t0 + 20 * NS]
    got = json.loads(run(capsys, "bits", str(log), "--id", f"can0/{HEARTBEAT_ID}", "--from",
                         "10", "--to", "20", "--json"))
    assert got["frames"] == len(inside)
    assert got["flips"][24] == len(inside) - 1  # the counter's lowest bit, byte 3


@pytest.mark.slow
def test_bits_map_names_the_signals_of_a_known_id(capsys, log) -> None:
    out = run(capsys, "bits", str(log), "--dbc", CAR, "--id", "can0/0x0B4")
    assert "(SPEED)" in out.splitlines()[0]
    assert "signals: A CHECKSUM, B SPEED" in out
    assert "byte 7" in out and "least significant first" in out


@pytest.mark.slow
@pytest.mark.parametrize(("before", "after", "was", "is_now"), [
    ("12.5:13.9", "14.1:15.5", 0, 1), ("15.5:16.9", "17.1:18.5", 1, 0),
    ("43.5:44.9", "45.1:46.5", 0, 1), ("13.4:13.9", "14.1:14.6", 0, 1)])
def test_compare_around_the_brake_lists_exactly_the_brake_bit(capsys, log, before, after, was,
                                                              is_now) -> None:
    """Of the ids no database knows, only the brake bit switches: the counters' bits, steady
    for a while in a window too, flip at a rhythm and are not switches."""
    got = json.loads(run(capsys, "bits", str(log), "--dbc", CAR, "--dbc", RADAR, "--compare",
                         before, after, "--unknown", "--json"))
    assert [(s["bus"], s["id"], s["bit"], s["before"], s["after"]) for s in got] == [
        ("can0", "0x2C4", BRAKE_BIT, was, is_now)]
    # without --unknown, the radar's tracks that changed between the windows come too, each
    # named by its signal
    every = json.loads(run(capsys, "bits", str(log), "--dbc", CAR, "--dbc", RADAR,
                           "--compare", before, after, "--json"))
    assert [s for s in every if s["message"] is None] == got
    assert all(s["signal"] for s in every if s["message"] is not None)


@pytest.mark.slow
def test_compare_names_the_signal_a_database_knows(capsys, log) -> None:
    out = run(capsys, "bits", str(log), "--dbc", CAR, "--dbc", RADAR, "--compare", "12.5:13.9",
              "14.1:15.5")
    assert "bit  32 (byte 4 bit 0)  0 -> 1  unknown id" in out


@pytest.mark.slow
def test_find_signal_finds_the_hidden_speed_and_writes_a_dbc_that_decodes_it(
        capsys, tmp_path, frames, log) -> None:
    found = tmp_path / "found.dbc"
    out = run(capsys, "find-signal", str(log), "--dbc", CAR, "--dbc", RADAR, "--like",
              "can0/SPEED.SPEED", "-o", str(found))
    first = out.split("\n#1 ")[1].splitlines()[0]
    assert "can0 0x2C4 start bit 23, 16 bits, big-endian unsigned" in first
    sg = next(line for line in out.splitlines() if "SPEED_LIKE_1" in line)
    scale = float(sg.split("(")[1].split(",")[0])
    # SPEED is km/h: raw * 0.001 m/s = raw * 0.0036 km/h
    assert scale == pytest.approx(SPEED_FIELD.scale * 3.6, rel=0.02)
    assert "counters" in out  # the counters were looked at, and refused

    db = cantools.database.load_file(str(found))
    signal = db.get_message_by_frame_id(BRAKE_ID).get_signal_by_name("SPEED_LIKE_1")
    assert (signal.start, signal.length, signal.byte_order) == (23, 16, "big_endian")

    archive = tmp_path / "with-found.mcap"
    assert main(["convert", str(log), "-o", str(archive), "--dbc", CAR, "--dbc",
                 f"can0={found}", "--quiet"]) == 0
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    t0 = frames[0].timestamp_ns
    errors = []
    with archive.open("rb") as f:
        for _, _, message, decoded in make_reader(
                f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                    topics=["/can/can0/ID_2C4"]):
            truth_kmh = ego_at((message.log_time - t0) / NS).speed * SPEEDOMETER_GAIN * 3.6
            errors.append(abs(decoded.SPEED_LIKE_1 - truth_kmh) / truth_kmh)
    assert len(errors) == 3000
    assert max(errors) < 0.01


def test_a_counter_that_follows_the_reference_does_not_win() -> None:
    """A 16-bit counter rises with a rising reference exactly as well as the true field does:
    it is refused as a counter, and the true field wins."""
    from bridge.bringup.search import Reference, search

    n = 2000
    t = np.arange(n, dtype=np.int64) * 10_000_000
    speed = 10 + t / NS * 0.5 + 0.3 * np.sin(t / NS)  # m/s, rising
    raw_speed = np.round(speed / 0.01).astype(np.int64)
    counter = np.arange(n) + 100
    payload = np.zeros((n, 8), dtype=np.uint8)
    payload[:, 0] = counter & 0xFF  # little-endian 16-bit counter in bytes 0-1
    payload[:, 1] = counter >> 8
    payload[:, 4] = raw_speed >> 8  # big-endian speed in bytes 4-5
    payload[:, 5] = raw_speed & 0xFF
    payload[:, 7] = 0x5A  # a constant byte
    found = search({("can0", 0x123): (t, payload)}, Reference("speed", "m/s", t, speed), top=3)
    best = found.candidates[0]
    assert (best.field.start_bit, best.field.length, best.field.big_endian) == (39, 16, True)
    assert best.scale == pytest.approx(0.01, rel=1e-3)
    assert found.refused.get("counters", 0) >= 1
    assert all(0 not in c.field.bits() for c in found.candidates)  # not the counter's step


@pytest.mark.slow
@pytest.mark.skipif(not SHARED_DBC.is_dir(), reason=SHARED_DBC_ORIGIN)
def test_find_signal_finds_toyota_speed_against_a_csv(capsys, tmp_path) -> None:
    import toyota_log as tl

    drive = tl.toyota_drive(60.0)
    log = tmp_path / "rav4.log"
    tl.write_log(drive, log)
    csv = tmp_path / "speed.csv"
    tl.write_speed_csv(drive, csv, clock="log")
    dbc = tl.dbc_without("SPEED", tmp_path)
    out = run(capsys, "find-signal", str(log), "--dbc", f"can0={dbc}", "--like", str(csv))
    first = out.split("\n#1 ")[1].splitlines()[0]
    assert "0x0B4 start bit 47, 16 bits, big-endian unsigned" in first, out
    sg = next(line for line in out.splitlines() if "_LIKE_1" in line)
    assert float(sg.split("(")[1].split(",")[0]) == pytest.approx(0.01 / 3.6, rel=0.02)
    # the same, its times from the log's first frame
    tl.write_speed_csv(drive, csv, clock="source")
    again = run(capsys, "find-signal", str(log), "--dbc", f"can0={dbc}", "--like", str(csv))
    assert again.split("\n#1 ")[1].splitlines()[0] == first


@pytest.mark.parametrize(("argv", "says"), [
    (["bits", "LOG", "--id", "can7/0x2C4"], "the source has no bus 'can7'"),
    (["bits", "LOG", "--id", "can0/0x7FE"], "bus can0 has no frame of id 0x7FE"),
    (["bits", "LOG", "--id", "can0/zz"], "'zz' is not an id"),
    (["bits", "LOG", "--id", "can0/0x2C4", "--from", "100", "--to", "200"], "an empty window"),
    (["bits", "LOG", "--compare", "100:110", "1:2"], "--compare 100:110: no frame"),
    (["bits", "LOG", "--compare", "5", "1:2"], "expected START:END"),
    (["find-signal", "LOG", "--dbc", CAR, "--like", "can0/SPEED.NOPE"],
     "message SPEED has no signal NOPE"),
    (["find-signal", "LOG", "--dbc", CAR, "--like", "can0/NOPE.X"],
     "no database of bus can0 has a message NOPE"),
    (["find-signal", "LOG", "--like", "CSV"], "words.csv:2: not a number in 'about,fast'"),
])
@pytest.mark.slow
def test_bad_input_is_one_line_naming_it(capsys, tmp_path, log, argv, says) -> None:
    csv = tmp_path / "words.csv"
    csv.write_text("time,speed\nabout,fast\n")
    argv = [str(log) if a == "LOG" else str(csv) if a == "CSV" else a for a in argv]
    err = fails(capsys, *argv)
    assert says in err and err.startswith("error: ") and "\n" not in err


def test_the_unknown_ids_are_the_simulators_own(log) -> None:
    db = [cantools.database.load_file(str(data_dir() / n))
          for n in ("highway_car.dbc", "highway_radar.dbc")]
    assert not {m.frame_id for d in db for m in d.messages} & set(UNKNOWN_IDS)


@pytest.mark.slow
def test_a_recorded_drive_is_a_source_with_its_attached_databases(capsys, tmp_path, log) -> None:
    """A drive converted with the car's databases tells the same ids as the log and the
    databases did: its raw frames, decoded with the databases it carries."""
    drive = tmp_path / "drive.mcap"
    assert main(["convert", str(log), "-o", str(drive), "--dbc", CAR, "--dbc", RADAR,
                 "--quiet"]) == 0
    from_log = run(capsys, "ids", str(log), "--dbc", CAR, "--dbc", RADAR, "--json")
    assert run(capsys, "ids", str(drive), "--json") == from_log
