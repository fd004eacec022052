"""Decoding by (bus, id) with cantools, and the protobuf types generated from DBC messages."""

from __future__ import annotations

from pathlib import Path

import cantools
import pytest
from conftest import ECOCAR_DBC
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from bridge.decode.codec import Decoded
from bridge.decode.database import load_database, parse_dbc_option
from bridge.decode.decoder import Decoder
from bridge.decode.outcome import Undecoded
from bridge.decode.proto_schema import MessageSchema
from bridge.errors import DatabaseError, UsageError
from bridge.frame import EXTENDED_KEY, Frame, frame_key, key_id
from bridge.packed import PackedFrames

ECOCAR = load_database(ECOCAR_DBC)


def frame(db: cantools.database.can.Database, name: str, bus: str = "can0",
          **values: float) -> Frame:
    m = db.get_message_by_name(name)
    signals = {s.name: 0 for s in m.signals}
    signals.update(values)
    data = m.encode(signals, strict=False)
    return Frame(1, bus, m.frame_id, data, m.is_extended_frame, m.is_fd, dlc=len(data))


def decoder() -> Decoder:
    return Decoder({None: [ECOCAR]})


def test_decoded_signals_are_what_cantools_decodes(ecocar: cantools.database.can.Database) -> None:
    f = frame(ecocar, "EgoMotion", VehicleSpeed=88.5, YawRate=-3.2, Counter=7)
    decoded = decoder().decode(f)
    assert isinstance(decoded, Decoded)
    assert decoded.codec.topic == "/can/can0/EgoMotion"
    expected = ecocar.get_message_by_name("EgoMotion").decode(f.data, decode_choices=False)
    assert dict(decoded.signals) == expected
    assert decoded.codec.schema.parse(decoded.payload) == expected


def test_every_decoded_field_is_present_even_when_zero(
        ecocar: cantools.database.can.Database) -> None:
    f = frame(ecocar, "EgoMotion")
    decoded = decoder().decode(f)
    assert isinstance(decoded, Decoded)
    parsed = decoded.codec.schema.parse(decoded.payload)
    assert set(parsed) == {s.name for s in ecocar.get_message_by_name("EgoMotion").signals}


def test_value_tables_become_open_enums(ecocar: cantools.database.can.Database) -> None:
    schema = MessageSchema(ecocar.get_message_by_name("RadarObj3_B"), "ecocar",
                           descriptor_pool.DescriptorPool())
    cls = schema.message_class
    field = cls.DESCRIPTOR.fields_by_name["Class"]
    assert field.enum_type is not None
    assert field.enum_type.values_by_number[3].name == "Class_pedestrian"
    msg = cls(Class=6)  # a raw value the DBC names 'reserved_6'
    assert cls.FromString(msg.SerializeToString()).Class == 6
    msg = cls(Class=42)  # and one it does not name at all stays representable
    assert cls.FromString(msg.SerializeToString()).Class == 42


def test_integer_signals_get_integer_fields_and_scaled_ones_double(
        ecocar: cantools.database.can.Database) -> None:
    schema = MessageSchema(ecocar.get_message_by_name("EgoMotion"), "ecocar",
                           descriptor_pool.DescriptorPool())
    fields = schema.message_class.DESCRIPTOR.fields_by_name
    t = descriptor_pb2.FieldDescriptorProto
    assert fields["Counter"].type == t.TYPE_UINT32
    assert fields["Checksum"].type == t.TYPE_UINT32
    assert fields["VehicleSpeed"].type == t.TYPE_DOUBLE
    assert fields["YawRate"].type == t.TYPE_DOUBLE


def test_multiplexed_signals_are_present_only_on_their_page(
        ecocar: cantools.database.can.Database) -> None:
    d = decoder()
    page1 = d.decode(frame(ecocar, "SensorDiag", DiagPage=1, TempCore=55))
    page2 = d.decode(frame(ecocar, "SensorDiag", DiagPage=2, SupplyVoltage=13.5))
    assert isinstance(page1, Decoded) and isinstance(page2, Decoded)
    fields1 = page1.codec.schema.parse(page1.payload)
    fields2 = page2.codec.schema.parse(page2.payload)
    assert "TempCore" in fields1 and "SupplyVoltage" not in fields1
    assert "SupplyVoltage" in fields2 and "TempCore" not in fields2
    assert fields2["SupplyVoltage"] == pytest.approx(13.5, abs=0.1)


def test_big_endian_signed_and_float_signals(ecocar: cantools.database.can.Database) -> None:
    d = decoder()
    steering = d.decode(frame(ecocar, "Steering", SteeringWheelAngle=-123.4))
    position = d.decode(frame(ecocar, "EgoPosition", Latitude=52.5, Longitude=-13.25))
    assert isinstance(steering, Decoded) and isinstance(position, Decoded)
    assert steering.signals["SteeringWheelAngle"] == pytest.approx(-123.4)
    assert position.codec.schema.parse(position.payload)["Longitude"] == -13.25


