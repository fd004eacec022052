"""Protobuf types generated at run time from DBC messages, so Foxglove can plot every signal.

One message type per DBC message, in its own ``.proto`` file so each MCAP schema carries only its
own definition: ``tankviz.dbc.<database>.<Message>`` in ``tankviz/dbc/<database>/<Message>.proto``
(the name made an identifier, unique in its database: :func:`type_names`).
Signals become fields in DBC order. A signal in every whole frame of its message (not
multiplexed: :func:`always_present`) has implicit presence, so a 0 is not written and reads back
as 0; a multiplexed signal is a proto3 ``optional`` field, absent where its multiplexer does not
select it. A frame shorter than its message may lack any signal, so its decoded message is of a
second type (``short``: :class:`MessageSchema`), every field ``optional``, absent where cut off.
Types:

- a value table on an unscaled integer signal becomes an (open) enum: raw values without a name
  stay representable, and 0 is named ``<signal>_UNNAMED`` when the DBC gives it no name;
- an integer signal with integer scaling (cantools decodes it to ``int``) becomes the smallest of
  uint32/sint32/uint64/sint64 that holds its whole range;
- everything else is a ``double``: also an integer signal whose range fits no 64-bit integer
  (a 64-bit raw value scaled by 2, or offset by 1), whose values beyond 2^53 are then rounded
  (:func:`rounded_range`; its database warns of it at load).

A J1939 message also has its frame's addresses (``source_address``, and ``destination_address``
for a PDU1 group) as ``uint32`` fields after the signals' (:mod:`bridge.decode.j1939`), of
implicit presence (every frame has them).

:func:`compile_encoder` turns a generated type into a function that writes the protobuf wire
format of cantools' decoded signals directly (tag, varint or zigzag varint or little-endian
double, fields in number order, every present field written but an implicit field's zero),
without building a message object: the bytes are exactly those of ``SerializeToString``. A
value protobuf would refuse or convert (not an ``int`` for an integer field, out of range, a key
the message does not have) goes through the message class instead, so it fails, or encodes,
just as protobuf does.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from cantools.database.can.message import Message as DbcMessage
from cantools.database.can.signal import Signal
from cantools.database.conversion import BaseConversion, IdentityConversion, LinearIntegerConversion
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap_protobuf.schema import build_file_descriptor_set

from bridge.decode.cache import Compile, compile_source
from bridge.protowire import DOUBLE, varint

FieldType = descriptor_pb2.FieldDescriptorProto

_NOT_IDENTIFIER = re.compile(r"[^A-Za-z0-9_]")
_INT32 = (-(2**31), 2**31 - 1)


def identifier(name: str) -> str:
    """A protobuf-safe identifier for a DBC name: letters, digits, underscores, no leading digit."""
    cleaned = _NOT_IDENTIFIER.sub("_", name.strip()) or "_"
    if cleaned[0].isdigit():
        cleaned = f"_{cleaned}"
    return cleaned


def type_names(messages: Iterable[DbcMessage]) -> dict[str, str]:
    """Each message's type name (:func:`identifier` of its name), unique in its database: a
    name that only its unsafe characters tell from an earlier one (``A-B``, ``A_B``) gets the
    message's id in hex (``A_B_101``)."""
    out: dict[str, str] = {}
    used: set[str] = set()
    for message in messages:
        if message.name in out:
            continue
        name = identifier(message.name)
        if name in used:
            name = f"{name}_{message.frame_id:X}"
        used.add(name)
        out[message.name] = name
    return out


@dataclass(frozen=True)
class SignalField:
    """How one signal is stored in the generated message."""

    signal: str
    field: str
    kind: str  # "enum", "int", "double"; "address": a J1939 message's, no signal
    #: implicit presence (a zero is not written and reads back as 0), else proto3 ``optional``
    implicit: bool = False


def always_present(message: DbcMessage) -> frozenset[str]:
    """The signals cantools decodes from every frame of the message's length: those no
    multiplexer selects (cantools unpacks every signal of a whole frame, or fails)."""
    return frozenset(s.name for s in message.signals if s.multiplexer_ids is None)


def _integer_range(signal: Signal) -> tuple[int, int] | None:
    """The scaled range of a signal that cantools decodes to int, else None."""
    conversion = BaseConversion.factory(
        scale=signal.scale, offset=signal.offset, choices=None, is_float=signal.is_float
    )
    if signal.is_float or not isinstance(conversion, IdentityConversion | LinearIntegerConversion):
        return None
    if signal.is_signed:
        raw_lo, raw_hi = -(2 ** (signal.length - 1)), 2 ** (signal.length - 1) - 1
    else:
        raw_lo, raw_hi = 0, 2**signal.length - 1
    scale, offset = int(signal.scale), int(signal.offset)
    ends = (raw_lo * scale + offset, raw_hi * scale + offset)
    return min(ends), max(ends)


