"""Presence of decoded signals (#36 decision 2): a signal in every whole frame of its message (no
multiplexer selects it; a J1939 message's addresses) is an implicit-presence field, so its 0 is
not written and reads back as 0; a multiplexed signal keeps explicit presence (absent, not 0);
a frame shorter than its message goes to ``<topic>/short``, whose type lets every signal be
absent. Every value read back with the class a reader builds from the recorded schema: 0, -0.0,
negative, NaN where the signal is a float, and each multiplexed signal absent and present."""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import cantools
import pytest
from google.protobuf import descriptor_pool
from hypothesis import given, settings
from hypothesis import strategies as st
from test_properties import class_from_descriptor_set

from bridge.decode.codec import Decoded
from bridge.decode.database import load_database
from bridge.decode.decoder import Decoder
from bridge.decode.proto_schema import MessageSchema
from bridge.frame import Frame

PRESENCE_DBC = """VERSION ""
BS_:
BU_: ECU
BO_ 256 Plain: 8 ECU
 SG_ Count : 0|8@1+ (1,0) [0|255] "" ECU
 SG_ Offset : 8|8@1- (1,0) [-128|127] "" ECU
 SG_ Gear : 16|4@1+ (1,0) [0|15] "" ECU
 SG_ Speed : 24|16@1- (0.01,0) [-327.68|327.67] "m/s" ECU
 SG_ Ratio : 40|24@1- (0.5,-3) [0|0] "" ECU
BO_ 257 Floats: 8 ECU
 SG_ Single : 0|32@1- (1,0) [0|0] "" ECU
 SG_ Scaled : 32|32@1- (2.5,0) [0|0] "" ECU
BO_ 258 Paged: 4 ECU
 SG_ Page M : 0|8@1+ (1,0) [0|255] "" ECU
 SG_ Temp m0 : 8|16@1- (0.1,0) [0|0] "degC" ECU
 SG_ Volt m1 : 8|16@1+ (1,0) [0|0] "mV" ECU
 SG_ Always : 24|8@1- (1,0) [0|0] "" ECU
VAL_ 256 Gear 0 "P" 1 "R" 2 "N" 3 "D" ;
SIG_VALTYPE_ 257 Single : 1;
"""


@pytest.fixture(scope="module")
def db_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("presence") / "presence.dbc"
    path.write_text(PRESENCE_DBC)
    return path


@pytest.fixture(scope="module")
def db(db_path: Path) -> cantools.database.can.Database:
    return cantools.database.load_file(db_path)


def decode(db_path: Path, db: cantools.database.can.Database, name: str,
           data: bytes | None = None, **values: Any) -> Decoded:
    message = db.get_message_by_name(name)
    payload = data if data is not None else message.encode(values, scaling=True, strict=False)
    decoded = Decoder({None: [load_database(db_path)]}).decode(
        Frame(1, "can0", message.frame_id, payload))
    assert decoded is not None
    return decoded


def read(decoded: Decoded) -> Any:
    """The message as a reader of the MCAP reads it: a class built from the schema record."""
    schema = decoded.codec.schema
    cls = class_from_descriptor_set(schema.file_descriptor_set(), schema.full_name)
    return cls.FromString(decoded.payload)


def test_signals_no_multiplexer_selects_have_no_presence_and_the_others_have(
        db_path: Path, db: cantools.database.can.Database) -> None:
    schema = decode(db_path, db, "Paged", Page=0, Temp=1.5, Always=3).codec.schema
    fields = schema.message_class.DESCRIPTOR.fields_by_name
    assert {n: f.has_presence for n, f in fields.items()} == {
        "Page": False, "Temp": True, "Volt": True, "Always": False}
    short = MessageSchema(db.get_message_by_name("Paged"), "presence",
                          descriptor_pool.DescriptorPool(), short=True)
    assert all(f.has_presence for f in short.message_class.DESCRIPTOR.fields)


def test_zeros_are_not_written_and_read_back_as_zero(
        db_path: Path, db: cantools.database.can.Database) -> None:
    decoded = decode(db_path, db, "Plain", Count=0, Offset=0, Gear=0, Speed=0.0, Ratio=0.0)
    assert dict(decoded.signals) == {"Count": 0, "Offset": 0, "Gear": 0, "Speed": 0.0,
                                     "Ratio": 0.0}
    assert decoded.payload == b""  # every value is its field's zero
    msg = read(decoded)
    assert (msg.Count, msg.Offset, msg.Gear, msg.Speed, msg.Ratio) == (0, 0, 0, 0.0, 0.0)


def test_negative_values_and_enums_round_trip(
        db_path: Path, db: cantools.database.can.Database) -> None:
    decoded = decode(db_path, db, "Plain", Count=255, Offset=-128, Gear=3, Speed=-1.5,
                     Ratio=-3.0)
    msg = read(decoded)
    assert (msg.Count, msg.Offset, msg.Gear, msg.Speed, msg.Ratio) == (255, -128, 3, -1.5, -3.0)
    assert decoded.signals["Ratio"] == -3.0


