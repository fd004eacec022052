"""Decoding in packs (a column per (bus, id)) gives, row for row, what decoding frame by frame
gives, and leaves the same statistics: on ecocar's frames and on a radar unlike ecocar's, with
truncated and longer payloads, unknown ids, error and remote frames, extended ids, payloads
cantools cannot decode (a multiplexer value no signal is defined for) and non-finite floats."""

from __future__ import annotations

import math
import random
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cantools
import pytest
from cantools.database.can.database import Database
from conftest import ECOCAR_DBC
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.decode import codec as codec_module
from bridge.decode.codec import Decoded
from bridge.decode.compiled import compile_column_decoder, compile_decoder
from bridge.decode.database import load_database
from bridge.decode.decoder import Decoder
from bridge.decode.outcome import Outcome
from bridge.frame import Frame
from bridge.io.can_logs import LogSource
from bridge.packed import PackedFrames
from bridge.resources import data_dir


def same_value(a: Any, b: Any) -> bool:
    return type(a) is type(b) and (a == b or (isinstance(a, float) and math.isnan(a)
                                              and math.isnan(b)))


def same_decoded(a: Outcome, b: Outcome) -> bool:
    if type(a) is not Decoded or type(b) is not Decoded:
        return a is b
    return (a.codec.topic == b.codec.topic and a.payload == b.payload
            and a.non_finite == b.non_finite and list(a.signals) == list(b.signals)
            and all(same_value(a.signals[k], b.signals[k]) for k in a.signals))


def counts(decoder: Decoder) -> tuple[Any, ...]:
    """Every statistic the decoder keeps: its summary, and every codec's counters."""
    stats = decoder.stats
    return (decoder.stats.to_dict(decoder.codecs()),
            dict(stats.frames), dict(stats.error_frames), dict(stats.remote_frames),
            dict(stats.unknown), dict(stats.errors), dict(stats.last_error),
            sorted((c.topic, c.decoded, c.truncated, c.longer, c.longest, dict(c.non_finite))
                   for c in decoder.codecs()))


def per_frame(decoder: Decoder, frames: Sequence[Frame]) -> list[Outcome]:
    return [decoder.decode(f) for f in frames]


def in_blocks(decoder: Decoder, frames: Sequence[Frame], sizes: Sequence[int]
              ) -> list[Outcome]:
    out: list[Outcome] = []
    at, turn = 0, 0
    while at < len(frames):
        size = sizes[turn % len(sizes)]
        pack = PackedFrames.from_bytes(PackedFrames.from_frames(frames[at:at + size]).to_bytes())
        out += decoder.decode_packed(pack)
        at, turn = at + size, turn + 1
    return out


def assert_same(databases: dict[str | None, list[Any]], frames: list[Frame],
                sizes: Sequence[int] = (4096, 1000, 37, 1)) -> tuple[Decoder, Decoder]:
    one, pack = Decoder(databases), Decoder(databases)
    expected = per_frame(one, frames)
    got = in_blocks(pack, frames, sizes)
    assert len(got) == len(expected)
    wrong = [i for i, (a, b) in enumerate(zip(expected, got, strict=True))
             if not same_decoded(a, b)]
    assert not wrong, f"rows {wrong[:10]} differ, e.g. {frames[wrong[0]]}"
    assert counts(pack) == counts(one)
    return one, pack


