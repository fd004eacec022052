"""Properties of decoding and of the generated protobuf types, on random payloads (hypothesis).

Every test runs on the bundled ecocar DBC, on a small DBC of edge cases defined here, and on the
public DBCs in ../shared/data/dbc (radar and object DBCs from opendbc: Tesla/Bosch radar, GM object
list, Delphi ESR), which are skipped where ../shared is absent:

- every generated schema loads the way an MCAP reader loads it;
- decoding any frame never raises, and every frame is decoded or counted once;
- decoded values are exactly cantools' values, in the protobuf too, absent signals absent;
- physical values encoded by cantools come back through the decoder within resolution.

At the end, two regression properties for bugs they found in ``bridge/``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Literal, cast

import pytest
from cantools.database.can.message import Message as DbcMessage
from cantools.database.can.signal import Signal
from cantools.database.conversion import BaseConversion, IdentityConversion, LinearIntegerConversion
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.decode.codec import Decoded
from bridge.decode.database import DatabaseFile, load_database
from bridge.decode.decoder import Decoder
from bridge.decode.outcome import Undecoded
from bridge.decode.proto_schema import MessageSchema
from bridge.frame import Frame
from bridge.resources import data_dir

SHARED_DBC = Path(__file__).resolve().parents[2] / "shared" / "data" / "dbc"
PUBLIC_DBCS = ("tesla_radar_bosch", "gm_global_a_object", "ESR")
BUS = "can0"

#: A small DBC with what the others lack: 64-bit and float signals, an extended-id CAN FD
#: message, big-endian scaled signals, value tables with negative values, duplicate labels or
#: without 0, several multiplexer branches, a 3-byte message.
EDGE_DBC = """\
VERSION ""

NS_ :

BS_:

BU_: ECU

BO_ 2566834709 Wide: 64 ECU
 SG_ U64 : 0|64@1+ (1,0) [0|0] "" ECU
 SG_ S64 : 64|64@1- (1,0) [0|0] "" ECU
 SG_ S64Scaled : 128|64@1- (4,-3) [0|0] "" ECU
 SG_ F32 : 192|32@1- (1,0) [0|0] "" ECU
 SG_ F64 : 224|64@1- (1,0) [0|0] "" ECU
 SG_ BigEndScaled : 295|13@0- (0.05,-10) [-200|200] "" ECU
 SG_ IntScale : 320|10@1+ (2,-100) [-100|1946] "" ECU
 SG_ NegChoices : 336|4@1- (1,0) [-8|7] "" ECU
 SG_ DupLabels : 340|3@1+ (1,0) [0|7] "" ECU
 SG_ Tiny : 343|1@1+ (1,0) [0|1] "" ECU
 SG_ NoZero : 344|3@1+ (1,0) [0|7] "" ECU
 SG_ Odd : 359|7@0+ (0.333,0.1) [0|0] "" ECU

BO_ 1 Mux: 8 ECU
 SG_ Page M : 0|4@1+ (1,0) [0|15] "" ECU
 SG_ A m0 : 8|16@1- (0.01,0) [-327.68|327.67] "" ECU
 SG_ B m1 : 8|8@1+ (1,0) [0|255] "" ECU
 SG_ C m1 : 16|24@0+ (1,0) [0|16777215] "" ECU
 SG_ D m15 : 8|56@1+ (1,0) [0|0] "" ECU
 SG_ Always : 4|4@1+ (1,0) [0|15] "" ECU

BO_ 2047 Short: 3 ECU
 SG_ Whole : 0|24@1+ (0.5,0) [0|8388607.5] "" ECU

VAL_ 2566834709 NegChoices -8 "min" -1 "minus_one" 0 "zero" 7 "max" ;
VAL_ 2566834709 DupLabels 0 "reserved" 1 "ok" 2 "reserved" 3 "Reserved" ;
VAL_ 2566834709 NoZero 1 "one" 2 "two" ;
VAL_ 1 Page 0 "first" 1 "second" 15 "last" ;
SIG_VALTYPE_ 2566834709 F32 : 1;
SIG_VALTYPE_ 2566834709 F64 : 2;
BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","reserved","J1939PG",
  "reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved",
  "reserved","reserved","StandardCAN_FD","ExtendedCAN_FD";
