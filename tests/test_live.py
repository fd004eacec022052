"""tankviz live and demo: every frame recorded, clean files on SIGTERM, salvageable on SIGKILL,
bus loss survived, recordings split into complete parts, slow viewers hurting nobody."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can
import pytest
import websockets
from conftest import ECOCAR_DBC, summary_counts, timeout_scale
from flaky_adapter import FlakyAdapter
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from waiting import wait_for, wait_for_async

from bridge.errors import InputError
from bridge.frame import NS, Frame
from bridge.io.buses import BusSpec, ReadSchedule, merge_batches
from bridge.io.drives import ArchiveSource, raw_frame_counts
from bridge.pipeline.drive import Drive, load_stages
from bridge.pipeline.live_engine import Live
from bridge.sim.ecocar import simulate
from bridge.sinks.base import Serialized, Sink
from bridge.sinks.drives import PartsRecorder, drive_name
from bridge.sinks.raw import cut
from bridge.sinks.server import ViewerServer


def frames_recorded(path: Path) -> int:
    with path.open("rb") as f:
        return sum(raw_frame_counts(make_reader(f)).values())


def seconds_on_disk(drives: Path) -> float:
    """The log time the chunks of the drive being recorded in ``drives`` cover so far: read from
    their headers alone (cheap: the test waits with this, beside a live process it must not slow
    down)."""
    from mcap.exceptions import McapError
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    found = sorted(drives.glob("*.mcap"))
    times: list[int] = []
    if found:
        with found[0].open("rb") as f, contextlib.suppress(McapError, ValueError):
            for record in StreamReader(f, emit_chunks=True).records:
                if isinstance(record, Chunk) and record.message_end_time:
                    times += [record.message_start_time, record.message_end_time]
    return (max(times) - min(times)) / NS if times else 0.0


def so_far(drives: Path, scratch: Path) -> Path | None:
    """The drive being recorded in ``drives``, as much of it as is on disk (the chunks flushed
    so far, as ``tankviz recover`` reads them), copied to ``scratch``; None before it has any."""
    from bridge.apps.recover import recover_file

    found = sorted(drives.glob("*.mcap"))
    if not found:
        return None
    try:
        recover_file(found[0], scratch, force=True)
    except InputError:  # made, but not even its header written yet
        return None
    return scratch


def can0_times(path: Path | None) -> list[int]:
    return [] if path is None else [f.timestamp_ns for f in ArchiveSource(path) if f.bus == "can0"]


def start_demo(tmp_path: Path, *extra: str) -> subprocess.Popen[str]:
    process = subprocess.Popen(
        [sys.executable, "-m", "bridge", "demo", "--port", "0", "--drives",
         str(tmp_path / "drives"), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    assert process.stdout is not None
    for line in process.stdout:
        if line.startswith("Ctrl+C"):
            return process
    raise AssertionError(f"demo did not start: {process.wait()}")


def run_live_on_virtual_bus(name: str, tmp_path: Path, **options: Any
                            ) -> tuple[Live, threading.Thread, str]:
    """``tankviz live`` (ecocar profile) on a fresh virtual bus, running in a thread; returns it,
    the thread and the bus channel to send on."""
    channel = f"{name}-{os.getpid()}"
    live = Live([BusSpec("can0", "virtual", channel)], load_stages([], "ecocar"),
                drives=tmp_path, **options)
    live.start()  # the bus is open before anything is sent on it
    runner = threading.Thread(target=live.run)
    runner.start()
    return live, runner, channel


def test_bus_specs_name_interface_channel_and_bitrate() -> None:
    assert BusSpec.parse("radar=socketcan:can0") == BusSpec("radar", "socketcan", "can0")
    assert BusSpec.parse("car=pcan:PCAN_USBBUS1@500000") == BusSpec(
        "car", "pcan", "PCAN_USBBUS1", 500000)
    assert BusSpec.parse("chassis") == BusSpec("chassis")
    with pytest.raises(Exception, match=r"--bus radar=can0: expected NAME=INTERFACE:CHANNEL"):
        BusSpec.parse("radar=can0")


def test_drives_are_named_by_their_utc_start() -> None:
    start = 1_767_268_800_000_000_000  # 2026-01-01T12:00:00Z
    assert drive_name(start, 1) == "2026-01-01T12-00-00Z.mcap"
    assert drive_name(start, 2) == "2026-01-01T12-00-00Z_part002.mcap"


@pytest.mark.slow
def test_sigterm_finishes_a_valid_drive_with_every_frame_the_car_sent(tmp_path: Path) -> None:
    demo = start_demo(tmp_path)

    def ran_long_enough() -> bool:  # what the assertions below need, on disk already
        if seconds_on_disk(tmp_path / "drives") < 2.5:
            return False
        drive = so_far(tmp_path / "drives", tmp_path / "so-far.mcap")
        return (drive is not None and frames_recorded(drive) > 5000
                and summary_counts(drive).get("/scene/ego", 0) >= 2.5 * 20)

    assert wait_for(ran_long_enough, 60 * timeout_scale(), step=0.25)
    demo.send_signal(signal.SIGTERM)
    out, _ = demo.communicate(timeout=30)
    assert demo.returncode == 0, out
    sent = int(re.search(r"the simulated car sent ([\d,]+) frames", out)[1].replace(",", ""))
    (drive,) = (tmp_path / "drives").glob("*.mcap")
    assert sent > 5000
    assert frames_recorded(drive) == sent
    counts = summary_counts(drive)
    assert counts["/scene/ego"] >= 2.5 * 20  # the scene at 20 Hz
    with drive.open("rb") as f:
        meta = next(m.metadata for m in make_reader(f).iter_metadata() if m.name == "tankviz")
    assert json.loads(meta["statistics"])["decode_errors"] == {}


@pytest.mark.slow
def test_sigkill_loses_at_most_about_the_last_second(tmp_path: Path) -> None:
    from bridge.apps.recover import recover_file

    demo = start_demo(tmp_path)

    def ran_long_enough() -> bool:  # what the assertions below need, on disk already
        if seconds_on_disk(tmp_path / "drives") < 2.5:
            return False
        times = can0_times(so_far(tmp_path / "drives", tmp_path / "so-far.mcap"))
        return len(times) > 1000 and max(times) - min(times) > 2.4 * NS

    assert wait_for(ran_long_enough, 60 * timeout_scale(), step=0.25)
    killed_at = time.time_ns()
    demo.send_signal(signal.SIGKILL)
    demo.communicate(timeout=30)
    (cut,) = (tmp_path / "drives").glob("*.mcap")
    fixed = tmp_path / "fixed.mcap"
    report = recover_file(cut, fixed)
    assert report.messages > 0
    times = [f.timestamp_ns for f in ArchiveSource(fixed) if f.bus == "can0"]
    # the recording covers the run but about its last second (the demo sends ~2,300 frames/s
    # on an idle machine, fewer on a loaded one: the time covered is what counts)
    assert len(times) > 1000 and max(times) - min(times) > 2.4 * NS
    # (a loaded machine adds what live had not read yet: TANKVIZ_TEST_TIMEOUT_SCALE)
    assert killed_at - max(times) < 1.6 * NS * timeout_scale()
    with fixed.open("rb") as f:  # written at the start of the drive: the cut file has them
        assert {a.name for a in make_reader(f).iter_attachments()} == {"ecocar.dbc",
                                                                       "profile-ecocar.toml"}


def unplug_for_a_second(live: Live, adapter: FlakyAdapter) -> None:
    """Run live on the adapter, unplug it for a second, plug it back, stop."""
    runner = threading.Thread(target=live.run)
    runner.start()
    # frames for half a second first (a loaded machine starts live slower): the bus's clock is
    # known before it is lost
    assert wait_for(lambda: adapter.sent > 500, 10 * timeout_scale())
    adapter.unplug()
    time.sleep(1.0)  # the scenario: the adapter is away for a second...
    assert wait_for(lambda: adapter.opens >= 3, 10 * timeout_scale())  # ...and tried again
    before_gap = adapter.sent
    adapter.plug_in()
    assert wait_for(lambda: adapter.sent > before_gap + 300, 10 * timeout_scale())
    live.stop()
    runner.join(10)


@pytest.mark.slow
def test_a_lost_bus_is_retried_the_gap_marked_and_recording_goes_on(tmp_path: Path) -> None:
    adapter = FlakyAdapter(tmp_path / "adapter")
    said: list[str] = []
    live = Live([BusSpec("chassis", "flaky", "x")], load_stages([str(ECOCAR_DBC)], "ecocar"),
                drives=tmp_path, open_bus=adapter.open, say=said.append)
    unplug_for_a_second(live, adapter)

    (drive,) = tmp_path.glob("*.mcap")
    assert frames_recorded(drive) == adapter.sent  # nothing lost before, during or after
    assert adapter.opens >= 3  # retried while the adapter was away
    assert said[0] == "bus chassis lost: CanOperationError: adapter unplugged; retrying"
    # (up half a second or more before: the frames missed are estimated from a second of it)
    assert re.fullmatch(r"bus chassis is back after \d\.\d s: (about [\d,]+ frames missed \(an "
                        r"estimate: [\d,]+ frames/s before, times how long it was down\)|the "
                        r"frames sent meanwhile were missed \(how many is not known: it was up "
                        r"less than a second before\))", said[1]), said
    with drive.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        logs = [m.message for _, c, _, m in reader.iter_decoded_messages() if c.topic == "/log"]
        meta = next(m.metadata for m in reader.iter_metadata() if m.name == "tankviz")
    assert [text for text in logs if text.startswith("bus chassis")] == said
    (gap,) = json.loads(meta["bus_gaps"])
    assert gap["bus"] == "chassis" and 0.8e9 < gap["to_ns"] - gap["from_ns"] < 3e9


@pytest.mark.slow
def test_a_lost_bus_is_noted_in_the_log_time_of_its_frames(tmp_path: Path) -> None:
    """An adapter that stamps with its own clock (an hour behind the wall clock here): the bus
    lost and back lines on /log and the gap in the metadata are in the frames' log time, beside
    the frames, not an hour after them."""
    adapter = FlakyAdapter(tmp_path / "adapter")
    adapter.step_clock(-3600.0)  # an adapter that stamps with a clock of its own
    live = Live([BusSpec("chassis", "flaky", "x")], load_stages([str(ECOCAR_DBC)], "ecocar"),
                drives=tmp_path, open_bus=adapter.open, say=lambda text: None)
    unplug_for_a_second(live, adapter)

    (drive,) = tmp_path.glob("*.mcap")
    with drive.open("rb") as f:
        reader = make_reader(f)
        frames = [m.log_time for _, c, m in reader.iter_messages() if c.topic.endswith("frames")]
        logs = [m.log_time for _, c, m in reader.iter_messages() if c.topic == "/log"]
        meta = next(m.metadata for m in reader.iter_metadata() if m.name == "tankviz")
    (gap,) = json.loads(meta["bus_gaps"])
    for t_ns in [*logs, gap["from_ns"], gap["to_ns"]]:
        assert frames[0] <= t_ns <= frames[-1] + NS, (t_ns - frames[-1]) / NS


@pytest.mark.slow
def test_recordings_split_into_complete_parts(tmp_path: Path) -> None:
    live, runner, channel = run_live_on_virtual_bus("split", tmp_path, split_duration_s=0.7)
    sent = 0
    with can.Bus(interface="virtual", channel=channel) as bus:
        for frame in simulate(duration_s=2.0):
            bus.send(can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                                 is_fd=frame.is_fd, dlc=frame.dlc))
            sent += 1
            if sent % 100 == 0:
                time.sleep(0.03)  # the car's pace
        assert wait_for(lambda: live.pipeline.frames >= sent, 10 * timeout_scale())
    live.stop()
    runner.join(10)
    parts = sorted(tmp_path.glob("*.mcap"))
    assert len(parts) >= 3
    assert parts[1].name.endswith("_part002.mcap")
    assert sum(frames_recorded(p) for p in parts) == sent
    for part in parts:  # each is a complete MCAP with its own databases and profile
        with part.open("rb") as f:
            reader = make_reader(f)
            assert {a.name for a in reader.iter_attachments()} == {"ecocar.dbc",
                                                                   "profile-ecocar.toml"}


def test_a_scene_goes_to_the_viewers_before_the_recorder_writes_it(tmp_path: Path) -> None:
    """Viewers wait for each scene; the recorder does not: live's server is its drive's first
    sink, and every sink gets a tick's messages in the order the sinks were added."""
    events: list[tuple[str, str]] = []

    class Viewers(Sink):
        def on_messages(self, messages: Sequence[Serialized], /) -> None:
            events.extend(("served", m.topic) for m in messages)

    class Recorder(Sink):
        def on_messages(self, messages: Sequence[Serialized], /) -> None:
            events.extend(("recorded", m.topic) for m in messages)

    drive = Drive(load_stages([], "ecocar"), [Viewers(), Recorder()])
    drive.run(simulate(duration_s=0.2))
    ego = [event[0] for event in events if event[1] == "/scene/ego"]
    assert len(ego) >= 2 * 3  # three ticks at least
    assert ego == ["served", "recorded"] * (len(ego) // 2)
    with ViewerServer(port=0) as server:
        live = Live([BusSpec("can0", "virtual", "order")], load_stages([], "ecocar"),
                    drives=tmp_path, server=server)
        assert live.pipeline.sinks == [server, live.recorder]


@pytest.mark.slow
def test_a_stalled_viewer_costs_the_recorder_nothing(tmp_path: Path) -> None:
    """One viewer never reads, another gets the scene at the scene rate, every frame is kept."""
    with ViewerServer(port=0, queue_limit=50) as server:
        live, runner, channel = run_live_on_virtual_bus("stall", tmp_path, server=server,
                                                        scene_rate=50)
        scenes: list[bytes] = []

        async def viewers() -> int:
            proto = [websockets.Subprotocol("foxglove.websocket.v1")]
            # A small receive window, so that its stall fills the server's buffers at once.
            small = socket.socket()
            small.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            small.connect(("127.0.0.1", server.port))
            small.setblocking(False)
            stalled = await websockets.connect(server.url, subprotocols=proto, max_queue=1,
                                               sock=small)
            channels: dict[str, int] = {}
            while "/scene/radar" not in channels:
                message = json.loads(await stalled.recv())
                channels.update({c["topic"]: c["id"] for c in message.get("channels", [])})
            everything = [{"id": i, "channelId": c} for i, c in enumerate(channels.values())]
            await stalled.send(json.dumps({"op": "subscribe", "subscriptions": everything}))
            stalled.transport.pause_reading()
            sent = 0
            async with websockets.connect(server.url, subprotocols=proto,
                                          max_size=None) as viewer:
                await viewer.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": 1, "channelId": channels["/scene/radar"]}]}))
                with can.Bus(interface="virtual", channel=channel) as bus:
                    started = time.monotonic()
                    for frame in simulate(duration_s=3.0):
                        due = started + (frame.timestamp_ns - 1_767_268_800_000_000_000) / NS
                        while time.monotonic() < due:
                            try:
                                data = await asyncio.wait_for(viewer.recv(), 0.002)
                                if isinstance(data, bytes):
                                    scenes.append(data)
                            except asyncio.TimeoutError:
                                pass
                        bus.send(can.Message(arbitration_id=frame.arbitration_id,
                                             data=frame.data, is_fd=frame.is_fd, dlc=frame.dlc))
                        sent += 1

                async def caught_up() -> bool:
                    """Live has taken in every frame sent (a loaded machine reads behind the
                    car) and the viewer got the scenes of those 3 s."""
                    with contextlib.suppress(asyncio.TimeoutError):
                        data = await asyncio.wait_for(viewer.recv(), 0.05)
                        if isinstance(data, bytes):
                            scenes.append(data)
                    return live.pipeline.frames >= sent and len(scenes) > 0.7 * 50 * 3

                assert await wait_for_async(caught_up, 30 * timeout_scale())
            stalled.transport.abort()
            return sent

        sent = asyncio.run(viewers())
        live.stop()
        runner.join(10)
    (drive,) = tmp_path.glob("*.mcap")
    assert frames_recorded(drive) == sent
    # The reading viewer kept getting the scene and lost nothing; the stalled one lost its own.
    assert len(scenes) > 0.7 * 50 * 3
    assert sorted(s.dropped for s in server.client_stats())[0] == 0
    assert max(s.dropped for s in server.client_stats()) > 0


def test_the_buses_batches_are_processed_in_time_order() -> None:
    """Each bus's new frames are read as a batch; batches of several buses are merged by time
    (equal times keep their order), so a scene tick comes after every earlier frame read."""
    radar = [Frame(t, "radar", 0x100, b"") for t in (10, 20, 30, 40)]
    camera = [Frame(t, "camera", 0x200, b"") for t in (15, 20, 35)]
    merged = merge_batches([radar, camera])
    assert [(f.timestamp_ns, f.bus) for f in merged] == [
        (10, "radar"), (15, "camera"), (20, "radar"), (20, "camera"), (30, "radar"),
        (35, "camera"), (40, "radar")]
    assert merge_batches([radar]) is radar


MS = 1_000_000


def test_the_buses_are_read_just_after_each_scene_tick_and_twice_between() -> None:
    schedule = ReadSchedule(20 * MS)  # 50 Hz
    tick = 1_767_268_800 * NS  # a scene tick: log time is a multiple of the period
    schedule.saw(tick - 3 * MS, tick - 3 * MS)  # a bus stamped with the wall clock
    reads = []
    now = tick
    for _ in range(4):
        now = schedule.next_read_ns(now)
        schedule.reading(now)
        reads.append((now - tick) / MS)
    # 0.5 ms after the tick (the scene goes out at once), halfway, 2.5 ms before the next tick
    assert reads == [0.5, 10.0, 17.5, 20.5]
    # A read that runs past the next one's time (here the one after the tick at 40 ms): that
    # one comes at once, it is not skipped.
    schedule.reading(tick + 37_500_000)
    assert schedule.next_read_ns(tick + 41 * MS) == tick + 40 * MS + MS // 2
    now = [tick + 41 * MS]
    slept: list[float] = []
    schedule.wait(clock=lambda: now[0], sleep=slept.append)
    assert slept == []  # at once
    # A sleep that ends early is slept again.

    def short_sleep(seconds: float) -> None:  # the first sleep ends 1 µs early
        slept.append(seconds)
        now[0] += round(seconds * NS) - (1_000 if len(slept) == 1 else 0)

    schedule.wait(clock=lambda: now[0], sleep=short_sleep)
    assert now[0] >= tick + 50 * MS and len(slept) == 2  # the halfway read, at its time
    assert schedule.log_time(tick + MS) == tick + MS // 2  # what every read frame is before


def test_the_read_schedule_follows_a_bus_stamped_by_its_own_clock() -> None:
    schedule = ReadSchedule(20 * MS)
    assert schedule.log_time(123) is None  # no frame yet: no log time
    wall0 = 1_767_268_800 * NS + 7 * MS
    clock0 = 3_600 * NS  # the adapter's clock at wall0: an hour since it was plugged in

    def read(wall: int, delay: int) -> None:  # the newest frame was stamped `delay` before
        schedule.saw(clock0 + (wall - wall0) - delay, wall)

    read(wall0, 900_000)
    assert schedule.offset_ns == clock0 - wall0 - 900_000  # a first estimate at once
    read(wall0 + 5 * MS, 200_000)
    assert schedule.offset_ns == clock0 - wall0 - 200_000  # a better one at once
    read(wall0 + 10 * MS, 600_000)
    assert schedule.offset_ns == clock0 - wall0 - 200_000
    # The adapter's clock slows down by 1 ms: a second later the offset follows it, from the
    # next read on (this read's log time stays what scheduled it).
    read(wall0 + NS, MS + 300_000)
    read(wall0 + NS + 5 * MS, MS + 400_000)
    read(wall0 + 2 * NS, MS + 500_000)
    assert schedule.offset_ns == clock0 - wall0 - 200_000
    read_at = schedule.next_read_ns(wall0 + 2 * NS)
    assert schedule.offset_ns == clock0 - wall0 - MS - 300_000
    # The next read comes 0.5 ms after a tick of the bus's own time.
    assert (read_at + schedule.offset_ns) % (20 * MS) == MS // 2


def test_the_read_after_a_tick_sees_it_due_when_the_offset_gets_smaller() -> None:
    """Once a second the offset is re-learned and may come out a few µs smaller (frames read a
    little later than before): the read scheduled just after a tick must still start the scene,
    not leave it to the next read half a period later."""
    schedule = ReadSchedule(20 * MS)
    tick = 1_767_268_800 * NS
    schedule.saw(tick - 2 * NS - 10_000, tick - 2 * NS)  # frames read 10 µs after stamped
    schedule.saw(tick - NS - 50_000, tick - NS)  # for the next second: 50 µs
    read_at = schedule.next_read_ns(tick - MS)
    assert read_at == tick + MS // 2 + 10_000  # 0.5 ms after the tick, as the offset says
    schedule.saw(read_at - 50_000, read_at)  # a new second: the offset is learned again
    assert schedule.log_time(read_at) == tick  # the scene at `tick` is due now
    schedule.next_read_ns(read_at)
    assert schedule.offset_ns == -50_000  # the new offset counts from the next read


@pytest.mark.slow
def test_the_scene_goes_on_when_the_buses_fall_silent(tmp_path: Path) -> None:
    live, runner, channel = run_live_on_virtual_bus("silent", tmp_path, scene_rate=50)
    with can.Bus(interface="virtual", channel=channel) as bus:
        for frame in simulate(duration_s=0.1):
            bus.send(can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                                 is_fd=frame.is_fd, dlc=frame.dlc))
        last_sent = time.time_ns()

        def scenes_after(drive: Path | None) -> list[int]:
            if drive is None:
                return []
            with drive.open("rb") as f:
                return [m.log_time for _, c, m in make_reader(f).iter_messages(
                    topics=["/scene/ego"]) if m.log_time > last_sent]

        # the car goes quiet: a second's scenes at least
        assert wait_for(lambda: len(scenes_after(so_far(tmp_path, tmp_path / "so-far"))) >= 40,
                        30 * timeout_scale(), step=0.25)
        live.stop()
        runner.join(10)
    (drive,) = tmp_path.glob("*.mcap")
    after = scenes_after(drive)
    assert len(after) >= 40  # the silent second still has its scenes, at 50 Hz of log time
    assert all(b - a == 20 * MS for a, b in itertools.pairwise(after))