def _integer_type(lo: int, hi: int) -> Any:
    if lo >= 0 and hi < 2**32:
        return FieldType.TYPE_UINT32
    if _INT32[0] <= lo and hi <= _INT32[1]:
        return FieldType.TYPE_SINT32
    if lo >= 0 and hi < 2**64:
        return FieldType.TYPE_UINT64
    if lo >= -(2**63) and hi < 2**63:
        return FieldType.TYPE_SINT64
    return None


def rounded_range(signal: Signal) -> tuple[int, int] | None:
    """The scaled range of a signal that cantools decodes to an exact ``int`` but that is stored
    as a ``double`` because the range fits no 64-bit integer type (so values beyond 2^53 are
    rounded), else None."""
    ends = _integer_range(signal)
    return ends if ends is not None and _integer_type(*ends) is None else None


def _enum_values(signal_field: str, choices: dict[int, Any]) -> list[tuple[str, int]]:
    values: list[tuple[str, int]] = []
    used: set[str] = set()
    if 0 not in choices:
        values.append((f"{signal_field}_UNNAMED", 0))
        used.add(values[0][0])
    for raw, label in sorted(choices.items(), key=lambda kv: (kv[0] != 0, kv[0])):
        name = f"{signal_field}_{identifier(str(label))}"
        if name in used:
            name = f"{name}_{raw}".replace("-", "m")
        used.add(name)
        values.append((name, int(raw)))
    return values


def describe_message(
    message: DbcMessage, package: str, file_name: str, addresses: tuple[str, ...] = (),
    *, short: bool = False,
) -> tuple[descriptor_pb2.FileDescriptorProto, list[SignalField]]:
    """The .proto file (as a descriptor) for one DBC message, and how each signal maps to it;
    ``addresses`` (a J1939 message's, :mod:`bridge.decode.j1939`) become ``uint32`` fields after
    the signals, of kind ``address`` (a signal of the same name makes one ``<name>_<number>``).
    The signals of :func:`always_present` and the addresses have implicit presence, unless
    ``short`` (the type of frames shorter than the message), where every field is optional."""
    implicit = frozenset() if short else always_present(message)
    proto = descriptor_pb2.FileDescriptorProto(name=file_name, package=package, syntax="proto3")
    type_name = file_name.rsplit("/", 1)[-1].removesuffix(".proto")
    out = proto.message_type.add(name=type_name)
    fields: list[SignalField] = []
    used: set[str] = set()
    for number, signal in enumerate(message.signals, start=1):
        name = identifier(signal.name)
        if name in used:
            name = f"{name}_{number}"
        used.add(name)
        field = out.field.add(name=name, number=number, label=FieldType.LABEL_OPTIONAL)
        bare = signal.name in implicit
        if not bare:
            field.proto3_optional = True
            field.oneof_index = len(out.oneof_decl)
            out.oneof_decl.add(name=f"_{name}")
        int_range = _integer_range(signal)
        choices: dict[int, Any] = dict(signal.choices or {})
        if (
            choices
            and int_range is not None
            and signal.scale == 1
            and signal.offset == 0
            and _INT32[0] <= int_range[0]
            and int_range[1] <= _INT32[1]
        ):
            enum = out.enum_type.add(name=f"{name}_Values")
            for value_name, value in _enum_values(name, dict(choices)):
                enum.value.add(name=value_name, number=value)
            if len({v.number for v in enum.value}) != len(enum.value):
                enum.options.allow_alias = True
            field.type = FieldType.TYPE_ENUM
            field.type_name = f".{package}.{type_name}.{enum.name}"
            fields.append(SignalField(signal.name, name, "enum", bare))
            continue
        int_type = _integer_type(*int_range) if int_range is not None else None
        if int_type is not None:
            field.type = int_type
            fields.append(SignalField(signal.name, name, "int", bare))
        else:
            field.type = FieldType.TYPE_DOUBLE
            fields.append(SignalField(signal.name, name, "double", bare))
    for number, address in enumerate(addresses, start=len(message.signals) + 1):
        name = address if address not in used else f"{address}_{number}"
        used.add(name)
        field = out.field.add(name=name, number=number, label=FieldType.LABEL_OPTIONAL,
                              type=FieldType.TYPE_UINT32)
        if short:
            field.proto3_optional, field.oneof_index = True, len(out.oneof_decl)
            out.oneof_decl.add(name=f"_{name}")
        fields.append(SignalField(address, name, "address", not short))
    return proto, fields


