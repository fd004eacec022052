"""The precompiled encoder of a generated DBC message type writes exactly the bytes that
protobuf's own ``SerializeToString`` writes for the same signals (hypothesis over random values
and random payloads, on ecocar.dbc, the public DBCs and a DBC made here to reach the corners),
and the decoder's per-message payload cache gives up on ids whose payloads never repeat."""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cantools
import pytest
from cantools.database.can.database import Database
from cantools.database.can.message import Message as DbcMessage
from conftest import ECOCAR_DBC
from google.protobuf import descriptor_pool
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bridge.decode.database import load_database
from bridge.decode.decoder import Decoder
from bridge.decode.proto_schema import MessageSchema, compile_encoder
from bridge.frame import Frame

#: A DBC that looks like no bundled car: 64-bit signals, a negative value table, a float32, two
#: signals of one name, names that are no protobuf identifiers, more than 15 signals (two-byte
#: field tags) and a multiplexer. A DBC cannot spell names that are no identifiers; KCD and ARXML
#: can, so two are renamed after loading (:data:`ODD_NAMES`).
CORNERS_DBC = """VERSION ""
BS_:
BU_: ECU
BO_ 2024 Wide: 8 ECU
 SG_ Big : 0|64@1+ (1,0) [0|0] "" ECU
BO_ 2025 WideSigned: 8 ECU
 SG_ Big : 7|64@0- (1,0) [0|0] "" ECU
BO_ 2026 Scaled64: 8 ECU
 SG_ Huge : 0|64@1+ (4,-7) [0|0] "" ECU
BO_ 2027 Mode: 8 ECU
 SG_ Gear : 0|4@1- (1,0) [-8|7] "" ECU
 SG_ TempMinusC : 8|12@1- (1,-40) [0|0] "degC" ECU
 SG_ Ratio : 32|32@1- (1,0) [0|0] "" ECU
 SG_ Temp_C : 20|8@1+ (0.5,0) [0|0] "" ECU
 SG_ NineLives : 28|4@1+ (1,0) [0|15] "" ECU
BO_ 2028 Many: 8 ECU
 SG_ S0 : 0|3@1+ (1,0) [0|7] "" ECU
 SG_ S1 : 3|3@1+ (1,0) [0|7] "" ECU
 SG_ S2 : 6|3@1+ (1,0) [0|7] "" ECU
 SG_ S3 : 9|3@1+ (1,0) [0|7] "" ECU
 SG_ S4 : 12|3@1+ (1,0) [0|7] "" ECU
 SG_ S5 : 15|3@1+ (1,0) [0|7] "" ECU
 SG_ S6 : 18|3@1+ (1,0) [0|7] "" ECU
 SG_ S7 : 21|3@1+ (1,0) [0|7] "" ECU
 SG_ S8 : 24|3@1+ (1,0) [0|7] "" ECU
 SG_ S9 : 27|3@1+ (1,0) [0|7] "" ECU
 SG_ S10 : 30|3@1+ (1,0) [0|7] "" ECU
 SG_ S11 : 33|3@1+ (1,0) [0|7] "" ECU
 SG_ S12 : 36|3@1+ (1,0) [0|7] "" ECU
 SG_ S13 : 39|3@1+ (1,0) [0|7] "" ECU
 SG_ S14 : 42|3@1+ (1,0) [0|7] "" ECU
 SG_ S15 : 45|3@1+ (1,0) [0|7] "" ECU
 SG_ S16 : 48|3@1- (0.25,0) [0|7] "" ECU
 SG_ S17 : 51|5@1- (1,0) [0|7] "" ECU
 SG_ S18 : 56|8@1+ (1,0) [0|7] "" ECU
BO_ 2029 Paged: 8 ECU
 SG_ Page M : 0|8@1+ (1,0) [0|0] "" ECU
 SG_ Volts m1 : 8|16@1+ (0.001,0) [0|0] "V" ECU
 SG_ Amps m2 : 8|16@1- (1,0) [0|0] "A" ECU
BO_ 2030 Twice: 8 ECU
 SG_ Same : 0|8@1+ (1,0) [0|0] "" ECU
 SG_ Same : 8|8@1- (1,0) [0|0] "" ECU
VAL_ 2027 Gear -1 "reverse" 0 "neutral" 1 "first" -8 "fault" ;
VAL_ 2028 S18 0 "off" 200 "on" ;
SIG_VALTYPE_ 2027 Ratio : 1;
"""