def test_print_systemd_unit(capsys: pytest.CaptureFixture[str]) -> None:
    from bridge.cli import main

    assert main(["live", "--bus", "car=socketcan:can0", "--profile", "ecocar",
                 "--print-systemd-unit"]) == 0
    unit = capsys.readouterr().out
    assert "[Service]" in unit and "WantedBy=multi-user.target" in unit
    (exec_line,) = [line for line in unit.splitlines() if line.startswith("ExecStart=")]
    assert exec_line.endswith("-m bridge live --bus car=socketcan:can0 --profile ecocar")
    assert "KillSignal=SIGTERM" in unit


def run_cli(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bridge", *argv], capture_output=True, text=True,
                          cwd=cwd, timeout=60)


@pytest.mark.slow
def test_simulate_writes_logs_and_drives_and_the_same_seed_the_same_log(tmp_path: Path) -> None:
    for name in ("a.blf", "b.blf", "c.asc", "d.mcap"):
        result = run_cli("simulate", "-o", name, "--duration", "2", cwd=tmp_path)
        assert result.returncode == 0, result.stderr
    assert (tmp_path / "a.blf").read_bytes()[200:] == (tmp_path / "b.blf").read_bytes()[200:]
    counts = summary_counts(tmp_path / "d.mcap")
    # 20 Hz over 2 s: 39 ticks on the grid between the first and last frame, and the final one
    assert counts["/scene/radar"] == 40 and counts["/can/can0/frames"] >= 2 * 40  # 20 ms blocks
    assert len(list(ArchiveSource(tmp_path / "d.mcap"))) > 4000
    refused = run_cli("simulate", "-o", "a.blf", cwd=tmp_path)
    assert refused.returncode == 1 and "exists already" in refused.stderr