def test_fd_frames_decode(ecocar: cantools.database.can.Database) -> None:
    f = frame(ecocar, "RadarHeader", ObjectCount=17)
    assert f.is_fd and len(f.data) == 64
    decoded = decoder().decode(f)
    assert isinstance(decoded, Decoded) and decoded.signals["ObjectCount"] == 17


def test_short_frames_decode_what_fits_and_are_counted(
        ecocar: cantools.database.can.Database) -> None:
    whole = frame(ecocar, "EgoMotion", VehicleSpeed=50, Checksum=0x5A)
    d = decoder()
    decoded = d.decode(whole._replace(data=whole.data[:3]))
    assert isinstance(decoded, Decoded)
    assert decoded.signals["VehicleSpeed"] == pytest.approx(50)
    assert "Checksum" not in decoded.signals
    assert [c.truncated for c in d.codecs() if c.truncated] == [1]
    assert d.stats.to_dict(d.codecs())["truncated"] == {"/can/can0/EgoMotion": 1}
    # its message is of the short type, beside the message's own, where the cut signals are
    # absent, not 0 (the message's own type writes no presence for them)
    assert decoded.codec.topic == "/can/can0/EgoMotion/short"
    assert decoded.codec.schema.full_name == "tankviz.dbc.ecocar.short.EgoMotion"
    short = decoded.codec.schema.message_class.FromString(decoded.payload)
    assert short.HasField("VehicleSpeed") and not short.HasField("Checksum")
    assert d.decode(whole) is not None and d.decode(whole).codec.topic == "/can/can0/EgoMotion"


def test_unknown_ids_error_frames_and_bad_payloads_are_counted_per_bus_and_id(
        ecocar: cantools.database.can.Database) -> None:
    d = decoder()
    assert d.decode(Frame(1, "can0", 0x7FF, b"\x00" * 8)) is Undecoded.UNKNOWN_ID
    assert d.decode(Frame(1, "can0", 0x100, b"", is_extended=True)) is Undecoded.UNKNOWN_ID
    assert d.decode(Frame(2, "can1", 0, b"", is_error=True)) is Undecoded.ERROR_FRAME
    bad_mux = frame(ecocar, "SensorDiag")._replace(data=bytes([9]) + bytes(7))
    assert d.decode(bad_mux) is Undecoded.DECODE_ERROR
    stats = d.stats.to_dict(d.codecs())
    assert stats["unknown_ids"] == {"can0/0x100": 1, "can0/0x7FF": 1}
    assert stats["error_frames"] == {"can1": 1}
    assert stats["decode_errors"] == {"can0/0x700": 1}
    assert "SensorDiag" in stats["last_decode_error"]["can0/0x700"]
    assert stats["frames"] == {"can0": 3, "can1": 1}


def test_each_frame_has_one_outcome_alone_or_in_a_block(
        ecocar: cantools.database.can.Database) -> None:
    """What the decoder made of a frame is its decoded message or why there is none, the same
    whether it came alone or in a pack."""
    bad_mux = frame(ecocar, "SensorDiag")._replace(data=bytes([9]) + bytes(7))
    cases = [
        (frame(ecocar, "EgoMotion"), Decoded),
        (Frame(1, "can0", 0x7FF, bytes(8)), Undecoded.UNKNOWN_ID),
        (Frame(1, "can0", 0x100, b"", is_extended=True), Undecoded.UNKNOWN_ID),  # 29-bit 0x100
        (bad_mux, Undecoded.DECODE_ERROR),
        (Frame(2, "can0", 0x100, b"", is_error=True), Undecoded.ERROR_FRAME),
        (Frame(3, "can0", 0x100, b"", is_remote=True, dlc=8), Undecoded.REMOTE),
    ]
    alone = [decoder().decode(f) for f, _ in cases]
    in_block = decoder().decode_packed(PackedFrames.from_frames([f for f, _ in cases]))
    for (_, want), one, pack in zip(cases, alone, in_block, strict=True):
        assert (type(one) if want is Decoded else one) is want
        assert (type(pack) if want is Decoded else pack) is want


def test_a_frame_key_tells_a_29_bit_id_from_an_11_bit_one() -> None:
    assert frame_key(0x100, False) == 0x100
    assert frame_key(0x100, True) == 0x100 | EXTENDED_KEY != 0x100
    assert key_id(frame_key(0x1FFFFFFF, True)) == 0x1FFFFFFF


def test_each_bus_decodes_with_its_own_databases(
        ecocar: cantools.database.can.Database, shared_dbc: Path) -> None:
    tesla = load_database(shared_dbc / "tesla_radar_bosch.dbc")
    d = Decoder({"radar": [tesla], "body": [ECOCAR]})
    radar_point = Frame(1, "radar", 0x310, bytes(8))
    assert isinstance(d.decode(radar_point), Decoded)  # RadarPoint0_A on the radar bus ...
    assert d.decode(radar_point._replace(bus="body")).codec.message.name == "RadarObj0_A"
    assert d.decode(radar_point._replace(bus="other")) is Undecoded.UNKNOWN_ID  # (no database)


