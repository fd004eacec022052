"""J1939 (#33 item 8): a DBC that says ``ProtocolType "J1939"`` (or a message's ``VFrameFormat``
``J1939PG``) defines parameter groups, not ids. A frame decodes by its PGN from any source address
and priority, as J1939 tools match it, with the destination address masked for PDU1 groups
(PF < 240); the decoded message keeps the frame's ``source_address`` (and a PDU1 group's
``destination_address``). The decoder, the health counts and bring-up's census agree on which
frames are unknown. A DBC without J1939 still matches ids exactly.
"""

from __future__ import annotations

import json
import random
from collections import Counter
from pathlib import Path
from typing import Any

import can
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from bridge.apps.inspect import summarize_file
from bridge.cli import main
from bridge.decode.codec import Decoded
from bridge.decode.database import load_database
from bridge.decode.decoder import Decoder
from bridge.frame import EXTENDED_KEY, Frame
from bridge.packed import PackedFrames

T0 = 1_700_000_000.0
J1939_DBC = """VERSION ""
BS_:
BU_: Engine Body
BO_ 2364540158 EEC1: 8 Engine
 SG_ EngineSpeed : 24|16@1+ (0.125,0) [0|8031.875] "rpm" Body
 SG_ Torque : 16|8@1+ (1,-125) [-125|125] "%" Body
BO_ 2566844926 CCVS1: 8 Engine
 SG_ WheelBasedVehicleSpeed : 8|16@1+ (0.00390625,0) [0|250.996] "km/h" Body
BO_ 2348810243 TSC1: 8 Body
 SG_ RequestedSpeed : 8|16@1+ (0.125,0) [0|8031.875] "rpm" Engine
BA_DEF_ "ProtocolType" STRING ;
BA_DEF_DEF_ "ProtocolType" "";
BA_ "ProtocolType" "J1939";
"""
# EEC1 0x0CF004FE: priority 3, PGN 0xF004 (PDU2), source 0xFE
# CCVS1 0x18FEF1FE: priority 6, PGN 0xFEF1 (PDU2), source 0xFE
# TSC1 0x0C000003: priority 3, PGN 0x0000 (PDU1, to 0x00), source 0x03
EEC1, CCVS1, TSC1 = 0x0CF004FE, 0x18FEF1FE, 0x0C000003


def j1939_id(priority: int, pgn: int, source: int) -> int:
    return priority << 26 | pgn << 8 | source