@pytest.mark.parametrize("single", [0.0, -0.0, math.nan, math.inf, -math.inf, -2.5])
def test_float_signals_keep_negative_zero_nan_and_infinities(
        db_path: Path, db: cantools.database.can.Database, single: float) -> None:
    data = struct.pack("<fi", single, 0)
    decoded = decode(db_path, db, "Floats", data)
    got = read(decoded).Single
    if math.isnan(single):
        assert math.isnan(got)
    else:
        assert got == single and math.copysign(1.0, got) == math.copysign(1.0, single)
    written = bool(decoded.payload)
    assert written == (single != 0.0 or math.copysign(1.0, single) < 0)  # -0.0 is written
    assert decoded.payload == decoded.codec.schema.serialize_with_protobuf(decoded.signals)


def test_each_multiplexed_signal_is_absent_or_present_as_its_page_says(
        db_path: Path, db: cantools.database.can.Database) -> None:
    first = read(decode(db_path, db, "Paged", Page=0, Temp=0.0, Always=0))
    assert first.HasField("Temp") and first.Temp == 0.0  # present, and 0
    assert not first.HasField("Volt")  # absent, not 0
    assert (first.Page, first.Always) == (0, 0)
    second = read(decode(db_path, db, "Paged", Page=1, Volt=0, Always=-7))
    assert second.HasField("Volt") and second.Volt == 0
    assert not second.HasField("Temp")
    assert (second.Page, second.Always) == (1, -7)


def test_a_short_frame_goes_beside_its_message_with_cut_signals_absent(
        db_path: Path, db: cantools.database.can.Database) -> None:
    whole = db.get_message_by_name("Plain").encode(
        {"Count": 0, "Offset": -1, "Gear": 0, "Speed": 0.0, "Ratio": 0.0}, scaling=True)
    decoded = decode(db_path, db, "Plain", whole[:2])
    assert decoded.codec.topic == "/can/can0/Plain/short"
    msg = read(decoded)
    assert msg.HasField("Count") and msg.Count == 0  # in the frame, 0: written
    assert msg.Offset == -1
    assert not any(msg.HasField(n) for n in ("Gear", "Speed", "Ratio"))  # cut off: absent


@settings(max_examples=300, deadline=None)
@given(name=st.sampled_from(["Plain", "Floats", "Paged"]),
       data=st.binary(min_size=8, max_size=8))
def test_every_payload_reads_back_as_cantools_decodes_it(
        db_path: Path, db: cantools.database.can.Database, name: str, data: bytes) -> None:
    """Random whole payloads (zeros, negative zeros and NaNs among them)."""
    message = db.get_message_by_name(name)
    data = data[:message.length]
    try:
        expected = message.decode(data, decode_choices=False)
    except Exception:
        return
    decoded = decode(db_path, db, name, data)
    msg = read(decoded)
    for signal in message.signals:
        field = msg.DESCRIPTOR.fields_by_name[signal.name]
        if signal.name not in expected:
            assert field.has_presence and not msg.HasField(signal.name)
            continue
        got, want = getattr(msg, signal.name), expected[signal.name]
        assert (math.isnan(got) and math.isnan(want)) or (
            got == want and math.copysign(1, got) == math.copysign(1, want)), signal.name
    assert decoded.payload == decoded.codec.schema.serialize_with_protobuf(decoded.signals)


J1939_DBC = """VERSION ""
BS_:
BU_: Engine Body
BO_ 2348810243 TSC1: 8 Body
 SG_ RequestedSpeed : 8|16@1+ (0.125,0) [0|8031.875] "rpm" Engine
BA_DEF_ "ProtocolType" STRING ;
BA_DEF_DEF_ "ProtocolType" "";
BA_ "ProtocolType" "J1939";
"""


def test_j1939_addresses_are_in_every_frame_so_address_0_is_not_written(
        tmp_path: Path) -> None:
    path = tmp_path / "j1939.dbc"
    path.write_text(J1939_DBC)
    decoder = Decoder({None: [load_database(path)]})
    # TSC1 (PDU1) from source 0x00 to destination 0x00, and from 0x03 to 0x2A
    for frame_id, addresses in ((0x0C000000, (0, 0)), (0x0C002A03, (3, 0x2A))):
        decoded = decoder.decode(Frame(1, "can0", frame_id, bytes(8), is_extended=True))
        assert decoded is not None
        msg = read(decoded)
        assert (msg.source_address, msg.destination_address) == addresses
        assert decoded.payload == decoded.codec.schema.serialize_with_protobuf(
            {**decoded.signals, "source_address": addresses[0],
             "destination_address": addresses[1]})
    short = decoder.decode(Frame(2, "can0", 0x0C000000, bytes(1), is_extended=True))
    assert short is not None and short.codec.topic == "/can/can0/TSC1/short"
    msg = read(short)
    assert msg.HasField("source_address") and msg.source_address == 0
    assert not msg.HasField("RequestedSpeed")
