"""Re-deriving a drive from its own MCAP: ``tankviz convert DRIVE.mcap`` and ``replay DRIVE.mcap``.

A recorded drive keeps every raw frame (``/can/<bus>/frames``), its databases and its profile. The
tests convert a log of a car unlike ecocar (opendbc's tesla_radar_bosch.dbc with
tests/profiles/bosch_radar.toml; conftest's ``shared_dbc`` skips them without ../shared/data/dbc)
and re-derive the drive: with the same profile the derived topics come out the same message for
message; with the lateral sign flipped every radar point is drawn mirrored; without --dbc and
--profile the attached ones are used.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import threading
from functools import partial
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
import websockets
from conftest import T0, WriteLog, message
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory

from bridge.apps.replay import replay_drive
from bridge.cli import main
from bridge.errors import InputError
from bridge.io.drives import ArchiveSource, read_drive
from bridge.pipeline import drive as drive_module
from bridge.pipeline.convert import convert
from bridge.pipeline.drive import load_stages
from bridge.profile.model import ProfileError
from bridge.resources import data_dir
from bridge.sinks.mcap import Recorder
from bridge.sinks.server import ViewerServer

PROFILES = Path(__file__).resolve().parent / "profiles"
BOSCH = PROFILES / "bosch_radar.toml"
PROTO = [websockets.Subprotocol("foxglove.websocket.v1")]

#: Radar points (slot: long, lat distance in m) the radar reports for the whole drive.
POINTS = {3: (30.0, 2.0), 7: (55.0, -4.5), 12: (18.0, 0.75)}


def derived(topic: str) -> bool:
    """The topics the pipeline derives from the frames (not the raw frames themselves)."""
    return (topic.startswith(("/scene/", "/perception/")) or topic == "/health"
            or (topic.startswith("/can/") and not topic.endswith("/frames")))


def messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """(log time, bytes) of every message, per topic, in file order."""
    topics: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for _, channel, msg in make_reader(f).iter_messages(log_time_order=False):
            topics.setdefault(channel.topic, []).append((msg.log_time, msg.data))
    return topics


def metadata(path: Path) -> dict[str, Any]:
    with path.open("rb") as f:
        record = next(m for m in make_reader(f).iter_metadata() if m.name == "tankviz")
    return {k: json.loads(v) if v.startswith(("[", "{")) else v
            for k, v in record.metadata.items()}


def radar_positions(path: Path) -> list[tuple[int, str, float, float]]:
    """(log time, entity id, x, y) of every radar point drawn on /scene/radar."""
    found = []
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, msg, update in reader.iter_decoded_messages(topics=["/scene/radar"]):
            for e in update.entities:
                for sphere in e.spheres:
                    found.append((msg.log_time, e.id, sphere.pose.position.x,
                                  sphere.pose.position.y))
    return found


@pytest.fixture
def bosch_log(shared_dbc: Path, write_log: WriteLog) -> Path:
    """Two seconds of a Bosch radar seeing three points at known places, and wheel speed."""
    db = cantools.database.load_file(shared_dbc / "tesla_radar_bosch.dbc")
    frames: list[can.Message] = []
    for i in range(100):
        t = T0 + i * 0.02
        frames.append(message(db, "Msg169_ESP_wheelSpeeds", t, ESP_wheelSpeedReL_HS=36.0))
        for n, (slot, (x, y)) in enumerate(POINTS.items()):
            at = t + 0.001 * (n + 1)
            frames.append(message(db, f"RadarPoint{slot}_A", at, LongDist=x - 0.05 * i,
                                  LatDist=y, ProbExist=90, Valid=1))
            frames.append(message(db, f"RadarPoint{slot}_B", at + 0.0005, Class=1))
    return write_log("bosch.blf", frames)


@pytest.fixture
def bosch_drive(bosch_log: Path, shared_dbc: Path, tmp_path: Path) -> Path:
    out = tmp_path / "drive.mcap"
    convert([bosch_log], out, [str(shared_dbc / "tesla_radar_bosch.dbc")], profile=BOSCH)
    return out


def test_re_deriving_with_the_same_profile_gives_the_same_drive(
        bosch_drive: Path, shared_dbc: Path, tmp_path: Path) -> None:
    again = tmp_path / "again.mcap"
    report = convert([bosch_drive], again, [str(shared_dbc / "tesla_radar_bosch.dbc")],
                     profile=BOSCH)
    first, second = messages(bosch_drive), messages(again)
    assert report.frames == len(list(ArchiveSource(bosch_drive))) == 100 * 7
    assert {"/scene/radar", "/perception/radar", "/health",
            "/can/can0/RadarPoint3_A"} <= set(first)
    for topic in sorted(t for t in first if derived(t)):
        assert second.get(topic) == first[topic], topic
    assert second["/can/can0/frames"] == first["/can/can0/frames"]
    meta = metadata(again)
    assert meta["source"]["file"] == "drive.mcap"
    assert meta["source"]["size"] == bosch_drive.stat().st_size
    assert len(meta["source"]["sha256"]) == 64
    original = metadata(bosch_drive)
    assert meta["source"]["metadata"]["statistics"] == original["statistics"]
    assert meta["source"]["metadata"]["profile"]["name"] == "bosch_radar"
    assert meta["statistics"]["decoded"] == original["statistics"]["decoded"]


def test_a_flipped_lateral_sign_mirrors_every_radar_point(
        bosch_drive: Path, shared_dbc: Path, tmp_path: Path) -> None:
    flipped = tmp_path / "bosch_right.toml"
    text = BOSCH.read_text()
    assert 'lateral = "left"' in text
    flipped.write_text(text.replace('lateral = "left"', 'lateral = "right"'))
    out = tmp_path / "mirrored.mcap"
    convert([bosch_drive], out, [str(shared_dbc / "tesla_radar_bosch.dbc")], profile=flipped)
    original, mirrored = radar_positions(bosch_drive), radar_positions(out)
    assert len(original) >= 3 * 30  # three points in every scene update of two seconds
    assert {round(y, 3) for _, _, _, y in original} == {2.0, -4.5, 0.75}
    assert [(t, i, x, -y) for t, i, x, y in original] == mirrored
    assert metadata(out)["profile"]["attachment"] == "profile-bosch_right.toml"


@pytest.mark.slow
def test_without_dbc_and_profile_the_attached_ones_are_used(
        bosch_log: Path, shared_dbc: Path, tmp_path: Path) -> None:
    car = tmp_path / "car"
    car.mkdir()
    shutil.copy(shared_dbc / "tesla_radar_bosch.dbc", car / "radar.dbc")
    profile = car / "bosch.toml"
    profile.write_text(BOSCH.read_text().replace(
        'name = "bosch_radar"', 'name = "bosch_radar"\ndatabases = ["radar.dbc"]'))
    drive = tmp_path / "drive.mcap"
    convert([bosch_log], drive, [], profile=profile)
    shutil.rmtree(car)  # the databases and the profile are only in the drive now
    out = tmp_path / "rederived.mcap"
    convert([drive], out, [])
    first, second = messages(drive), messages(out)
    assert first["/scene/radar"] and second["/scene/radar"] == first["/scene/radar"]
    for topic in (t for t in first if derived(t)):
        assert second.get(topic) == first[topic], topic
    meta = metadata(out)
    assert meta["profile"]["attachment"] == "profile-bosch.toml"
    assert [d["attachment"] for d in meta["databases"]] == ["radar.dbc"]
    assert meta["bus_databases"] == metadata(drive)["bus_databases"]


@pytest.mark.slow
def test_a_profile_whose_databases_point_elsewhere_uses_the_attached_ones(
        bosch_drive: Path, tmp_path: Path) -> None:
    elsewhere = tmp_path / "elsewhere.toml"
    elsewhere.write_text(BOSCH.read_text().replace(
        'name = "bosch_radar"', 'name = "bosch_radar"\ndatabases = ["no/such/radar.dbc"]'))
    out = tmp_path / "out.mcap"
    convert([bosch_drive], out, [], profile=elsewhere)
    assert messages(out)["/scene/radar"] == messages(bosch_drive)["/scene/radar"]


def test_a_drive_recorded_at_another_scene_rate_is_re_derived_at_its_own(
        bosch_log: Path, shared_dbc: Path, tmp_path: Path) -> None:
    dbc = [str(shared_dbc / "tesla_radar_bosch.dbc")]
    drive, again = tmp_path / "at10.mcap", tmp_path / "again.mcap"
    convert([bosch_log], drive, dbc, profile=BOSCH, scene_rate=10.0)
    convert([drive], again, dbc, profile=BOSCH)
    assert metadata(again)["profile"]["scene_rate_hz"] == 10.0
    assert messages(again)["/scene/radar"] == messages(drive)["/scene/radar"]
    # a rate given says otherwise
    faster = tmp_path / "faster.mcap"
    convert([drive], faster, dbc, profile=BOSCH, scene_rate=20.0)
    assert len(messages(faster)["/scene/radar"]) > len(messages(drive)["/scene/radar"])


def test_re_deriving_twice_gives_the_same_bytes(bosch_drive: Path, tmp_path: Path) -> None:
    one, two = tmp_path / "one.mcap", tmp_path / "two.mcap"
    convert([bosch_drive], one, [])
    convert([bosch_drive], two, [])
    assert one.read_bytes() == two.read_bytes()


@pytest.mark.slow
def test_the_sample_drive_re_derives_to_the_same_scene(tmp_path: Path, sample_drive: Path
                                                       ) -> None:
    drive = sample_drive
    out = tmp_path / "out.mcap"
    convert([drive], out, [])
    first, second = messages(drive), messages(out)
    assert "/scene/tracks" in first
    for topic in (t for t in first if derived(t)):
        assert second.get(topic) == first[topic], topic


def test_an_mcap_that_is_not_a_drive_is_one_line(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    other = tmp_path / "points.mcap"
    with other.open("wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("p", "jsonschema", b"{}")
        channel = writer.register_channel("/points", "json", schema)
        writer.add_message(channel, 1, b"{}", 1)
        writer.finish()
    assert main(["convert", str(other), "-o", str(tmp_path / "out.mcap"), "-q"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"error: {other}: not a tankviz drive: it has no raw CAN frames "
                          "(/can/<bus>/frames)")
    assert not (tmp_path / "out.mcap").exists()
    text = tmp_path / "notes.mcap"
    text.write_bytes(b"just some text")
    with pytest.raises(InputError, match=r"notes.mcap: not an MCAP file"):
        read_drive(text)


@pytest.mark.slow
def test_a_drive_cut_short_re_derives_what_it_holds_and_says_what_is_lost(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    drive = tmp_path / "sample.mcap"
    with monkeypatch.context() as patch:  # chunks of 1 MiB: the sample drive has several
        patch.setattr(drive_module, "Recorder", partial(Recorder, chunk_size=1024 * 1024))
        convert([data_dir() / "ecocar_sample.blf"], drive, [], profile="ecocar")
    whole = len(list(ArchiveSource(drive)))
    cut = tmp_path / "cut.mcap"
    data = drive.read_bytes()
    with drive.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 1
    last = max(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    # a power loss: the last chunk is incomplete
    cut.write_bytes(data[: last.chunk_start_offset + last.chunk_length // 2])
    out = tmp_path / "out.mcap"
    report = convert([cut], out, [])  # the attachments are at the start: still there
    assert 0 < report.frames < whole
    (issue,) = report.issues
    assert str(issue).startswith(f"{cut}:byte ")
    assert "cut short" in str(issue) and "tankviz recover" in str(issue)
    assert messages(out)["/scene/tracks"]
    assert metadata(out)["source"]["complete"] is False
    assert metadata(out)["created"]  # the cut drive has none to keep: the time it was made


def test_a_drive_cut_before_its_first_frame_is_one_line(bosch_drive: Path,
                                                        tmp_path: Path) -> None:
    cut = tmp_path / "cut.mcap"
    data = bosch_drive.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])  # its one chunk is incomplete
    with pytest.raises(InputError, match=r"cut.mcap: cut short or damaged before any raw CAN "
                       r"frame \(/can/<bus>/frames\) could be read"):
        convert([cut], tmp_path / "out.mcap", [])


def test_one_drive_at_a_time_and_no_logs_beside_it(bosch_drive: Path, bosch_log: Path,
                                                  tmp_path: Path) -> None:
    with pytest.raises(InputError, match="re-derive one drive at a time"):
        convert([bosch_drive, bosch_log], tmp_path / "out.mcap", [])


@pytest.mark.slow
def test_replay_serves_the_re_derived_scene_live(bosch_drive: Path, shared_dbc: Path,
                                                 tmp_path: Path) -> None:
    flipped = tmp_path / "bosch_right.toml"
    flipped.write_text(BOSCH.read_text().replace('lateral = "left"', 'lateral = "right"'))
    stages = load_stages([str(shared_dbc / "tesla_radar_bosch.dbc")], flipped)
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    stop = threading.Event()
    with ViewerServer(port=0, server_time=True) as server:
        payloads = watch(server, "/scene/radar", stop, lambda: replay_drive(
            bosch_drive, stages, server, speed=4.0, loop=True, stopping=stop))
    ys = set()
    for payload in payloads:
        update = SceneUpdate.FromString(payload)
        ys |= {round(s.pose.position.y, 3) for e in update.entities for s in e.spheres}
    assert ys == {-2.0, 4.5, -0.75}  # mirrored: served from the frames, not as recorded


def watch(server: ViewerServer, topic: str, stop: threading.Event, run: Any,
          enough: int = 10) -> list[bytes]:
    """Run the replay (looping until ``stop``) in a thread; subscribe to ``topic`` once it is
    advertised; its first ``enough`` payloads."""
    payloads: list[bytes] = []
    replaying = threading.Thread(target=run)

    async def session() -> None:
        async with websockets.connect(server.url, subprotocols=PROTO, max_size=None) as ws:
            replaying.start()
            channel = None
            while channel is None:
                raw = await asyncio.wait_for(ws.recv(), 10)
                if isinstance(raw, bytes):
                    continue
                channel = next((c["id"] for c in json.loads(raw).get("channels", [])
                                if c["topic"] == topic), None)
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 1, "channelId": channel}]}))
            while replaying.is_alive():
                try:
                    data = await asyncio.wait_for(ws.recv(), 0.5)
                except asyncio.TimeoutError:
                    continue
                if isinstance(data, bytes) and data[0] == 1:
                    payloads.append(data[13:])
                    if len(payloads) >= enough:
                        stop.set()

    try:
        asyncio.run(session())
    finally:
        stop.set()
    replaying.join(10)
    assert payloads, f"nothing on {topic}"
    return payloads


@pytest.mark.slow
def test_replay_drive_cli_with_a_profile(bosch_drive: Path, shared_dbc: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(bosch_drive), "--profile", str(BOSCH), "--dbc",
                 str(shared_dbc / "tesla_radar_bosch.dbc"), "--port", "0", "--speed", "20"]) == 0
    out = capsys.readouterr().out
    assert f"re-deriving {bosch_drive}" in out
    assert "replayed 700 frames" in out


def test_an_attached_profile_that_does_not_fit_new_databases_names_the_drive(
        bosch_drive: Path, tmp_path: Path) -> None:
    other = tmp_path / "other.dbc"
    other.write_text('VERSION ""\n\n\nBU_: X\n\nBO_ 256 Speed: 8 X\n'
                     ' SG_ Value : 0|16@1+ (0.1,0) [0|100] "m/s" X\n')
    with pytest.raises(ProfileError) as caught:
        convert([bosch_drive], tmp_path / "out.mcap", [str(other)])
    assert str(caught.value).startswith(f"{bosch_drive} (attached profile-bosch_radar.toml): ")
    assert "RadarPoint" in str(caught.value)
