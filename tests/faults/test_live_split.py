"""Live's buses read in a process of their own (:mod:`bridge.io.bus_reader`), with the car in
another process on udp_multicast:

- every frame crosses, each bus's in the order sent, each read's frames in time order;
- a stop sent to the whole process group (systemd's, Ctrl+C, a closed terminal) finishes the drive
  with every frame the car sent: the reading process waits for the pipeline's word;
- the reading process killed is said, the drive is finished (a complete MCAP with the frames
  before), live exits 1;
- an adapter unplugged in the reading process is said lost and back, its gap recorded, and no
  frame it received is lost.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from conftest import summary_counts, timeout_scale
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from multicast import multicast_or_skip, send, unique_group
from waiting import wait_for

from bridge.frame import Frame
from bridge.io.bus_reader import Died, Read, ReaderProcess
from bridge.io.buses import BusSpec
from bridge.io.drives import ArchiveSource

LIMIT_S = 60.0


@pytest.fixture(autouse=True)
def _multicast() -> None:
    multicast_or_skip()


def test_every_frame_crosses_in_order() -> None:
    a, b = unique_group(0), unique_group(1)
    reader = ReaderProcess([BusSpec("a", "udp_multicast", a), BusSpec("b", "udp_multicast", b)],
                           20_000_000)
    reads: list[Read] = []
    try:
        wait_for(lambda: bool(reads.extend(i for i in reader.take(0.05) if isinstance(i, Read)))
                 or all(link.opened for link in reader.links), LIMIT_S * timeout_scale())
        assert send(a, 990) == (990, 0)
        assert send(b, 100) == (100, 0)

        def frames() -> list[Frame]:
            return [f for r in reads if r.pack is not None for f in r.pack]

        def more() -> bool:
            items = reader.take(0.05)
            assert not any(isinstance(i, Died) for i in items)
            reads.extend(i for i in items if isinstance(i, Read))
            return len(frames()) >= 1090

        wait_for(more, LIMIT_S * timeout_scale())
    finally:
        reader.stop()
        wait_for(lambda: bool(reader.take(0.05)) or reader.ended, LIMIT_S * timeout_scale())
        reader.close()
    got = frames()
    for bus, n in (("a", 990), ("b", 100)):
        assert [int.from_bytes(f.data, "big") for f in got if f.bus == bus] == list(range(n))
    for r in reads:
        if r.pack is not None:
            assert list(r.pack.t) == sorted(r.pack.t)
    assert [r.read_ns for r in reads] == sorted(r.read_ns for r in reads)


def start_live(tmp_path: Path, group: str) -> subprocess.Popen[str]:
    process = subprocess.Popen(
        [sys.executable, "-m", "bridge", "live", "--bus", f"a=udp_multicast:{group}",
         "--profile", "ecocar", "--no-server", "--drives", str(tmp_path / "drives")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path,
        start_new_session=True, env={**os.environ, "TANKVIZ_LIVE_READER": "process"})
    assert process.stdout is not None
    for line in process.stdout:
        if line.startswith("Ctrl+C stops"):
            break
    return process


def reader_pid(pid: int) -> int:
    """The reading process: the child of ``pid`` that is not multiprocessing's resource
    tracker."""
    children = [int(c) for task in Path(f"/proc/{pid}/task").iterdir()
                for c in (task / "children").read_text().split()]
    (child,) = [c for c in children
                if b"resource_tracker" not in Path(f"/proc/{c}/cmdline").read_bytes()]
    return child


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_a_stop_sent_to_the_whole_group_records_every_frame(tmp_path: Path,
                                                            signum: signal.Signals) -> None:
    """systemd's stop (KillMode=control-group), Ctrl+C and a closed terminal reach every
    process of the group, the reading one too."""
    group = unique_group()
    live = start_live(tmp_path, group)
    try:
        assert send(group, 990) == (990, 0)
    finally:
        os.killpg(live.pid, signum)
    out = live.communicate(timeout=LIMIT_S * timeout_scale())[0]
    assert live.returncode == 0, out
    assert "990 frames;" in out, out


def test_the_reading_process_killed_is_said_and_the_drive_finished(tmp_path: Path) -> None:
    group = unique_group()
    live = start_live(tmp_path, group)
    try:
        assert send(group, 500) == (500, 0)
        drives = tmp_path / "drives"
        # the recorder's flush (once a second) shows the frames came through
        wait_for(lambda: sum(p.stat().st_size for p in drives.glob("*.mcap")) > 20_000,
                 LIMIT_S * timeout_scale())
        os.kill(reader_pid(live.pid), signal.SIGKILL)
        out = live.communicate(timeout=LIMIT_S * timeout_scale())[0]
    finally:
        if live.poll() is None:
            live.kill()
    assert live.returncode == 1, out
    assert ("the process reading the buses ended without a word (killed by SIGKILL): the drive "
            "is finished here") in out, out
    (drive,) = (tmp_path / "drives").glob("*.mcap")
    counts = summary_counts(drive)  # (a complete file, the death on /log)
    assert counts["/log"] >= 1
    frames = int(out.split(" frames;")[0].split()[-1].replace(",", ""))
    assert 0 < frames <= 500
    (drive,) = (tmp_path / "drives").glob("*.mcap")
    assert len([f for f in ArchiveSource(drive)]) == frames


@pytest.mark.slow
def test_an_adapter_unplugged_in_the_reading_process_is_said_and_its_gap_recorded(
        tmp_path: Path) -> None:
    """The adapter breaks where the buses are read, in the reading process: the pipeline's
    process says it is lost and back, records the gap, and every frame the adapter received
    before and after."""
    from flaky_adapter import FlakyAdapter

    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.live_engine import Live

    drives = tmp_path / "drives"
    adapter = FlakyAdapter(tmp_path)
    said: list[str] = []
    live = Live([BusSpec("chassis", "flaky", "x")], load_stages([], "ecocar"), drives=drives,
                open_bus=adapter.open, say=said.append, reader="process")
    runner = threading.Thread(target=live.run)
    runner.start()
    try:
        assert wait_for(lambda: live.pipeline.frames > 500, LIMIT_S * timeout_scale())
        adapter.unplug()
        assert wait_for(lambda: any("lost" in line for line in said), LIMIT_S * timeout_scale())
        before = live.pipeline.frames
        time.sleep(1.0)  # the scenario: the adapter is away for a second
        adapter.plug_in()
        assert wait_for(lambda: live.pipeline.frames > before + 300, LIMIT_S * timeout_scale())
    finally:
        live.stop()
        runner.join(LIMIT_S)
    assert not runner.is_alive()
    assert said[0] == "bus chassis lost: CanOperationError: adapter unplugged; retrying", said
    assert said[1].startswith("bus chassis is back after "), said
    (drive,) = drives.glob("*.mcap")
    numbers = [int.from_bytes(f.data, "little") for f in ArchiveSource(drive)]
    assert numbers == list(range(1, len(numbers) + 1))  # none lost before, during or after
    with drive.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        logs = [m.message for _, c, _, m in reader.iter_decoded_messages() if c.topic == "/log"]
        meta = next(m.metadata for m in reader.iter_metadata() if m.name == "tankviz")
    assert [text for text in logs if text.startswith("bus chassis")] == said[:2]
    (gap,) = json.loads(meta["bus_gaps"])
    assert gap["bus"] == "chassis" and 0.8e9 < gap["to_ns"] - gap["from_ns"] < 3e9


@pytest.mark.slow
@pytest.mark.parametrize("step_s", [-30.0, 3.0])
def test_the_car_clock_stepping_in_the_reading_process_is_followed(tmp_path: Path,
                                                                   step_s: float) -> None:
    """The car's clock steps (30 s back, 3 s ahead): the reading process's schedule and the
    pipeline take the new clock, the step is noted once, no bus falls silent, every frame is
    recorded and the scene goes on, on the new clock."""
    from flaky_adapter import FlakyAdapter

    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.live_engine import Live

    drives = tmp_path / "drives"
    adapter = FlakyAdapter(tmp_path)
    live = Live([BusSpec("chassis", "flaky", "x")], load_stages([], "ecocar"), drives=drives,
                open_bus=adapter.open, say=lambda text: None, reader="process")
    runner = threading.Thread(target=live.run)
    runner.start()
    try:
        assert wait_for(lambda: live.pipeline.frames > 1000, LIMIT_S * timeout_scale())
        adapter.step_clock(step_s)
        assert wait_for(lambda: bool(live.pipeline.steps), LIMIT_S * timeout_scale())
        stepped_at = live.pipeline.frames
        assert wait_for(lambda: live.pipeline.frames > stepped_at + 2000,
                        LIMIT_S * timeout_scale())
    finally:
        live.stop()
        runner.join(LIMIT_S)
    (drive,) = drives.glob("*.mcap")
    numbers = [int.from_bytes(f.data, "little") for f in ArchiveSource(drive)]
    assert numbers == list(range(1, len(numbers) + 1))
    with drive.open("rb") as f:
        reader = make_reader(f)
        scenes = [m.log_time for _, c, m in reader.iter_messages(log_time_order=False)
                  if c.topic.startswith("/scene/")]
        meta = json.loads(next(m.metadata for m in reader.iter_metadata()
                               if m.name == "tankviz")["alarms"] or "[]")
        steps = json.loads(next(m.metadata for m in reader.iter_metadata()
                                if m.name == "tankviz")["clock_steps"])
    assert len(steps) == 1, steps
    # (one id at 1 kHz is babbling: the adapter's nature, not the step's)
    assert not [a["alarm"] for a in meta if a["event"] == "raised"
                and a["alarm"] == "bus.chassis.silent"], meta
    step_ns = steps[0]["to_ns"]
    assert sum(1 for t in scenes if t >= step_ns) > 50  # a second of scenes on the new clock