ODD_NAMES = {"TempMinusC": "Temp-C", "NineLives": "9lives"}

_LOADED: dict[str, list[tuple[DbcMessage, MessageSchema]]] = {}


def _messages(path: Path, rename: Mapping[str, str] | None = None
              ) -> list[tuple[DbcMessage, MessageSchema]]:
    """Every message of a DBC with its generated schema (loaded once per file)."""
    if str(path) in _LOADED:
        return _LOADED[str(path)]
    db = cantools.database.load_file(str(path), strict=False)
    assert isinstance(db, Database)
    pool = descriptor_pool.DescriptorPool()
    out = []
    for m in db.messages:
        for signal in m.signals:
            signal.name = (rename or {}).get(signal.name, signal.name)
        m.refresh(strict=False)
        out.append((m, MessageSchema(m, path.stem, pool)))
    _LOADED[str(path)] = out
    return out


def protobuf_bytes(schema: MessageSchema, signals: Mapping[str, Any]) -> bytes:
    """What protobuf itself writes for these signals: the message built from keyword args."""
    kwargs = {schema.renamed.get(k, k): v for k, v in signals.items()}
    return bytes(schema.message_class(**kwargs).SerializeToString())


def _value(signal: Any, kind: str) -> st.SearchStrategy[Any]:
    if kind == "double":
        return st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from(
            [0.0, -0.0, math.nan, -math.inf, math.inf,
             struct.unpack("<d", b"\x01\x00\x00\x00\x00\x00\xf8\x7f")[0]])  # a NaN with a payload
    lo, hi = ((-(2 ** (signal.length - 1)), 2 ** (signal.length - 1) - 1) if signal.is_signed
              else (0, 2**signal.length - 1))
    scale, offset = int(signal.scale), int(signal.offset)
    ends = (lo * scale + offset, hi * scale + offset)
    return st.integers(min(ends), max(ends)) | st.sampled_from([min(ends), max(ends), 0]
                                                                if min(ends) <= 0 <= max(ends)
                                                                else [min(ends), max(ends)])


@st.composite
def signal_values(draw: st.DrawFn, messages: list[tuple[DbcMessage, MessageSchema]]
                  ) -> tuple[MessageSchema, dict[str, Any]]:
    """A message and values for a random subset of its signals (absent: another mux page)."""
    message, schema = messages[draw(st.integers(0, len(messages) - 1))]  # (an index: a short repr)
    values: dict[str, Any] = {}
    for signal, field in zip(message.signals, schema.fields, strict=True):
        if draw(st.booleans()) or draw(st.booleans()):
            values[signal.name] = draw(_value(signal, field.kind))
    return schema, values


@st.composite
def decoded_payloads(draw: st.DrawFn, messages: list[tuple[DbcMessage, MessageSchema]]
                     ) -> tuple[MessageSchema, dict[str, Any]]:
    """A message and what cantools decodes from a random payload of it (maybe truncated)."""
    message, schema = messages[draw(st.integers(0, len(messages) - 1))]  # (an index: a short repr)
    data = draw(st.binary(min_size=0, max_size=max(message.length, 1)))
    try:
        signals = message.decode(data, decode_choices=False, allow_truncated=True)
    except Exception:  # a multiplexer value the DBC does not define
        assume(False)
    assert isinstance(signals, dict)
    return schema, signals


def _same(schema: MessageSchema, signals: Mapping[str, Any]) -> None:
    assert compile_encoder(schema)(signals) == protobuf_bytes(schema, signals)
    assert schema.serialize(dict(signals)) == protobuf_bytes(schema, signals)