#: (smallest, largest value, how it is written) of each integer field type
_VARINTS = {
    FieldType.TYPE_UINT32: (0, 2**32 - 1, "unsigned"),
    FieldType.TYPE_UINT64: (0, 2**64 - 1, "unsigned"),
    FieldType.TYPE_SINT32: (-(2**31), 2**31 - 1, "zigzag"),
    FieldType.TYPE_SINT64: (-(2**63), 2**63 - 1, "zigzag"),
    FieldType.TYPE_ENUM: (-(2**31), 2**31 - 1, "int32"),
}
#: tag bytes -> the tag followed by each one-byte varint 0..127 (shared by every message)
_SMALL: dict[bytes, tuple[bytes, ...]] = {}

Encoder = Callable[[Mapping[str, Any]], bytes]



def compile_encoder(schema: MessageSchema, code: Compile = compile_source) -> Encoder:
    """A function from cantools' decoded signals (keyed by signal name, ``decode_choices=False``)
    to the serialized message, byte for byte what the message class's ``SerializeToString``
    gives (see the module docstring); it falls back to the message class for anything else.
    ``code`` compiles its source (:class:`bridge.decode.cache.CodeCache`: once for every run)."""
    fallback = schema.serialize_with_protobuf
    field_of = {f.signal: f.field for f in schema.fields if f.kind != "address"}
    field_of.update(schema.renamed)  # a repeated signal name: the last one's field, as kwargs do
    implicit = {f.field for f in schema.fields if f.implicit}
    source: dict[str, str] = {}
    for key, name in field_of.items():
        if name in source:  # two keys for one field: only protobuf itself knows the answer
            return fallback
        source[name] = key
    names: dict[str, Any] = {"F": fallback, "V": varint, "M": math.copysign,
                             "D1": DOUBLE.pack, "D2": struct.Struct("<BBd").pack}
    # Every signal present (a whole frame of a message without multiplexing) with every integer
    # below 128 as a varint, none of them an implicit field's zero: one struct.pack of the tags
    # and values.
    keys: list[str] = []
    tests: list[str] = []
    args: list[str] = []
    formats: list[str] = []
    # The same with an implicit field's zero among them: the pieces joined, a zero's empty.
    loose: list[str] = []
    pieces: list[str] = []
    # Otherwise field by field; an implicit field's zero appends b"" (protobuf does not write it:
    # 0, and 0.0 but not -0.0, whose bits are not zero), so that every key is counted.
    lines = ["    out = []", "    a = out.append"]
    for n, fd in enumerate(sorted(schema.message_class.DESCRIPTOR.fields,
                                  key=lambda fd: fd.number)):
        src = source.get(fd.name)
        if src is None:
            continue
        bare = fd.name in implicit
        double = fd.type == FieldType.TYPE_DOUBLE
        tag = varint(fd.number << 3 | 1) if double else varint(fd.number << 3)
        if len(tag) > 2:
            return fallback
        v = f"v{n}"
        keys.append(f"{v} = s[{src!r}]")
        args += [str(b) for b in tag]
        formats.append("B" * len(tag) + ("d" if double else "B"))
        lines += [f"    v = s.get({src!r})", "    if v is not None:"]
        if double:
            loose.append(f"({v}.__class__ is float or {v}.__class__ is int)")
            tests.append(loose[-1] + (f" and {v} != 0" if bare else ""))
            args.append(v)
            pack = f"D{len(tag)}({', '.join(str(b) for b in tag)}, v)"
            piece = pack.replace(", v)", f", {v})")
            pieces.append(f"({piece} if {v} != 0 or M(1.0, {v}) < 0 else b'')" if bare
                          else piece)
            lines += ["        c = v.__class__",
                      f"        if c is float or c is int: a({pack}"
                      + (" if v != 0 or M(1.0, v) < 0 else b'')" if bare else ")"),
                      "        else: return F(s)"]
            continue
        lo, hi, how = _VARINTS[fd.type]
        small = _SMALL.get(tag)
        if small is None:
            small = _SMALL[tag] = tuple(tag + bytes((i,)) for i in range(128))
        names[f"S{n}"], names[f"T{n}"] = small, tag
        names[f"Z{n}"] = (b"", *small[1:]) if bare else small
        first = 1 if bare else 0
        if how == "zigzag":
            loose.append(f"{v}.__class__ is int and -64 <= {v} < 64")
            tests.append(loose[-1] + (f" and {v} != 0" if bare else ""))
            args.append(f"({v} << 1) ^ ({v} >> 63)")
            pieces.append(f"Z{n}[({v} << 1) ^ ({v} >> 63)]")
            small_case = (f"if -64 <= v < 64: a(S{n}[(v << 1) ^ (v >> 63)])",
                          f"elif {lo} <= v <= {hi}: a(T{n} + V((v << 1) ^ (v >> 63)))")
        elif how == "int32":
            loose.append(f"{v}.__class__ is int and 0 <= {v} < 128")
            tests.append(f"{v}.__class__ is int and {first} <= {v} < 128")
            args.append(v)
            pieces.append(f"Z{n}[{v}]")
            small_case = (f"if 0 <= v < 128: a(S{n}[v])",
                          f"elif {lo} <= v <= {hi}: a(T{n} + V(v if v >= 0 else v + {2**64}))")
        else:
            loose.append(f"{v}.__class__ is int and 0 <= {v} < 128")
            tests.append(f"{v}.__class__ is int and {first} <= {v} < 128")
            args.append(v)
            pieces.append(f"Z{n}[{v}]")
            small_case = (f"if 0 <= v < 128: a(S{n}[v])",
                          f"elif {lo} <= v <= {hi}: a(T{n} + V(v))")
        lines += ["        if v.__class__ is not int: return F(s)",
                  *(["        if v == 0: a(b'')", f"        el{small_case[0]}"] if bare
                    else [f"        {small_case[0]}"]),
                  f"        {small_case[1]}",
                  "        else: return F(s)"]
    names["P"] = struct.Struct("<" + "".join(formats)).pack
    lines = ["def encode(s):",
             f"    if len(s) == {len(keys)}:",
             "        try:",
             *(f"            {k}" for k in keys or ["pass"]),
             "        except KeyError:",
             "            pass",
             "        else:",
             f"            if {' and '.join(tests) or 'True'}:",
             f"                return P({', '.join(args)})",
             *([f"            if {' and '.join(loose)}:",
                f"                return b''.join(({', '.join(pieces)},))"] if implicit and keys
               else []),
             *lines,
             "    if len(out) != len(s): return F(s)",
             "    return b''.join(out)"]
    exec(code("\n".join(lines)), names)
    encode: Encoder = names["encode"]
    return encode