BA_ "VFrameFormat" BO_ 2566834709 15;
"""

#: Examples per test and database: the whole file runs in well under 30 s on two cores.
EXAMPLES = 300


class Subject:
    """One database with a decoder for it on every bus, shared by the examples of a test."""

    def __init__(self, file: DatabaseFile) -> None:
        self.file = file
        self.decoder = Decoder({None: [file]})
        self.messages: list[DbcMessage] = list(file.db.messages)
        self._readers: dict[str, Any] = {}

    def __repr__(self) -> str:  # hypothesis prints it with every falsifying example
        return f"Subject({self.file.path.name})"

    def reader_class(self, schema: MessageSchema) -> Any:
        """The class a reader of the MCAP builds from the schema record (FileDescriptorSet)."""
        cls = self._readers.get(schema.full_name)
        if cls is None:
            cls = self._readers[schema.full_name] = class_from_descriptor_set(
                schema.file_descriptor_set(), schema.full_name)
        return cls


def class_from_descriptor_set(data: bytes, full_name: str) -> Any:
    """What Foxglove (or any MCAP reader) does with a protobuf schema: parse, pool, class."""
    files = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(full_name))


@pytest.fixture(scope="module", params=["ecocar", "edge", *PUBLIC_DBCS])
def subject(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Subject:
    name: str = request.param
    if name == "edge":
        path = tmp_path_factory.mktemp("dbc") / "edge.dbc"
        path.write_text(EDGE_DBC)
    elif name == "ecocar":
        path = data_dir() / "ecocar.dbc"
    else:
        path = SHARED_DBC / f"{name}.dbc"
    if not path.is_file():
        pytest.skip(f"public DBC {path.name} not found in {SHARED_DBC}: they come from "
                    "../shared/data/dbc beside the project: public DBC files of comma.ai's "
                    "opendbc (MIT), not part of this repository")
    return Subject(load_database(path))


def schemas(subject: Subject) -> Iterator[tuple[DbcMessage, MessageSchema]]:
    pool = descriptor_pool.DescriptorPool()
    for message in subject.messages:
        yield message, MessageSchema(message, subject.file.name, pool)


def frame_for(message: DbcMessage, data: bytes, bus: str = BUS) -> Frame:
    return Frame(1_000, bus, message.frame_id, data, message.is_extended_frame, message.is_fd,
                 dlc=len(data))


def outcomes(decoder: Decoder) -> dict[str, int]:
    """Every counter a frame can land in."""
    s = decoder.stats
    return {
        "frames": sum(s.frames.values()),
        "decoded": sum(c.decoded for c in decoder.codecs()),
        "unknown": sum(s.unknown.values()),
        "errors": sum(s.errors.values()),
        "error_frames": sum(s.error_frames.values()),
        "remote_frames": sum(s.remote_frames.values()),
    }


def kinds(schema: MessageSchema) -> dict[str, str]:
    return {f.signal: f.kind for f in schema.fields}


def assert_same_values(schema: MessageSchema, got: dict[str, Any],
                       expected: dict[str, Any]) -> None:
    """Exactly cantools' values: ints as ints, doubles as the same float, enums as the raw int."""
    assert set(got) == set(expected), "present signals differ"
    kind = kinds(schema)
    for name, value in expected.items():
        if kind[name] in ("int", "enum"):
            assert isinstance(got[name], int), f"{name}: {got[name]!r} is not an int"
            assert got[name] == value, f"{name}: {got[name]!r} != {value!r}"
        elif isinstance(value, float) and math.isnan(value):
            assert math.isnan(got[name]), f"{name}: {got[name]!r} is not NaN"
        else:
            # A double holds cantools' float exactly; an int that only a double can hold (a
            # scaled 64-bit signal beyond int64) is the double nearest to it, as documented.
            assert isinstance(got[name], float), f"{name}: {got[name]!r} is not a float"
            assert got[name] == float(value), f"{name}: {got[name]!r} != {value!r}"


# ---------------------------------------------------------------------------------------------