def _corners(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("dbc") / "corners.dbc"
    path.write_text(CORNERS_DBC)
    return path


@pytest.fixture(scope="module")
def corners(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[DbcMessage, MessageSchema]]:
    return _messages(_corners(tmp_path_factory), ODD_NAMES)


ECOCAR_MESSAGES = _messages(ECOCAR_DBC)
FIXTURES = [HealthCheck.function_scoped_fixture]


@given(data=st.data())
def test_ecocar_values_encode_as_protobuf_does(data: st.DataObject) -> None:
    _same(*data.draw(signal_values(ECOCAR_MESSAGES)))


@given(data=st.data())
def test_ecocar_payloads_encode_as_protobuf_does(data: st.DataObject) -> None:
    _same(*data.draw(decoded_payloads(ECOCAR_MESSAGES)))


@settings(suppress_health_check=FIXTURES, deadline=None)  # the first example loads
@given(data=st.data())
def test_corner_values_and_payloads_encode_as_protobuf_does(
        data: st.DataObject, corners: list[tuple[DbcMessage, MessageSchema]]) -> None:
    _same(*data.draw(signal_values(corners)))
    _same(*data.draw(decoded_payloads(corners)))


@pytest.mark.slow
@settings(suppress_health_check=FIXTURES, deadline=None)  # the first example loads
@given(data=st.data())
def test_public_dbc_values_and_payloads_encode_as_protobuf_does(
        data: st.DataObject, shared_dbc: Path) -> None:
    messages = [m for path in sorted(shared_dbc.glob("*.dbc")) for m in _messages(path)]
    _same(*data.draw(signal_values(messages)))
    _same(*data.draw(decoded_payloads(messages)))


def test_corner_cases_by_example(corners: list[tuple[DbcMessage, MessageSchema]]) -> None:
    by_name = {m.name: s for m, s in corners}
    examples: list[tuple[str, dict[str, Any]]] = [
        ("Wide", {"Big": 2**64 - 1}),
        ("WideSigned", {"Big": -(2**63)}),
        ("Scaled64", {"Huge": 4 * (2**64 - 1) - 7}),  # beyond 64 bits: a double field
        ("Mode", {"Gear": -8, "Temp-C": -40, "Ratio": -0.0, "Temp_C": 127.5, "9lives": 0}),
        ("Mode", {"Gear": -1, "Ratio": math.nan}),
        ("Many", {f"S{i}": 7 for i in range(16)} | {"S16": -1.0, "S17": -16, "S18": 200}),
        ("Paged", {"Page": 2, "Amps": -32768}),
        ("Twice", {"Same": 255}),
        ("Twice", {}),
    ]
    for name, signals in examples:
        _same(by_name[name], signals)


def test_a_value_protobuf_refuses_is_refused_the_same_way(
        corners: list[tuple[DbcMessage, MessageSchema]]) -> None:
    """Not what cantools gives, but the encoder must not write what protobuf would refuse."""
    schema = {m.name: s for m, s in corners}["Many"]
    for bad in ({"S0": 1.5}, {"S0": -1}, {"S0": "one"}, {"Nope": 1}):
        with pytest.raises((TypeError, ValueError)):
            protobuf_bytes(schema, bad)
        with pytest.raises((TypeError, ValueError)):
            compile_encoder(schema)(bad)


def test_ids_whose_payloads_never_repeat_are_not_cached(tmp_path: Path) -> None:
    dbc = tmp_path / "counting.dbc"
    dbc.write_text('VERSION ""\nBS_:\nBU_: X\n'
                   'BO_ 16 Odometer: 4 X\n SG_ Metres : 0|32@1+ (1,0) [0|0] "m" X\n'
                   'BO_ 17 Lights: 1 X\n SG_ On : 0|1@1+ (1,0) [0|1] "" X\n')
    decoder = Decoder({None: [load_database(dbc)]})
    for n in range(5000):
        odometer = decoder.decode(Frame(n, "body", 16, n.to_bytes(4, "little")))
        lights = decoder.decode(Frame(n, "body", 17, bytes([n // 1000 % 2])))
        assert odometer is not None and odometer.signals == {"Metres": n}
        assert lights is not None and lights.signals == {"On": n // 1000 % 2}
    counting, repeating = (decoder.codecs_for("body")[i] for i in (0, 1))
    assert counting.message.name == "Odometer" and not counting.caching
    assert repeating.message.name == "Lights" and repeating.caching
    assert counting.decoded == repeating.decoded == 5000