def frames(n: int = 120, seed: int = 1) -> list[Frame]:
    """EEC1 and CCVS1 from three sources each at varied priorities (one third from the DBC's
    own source), TSC1 from the DBC's source to another engine and from another source."""
    rng = random.Random(seed)
    out = []
    for i in range(n):
        pgn, sources = [(0xF004, (0xFE, 0x00, 0x01)), (0xFEF1, (0xFE, 0x17, 0x21))][i % 2]
        arbitration_id = j1939_id(rng.choice((3, 6, 7)), pgn, sources[i // 2 % 3])
        out.append(Frame(int((T0 + i / 100) * 1e9), "can0", arbitration_id,
                         bytes(rng.randrange(256) for _ in range(8)), is_extended=True))
    for i, arbitration_id in enumerate((TSC1, 0x0C000127, 0x0C00FF03)):
        out.append(Frame(int((T0 + 2 + i / 100) * 1e9), "can0", arbitration_id,
                         bytes(8), is_extended=True))
    return out


@pytest.fixture
def dbc(tmp_path: Path) -> Path:
    path = tmp_path / "truck.dbc"
    path.write_text(J1939_DBC)
    return path


def test_every_source_and_priority_of_a_pgn_decodes_and_keeps_its_source(dbc: Path) -> None:
    decoder = Decoder({None: [load_database(dbc)]})
    results = [decoder.decode(f) for f in frames()]
    assert all(isinstance(r, Decoded) for r in results)
    assert decoder.stats.unknown == {}
    for frame, decoded in zip(frames(), results, strict=True):
        assert decoded is not None
        parsed = decoded.codec.schema.parse(decoded.payload)
        assert parsed["source_address"] == frame.arbitration_id & 0xFF
        name = decoded.codec.message.name
        assert decoded.codec.topic == f"/can/can0/{name}"
        assert ("destination_address" in parsed) == (name == "TSC1")
        if name == "TSC1":
            assert parsed["destination_address"] == frame.arbitration_id >> 8 & 0xFF
        else:  # the signals themselves, as cantools decodes the DBC's own id
            own = load_database(dbc).db.get_message_by_name(name)
            assert decoded.signals == own.decode(frame.data, decode_choices=False)
    summary = decoder.stats.to_dict(decoder.codecs())
    assert summary["decoded"] == {"/can/can0/CCVS1": 60, "/can/can0/EEC1": 60,
                                  "/can/can0/TSC1": 3}
    # one message per DBC message for the channels and layouts
    assert sorted(c.message.name for c in decoder.codecs_for("can0")) == ["CCVS1", "EEC1",
                                                                           "TSC1"]


def test_blocks_decode_as_frame_by_frame_and_the_health_census_agrees(dbc: Path) -> None:
    one, pack = (Decoder({None: [load_database(dbc)]}) for _ in range(2))
    by_frame = [one.decode(f) for f in frames()]
    by_block = pack.decode_packed(PackedFrames.from_frames(frames()))
    assert [d.payload if d else None for d in by_frame] == [
        d.payload if d else None for d in by_block]
    assert pack.stats.unknown == {}
    other = j1939_id(6, 0xFEF1, 0x99) | EXTENDED_KEY
    assert pack.knows("can0", other)
    assert not pack.knows("can0", j1939_id(6, 0xFEF2, 0x99) | EXTENDED_KEY)
    assert not pack.knows("can0", 0x4FE)  # a standard id is no J1939 frame
    found = pack.message_of("can0", other)
    assert found is not None and found.name == "CCVS1"


def test_without_j1939_an_id_matches_exactly(dbc: Path, tmp_path: Path) -> None:
    plain = tmp_path / "plain.dbc"
    plain.write_text(J1939_DBC.split("BA_DEF_")[0])
    decoder = Decoder({None: [load_database(plain)]})
    for f in frames():
        decoder.decode(f)
    own = Counter(f.arbitration_id for f in frames() if f.arbitration_id in (EEC1, CCVS1, TSC1))
    assert sum(decoder.stats.unknown.values()) == len(frames()) - sum(own.values()) > 80
    summary = decoder.stats.to_dict(decoder.codecs())
    assert summary["decoded"] == {"/can/can0/CCVS1": own[CCVS1], "/can/can0/EEC1": own[EEC1],
                                  "/can/can0/TSC1": 1}


def test_vframeformat_j1939pg_is_j1939_too(tmp_path: Path) -> None:
    path = tmp_path / "pg.dbc"
    path.write_text(J1939_DBC.split("BA_DEF_")[0] + (
        'BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","reserved","J1939PG";\n'
        'BA_DEF_DEF_ "VFrameFormat" "J1939PG";\n'))
    decoder = Decoder({None: [load_database(path)]})
    assert isinstance(decoder.decode(Frame(0, "can0", j1939_id(7, 0xF004, 0x42), bytes(8),
                                           is_extended=True)), Decoded)


def test_convert_decodes_every_source_and_bring_up_calls_none_unknown(
        dbc: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "truck.blf"
    with can.Logger(str(log)) as writer:
        for f in frames():
            writer.on_message_received(can.Message(
                timestamp=f.timestamp_ns / 1e9, arbitration_id=f.arbitration_id, data=f.data,
                is_extended_id=True, channel=0))
    out = tmp_path / "truck.mcap"
    assert main(["convert", str(log), "-o", str(out), "--dbc", str(dbc)]) == 0
    assert "unknown ids 0" in capsys.readouterr().out
    stats = json.loads(summarize_file(out).metadata["tankviz"]["statistics"])
    assert stats["unknown_ids"] == {}
    assert stats["decoded"] == {"/can/can0/CCVS1": 60, "/can/can0/EEC1": 60, "/can/can0/TSC1": 3}
    with out.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        by_topic: dict[str, list[Any]] = {}
        for _, channel, _, message in reader.iter_decoded_messages():
            by_topic.setdefault(channel.topic, []).append(message)
    assert len(by_topic["/can/can0/EEC1"]) == 60
    assert {m.source_address for m in by_topic["/can/can0/EEC1"]} == {0xFE, 0x00, 0x01}
    assert "/can/can0/unknown" not in by_topic
    assert by_topic["/health"][-1].buses[0].unknown_ids_total == 0  # health agrees
    rows = by_topic["/can/can0/ids"][-1].rows
    assert len(rows) == len({f.arbitration_id for f in frames()})
    assert [row.message for row in rows if row.message not in ("EEC1", "CCVS1", "TSC1")] == []


@pytest.mark.slow
def test_a_frames_pgn_is_cantools_own() -> None:
    """pgn_key is cantools' pgn_from_frame_id (PDU1's destination masked) written as bit
    operations: it runs for every frame of an id no database names on a J1939 bus."""
    from cantools.j1939 import pgn_from_frame_id

    from bridge.decode.j1939 import pgn_key

    rng = random.Random(1939)
    for frame_id in [0, 0x1FFFFFFF, 0x0CF00400, 0x18FEF100, 0x18EAFF00,
                     *(rng.getrandbits(29) for _ in range(20_000))]:
        assert pgn_key(frame_id) == pgn_from_frame_id(frame_id), hex(frame_id)