def test_every_generated_schema_loads_in_a_fresh_pool(subject: Subject) -> None:
    """For every message, the schema record tankviz writes (a serialized FileDescriptorSet)
    parses, loads into an empty descriptor pool and yields a class with one field per signal and
    one enum value per value-table entry: what a reader of the MCAP needs, nothing else."""
    for message, schema in schemas(subject):
        cls = class_from_descriptor_set(schema.file_descriptor_set(), schema.full_name)
        fields = cls.DESCRIPTOR.fields_by_name
        assert [f.field for f in schema.fields] == [f.name for f in cls.DESCRIPTOR.fields]
        assert len(schema.fields) == len(message.signals)
        for signal, sf in zip(message.signals, schema.fields, strict=True):
            assert sf.signal == signal.name
            if sf.kind == "enum":
                numbers = set(fields[sf.field].enum_type.values_by_number)
                assert {int(v) for v in signal.choices or {}} <= numbers, signal.name


@pytest.mark.slow
@given(data=st.data())
@settings(max_examples=EXAMPLES, deadline=None)
def test_decode_never_raises_and_accounts_for_every_frame(subject: Subject,
                                                          data: st.DataObject) -> None:
    """Any frame (a known or unknown id, random flags, 0..64 random bytes, error and remote
    frames) is either decoded or counted in exactly one of unknown / decode error / error frame /
    remote frame: the decoder never raises and never loses a frame."""
    known = sorted({m.frame_id for m in subject.messages})
    frame_id = data.draw(st.one_of(st.sampled_from(known), st.integers(0, 0x7FF),
                                   st.integers(0, 0x1FFFFFFF)), label="id")
    payload = data.draw(st.binary(max_size=64), label="data")
    frame = Frame(
        timestamp_ns=data.draw(st.integers(0, 2**63 - 1)),
        bus=data.draw(st.sampled_from([BUS, "radar"]), label="bus"),
        arbitration_id=frame_id,
        data=payload,
        is_extended=data.draw(st.booleans(), label="extended"),
        is_fd=data.draw(st.booleans(), label="fd"),
        is_error=data.draw(st.sampled_from([False] * 9 + [True]), label="error"),
        is_remote=data.draw(st.sampled_from([False] * 9 + [True]), label="remote"),
        dlc=len(payload),
    )
    decoder = subject.decoder
    before = outcomes(decoder)
    result = decoder.decode(frame)
    after = outcomes(decoder)
    moved = {k for k in after if after[k] != before[k]}
    assert after["frames"] == before["frames"] + 1
    assert len(moved) == 2, f"one frame landed in {moved - {'frames'}}"
    (outcome,) = moved - {"frames"}
    assert after[outcome] == before[outcome] + 1
    if frame.is_error:
        assert (result, outcome) == (Undecoded.ERROR_FRAME, "error_frames")
    elif frame.is_remote:
        assert (result, outcome) == (Undecoded.REMOTE, "remote_frames")
    elif isinstance(result, Undecoded):
        assert (result, outcome) in ((Undecoded.UNKNOWN_ID, "unknown"),
                                     (Undecoded.DECODE_ERROR, "errors"))
    else:
        assert isinstance(result, Decoded)
        assert outcome == "decoded"
        assert result.codec.message.frame_id == frame.arbitration_id
        assert result.codec.message.is_extended_frame == frame.is_extended
        result.codec.schema.parse(result.payload)


@pytest.mark.slow
@given(data=st.data())
@settings(max_examples=EXAMPLES, deadline=None)
def test_decoded_values_are_exactly_cantools_values(subject: Subject,
                                                     data: st.DataObject) -> None:
    """For a random payload of a message (full length or cut short), tankviz decodes exactly
    what cantools decodes (``decode_choices=False, allow_truncated=True``), and the protobuf it
    records holds the same values, read back with the writer's class and with the class a reader
    builds from the schema record; signals cut off or multiplexed out are absent. A payload
    cantools cannot decode is counted as a decode error."""
    message = data.draw(st.sampled_from(subject.messages), label="message")
    length = message.length
    payload = data.draw(st.one_of(st.binary(min_size=length, max_size=length),
                                  st.binary(max_size=length)), label="data")
    try:
        expected = cast(dict[str, Any], message.decode(payload, decode_choices=False,
                                                       allow_truncated=True))
    except Exception:
        errors = sum(subject.decoder.stats.errors.values())
        assert subject.decoder.decode(frame_for(message, payload)) is Undecoded.DECODE_ERROR
        assert sum(subject.decoder.stats.errors.values()) == errors + 1
        return
    decoded = subject.decoder.decode(frame_for(message, payload))
    assert isinstance(decoded, Decoded), subject.decoder.stats.last_error
    assert decoded.codec.message is message
    assert dict(decoded.signals) == expected or _nan_equal(dict(decoded.signals), expected)
    schema = decoded.codec.schema
    assert_same_values(schema, schema.parse(decoded.payload), expected)
    reader = subject.reader_class(schema).FromString(decoded.payload)
    by_field = {f.field: f.signal for f in schema.fields}
    assert_same_values(schema, {by_field[k]: v for k, v in read_signals(reader).items()},
                       expected)


