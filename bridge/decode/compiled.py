"""A precompiled decoder per DBC message: cantools' own decoding, without its per-signal calls.

:func:`compile_decoder` returns a function equal to ``message.decode(data, decode_choices=False,
allow_truncated=True)``, key order and value types included (tests/test_decode_compiled.py), or
None for a message it cannot compile. Only the plain case is compiled: a message neither
multiplexed nor a container, whose signals do not overlap, with conversions cantools uses for
numbers (identity, linear, linear integer, also under a value table); the function hands a payload
of another length than the message's to cantools. :func:`compile_column_decoder` decodes a column
of payloads of the message's length in one call
(:meth:`bridge.decode.decoder.MessageCodec.decode_many`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from cantools.database.can.message import Message as DbcMessage
from cantools.database.conversion import (
    IdentityConversion,
    LinearConversion,
    LinearIntegerConversion,
    NamedSignalConversion,
)

from bridge.decode.cache import Compile, compile_source

Decode = Callable[[bytes], dict[str, Any]]
DecodeColumn = Callable[[Sequence[bytes]], list[dict[str, Any]]]


def _conversion(signal: Any) -> Any:
    """The numeric conversion cantools applies with ``decode_choices=False``, or None."""
    conversion = signal.conversion
    if isinstance(conversion, NamedSignalConversion):
        conversion = getattr(conversion, "_conversion", None)
    if type(conversion) in (IdentityConversion, LinearConversion, LinearIntegerConversion):
        return conversion
    return None


def compile_decoder(message: DbcMessage) -> Decode | None:
    """``data -> signals`` for ``message``, equal to cantools' ``decode(data,
    decode_choices=False, allow_truncated=True)``; None where only cantools can decode it."""
    made = compile_decoders(message)
    return None if made is None else made[0]


def compile_column_decoder(message: DbcMessage) -> DecodeColumn | None:
    """``payloads -> [signals, ...]`` for ``message``: :func:`compile_decoder`'s result for each
    payload, in one call (one loop in one generated function), for payloads that all have the
    message's length (which the plain case never fails to decode); None where
    :func:`compile_decoder` gives None."""
    made = compile_decoders(message)
    return None if made is None else made[1]


def compile_decoders(message: DbcMessage, code: Compile = compile_source
                     ) -> tuple[Decode, DecodeColumn] | None:
    """:func:`compile_decoder` and :func:`compile_column_decoder` of ``message``, made at once;
    ``code`` compiles their source (:class:`bridge.decode.cache.CodeCache`: once for every run)."""
    codecs = getattr(message, "_codecs", None)
    if (message.is_container or message.is_multiplexed() or not isinstance(codecs, dict)
            or codecs.get("multiplexers") or "formats" not in codecs):
        return None
    signals = codecs.get("signals") or []
    formats = codecs["formats"]
    big = getattr(formats, "big_endian", None)
    little = getattr(formats, "little_endian", None)
    if big is None or little is None:
        return None
    names: dict[str, Any] = {"BE": big.unpack, "LE": little.unpack, "SLOW": message.decode}
    values = []
    for i, signal in enumerate(signals):
        conversion = _conversion(signal)
        if conversion is None:
            return None
        raw = f"u[{signal.name!r}]"
        if type(conversion) is IdentityConversion:
            values.append(f"{signal.name!r}: {raw}")
        else:
            names[f"K{i}"], names[f"O{i}"] = conversion.scale, conversion.offset
            values.append(f"{signal.name!r}: {raw} * K{i} + O{i}")
    has_big = any(s.byte_order == "big_endian" for s in signals)
    has_little = any(s.byte_order == "little_endian" for s in signals)
    unpack = ("{**BE(data), **LE(data[::-1])}" if has_big and has_little
              else "BE(data)" if has_big else "LE(data[::-1])" if has_little else "{}")
    result = "{" + ", ".join(values) + "}"
    source = "\n".join([
        "def decode(data):",
        f"    if len(data) != {message.length}:",
        "        return SLOW(data, decode_choices=False, allow_truncated=True)",
        f"    u = {unpack}",
        f"    return {result}",
        "",
        "def decode_column(datas):",
        (f"    return [{result} for u in map(BE, datas)]" if unpack == "BE(data)" else
         f"    return [{result} for u in map(LE, [data[::-1] for data in datas])]"
         if unpack == "LE(data[::-1])" else
         f"    return [{result} for u in [{unpack} for data in datas]]"),
    ])
    exec(code(source), names)
    decode: Decode = names["decode"]
    try:  # formats cantools built for signals that overlap cannot unpack any payload
        decode(bytes(message.length))
    except Exception:
        return None  # cantools' own decode says why, frame by frame
    return decode, names["decode_column"]
