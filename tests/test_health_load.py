"""Bus load from a sample of exact bit counts: the first frames of each kind are counted exactly,
then one in about sixteen, and the others count the running mean of their kind; the load stays
within 1 % of the exact one on real-like traffic, and everything else the monitor counts per
frame stays exact.

The traffic: the benches' simulated ecocar drive on three buses (``tools/benchlib.py``: CAN FD
radar frames, noisy signals) and a candump-like log of a car without a profile
(``tools/bench_health.py``: ~100 ids, 11- and 29-bit, counters, checksums, random bytes, CAN
FD frames with and without bit rate switch, remote and error frames). "Exact" is
:func:`bridge.health.bus_bits.frame_bits` summed over every frame.
"""

from __future__ import annotations

import functools
import importlib.util
import random
import sys
import types
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import pytest

from bridge.decode.decoder import Decoder
from bridge.frame import NS, Frame
from bridge.health.bus_bits import EXACT_FIRST, FrameKind, frame_bits
from bridge.health.monitor import HealthMonitor
from bridge.pb.health_pb2 import Health
from bridge.topics import HEALTH_TOPIC

TOOLS = Path(__file__).resolve().parents[1] / "tools"
T0 = 1_700_000_000 * NS


def tool(name: str) -> types.ModuleType:
    """A script of tools/ imported as a module (for its traffic generators)."""
    spec = importlib.util.spec_from_file_location(f"_tool_{name}", TOOLS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@functools.cache
def simulated_drive() -> list[Frame]:
    """250,000 frames (~100 s) of the benches' simulated drive (bridge.sim's ecocar): radar
    objects at 20 Hz get well past the exactly counted first frames of their kind."""
    return list(tool("benchlib").ecocar_frames(250_000))


@functools.cache
def candump_log() -> list[Frame]:
    return tool("bench_health").candump_frames(300_000)


def health(frames: Iterable[Frame], bitrates: dict[str, int],
           data_bitrates: dict[str, int]) -> list[Health]:
    """The /health messages of the frames, watched without a profile or databases."""
    decoder = Decoder({})
    monitor = HealthMonitor(None, decoder, bitrates=bitrates, data_bitrates=data_bitrates)
    out = []
    last = 0
    for frame in frames:
        out += monitor.advance(frame.timestamp_ns)
        monitor.on_frame(frame, decoder.decode(frame))
        last = frame.timestamp_ns
    out += monitor.finish(last)
    return [m.message for m in out if m.topic == HEALTH_TOPIC]


def exact_loads(frames: list[Frame], messages: list[Health], bitrates: dict[str, int],
                data_bitrates: dict[str, int]) -> list[tuple[int, str, float]]:
    """(log time, bus, exact load) of every full window the messages report: the frames with
    window start <= stamp < message time (a frame at a check's time comes after the check)."""
    out = []
    period = NS // 10  # the monitor's checks (HealthSettings.eval_hz), from the first frame on
    first_check = (frames[0].timestamp_ns // period + 1) * period
    for msg in messages:
        t = msg.timestamp.seconds * NS + msg.timestamp.nanos
        window_ns = round(msg.window_s * NS)
        if t - window_ns < first_check:
            continue
        seconds: dict[str, float] = {}
        for f in frames:
            if t - window_ns <= f.timestamp_ns < t:
                arbitration, data_phase = frame_bits(f)
                seconds[f.bus] = seconds.get(f.bus, 0.0) + arbitration / bitrates[f.bus] + (
                    data_phase / data_bitrates[f.bus] if data_phase else 0.0)
        out += [(t, bus, s / msg.window_s) for bus, s in sorted(seconds.items())]
    return out


def assert_loads_within_one_percent(frames: list[Frame], bitrates: dict[str, int],
                                    data_bitrates: dict[str, int]) -> None:
    messages = health(frames, bitrates, data_bitrates)
    exact = exact_loads(frames, messages, bitrates, data_bitrates)
    reported = {(m.timestamp.seconds * NS + m.timestamp.nanos, b.bus): b.load
                for m in messages for b in m.buses}
    assert len(exact) > 100
    errors = [(reported[t, bus] - load) / load for t, bus, load in exact]
    worst = max(errors, key=abs)
    assert abs(worst) < 0.01, f"the worst window is {worst:+.2%} off the exact load"
    whole = sum(reported[t, bus] for t, bus, _ in exact) / sum(load for _, _, load in exact)
    assert whole == pytest.approx(1.0, abs=0.002)


# --- one kind of frame ------------------------------------------------------------------------


def counter_frames(n: int, *, seed: int = 3, ident: int = 0x1A5) -> list[Frame]:
    """A 100 Hz id with a rolling counter, a checksum and two noisy bytes."""
    rng = random.Random(seed)
    frames = []
    for k in range(n):
        data = bytearray([k & 0x0F, 0x40, rng.randrange(256), rng.randrange(256), 0, 0, 0x12, 0])
        data[7] = sum(data[:7]) & 0xFF
        frames.append(Frame(T0 + k * 10_000_000, "can0", ident, bytes(data), dlc=8))
    return frames


def test_a_kind_counts_its_first_frames_exactly_then_a_sample_and_its_mean() -> None:
    frames = counter_frames(EXACT_FIRST + 4000)
    kind = FrameKind(frames[0])
    counted = [kind.bits(f) for f in frames]
    assert counted[:EXACT_FIRST] == [frame_bits(f) for f in frames[:EXACT_FIRST]]
    assert kind.frames == len(frames)
    sampled = kind.exact - EXACT_FIRST
    assert 4000 / 24 <= sampled <= 4000 / 9  # about one in sixteen, at irregular gaps
    true_mean = sum(frame_bits(f)[0] for f in frames) / len(frames)
    estimate = kind.estimates[frames[-1].data.count(0)][0]  # bits of one frame like the last
    assert estimate == pytest.approx(true_mean, abs=1.0)
    assert sum(a for a, _ in counted) == pytest.approx(true_mean * len(frames), rel=0.002)
    assert all(d == 0.0 for _, d in counted)  # a classic frame has no data phase


def test_the_sample_is_the_same_on_every_run() -> None:
    """Same frames, same figures: a drive converted twice is the same file."""
    frames = counter_frames(EXACT_FIRST + 500)
    first, second = FrameKind(frames[0]), FrameKind(frames[0])
    assert [first.bits(f) for f in frames] == [second.bits(f) for f in frames]


def test_an_error_frame_kind_counts_its_fixed_bits() -> None:
    error = Frame(T0, "can0", 0, b"", is_error=True)
    kind = FrameKind(error)
    assert {kind.bits(error) for _ in range(EXACT_FIRST + 100)} == {frame_bits(error)}


# --- whole drives -----------------------------------------------------------------------------


def test_a_short_drive_counts_every_frame_exactly() -> None:
    """Fewer than EXACT_FIRST frames of each kind (the bundled sample, a short test drive): the
    load is the exact sum (to rounding: an estimate would be a thousandth or so off)."""
    frames = sorted(counter_frames(900) + counter_frames(900, seed=4, ident=0x18DAF110),
                    key=lambda f: f.timestamp_ns)
    frames = [f._replace(is_extended=f.arbitration_id > 0x7FF) for f in frames]
    messages = health(frames, {"can0": 500_000}, {})
    exact = exact_loads(frames, messages, {"can0": 500_000}, {})
    assert len(exact) >= 7
    for t, bus, load in exact:
        msg = next(m for m in messages if m.timestamp.seconds * NS + m.timestamp.nanos == t)
        assert next(b for b in msg.buses if b.bus == bus).load == pytest.approx(load, rel=1e-9)


@pytest.mark.slow
def test_the_load_of_a_simulated_drive_is_within_one_percent_of_exact() -> None:
    assert_loads_within_one_percent(simulated_drive(),
                                    {"can0": 500_000, "can1": 500_000, "can2": 500_000},
                                    {"can0": 2_000_000})


@pytest.mark.slow
def test_the_load_of_a_candump_log_with_can_fd_is_within_one_percent_of_exact() -> None:
    frames = candump_log()
    assert any(f.is_fd and f.bitrate_switch for f in frames)
    assert any(f.is_fd and not f.bitrate_switch for f in frames)
    assert any(f.is_extended for f in frames) and any(f.is_error for f in frames)
    assert_loads_within_one_percent(frames, {"can0": 500_000, "can1": 500_000},
                                    {"can1": 2_000_000})


@pytest.mark.slow
def test_everything_else_is_counted_exactly() -> None:
    """Frames, ids, unknown ids, error frames and the busiest id are counted for every frame."""
    frames = candump_log()[:120_000]
    messages = health(frames, {"can0": 500_000, "can1": 500_000}, {"can1": 2_000_000})
    last = messages[-1]
    t = last.timestamp.seconds * NS + last.timestamp.nanos
    for bus in last.buses:
        mine = [f for f in frames if f.bus == bus.bus and f.timestamp_ns < t]
        assert bus.frames_total == len(mine)
        assert bus.error_frames_total == sum(f.is_error for f in mine)
        assert bus.unknown_ids_total == sum(not f.is_error and not f.is_remote for f in mine)
        window = Counter(f.arbitration_id for f in mine if f.timestamp_ns >= t - NS)
        assert bus.top_id_hz == pytest.approx(max(window.values()))