def read_signals(decoded: Any) -> dict[str, Any]:
    """A decoded message's fields as a reader sees them: those with presence that are set, and
    every field of implicit presence (0 where none was written)."""
    out = {d.name: v for d, v in decoded.ListFields()}
    for d in decoded.DESCRIPTOR.fields:
        if not d.has_presence:
            out.setdefault(d.name, getattr(decoded, d.name))
    return out


def _nan_equal(a: dict[str, Any], b: dict[str, Any]) -> bool:
    def key(v: Any) -> Any:
        return "nan" if isinstance(v, float) and math.isnan(v) else v

    return {k: key(v) for k, v in a.items()} == {k: key(v) for k, v in b.items()}


# ---------------------------------------------------------------------------------------------
# Encode side: physical values in range → cantools encode → tankviz decode


def _is_integer(signal: Signal) -> bool:
    """Whether cantools decodes the signal to int (integer scaling, not a float signal)."""
    conversion = BaseConversion.factory(scale=signal.scale, offset=signal.offset, choices=None,
                                        is_float=signal.is_float)
    return not signal.is_float and isinstance(conversion,
                                              IdentityConversion | LinearIntegerConversion)


def _raw_range(signal: Signal) -> tuple[int, int]:
    """Raw values that both fit the signal and scale into its DBC [minimum, maximum] (if the DBC
    gives a usable one)."""
    if signal.is_signed:
        lo, hi = -(2 ** (signal.length - 1)), 2 ** (signal.length - 1) - 1
    else:
        lo, hi = 0, 2**signal.length - 1
    if signal.minimum is None or signal.maximum is None or signal.minimum >= signal.maximum:
        return lo, hi
    ends = sorted(((signal.minimum - signal.offset) / signal.scale,
                   (signal.maximum - signal.offset) / signal.scale))
    in_lo, in_hi = max(lo, math.ceil(ends[0] - 1e-9)), min(hi, math.floor(ends[1] + 1e-9))
    return (in_lo, in_hi) if in_lo <= in_hi else (lo, hi)


def physical_value(signal: Signal) -> st.SearchStrategy[float | int]:
    """A physical value the signal can carry: exact for integer signals and float signals, any
    value within the representable range (to be rounded to the resolution) otherwise."""
    if signal.is_float:
        width: Literal[32, 64] = 32 if signal.length == 32 else 64
        return st.floats(width=width, allow_nan=False, allow_infinity=False)
    lo, hi = _raw_range(signal)
    if _is_integer(signal):
        scale, offset = int(signal.scale), int(signal.offset)
        return st.integers(lo, hi).map(lambda raw: raw * scale + offset)
    ends = sorted((lo * signal.scale + signal.offset, hi * signal.scale + signal.offset))
    return st.floats(ends[0], ends[1], allow_nan=False)


def _signals_of_one_branch(message: DbcMessage, tree: Sequence[Any],
                           data: st.DataObject) -> dict[str, int | None]:
    """The signals of one multiplexing branch: name → the multiplexer value chosen (or None)."""
    chosen: dict[str, int | None] = {}
    for node in tree:
        if isinstance(node, str):
            chosen.setdefault(node, None)
            continue
        for mux, branches in node.items():
            value = data.draw(st.sampled_from(sorted(branches)), label=mux)
            chosen[mux] = value
            chosen.update(_signals_of_one_branch(message, branches[value], data))
    return chosen