@pytest.mark.slow
def test_live_refuses_nonsense(tmp_path: Path) -> None:
    no_bus = run_cli("live", cwd=tmp_path)
    assert no_bus.returncode == 1
    assert no_bus.stderr.strip() == ("error: live: name at least one --bus "
                                     "NAME=INTERFACE:CHANNEL[@BITRATE]")
    nothing = run_cli("live", "--bus", "a=virtual:x", "--no-record", "--no-server", cwd=tmp_path)
    assert nothing.stderr.strip() == "error: --no-record and --no-server: nothing would be done"
    wrong = subprocess.run([sys.executable, "-m", "bridge", "live", "--bus", "a=virtual:x",
                            "--no-server", "--drives", str(tmp_path)], capture_output=True,
                           text=True, cwd=tmp_path, timeout=60,
                           env={**os.environ, "TANKVIZ_LIVE_READER": "thread"})
    assert wrong.returncode == 1
    assert wrong.stderr.strip() == "error: TANKVIZ_LIVE_READER=thread: must be process or here"
    assert not list(tmp_path.glob("*.mcap"))


def test_a_due_flush_waits_for_the_next_scene_but_not_long(tmp_path: Path) -> None:
    """Writing a second's chunk takes ~10 ms: right after a scene, it delays no scene."""
    now = [100.0]
    drive = PartsRecorder(tmp_path, lambda recorder, extra: None, flush_interval_s=1.0,
                          flush_wait_s=0.1, clock=lambda: now[0])
    frame = Frame(1, "can0", 0x100, b"\x01\x02", False, False, False, False, False, False, 2)

    def on_disk() -> int:
        drive.on_raw(cut([frame]))
        drive.tick()
        return drive.files[0].stat().st_size

    written = on_disk()  # the header only: the chunk is being built
    now[0] += 1.05  # due, but no scene yet
    assert on_disk() == written
    drive.on_messages([Serialized("/scene/ego", SceneUpdate, b"", 2)])
    drive.tick()  # a scene was written: flush now
    assert drive.files[0].stat().st_size > written
    written = drive.files[0].stat().st_size
    now[0] += 1.05
    assert on_disk() == written
    now[0] += 0.06  # no scene for 1.11 s: flush anyway
    assert on_disk() > written
    drive.finish()


class QueueBus(can.BusABC):
    """A bus with python-can's own recv (a socketcan, a pcan...): frames from a list."""

    def __init__(self, messages: list[can.Message], **kwargs: Any) -> None:
        super().__init__(channel="queue", **kwargs)
        self.messages = messages

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return (self.messages.pop(0) if self.messages else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise NotImplementedError


def test_a_bus_is_read_through_its_recv_internal_its_filters_applied() -> None:
    """A bus with python-can's own recv is read through _recv_internal (without recv's clock
    readings and log call), filtered as recv filters; a refused frame does not end the read
    (recv(0) returns None at it)."""
    import queue

    from bridge.io.buses import BusLink

    stamp = time.time()
    messages = [can.Message(timestamp=stamp + i, arbitration_id=0x100 + i % 2 * 0x100,
                            data=bytes([i])) for i in range(6)]
    bus = QueueBus(messages, can_filters=[{"can_id": 0x100, "can_mask": 0x700}])
    link = BusLink(BusSpec("can0", "fake", "x"), queue.SimpleQueue())
    link._bus = bus
    assert [f.data for f in link.poll()] == [b"\0", b"\2", b"\4"]
    assert link.poll() == [] and not messages
    bus.shutdown()