def ecocar_frames() -> list[Frame]:
    """The sample drive's frames, with every kind of frame that does not simply decode."""
    frames = list(LogSource(data_dir() / "ecocar_sample.blf"))[:30_000]
    db = cantools.database.load_file(ECOCAR_DBC, strict=False)
    assert isinstance(db, Database)
    diag = db.get_message_by_name("SensorDiag")
    ego = db.get_message_by_name("EgoPosition")
    mux = next(s for s in diag.signals if s.is_multiplexer)
    bad_mux = bytearray(diag.length)
    bad_mux[mux.start // 8] = 0xEE  # a multiplexer value SensorDiag does not define
    float_signal = next(s for s in ego.signals if s.is_float)
    nan = bytearray(ego.encode({s.name: 0 for s in ego.signals}, strict=False))
    fmt = "<d" if float_signal.length == 64 else "<f"
    struct.pack_into(fmt, nan, float_signal.start // 8, math.inf)
    rng = random.Random(26)
    out: list[Frame] = []
    for i, f in enumerate(frames):
        out.append(f)
        t, bus = f.timestamp_ns, f.bus
        k = i % 997
        if k == 1:
            out.append(f._replace(data=f.data[:3]))  # truncated
        elif k == 2:
            out.append(f._replace(data=f.data + bytes(56), is_fd=True, dlc=64))  # longer (FD)
        elif k == 3:
            out.append(Frame(t, bus, 0x7FE, bytes(8), dlc=8))  # unknown
        elif k == 4:
            out.append(Frame(t, bus, 0x1ABCDE, bytes(8), is_extended=True, dlc=8))  # unknown, ext
        elif k == 5:
            out.append(Frame(t, bus, f.arbitration_id, b"", is_error=True))
        elif k == 6:
            out.append(Frame(t, bus, f.arbitration_id, b"", is_remote=True, dlc=8))
        elif k == 7:
            out.append(Frame(t, bus, diag.frame_id, bytes(bad_mux), dlc=diag.length))
        elif k == 8:
            out.append(Frame(t, bus, ego.frame_id, bytes(nan), dlc=ego.length))
        elif k == 9:
            out.append(Frame(t, bus, diag.frame_id, rng.randbytes(diag.length), dlc=8))
        elif k == 10:
            out.append(Frame(t, "can9", f.arbitration_id, f.data, dlc=len(f.data)))  # new bus
        elif k == 11:
            # the same id, extended: another key (unknown), counted under the same number
            out.append(Frame(t, bus, diag.frame_id, bytes(bad_mux), is_extended=True, dlc=8))
        elif k == 12:  # a standard id beyond 29 bits (a damaged archive's): its key has bit 31
            out.append(Frame(t, bus, 0x8000_0000 | diag.frame_id, bytes(8), dlc=8))
    return out


@pytest.mark.slow
def test_ecocar_frames_decode_the_same_in_blocks() -> None:
    database = load_database(ECOCAR_DBC)
    frames = ecocar_frames()

    one, _ = assert_same({None: [database]}, frames)

    stats = one.stats
    assert stats.errors and stats.unknown and stats.error_frames and stats.remote_frames
    assert any(c.truncated for c in one.codecs()) and any(c.longer for c in one.codecs())
    assert any(c.non_finite for c in one.codecs())


@pytest.mark.slow
def test_payloads_that_repeat_beyond_the_cache_and_messages_that_stop_caching() -> None:
    """Long columns: a message whose payloads never repeat stops caching frame by frame, while
    the pack path counts its trials per distinct payload; the results are the same."""
    database = load_database(ECOCAR_DBC)
    base = list(LogSource(data_dir() / "ecocar_sample.blf"))
    rng = random.Random(3)
    frames = [f._replace(data=rng.randbytes(len(f.data))) if i % 2 else f
              for i, f in enumerate(base)]

    assert_same({None: [database]}, frames, sizes=(16384, 8192))
    assert_same({None: [database]}, frames, sizes=(3,))


def radar_frames(db: Database, count: int) -> list[Frame]:
    """A radar unlike ecocar's (Tesla's Bosch radar: 92 messages, one multiplexed by a VIN
    part): random payloads, some repeating, some truncated, some with a multiplexer value the
    message does not define, on two buses."""
    rng = random.Random(7)
    messages = db.messages
    vin = db.get_message_by_name("VIN_VIP_405HS")
    mux = next(s for s in vin.signals if s.is_multiplexer)
    frames = []
    remembered: dict[int, bytes] = {}
    for i in range(count):
        m = rng.choice(messages)
        data = remembered.get(m.frame_id) if rng.random() < 0.5 else None
        if data is None:
            data = remembered[m.frame_id] = rng.randbytes(m.length)
        bus = "radar" if i % 3 else "chassis"
        if i % 101 == 0:
            data = data[: m.length // 2]
        frames.append(Frame(i * 1000, bus, m.frame_id, data, dlc=len(data)))
        if i % 211 == 0:
            bad = bytearray(vin.length)
            bad[mux.start // 8] = 0x77
            frames.append(Frame(i * 1000, bus, vin.frame_id, bytes(bad), dlc=8))
        if i % 307 == 0:
            frames.append(Frame(i * 1000, bus, 0x7FF, bytes(8), dlc=8))
            frames.append(Frame(i * 1000, bus, m.frame_id, b"", is_remote=True, dlc=m.length))
            frames.append(Frame(i * 1000, bus, 0, b"", is_error=True))
    return frames


@pytest.mark.slow
def test_a_radar_unlike_ecocar_decodes_the_same_in_blocks(shared_dbc: Path) -> None:
    path = shared_dbc / "tesla_radar_bosch.dbc"
    database = load_database(path)
    frames = radar_frames(database.db, 40_000)

    one, _ = assert_same({"radar": [database], "chassis": [database]}, frames)

    assert one.stats.errors and one.stats.unknown
    assert any("VIN_VIP_405HS" in text for text in one.stats.last_error.values())


def test_a_column_decodes_as_its_frames_do() -> None:
    database = load_database(ECOCAR_DBC)
    frames = [f for f in LogSource(data_dir() / "ecocar_sample.blf")]
    key = frames[0].arbitration_id
    column = [f for f in frames if f.arbitration_id == key and f.bus == frames[0].bus]
    one, many = Decoder({None: [database]}), Decoder({None: [database]})

    expected = per_frame(one, column)
    got = many.decode_packed(PackedFrames.from_frames(column))

    assert all(same_decoded(a, b) for a, b in zip(expected, got, strict=True))
    assert counts(many) == counts(one)


def test_a_codec_decodes_a_column_in_one_step_with_the_same_counts() -> None:
    database = load_database(ECOCAR_DBC)
    one, many = Decoder({None: [database]}), Decoder({None: [database]})
    [codec_one] = [c for c in one.codecs_for("can0") if c.message.name == "SensorDiag"]
    [codec_many] = [c for c in many.codecs_for("can0") if c.message.name == "SensorDiag"]
    rng = random.Random(1)
    datas = [rng.randbytes(rng.choice((8, 8, 8, 4, 12))) for _ in range(600)] * 2

    expected: list[Any] = []
    for data in datas:
        try:
            expected.append(codec_one.decode(data))
        except Exception as exc:
            expected.append(type(exc))
    got, _ = codec_many.decode_many(datas)

    assert [type(g) if isinstance(g, Exception) else g.payload for g in got] == \
        [e if isinstance(e, type) else e.payload for e in expected]
    assert any(isinstance(g, Exception) for g in got)
    assert (codec_many.decoded, codec_many.truncated, codec_many.longer, codec_many.longest) == \
        (codec_one.decoded, codec_one.truncated, codec_one.longer, codec_one.longest)


@pytest.mark.slow
def test_the_block_path_is_checked_against_a_wrong_count(monkeypatch: pytest.MonkeyPatch) -> None:
    """The comparison above can fail: a column that forgot its truncated frames is caught."""
    database = load_database(ECOCAR_DBC)
    frames = ecocar_frames()[:5000]
    real = codec_module.MessageCodec.decode_many

    def forgetful(self: codec_module.MessageCodec, datas: Sequence[bytes]) -> Any:
        truncated = self.truncated
        out = real(self, datas)
        self.truncated = truncated
        return out

    monkeypatch.setattr(codec_module.MessageCodec, "decode_many", forgetful)
    with pytest.raises(AssertionError):
        assert_same({None: [database]}, frames)


def databases() -> list[Path]:
    shared = Path(__file__).resolve().parents[2] / "shared" / "data" / "dbc"
    return [ECOCAR_DBC, *sorted(shared.glob("*.dbc"))]


@pytest.mark.parametrize("path", databases(), ids=lambda p: p.name)
def test_the_column_decoder_gives_each_payloads_signals(path: Path) -> None:
    """compile_column_decoder is compile_decoder in one call: the same signals, in the same
    order, of the same types, for every message the plain case compiles."""
    db = cantools.database.load_file(path, strict=False)
    assert isinstance(db, Database)
    rng = random.Random(path.name)
    compiled = 0
    for message in db.messages:
        one, column = compile_decoder(message), compile_column_decoder(message)
        assert (one is None) == (column is None)
        if one is None or column is None:
            continue
        compiled += 1
        payloads = [bytes(message.length), *(rng.randbytes(message.length) for _ in range(20))]
        got = column(payloads)
        assert len(got) == len(payloads)
        for data, signals in zip(payloads, got, strict=True):
            expected = one(data)
            assert list(signals) == list(expected)
            assert all(same_value(signals[k], expected[k]) for k in expected), message.name
    assert compiled


def test_a_standard_id_with_bit_31_is_counted_under_its_own_number() -> None:
    """A pack without extended frames: a key with bit 31 set is a (damaged) standard id, not
    an extended one, and is counted as decoding it frame by frame counts it."""
    database = load_database(ECOCAR_DBC)
    frames = [Frame(1, "can0", 0x8000_0123, bytes(8), dlc=8), Frame(2, "can0", 0x123, bytes(8))]

    one, _ = assert_same({None: [database]}, frames, sizes=(2,))

    assert ("can0", 0x8000_0123) in one.stats.unknown


_ECOCAR = load_database(ECOCAR_DBC)
_IDS = [*sorted({m.frame_id for m in _ECOCAR.db.messages})[:12], 0x7FE]

frames_strategy = st.lists(st.builds(
    Frame, timestamp_ns=st.integers(0, 10**12), bus=st.sampled_from(["can0", "can1", "x"]),
    arbitration_id=st.sampled_from(_IDS), data=st.sampled_from(
        [bytes(8), b"\xff" * 8, bytes(range(8)), b"\x01\x02\x03", bytes(64), b"", b"\x80" * 8]),
    is_extended=st.booleans(), is_fd=st.booleans(), is_error=st.booleans(),
    is_remote=st.booleans(), dlc=st.integers(0, 15)), max_size=120)


@pytest.mark.slow
@settings(max_examples=60, deadline=None)  # a new decoder prepares its messages: slow at first
@given(frames_strategy, st.lists(st.integers(1, 50), min_size=1, max_size=4))
def test_any_frames_in_any_blocks_decode_as_one_by_one(frames: list[Frame],
                                                       sizes: list[int]) -> None:
    assert_same({None: [_ECOCAR]}, frames, sizes)