@pytest.mark.slow
@given(data=st.data())
@settings(max_examples=EXAMPLES, deadline=None)
def test_encoded_physical_values_decode_back_within_resolution(subject: Subject,
                                                               data: st.DataObject) -> None:
    """Random in-range physical values (one multiplexing branch, for multiplexed messages),
    encoded by cantools, come back through the decoder and its protobuf to the same values:
    exactly for integer and float signals, within half a resolution step for scaled ones."""
    message = data.draw(st.sampled_from(subject.messages), label="message")
    branch = _signals_of_one_branch(message, message.signal_tree, data)
    values: dict[str, float | int] = {}
    for signal in message.signals:
        if signal.name not in branch:
            continue
        mux_value = branch[signal.name]
        values[signal.name] = (mux_value if mux_value is not None
                               else data.draw(physical_value(signal), label=signal.name))
    payload = message.encode(values, scaling=True, padding=False, strict=False)
    decoded = subject.decoder.decode(frame_for(message, payload))
    assert isinstance(decoded, Decoded), subject.decoder.stats.last_error
    got = decoded.codec.schema.parse(decoded.payload)
    assert set(got) == set(values)
    kind = kinds(decoded.codec.schema)
    for signal in message.signals:
        if signal.name not in values:
            continue
        sent, back = values[signal.name], got[signal.name]
        if signal.is_float or kind[signal.name] in ("int", "enum"):
            assert back == sent, f"{signal.name}: sent {sent!r}, got {back!r}"
        elif _is_integer(signal):  # beyond int64 after scaling: the nearest double
            assert back == float(sent), f"{signal.name}: sent {sent!r}, got {back!r}"
        else:
            step = abs(signal.scale)
            assert abs(back - sent) <= step / 2 + 1e-9 * max(1.0, abs(sent)), (
                f"{signal.name}: sent {sent!r}, got {back!r} (resolution {step})")


# ---------------------------------------------------------------------------------------------
# Regressions: both found by these properties (fixed in bridge/decode.py and bridge/schema.py)


def _counts(decoder: Decoder) -> tuple[int, int, int]:
    stats = decoder.stats.to_dict(decoder.codecs())
    return (sum(stats["decoded"].values()), sum(stats["truncated"].values()),
            sum(stats["decode_errors"].values()))


@pytest.mark.slow
@given(data=st.data())
@settings(max_examples=EXAMPLES, deadline=None)
def test_decoding_a_frame_again_counts_it_again(subject: Subject, data: st.DataObject) -> None:
    """The payload cache is invisible: decoding the same frame a second time returns the same
    values and moves the same counters (decoded, truncated, decode errors) as the first time.
    (A short frame used to be counted as truncated only on a cache miss.)"""
    message = data.draw(st.sampled_from(subject.messages), label="message")
    payload = data.draw(st.binary(max_size=message.length), label="data")
    frame = frame_for(message, payload)
    decoder = subject.decoder
    before = _counts(decoder)
    first = decoder.decode(frame)
    middle = _counts(decoder)
    second = decoder.decode(frame)
    after = _counts(decoder)
    assert type(first) is type(second)
    if isinstance(first, Decoded) and isinstance(second, Decoded):
        assert first.payload == second.payload
    else:
        assert first == second
    assert [m - b for m, b in zip(middle, before, strict=True)] == [
        a - m for a, m in zip(after, middle, strict=True)]


WIDE_ENUM_DBC = """\
VERSION ""

NS_ :

BS_:

BU_: ECU

BO_ 256 Status: 4 ECU
 SG_ Code : 0|32@1+ (1,0) [0|4294967295] "" ECU

VAL_ 256 Code 0 "none" 1 "overheat" ;
"""


@pytest.fixture(scope="module")
def wide_enum(tmp_path_factory: pytest.TempPathFactory) -> Subject:
    path = tmp_path_factory.mktemp("dbc") / "wide_enum.dbc"
    path.write_text(WIDE_ENUM_DBC)
    return Subject(load_database(path))


@given(raw=st.integers(0, 2**32 - 1))
@settings(max_examples=50, deadline=None)
def test_a_value_table_on_a_32_bit_signal_keeps_every_raw_value(wide_enum: Subject,
                                                                 raw: int) -> None:
    """A 32-bit unsigned signal with a value table (a status or error code) decodes every raw
    value, named or not, into its protobuf field. (It used to become an int32 enum, so raw values
    from 2**31 failed to serialize and the frame was counted as a decode error.)"""
    message = wide_enum.messages[0]
    decoded = wide_enum.decoder.decode(frame_for(message, raw.to_bytes(4, "little")))
    assert isinstance(decoded, Decoded), wide_enum.decoder.stats.last_error
    assert decoded.codec.schema.parse(decoded.payload) == {"Code": raw}
