"""The health monitor counts a pack's frames in bulk (``HealthMonitor.count_packed`` and
``count_rows``, what offline convert uses) exactly as frame by frame (``on_frame``, live): every
count of every bus, kind of frame and family, in the same order, after drives with what upsets
counting - gaps, unknown and 29-bit ids, error, remote and short frames, CAN FD frames with bit
rate switch on a second bus, non-finite values, clock steps - and when a bus has so many kinds
of frame that the monitor forgets them (those packs are counted frame by frame)."""

from __future__ import annotations

import struct
from typing import Any

import pytest
from test_packed_pipeline import damaged, in_blocks

from bridge.frame import NS, Frame
from bridge.health import traffic
from bridge.health.monitor import HealthMonitor
from bridge.pipeline.drive import Drive, load_stages
from bridge.resources import data_dir
from bridge.sim.ecocar import simulate

ECOCAR_POSITION = 272  # EgoPosition: Latitude is an IEEE float32 in bytes 0-3


def health_state(health: HealthMonitor) -> dict[str, Any]:
    """Everything the monitor counted, in the order it holds it."""
    buses = {}
    for name, bus in health._buses.items():
        buses[name] = {
            **{slot: getattr(bus, slot) for slot in (
                "first_ns", "last_ns", "frames", "bits", "brs_bits", "error_frames", "unknown",
                "decode_errors", "non_finite", "gaps", "gap_ns", "cycles")},
            "ids": list(bus.ids.items()),
            "families": sorted(bus.families),
            # (a bus's kinds are only looked up, and all forgotten at once: their order is not
            # state)
            "kinds": sorted((key, k.frames, k.exact, k.next_exact, list(k.estimates.items()),
                             list(k._counts.items())) for key, k in bus.kinds.items()),
        }
    families = [(f.name, f.frames, f.first_ns, f.last_ns, f.resumed_ns, sorted(f.buses),
                 sorted(f.seen_messages)) for f in health.families]
    return {"buses": buses, "families": families, "bad": list(health._bad_values.items()),
            "alarms": list(health._alarms), "first_ns": health.first_ns,
            # (the codecs whose families are looked up: a message's whole and short frames have
            # a codec each, and a pack looks up its column's first; the families are by name)
            "families_of": sorted({c.message.name for c in health._families_of})}


def troubled_drive() -> list[Frame]:
    """Ecocar, damaged, with a silent second on can0, non-finite latitudes, and CAN FD frames
    with bit rate switch (and some without) on can1."""
    simulated = list(simulate(duration_s=5.0, seed=7))
    t0 = simulated[0].timestamp_ns
    frames = damaged([f for f in simulated  # a gap
                      if not t0 + NS <= f.timestamp_ns < t0 + 2 * NS])
    out = []
    for i, f in enumerate(frames):
        if f.arbitration_id == ECOCAR_POSITION and not f.is_extended and len(f.data) == 8:
            value = (float("inf"), float("nan"), 48.1)[i % 3]
            f = f._replace(data=struct.pack("<f", value) + f.data[4:])
        out.append(f)
        if i % 7 == 0:
            payload = bytes((i * 37 + k) % 256 if k % 3 else 0 for k in range(12 + i % 3 * 10))
            out.append(Frame(f.timestamp_ns + 1000, "can1", 0x100 + i % 5, payload,
                             is_fd=True, bitrate_switch=i % 2 == 0, dlc=len(payload)))
    return out


def counted(frames: list[Frame], size: int | None) -> dict[str, Any]:
    drive = Drive(load_stages([], "ecocar"), bitrates={"can0": 500_000, "can1": 500_000})
    if size is None:
        drive.run(frames)
    else:
        drive.run_packed(in_blocks(frames, size))
    assert drive.health is not None
    return health_state(drive.health)


@pytest.mark.slow
@pytest.mark.parametrize("size", [1, 97, 4096])
def test_a_block_is_counted_as_its_frames_one_by_one(size: int) -> None:
    frames = troubled_drive()
    one_by_one = counted(frames, None)
    assert one_by_one["buses"]["can0"]["gaps"] >= 1
    assert one_by_one["buses"]["can0"]["unknown"] and one_by_one["buses"]["can0"]["non_finite"]
    assert one_by_one["buses"]["can0"]["error_frames"]
    assert one_by_one["buses"]["can1"]["brs_bits"] > 0
    assert counted(frames, size) == one_by_one


@pytest.mark.slow
def test_a_bus_with_more_kinds_than_kept_is_counted_frame_by_frame(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(traffic, "MAX_KINDS", 40)
    frames = troubled_drive()
    one_by_one = counted(frames, None)
    assert counted(frames, 4096) == one_by_one
    assert counted(frames, 5) == one_by_one


def test_a_message_first_seen_shortens_its_bus_gap_time_from_the_next_frame_on() -> None:
    # ecocar's message 256 comes every 10 ms: its bus is silent after 5 x 10 ms. Without a
    # profile, health checks come every 100 ms, so the run of rows between two checks holds a
    # frame 70 ms after the first: a gap, once the first told the bus's gap time.
    t0 = 1_767_268_890 * NS + 1_000_000
    frames = [Frame(t0 + ms * 1_000_000, "can0", 256, bytes(8), dlc=8)
              for ms in (0, 70, 80, 90, 180, 190)]

    def gaps(size: int | None) -> int:
        drive = Drive(load_stages([str(data_dir() / "ecocar.dbc")], None))
        if size is None:
            drive.run(frames)
        else:
            drive.run_packed(in_blocks(frames, size))
        assert drive.health is not None
        return drive.health._buses["can0"].gaps

    assert gaps(None) == 2
    assert gaps(len(frames)) == 2