def test_two_databases_defining_one_id_differently_on_one_bus_is_an_error(
        tmp_path: Path) -> None:
    a = tmp_path / "a.dbc"
    b = tmp_path / "b.dbc"
    a.write_text('VERSION ""\nBS_:\nBU_: X\nBO_ 256 Speed: 8 X\n'
                 ' SG_ V : 0|16@1+ (0.01,0) [0|655] "m/s" X\n')
    b.write_text('VERSION ""\nBS_:\nBU_: X\nBO_ 256 Brake: 8 X\n'
                 ' SG_ P : 0|8@1+ (1,0) [0|255] "bar" X\n')
    with pytest.raises(DatabaseError, match=r"b\.dbc: id 0x100 is Brake here but Speed \(defined "
                       r"differently\) in .*a\.dbc; give each file its own bus"):
        Decoder({None: [load_database(a), load_database(b)]})
    Decoder({"can0": [load_database(a)], "can1": [load_database(b)]})  # fine on separate buses
    Decoder({None: [load_database(a), load_database(a)]})  # and the same file twice is fine


def test_a_database_cantools_cannot_load_names_the_file_and_the_reason(tmp_path: Path) -> None:
    broken = tmp_path / "broken.dbc"
    broken.write_text('VERSION ""\nBO_ 256 Speed: 8 X\n SG_ V : 0|16@1+ (0.01,0) [0|655] "m/s"\n'
                      "BO_ this is not a message\n")
    with pytest.raises(DatabaseError, match=r"broken\.dbc: cantools cannot load it: .+"):
        load_database(broken)
    with pytest.raises(DatabaseError, match=r"nope\.dbc: no such file"):
        load_database(tmp_path / "nope.dbc")


def test_dbc_options_name_a_bus_or_every_bus(tmp_path: Path) -> None:
    assert parse_dbc_option("radar=/x/r.dbc") == ("radar", Path("/x/r.dbc"))
    assert parse_dbc_option("/x/r.dbc") == (None, Path("/x/r.dbc"))
    odd = tmp_path / "a=b.dbc"
    odd.write_text("")
    assert parse_dbc_option(str(odd)) == (None, odd)  # an existing path wins
    with pytest.raises(UsageError, match="no path after 'radar='"):
        parse_dbc_option("radar=")


def test_generated_schemas_are_self_contained_file_descriptor_sets(
        ecocar: cantools.database.can.Database) -> None:
    schema = MessageSchema(ecocar.get_message_by_name("CamLaneLeft"), "ecocar",
                           descriptor_pool.DescriptorPool())
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.file_descriptor_set())
    assert [f.name for f in fds.file] == ["tankviz/dbc/ecocar/CamLaneLeft.proto"]
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.full_name))
    assert schema.full_name == "tankviz.dbc.ecocar.CamLaneLeft"
    assert "C2_Curvature" in cls.DESCRIPTOR.fields_by_name


def test_a_message_is_prepared_when_it_first_comes_not_with_its_bus(
        ecocar: cantools.database.can.Database, monkeypatch: pytest.MonkeyPatch) -> None:
    from bridge.decode import decoder as module

    made: list[str] = []

    class Counted(MessageSchema):
        def __init__(self, message: object, *args: object, **kwargs: bool) -> None:
            made.append(message.name)  # type: ignore[attr-defined]
            super().__init__(message, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(module, "MessageSchema", Counted)
    d = decoder()
    for bus in ("radar", "camera", "chassis"):
        d.decode(frame(ecocar, "EgoMotion", bus, Speed=10))
    d.decode(frame(ecocar, "Steering", "chassis"))

    assert made == ["EgoMotion", "Steering"]  # one type per message, shared by the buses
    assert len(d.codecs_for("radar")) == len(ecocar.messages)  # every codec is there to use
    assert made == ["EgoMotion", "Steering"]


def test_databases_of_the_same_name_are_told_apart_in_the_order_given(tmp_path: Path) -> None:
    first, second = tmp_path / "a" / "car.dbc", tmp_path / "b" / "car.dbc"
    for path, name in ((first, "Speed"), (second, "Brake")):
        path.parent.mkdir()
        path.write_text(f'VERSION ""\nBS_:\nBU_: X\nBO_ {256 if name == "Speed" else 257} '
                        f'{name}: 8 X\n SG_ V : 0|16@1+ (0.01,0) [0|655] "" X\n')
    a, b = load_database(first), load_database(second)
    d = Decoder({None: [a, b]})

    brake = d.decode(Frame(1, "can0", 257, bytes(8)))  # the second database's message first
    speed = d.decode(Frame(2, "can0", 256, bytes(8)))

    assert isinstance(speed, Decoded) and isinstance(brake, Decoded)
    assert speed.codec.schema.full_name == "tankviz.dbc.car.Speed"
    assert brake.codec.schema.full_name == f"tankviz.dbc.car_{b.sha256[:8]}.Brake"