class MessageSchema:
    """A DBC message's generated protobuf class and how to fill it from cantools' decoded dict:
    ``tankviz.dbc.<database>.<Message>``, or with ``short`` the type of frames shorter than the
    message, ``tankviz.dbc.<database>.short.<Message>``, every field ``optional``."""

    def __init__(self, message: DbcMessage, database_name: str,
                 pool: descriptor_pool.DescriptorPool, addresses: tuple[str, ...] = (),
                 type_name: str | None = None, code: Compile = compile_source, *,
                 short: bool = False) -> None:
        type_name = type_name or identifier(message.name)  # (:func:`type_names`)
        folder = f"{identifier(database_name)}{'.short' if short else ''}"
        package = f"tankviz.dbc.{folder}"
        file_name = f"tankviz/dbc/{folder.replace('.', '/')}/{type_name}.proto"
        proto, fields = describe_message(message, package, file_name, addresses, short=short)
        #: the type of frames shorter than the message (every field optional)
        self.short = short
        #: how each signal is stored
        self.fields = [f for f in fields if f.kind != "address"]
        #: a J1939 message's address fields (name, number), written after the signals' by the
        #: decoder (:func:`bridge.decode.j1939.address_suffix`)
        self.addresses = tuple((f.field, len(self.fields) + i)
                               for i, f in enumerate(fields[len(self.fields):], start=1))
        pool.Add(proto)
        self.full_name = f"{package}.{type_name}"
        self.message_class: Any = message_factory.GetMessageClass(
            pool.FindMessageTypeByName(self.full_name)
        )
        #: signal name -> field name, only where they differ
        self.renamed = {f.signal: f.field for f in self.fields if f.signal != f.field}
        #: cantools' decoded signals to the serialized message (:func:`compile_encoder`)
        self.encode = compile_encoder(self, code)

    def file_descriptor_set(self) -> bytes:
        """The serialized FileDescriptorSet of this type, built as mcap_protobuf builds it."""
        return bytes(build_file_descriptor_set(self.message_class).SerializeToString())

    def serialize(self, signals: Mapping[str, Any]) -> bytes:
        """Encode cantools' decoded signals (``decode_choices=False``) as this message."""
        return self.encode(signals)

    def serialize_with_protobuf(self, signals: Mapping[str, Any]) -> bytes:
        """:meth:`serialize` the slow way: the message class from keyword arguments."""
        if self.renamed:
            signals = {self.renamed.get(k, k): v for k, v in signals.items()}
        return bytes(self.message_class(**signals).SerializeToString())

    def parse(self, data: bytes) -> dict[str, Any]:
        """The signals present in a serialized message, keyed by signal name (for tests, tools):
        an implicit field always is (0 where it was not written)."""
        msg = self.message_class.FromString(data)
        by_field = {f.field: f.signal for f in self.fields}
        by_field.update((name, name) for name, _ in self.addresses)
        out = {by_field[d.name]: v for d, v in msg.ListFields()}
        for d in msg.DESCRIPTOR.fields:
            if not d.has_presence:
                out.setdefault(by_field[d.name], getattr(msg, d.name))
        return out
