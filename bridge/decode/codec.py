"""One DBC message as seen on one bus (:class:`MessageCodec`): its payloads decoded, remembered
and encoded in protobuf's wire format, one at a time or a column at once, and its counts.

A payload seen before on a message returns the same :class:`Decoded` (a bounded cache per
message, which a message whose payloads never repeat stops using for a while). A new one is
decoded by the message's precompiled decoder where it has one
(:func:`bridge.decode.compiled.compile_decoder`: cantools' very result), else by cantools, and
encoded by the message's precompiled encoder (:func:`bridge.decode.proto_schema.compile_encoder`),
byte for byte protobuf's own encoding; a payload shorter than the message is the message of its
:attr:`MessageCodec.short` codec (its own topic and type, every signal optional). A float signal
that decodes to +inf, -inf or NaN is kept as it came and named in :attr:`Decoded.non_finite`.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from functools import cached_property, partial
from typing import Any, NamedTuple, cast

from cantools.database.can.message import Message as DbcMessage

from bridge.decode.compiled import DecodeColumn
from bridge.decode.database import DatabaseFile
from bridge.decode.j1939 import address_suffix
from bridge.decode.proto_schema import MessageSchema
from bridge.topics import message_topic, short_topic

#: Distinct payloads remembered per message; real traffic repeats many (status, static objects).
#: 256 holds every payload of a static message with an 8-bit rolling counter; more hit no more
#: often on the simulated or the Ford-like traffic of tools/bench_decode.py (1024, 256 and 64
#: decode at the same speed) and only make memory grow for minutes (at 1024, by 6 MB between
#: 200k and 400k frames of the simulated drive) and live's full collections walk more.
_CACHE_SIZE = 256
#: Misses per trial of a message's payload cache: a trial with fewer hits than misses / 8 ...
_TRIAL_MISSES = 512
#: ... stops caching that message for this many frames, then it is tried again.
_REST_FRAMES = 16 * _TRIAL_MISSES


class Decoded(NamedTuple):
    """One decoded frame: its message, the signal values and their protobuf encoding, and the
    float signals whose value is not finite (+inf, -inf, NaN)."""

    codec: MessageCodec
    signals: Mapping[str, Any]
    payload: bytes
    non_finite: tuple[str, ...] = ()


#: ``Decoded`` of a tuple of its fields: the very object ``Decoded(*fields)`` makes, without
#: its Python-level ``__new__`` (the column decode's per-payload path)
_new_decoded = partial(tuple.__new__, Decoded)


class MessageCodec:
    """One DBC message as seen on one bus: cantools decoding, the protobuf type, the topic.

    A decoded payload is remembered (up to ``_CACHE_SIZE`` distinct ones, then forgotten all at
    once), and the same payload again returns the same :class:`Decoded`. A message whose
    payloads do not repeat (a counter or a checksum in every frame, a noisy measurement) is not
    worth it: after ``_TRIAL_MISSES`` misses with fewer than one hit per 8 misses, it stops
    remembering (:attr:`caching` False, its memory freed) for ``_REST_FRAMES`` frames, then tries
    again.

    What a message costs to prepare (its protobuf type and encoder, :attr:`schema`; its compiled
    decoder; both shared by every bus the message is on) is made when it is first needed: a
    database of a hundred messages on three buses, of which each bus carries a few, does not make
    them all before its first frame.
    """

    def __init__(self, message: DbcMessage, database: DatabaseFile,
                 schema: Callable[..., MessageSchema], bus: str,
                 decoder: Callable[[], Callable[[bytes], Any]],
                 column_decoder: Callable[[], DecodeColumn | None] | None = None, *,
                 j1939_id: int | None = None, derived: bool = False) -> None:
        self.message = message
        self.database = database
        self._schema = schema
        self._decoder = decoder
        self._column_decoder = column_decoder
        #: the column decoder once made (None: there is none, every payload is decoded alone)
        self._decode_column: DecodeColumn | None = None
        self._column_made = column_decoder is None
        self.bus = bus
        self.topic = message_topic(bus, message.name)
        #: a J1939 message: the id of its frames, whose addresses its decoded messages keep
        self.j1939_id = j1939_id
        #: a J1939 message's codec for another id than the database's (same topic, schema)
        self.derived = derived
        self.length = message.length
        self.decoded = 0
        self.truncated = 0
        #: CAN FD frames longer than the message, and the longest of them
        self.longer = 0
        self.longest = 0
        #: the float signals, which alone can decode to +inf, -inf or NaN
        self.floats = tuple(s.name for s in message.signals if s.is_float)
        #: non-finite values per signal name
        self.non_finite: Counter[str] = Counter()
        self._cache: dict[bytes, Decoded] = {}
        #: whether new payloads are remembered now
        self.caching = True
        self._misses = 0  # in this trial (caching), since ...
        self._since = 0  # ... this many decoded frames; or (not caching) until then
        self._decode: Callable[[bytes], Any] = self._first_decode
        self._encode: Callable[[Mapping[str, Any]], bytes] = self._first_encode

    @cached_property
    def schema(self) -> MessageSchema:
        """The message's protobuf type (made on first use)."""
        return self._schema()

    def _first_decode(self, data: bytes) -> Any:
        self._decode = self._decoder()
        return self._decode(data)

    @cached_property
    def short(self) -> MessageCodec:
        """The codec of the message's frames shorter than it (which may lack any signal): its
        own topic (:func:`bridge.topics.short_topic`) and type (every field ``optional``,
        :class:`MessageSchema` ``short``); its frames are counted by this codec."""
        codec = MessageCodec(self.message, self.database, partial(self._schema, short=True),
                             self.bus, self._decoder, j1939_id=self.j1939_id, derived=True)
        codec.topic = short_topic(self.topic)
        return codec

    def _first_encode(self, signals: Mapping[str, Any]) -> bytes:
        encode = self.schema.encode
        if self.j1939_id is not None:
            suffix = address_suffix(self.j1939_id, tuple(n for _, n in self.schema.addresses),
                                    implicit=not self.schema.short)
            self._encode = lambda s: encode(s) + suffix
        else:
            self._encode = encode
        return self._encode(signals)

    def decode(self, data: bytes) -> Decoded:
        """Decode one payload; raises whatever cantools raises for a payload it cannot decode."""
        into = self
        if len(data) != self.length:
            if len(data) < self.length:
                self.truncated += 1
                into = self.short
            else:
                self.longer += 1
                self.longest = max(self.longest, len(data))
        hit = self._cache.get(data)
        if hit is not None:
            self.decoded += 1
            if hit.non_finite:
                self.non_finite.update(hit.non_finite)
            return hit
        signals: dict[str, Any] = self._decode(data)
        bad = (tuple(n for n in self.floats if not math.isfinite(signals.get(n, 0.0)))
               if self.floats else ())
        if bad:
            self.non_finite.update(bad)
        result = Decoded(into, signals, into._encode(signals), bad)
        self.decoded += 1
        if self.caching:
            if len(self._cache) >= _CACHE_SIZE:
                self._cache.clear()
            self._cache[data] = result
            self._misses += 1
            if self._misses >= _TRIAL_MISSES:
                self._trial_ends()
        elif self.decoded >= self._since:
            self.caching, self._misses, self._since = True, 0, self.decoded
        return result

    def decode_many(self, datas: Sequence[bytes]) -> tuple[list[Decoded | Exception], bool]:
        """Decode a column of payloads in one step: what :meth:`decode` on each, in order, returns,
        with the same counts afterwards (``decoded``, ``truncated``, ``longer``, ``longest``,
        ``non_finite``); a payload it cannot decode has in its place the exception :meth:`decode`
        would raise (not counted as decoded, as :meth:`decode` does not). And whether one failed.

        Each distinct payload of the column is decoded once (or taken from the cache), so equal
        payloads share one :class:`Decoded`; the cache learns the new ones as :meth:`decode`
        would, its trials counted per distinct payload (which only changes what is remembered,
        never a result)."""
        n = len(datas)
        if not n:
            return [], False
        length = self.length
        if len(set(map(len, datas))) > 1 or len(datas[0]) != length:
            for size, count in Counter(map(len, datas)).items():
                if size < length:
                    self.truncated += count
                elif size > length:
                    self.longer += count
                    self.longest = max(self.longest, size)
        cache = self._cache
        results: dict[bytes, Decoded | Exception | None] = dict.fromkeys(datas)
        failed = counted = False  # a payload that failed; one with non-finite values counted
        half_counted: dict[bytes, tuple[str, ...]] = {}  # failed after counting non-finite ones
        new: list[bytes] = []
        for data in results:
            hit = cache.get(data)
            if hit is None:
                new.append(data)
            else:
                results[data] = hit
                counted = counted or bool(hit.non_finite)
        if not self._column_made:
            self._decode_column, self._column_made = self._column_decoder(), True  # type: ignore[misc]
        column = self._decode_column
        decoded: list[tuple[bytes, dict[str, Any] | None]] = []
        if column is not None and new:
            exact = [d for d in new if len(d) == length]
            decoded += zip(exact, column(exact), strict=True)
            if len(exact) != len(new):
                decoded += ((d, None) for d in new if len(d) != length)
        else:
            decoded += ((d, None) for d in new)
        floats, encode, decode = self.floats, self._encode, self._decode
        caching = self.caching
        for data, signals in decoded:
            bad: tuple[str, ...] = ()
            try:
                if signals is None:
                    signals = cast("dict[str, Any]", decode(data))
                bad = (tuple(n for n in floats if not math.isfinite(signals.get(n, 0.0)))
                       if floats else ())
                if len(data) < length:
                    result = _new_decoded((self.short, signals, self.short._encode(signals), bad))
                else:
                    result = _new_decoded((self, signals, encode(signals), bad))
            except Exception as exc:  # decode() raises it: the caller counts it
                results[data] = exc
                failed = True
                if bad:
                    half_counted[data] = bad
                continue
            results[data] = result
            counted = counted or bool(bad)
            if caching:
                if len(cache) >= _CACHE_SIZE:
                    cache.clear()
                cache[data] = result
                self._misses += 1
        out = cast("list[Decoded | Exception]", list(map(results.__getitem__, datas)))
        if not failed:
            self.decoded += n
        else:
            self.decoded += sum(1 for r in out if type(r) is Decoded)
        if counted or half_counted:
            occurrences = Counter(datas) if len(results) < n else None
            for data, done in results.items():
                bad = done.non_finite if type(done) is Decoded else half_counted.get(data, ())
                if bad:
                    times = occurrences[data] if occurrences is not None else 1
                    for name in bad:
                        self.non_finite[name] += times
        if caching:
            if self._misses >= _TRIAL_MISSES:
                self._trial_ends()
        elif self.decoded >= self._since:
            self.caching, self._misses, self._since = True, 0, self.decoded
        return out, failed

    def _trial_ends(self) -> None:
        hits = self.decoded - self._since - self._misses
        if hits * 8 < self._misses:
            self.caching, self._since = False, self.decoded + _REST_FRAMES
            self._cache.clear()
        else:
            self._misses, self._since = 0, self.decoded
