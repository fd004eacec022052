"""Protobuf types generated at run time from DBC messages, so Foxglove can plot every signal.

One message type per DBC message, in its own ``.proto`` file so each MCAP schema carries only its
own definition: ``tankviz.dbc.<database>.<Message>`` in ``tankviz/dbc/<database>/<Message>.proto``.
Signals become proto3 ``optional`` fields (field numbers in DBC order), so a multiplexed signal
that its multiplexer does not select is simply absent:

- a value table on an unscaled integer signal becomes an (open) enum: raw values without a name
  stay representable, and 0 is named ``<signal>_UNNAMED`` when the DBC gives it no name;
- an integer signal with integer scaling (cantools decodes it to ``int``) becomes the smallest of
  uint32/sint32/uint64/sint64 that holds its whole range;
- everything else is a ``double``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from cantools.database.can.message import Message as DbcMessage
from cantools.database.can.signal import Signal
from cantools.database.conversion import BaseConversion, IdentityConversion, LinearIntegerConversion
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap_protobuf.schema import build_file_descriptor_set

FieldType = descriptor_pb2.FieldDescriptorProto

_NOT_IDENTIFIER = re.compile(r"[^A-Za-z0-9_]")
_INT32 = (-(2**31), 2**31 - 1)


def identifier(name: str) -> str:
    """A protobuf-safe identifier for a DBC name: letters, digits, underscores, no leading digit."""
    cleaned = _NOT_IDENTIFIER.sub("_", name.strip()) or "_"
    if cleaned[0].isdigit():
        cleaned = f"_{cleaned}"
    return cleaned


@dataclass(frozen=True)
class SignalField:
    """How one signal is stored in the generated message."""

    signal: str
    field: str
    kind: str  # "enum", "int" or "double"


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
    message: DbcMessage, package: str, file_name: str
) -> tuple[descriptor_pb2.FileDescriptorProto, list[SignalField]]:
    """The .proto file (as a descriptor) for one DBC message, and how each signal maps to it."""
    proto = descriptor_pb2.FileDescriptorProto(name=file_name, package=package, syntax="proto3")
    type_name = identifier(message.name)
    out = proto.message_type.add(name=type_name)
    fields: list[SignalField] = []
    used: set[str] = set()
    for number, signal in enumerate(message.signals, start=1):
        name = identifier(signal.name)
        if name in used:
            name = f"{name}_{number}"
        used.add(name)
        field = out.field.add(name=name, number=number, label=FieldType.LABEL_OPTIONAL)
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
            fields.append(SignalField(signal.name, name, "enum"))
            continue
        int_type = _integer_type(*int_range) if int_range is not None else None
        if int_type is not None:
            field.type = int_type
            fields.append(SignalField(signal.name, name, "int"))
        else:
            field.type = FieldType.TYPE_DOUBLE
            fields.append(SignalField(signal.name, name, "double"))
    return proto, fields


class MessageSchema:
    """A DBC message's generated protobuf class and how to fill it from cantools' decoded dict."""

    def __init__(self, message: DbcMessage, database_name: str,
                 pool: descriptor_pool.DescriptorPool) -> None:
        package = f"tankviz.dbc.{identifier(database_name)}"
        file_name = f"tankviz/dbc/{identifier(database_name)}/{identifier(message.name)}.proto"
        proto, self.fields = describe_message(message, package, file_name)
        pool.Add(proto)
        self.full_name = f"{package}.{identifier(message.name)}"
        self.message_class: Any = message_factory.GetMessageClass(
            pool.FindMessageTypeByName(self.full_name)
        )
        #: signal name -> field name, only where they differ
        self.renamed = {f.signal: f.field for f in self.fields if f.signal != f.field}

    def file_descriptor_set(self) -> bytes:
        """The serialized FileDescriptorSet of this type, built as mcap_protobuf builds it."""
        return bytes(build_file_descriptor_set(self.message_class).SerializeToString())

    def serialize(self, signals: dict[str, Any]) -> bytes:
        """Encode cantools' decoded signals (``decode_choices=False``) as this message."""
        if self.renamed:
            signals = {self.renamed.get(k, k): v for k, v in signals.items()}
        return bytes(self.message_class(**signals).SerializeToString())

    def parse(self, data: bytes) -> dict[str, Any]:
        """The signals present in a serialized message, keyed by signal name (for tests, tools)."""
        msg = self.message_class.FromString(data)
        by_field = {f.field: f.signal for f in self.fields}
        return {by_field[d.name]: v for d, v in msg.ListFields()}
