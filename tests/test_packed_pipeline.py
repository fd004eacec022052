"""Frames in packs (offline convert: ``Pipeline.process_packed``) and in reads (live:
``Pipeline.process_many``) make the same drive as frames one by one (``Pipeline.process``): every
message of every topic, byte for byte, and the same statistics, on ecocar and on two cars unlike
it, with damaged frames and clock steps, and with packs that cut across scene ticks, health
checks and steps."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cantools
import pytest
from conftest import T0
from mcap.reader import make_reader

from bridge.frame import NS, Frame
from bridge.packed import PackedFrames
from bridge.pipeline.drive import Drive, Stages, load_stages
from bridge.sim.ecocar import simulate
from bridge.sim.highway import simulate_highway

PROFILES = Path(__file__).resolve().parent / "profiles"

Topics = dict[str, list[tuple[int, bytes]]]


def recorded(stages: Callable[[], Stages], feed: Callable[[Drive], int]
             ) -> tuple[Topics, dict[str, Any]]:
    """Every message per topic (log time, bytes, in file order) and the metadata of a drive
    (made with new stages: the decoder counts what it decodes)."""
    drive = Drive(stages())
    out = io.BytesIO()
    drive.record(out, attachment_time_ns=0)
    feed(drive)
    drive.finish()
    out.seek(0)
    reader = make_reader(out)
    topics: Topics = {}
    for _, channel, message in reader.iter_messages(log_time_order=False):
        topics.setdefault(channel.topic, []).append((message.log_time, message.data))
    (meta,) = [dict(m.metadata) for m in reader.iter_metadata() if m.name == "tankviz"]
    meta.pop("created")
    return topics, {k: json.loads(v) if v[:1] in "[{" else v for k, v in meta.items()}


def in_blocks(frames: list[Frame], size: int) -> list[PackedFrames]:
    return [PackedFrames.from_frames(frames[i:i + size]) for i in range(0, len(frames), size)]


def in_reads(drive: Drive, frames: list[Frame], size: int) -> int:
    """Frames as live reads them: ``size`` at a time (``Pipeline.process_many``)."""
    for i in range(0, len(frames), size):
        drive.pipeline.process_many(frames[i:i + size])
    return len(frames)


def assert_same_drive(stages: Callable[[], Stages], frames: list[Frame]) -> Topics:
    one_by_one = recorded(stages, lambda d: d.run(frames))
    for size in (1, 97, 4096):
        cut = in_blocks(frames, size)
        assert recorded(stages, lambda d, cut=cut: d.run_packed(cut)) == one_by_one, (
            f"packs of {size}")
    for size in (1, 83):
        assert recorded(stages, lambda d, size=size: in_reads(d, frames, size)) == one_by_one, (
            f"reads of {size}")
    return one_by_one[0]


def damaged(frames: list[Frame]) -> list[Frame]:
    """A drive with what cars and loggers do: short frames, unknown and 29-bit ids, error and
    remote frames, a clock that steps back 30 s and later forward two minutes."""
    out = []
    n = len(frames)
    for i, f in enumerate(frames):
        t = f.timestamp_ns
        if i > n * 0.4:
            t -= 30 * NS
        if i > n * 0.7:
            t += 120 * NS
        f = f._replace(timestamp_ns=t)
        if i % 501 == 0:
            f = f._replace(data=f.data[:3])
        elif i % 703 == 0:
            f = f._replace(arbitration_id=0x7AB)
        elif i % 907 == 0:
            f = f._replace(is_extended=True)
        elif i % 1009 == 0:
            f = f._replace(is_error=True, data=b"", dlc=0)
        elif i % 1103 == 0:
            f = f._replace(is_remote=True, data=b"")
        out.append(f)
    return out


@pytest.mark.slow
def test_ecocar_with_damage_and_clock_steps() -> None:
    frames = damaged(list(simulate(duration_s=6.0, seed=3)))
    topics = assert_same_drive(lambda: load_stages([], "ecocar"), frames)
    assert topics["/scene/radar"] and topics["/health"]


@pytest.mark.slow
def test_the_highway_car_on_two_buses() -> None:
    frames = list(simulate_highway(duration_s=6.0, seed=1, road="winding"))
    assert {f.bus for f in frames} == {"can0", "can1"}
    topics = assert_same_drive(lambda: load_stages([], "highway"), frames)
    assert topics["/scene/tracks"] and "/can/can1/frames" in topics


@pytest.mark.slow
def test_a_gm_car_with_polar_tracks(shared_dbc: Path) -> None:
    dbc = shared_dbc / "gm_global_a_object.dbc"
    db = cantools.database.load_file(dbc)
    frames = []
    for i in range(400):
        t = T0 + i * 0.01
        for slot in (1, 2, 3):
            m = db.get_message_by_name(f"LRRObject{slot:02d}")
            data = m.encode({**{s.name: 0 for s in m.signals},
                             "TrkRange": 20 + slot * 10 - i * 0.05, "TrkAzimuth": slot - 2,
                             "TrkRangeRate": -1.5, "TrkObjectID": slot + 4})
            frames.append(Frame(round((t + slot * 1e-4) * 1e6) * 1000, "can0", m.frame_id,
                                data, dlc=len(data)))
    topics = assert_same_drive(lambda: load_stages([str(dbc)], PROFILES / "gm_object.toml"),
                               damaged(frames))
    assert topics["/scene/ego"]


@pytest.mark.parametrize("size", [1, 50])
def test_progress_is_told_every_so_many_frames(size: int) -> None:
    frames = list(simulate(duration_s=1.0, seed=1))
    told: list[int] = []
    drive = Drive(load_stages([], "ecocar"))
    count = drive.run_packed(in_blocks(frames, size), progress=told.append, every=300)
    assert count == len(frames)
    assert len(told) == len(frames) // 300 and told == sorted(told)
    assert all(300 * (k + 1) <= n < 300 * (k + 1) + size for k, n in enumerate(told))


def test_a_drive_lists_each_channel_once() -> None:
    """Health emits /log too: the drive's channels name it once, as every other topic."""
    drive = Drive(load_stages([], "ecocar"))
    topics = [c.topic for c in drive.pipeline.channels(["can0"])]
    assert "/log" in topics and "/health" in topics
    assert len(topics) == len(set(topics))
