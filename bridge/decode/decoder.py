"""Decode: CAN frames to signals with cantools, by (bus, id), each bus with its own databases; a
J1939 message by its PGN from any source address (:mod:`bridge.decode.j1939`: a codec is made
for each id of it seen, one topic and schema for all, the address in each decoded message).

Every frame has one :class:`Outcome`: decoded, an unknown id (no database of its bus defines
it), a decode error, an error frame or a remote frame. Those that do not decode are counted per
bus, or per (bus, id), in :class:`DecodeStats`, never raised: the recorder keeps every raw frame,
so nothing is lost. :meth:`Decoder.outcome` tells what :meth:`Decoder.decode` made of a frame, so
that the health monitor counts it without sorting it again. Frames shorter than their DBC length
decode what fits and are counted too; CAN FD frames longer than their message decode what the
message defines and are counted with the longest length seen (``longer`` in the statistics).

Decoding repeats: a payload seen before on a message returns the same :class:`Decoded` (a bounded
cache per message, which a message whose payloads never repeat stops using for a while: see
:class:`MessageCodec`). A new one is decoded by the message's precompiled decoder where it has
one (:func:`bridge.decode.compiled.compile_decoder`: cantools' own formats and conversions, its
very result), else by cantools, and encoded by the message's precompiled encoder
(:func:`bridge.decode.proto_schema.compile_encoder`), byte for byte protobuf's own encoding.

Offline, frames come in blocks (:class:`bridge.block.FrameBlock`): :meth:`Decoder.decode_block`
decodes a block a column per ``(bus, key)`` (:meth:`Decoder.decode_column`,
:meth:`MessageCodec.decode_many`): each distinct payload of a column once, the payloads of the
message's length in one call of its precompiled column decoder
(:func:`bridge.decode.compiled.compile_column_decoder`), and every count the same as decoding the
block's frames one by one in order (what it returns too, row for row; tests/test_decode_block.py
checks it). Only what the payload cache remembers may differ, never a result.

A float signal (IEEE, ``SIG_VALTYPE_``) that decodes to +inf, -inf or NaN is kept in the decoded
message as it came, named in :attr:`Decoded.non_finite` and counted per bus, message and signal
(``non_finite`` in the statistics); the world never takes such a value
(:mod:`bridge.world.observe`).

Problems that would silence, move or mix a message without a word are warnings: those of a
database itself are named in :attr:`DatabaseFile.warnings` when the file is loaded
(:mod:`bridge.decode.database`), and :meth:`Decoder.warnings` adds a message moved off a topic of
tankviz's own on one bus (:func:`bridge.topics.message_topic`), buses that share their topics and,
once frames have been decoded, every ``--dbc BUS=`` whose bus no frame came from.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from functools import cached_property, partial
from typing import Any, NamedTuple, cast

from cantools.database.can.message import Message as DbcMessage
from google.protobuf import descriptor_pool

from bridge.block import ERROR, EXTENDED, REMOTE, FrameBlock
from bridge.decode.compiled import DecodeColumn, compile_decoders
from bridge.decode.database import DatabaseFile as DatabaseFile
from bridge.decode.database import database_warnings as database_warnings
from bridge.decode.database import layout as _layout
from bridge.decode.database import load_database as load_database
from bridge.decode.database import parse_dbc_option as parse_dbc_option
from bridge.decode.j1939 import address_fields, address_suffix, is_j1939, pgn_key
from bridge.decode.proto_schema import MessageSchema, identifier, type_names
from bridge.errors import DatabaseError
from bridge.frame import EXTENDED_KEY, Frame, frame_key
from bridge.topics import BUS_LEAVES, bus_segment, message_topic, own_topic, short_topic

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

#: bytes.translate table of block flags: 1 where the frame is extended, else 0
_EXTENDED_ONLY = bytes(1 if f & EXTENDED else 0 for f in range(256))

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

    def decode_many(self, datas: Sequence[bytes]) -> list[Decoded | Exception]:
        """Decode a column of payloads in one step: what :meth:`decode` on each, in order, returns,
        with the same counts afterwards (``decoded``, ``truncated``, ``longer``, ``longest``,
        ``non_finite``); a payload it cannot decode has in its place the exception :meth:`decode`
        would raise (not counted as decoded, as :meth:`decode` does not).

        Each distinct payload of the column is decoded once (or taken from the cache), so equal
        payloads share one :class:`Decoded`; the cache learns the new ones as :meth:`decode`
        would, its trials counted per distinct payload (which only changes what is remembered,
        never a result)."""
        return self._decode_many(datas)[0]

    def _decode_many(self, datas: Sequence[bytes]) -> tuple[list[Decoded | Exception], bool]:
        """:meth:`decode_many`, and whether a payload failed."""
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


class Outcome(Enum):
    """What the decoder made of a frame (as cantools' monitor has ``MessageFormattingResult``)."""

    #: a message of its bus's databases, decoded
    DECODED = "decoded"
    #: no database of its bus defines its id
    UNKNOWN_ID = "unknown_id"
    #: a message of its bus's databases that cantools cannot decode
    DECODE_ERROR = "decode_error"
    ERROR_FRAME = "error_frame"
    REMOTE = "remote"


# The outcomes as module globals, for the per-frame paths (quicker than the class's attributes).
_DECODED, _UNKNOWN_ID, _DECODE_ERROR = Outcome.DECODED, Outcome.UNKNOWN_ID, Outcome.DECODE_ERROR
_ERROR_FRAME, _REMOTE = Outcome.ERROR_FRAME, Outcome.REMOTE


@dataclass
class DecodeStats:
    """What happened to every frame, per bus and per (bus, id)."""

    frames: Counter[str] = field(default_factory=Counter)
    error_frames: Counter[str] = field(default_factory=Counter)
    remote_frames: Counter[str] = field(default_factory=Counter)
    unknown: Counter[tuple[str, int]] = field(default_factory=Counter)
    errors: Counter[tuple[str, int]] = field(default_factory=Counter)
    last_error: dict[tuple[str, int], str] = field(default_factory=dict)

    def to_dict(self, codecs: Iterable[MessageCodec]) -> dict[str, Any]:
        """A JSON-ready summary (stored in the MCAP metadata, printed by ``inspect``)."""

        def ids(counter: Counter[tuple[str, int]]) -> dict[str, int]:
            return {f"{bus}/0x{i:X}": n for (bus, i), n in sorted(counter.items())}

        codecs = sorted(codecs, key=lambda c: c.topic)  # (a J1939 message's: one topic)
        decoded: Counter[str] = Counter()
        truncated: Counter[str] = Counter()
        longer: dict[str, dict[str, int]] = {}
        non_finite: Counter[str] = Counter()
        for c in codecs:
            decoded[c.topic] += c.decoded
            truncated[c.topic] += c.truncated
            if c.longer:
                seen = longer.setdefault(c.topic, {"frames": 0, "message_bytes": c.length,
                                                   "longest": 0})
                seen["frames"] += c.longer
                seen["longest"] = max(seen["longest"], c.longest)
            for name, n in sorted(c.non_finite.items()):
                non_finite[f"{c.bus}/{c.message.name}.{name}"] += n
        return {
            "frames": dict(sorted(self.frames.items())),
            "decoded": {topic: n for topic, n in decoded.items() if n},
            "truncated": {topic: n for topic, n in truncated.items() if n},
            "longer": longer,
            "unknown_ids": ids(self.unknown),
            "decode_errors": ids(self.errors),
            "last_decode_error": {f"{bus}/0x{i:X}": text
                                  for (bus, i), text in sorted(self.last_error.items())},
            "error_frames": dict(sorted(self.error_frames.items())),
            "remote_frames": dict(sorted(self.remote_frames.items())),
            "non_finite": dict(non_finite),
        }


class Decoder:
    """Decodes frames by (bus, id). ``databases`` maps a bus name (None: every bus) to files."""

    def __init__(self, databases: Mapping[str | None, Iterable[DatabaseFile]]) -> None:
        self._databases = {bus: list(files) for bus, files in databases.items()}
        self._pool = descriptor_pool.DescriptorPool()
        self._schemas: dict[tuple[str, str, bool], MessageSchema] = {}
        #: per database's part of the types' names, its messages' type names
        self._type_names: dict[str, dict[str, str]] = {}
        #: compiled decoders by id of the DBC message (the databases keep the messages alive)
        self._decoders: dict[int, tuple[Callable[[bytes], Any], DecodeColumn | None]] = {}
        self._tables: dict[str, dict[int, MessageCodec]] = {}
        #: per bus with J1939 messages, each PGN's (:func:`~bridge.decode.j1939.pgn_key`)
        self._pgns: dict[str, dict[int, tuple[DatabaseFile, DbcMessage]]] = {}
        self._database_names: dict[str, str] = {}
        #: topic segment -> the buses that have it (:func:`~bridge.topics.bus_segment`)
        self._segments: dict[str, list[str]] = {}
        #: a line for each message of a bus moved off a topic of tankviz's own there alone
        self._moved: list[str] = []
        self.stats = DecodeStats()
        #: the latest frame :meth:`decode` returned None for, and why (read by :meth:`outcome`;
        #: the health monitor reads them itself, as :meth:`outcome` does, in its per-frame path)
        self.undecoded: Frame | None = None
        self.why = Outcome.UNKNOWN_ID
        # Check every combination now, so a conflict is reported before any work is done.
        for bus in self._databases:
            self._check(self._files_for(bus))

    @property
    def files(self) -> list[DatabaseFile]:
        """Every database in use, each once."""
        seen: dict[str, DatabaseFile] = {}
        for files in self._databases.values():
            for f in files:
                seen.setdefault(str(f.path), f)
        return list(seen.values())

    def warnings(self) -> list[str]:
        """What silences, moves or mixes messages: the databases' warnings, a message of a bus
        moved off a topic of tankviz's own on that bus alone, buses whose names make one topic
        segment, then every ``--dbc BUS=`` whose bus no frame came from (once frames have been
        decoded)."""
        lines = [text for f in self.files for text in f.warnings] + self._moved
        for segment, buses in self._segments.items():
            if len(buses) > 1:
                named = sorted(buses)
                lines.append(f"buses {', '.join(named[:-1])} and {named[-1]} share the topics "
                             f"/can/{segment}/...: their decoded messages are mixed there (each "
                             "raw frame keeps its bus)")
        seen = self.stats.frames
        if seen:
            have = ", ".join(sorted(seen))
            lines += [f"--dbc {bus}={f.path}: no input has bus {bus} (the inputs have {have}), "
                      "so nothing was decoded with it"
                      for bus, files in self._databases.items()
                      if bus is not None and bus not in seen for f in files]
        return lines

    def buses_for(self, database: DatabaseFile) -> list[str]:
        """The buses a database applies to (``*`` for every bus)."""
        return [bus or "*" for bus, files in self._databases.items() if database in files]

    def codecs(self) -> list[MessageCodec]:
        """Every message seen on a bus so far (or prepared with :meth:`codecs_for`)."""
        return [c for table in self._tables.values() for c in table.values()]

    def codecs_for(self, bus: str) -> list[MessageCodec]:
        """Every message the databases of ``bus`` define there, each once."""
        table = self._tables.get(bus)
        table = table if table is not None else self._table(bus)
        return [c for c in table.values() if not c.derived]

    def _files_for(self, bus: str | None) -> list[DatabaseFile]:
        files = list(self._databases.get(None, []))
        if bus is not None:
            files += [f for f in self._databases.get(bus, []) if f not in files]
        return files

    def _check(self, files: list[DatabaseFile]) -> None:
        owner: dict[int, tuple[DatabaseFile, DbcMessage]] = {}
        names: dict[str, tuple[DatabaseFile, DbcMessage]] = {}
        for f in files:
            for message in f.db.messages:
                key = frame_key(message.frame_id, message.is_extended_frame)
                if key in owner and _layout(owner[key][1]) != _layout(message):
                    other_file, other = owner[key]
                    raise DatabaseError(
                        f.path,
                        f"id 0x{message.frame_id:X} is {message.name} here but "
                        f"{other.name} (defined differently) in {other_file.path}; "
                        "give each file its own bus: --dbc BUS=PATH, or in a profile [profile] "
                        f"databases = {{ BUS = [\"{other_file.path.name}\"], "
                        f"OTHER_BUS = [\"{f.path.name}\"] }}",
                    )
                owner.setdefault(key, (f, message))
                if message.name in names and names[message.name][1].frame_id != message.frame_id:
                    other_file, other = names[message.name]
                    raise DatabaseError(
                        f.path,
                        f"message {message.name} (id 0x{message.frame_id:X}) has the same name "
                        f"as id 0x{other.frame_id:X} in {other_file.path}",
                    )
                names.setdefault(message.name, (f, message))

    def _database_name(self, database: DatabaseFile) -> str:
        """The database's part of its types' names, unique among the databases (named in the
        order their buses' tables are made)."""
        name = self._database_names.get(database.sha256)
        if name is None:
            name = identifier(database.name)
            if name in self._database_names.values():
                name = f"{name}_{database.sha256[:8]}"
            self._database_names[database.sha256] = name
        return name

    def _schema(self, database: DatabaseFile, message: DbcMessage, *,
                short: bool = False) -> MessageSchema:
        name = self._database_name(database)
        key = (name, message.name, short)
        schema = self._schemas.get(key)
        if schema is None:
            addresses = address_fields(message) if is_j1939(message, database.db) else ()
            types = self._type_names.get(name)
            if types is None:
                types = self._type_names[name] = type_names(database.db.messages)
            schema = self._schemas[key] = MessageSchema(message, name, self._pool, addresses,
                                                        types[message.name], short=short)
        return schema

    def _decoders_of(self, message: DbcMessage
                     ) -> tuple[Callable[[bytes], Any], DecodeColumn | None]:
        made = self._decoders.get(id(message))
        if made is None:
            made = self._decoders[id(message)] = compile_decoders(message) or (partial(
                message.decode, decode_choices=False, allow_truncated=True), None)
        return made

    def _decoder(self, message: DbcMessage) -> Callable[[bytes], Any]:
        return self._decoders_of(message)[0]

    def _column_decoder(self, message: DbcMessage) -> DecodeColumn | None:
        return self._decoders_of(message)[1]

    def _codec(self, bus: str, f: DatabaseFile, message: DbcMessage, j1939_id: int | None,
               derived: bool = False) -> MessageCodec:
        return MessageCodec(message, f, partial(self._schema, f, message), bus,
                            partial(self._decoder, message), partial(self._column_decoder, message),
                            j1939_id=j1939_id, derived=derived)

    def _table(self, bus: str) -> dict[int, MessageCodec]:
        table: dict[int, MessageCodec] = {}
        pgns: dict[int, tuple[DatabaseFile, DbcMessage]] = {}
        for f in self._files_for(bus if bus in self._databases else None):
            self._database_name(f)
            for message in f.db.messages:
                key = frame_key(message.frame_id, message.is_extended_frame)
                j1939 = is_j1939(message, f.db)
                if j1939:
                    pgns.setdefault(pgn_key(message.frame_id), (f, message))
                if key not in table:
                    codec = table[key] = self._codec(bus, f, message,
                                                     message.frame_id if j1939 else None)
                    what = own_topic(bus, message.name)
                    if what is not None and message.name not in BUS_LEAVES:
                        self._moved.append(
                            f"{f.path}: message {message.name} (0x{message.frame_id:X}) would "
                            f"take {what} topic on bus {bus}: its signals go to {codec.topic}")
        self._segments.setdefault(bus_segment(bus), []).append(bus)
        if pgns:
            self._pgns[bus] = pgns
        self._tables[bus] = table
        return table

    def _match(self, bus: str, key: int) -> MessageCodec | None:
        """The codec of frame ``key`` on ``bus`` (whose table is made) that is no id of its
        databases: a J1939 message's by the frame's PGN (made for that id), else None."""
        pgns = self._pgns.get(bus)
        if pgns is None or not key & EXTENDED_KEY:
            return None
        ident = key & ~EXTENDED_KEY
        found = pgns.get(pgn_key(ident))
        if found is None:
            return None
        codec = self._tables[bus][key] = self._codec(bus, *found, ident, derived=True)
        return codec

    def decode(self, frame: Frame) -> Decoded | None:
        """Decode one frame, or count why it cannot be decoded (its :class:`Outcome`, which
        :meth:`outcome` then tells) and return None."""
        bus = frame.bus
        table = self._tables.get(bus)
        if table is None:
            table = self._table(bus)
        self.stats.frames[bus] += 1
        # frame_key inlined (the per-frame path)
        codec = table.get(frame.arbitration_id | EXTENDED_KEY if frame.is_extended
                          else frame.arbitration_id)
        if codec is None and frame.is_extended and bus in self._pgns:
            codec = self._match(bus, frame.arbitration_id | EXTENDED_KEY)
        if codec is not None and not (frame.is_error or frame.is_remote):
            try:
                return codec.decode(frame.data)
            except Exception as exc:  # cantools: DecodeError, ValueError, KeyError for a bad mux
                key = (bus, frame.arbitration_id)
                self.stats.errors[key] += 1
                self.stats.last_error[key] = f"{codec.message.name}: {type(exc).__name__}: {exc}"
                self.undecoded, self.why = frame, _DECODE_ERROR
                return None
        if frame.is_error:
            self.stats.error_frames[bus] += 1
            why = _ERROR_FRAME
        elif frame.is_remote:
            self.stats.remote_frames[bus] += 1
            why = _REMOTE
        else:
            self.stats.unknown[(bus, frame.arbitration_id)] += 1
            why = _UNKNOWN_ID
        self.undecoded, self.why = frame, why
        return None

    def decode_column(self, bus: str, key: int, datas: Sequence[bytes],
                      flags: bytes | None = None) -> list[Decoded | None]:
        """Decode a column of frames of one ``bus`` and frame ``key``
        (:func:`~bridge.frame.frame_key`) in one step: their payloads ``datas`` and, one byte
        per frame, their ``flags`` as a :class:`~bridge.block.FrameBlock` has them (None: none
        set, and the key alone tells whether an id is extended). What :meth:`decode` on each of
        those frames, in order, returns, and the same statistics (:attr:`stats`, every codec's
        counts) afterwards. Unlike :meth:`decode`, it leaves :attr:`undecoded` and :attr:`why`
        as they were: there is no frame to name (:meth:`outcome` sorts frames fed by hand)."""
        results, errors = self._column(bus, key, datas, flags, flags is None)
        for stats_key, (_, text) in errors.items():
            self.stats.last_error[stats_key] = text
        return results

    def decode_block(self, block: FrameBlock) -> list[Decoded | None]:
        """Decode every frame of ``block``, a column per ``(bus, key)``
        (:meth:`decode_column`): one entry per row, in row order, what :meth:`decode` of the
        row's frame returns, with the same statistics afterwards as decoding the frames one by
        one in order. Like :meth:`decode_column`, it leaves :attr:`undecoded` and :attr:`why`."""
        n = len(block)
        out: list[Decoded | None] = [None] * n
        if not n:
            return out
        payloads = block.payloads()
        # (an FD or BRS bit alone changes nothing in decoding)
        flags = block.flags if block.all_flags() & (ERROR | REMOTE | EXTENDED) else None
        buses = block.buses
        last: dict[tuple[str, int], tuple[int, str]] = {}
        for (bus_index, key), rows in block.groups().items():
            if len(rows) == n:
                datas, these = payloads, flags
            else:
                datas = list(map(payloads.__getitem__, rows))
                these = None if flags is None else bytes(map(flags.__getitem__, rows))
            results, errors = self._column(buses[bus_index], key, datas, these, False)
            if len(rows) == n:
                out = results
            else:
                deque(map(out.__setitem__, rows, results), 0)  # out[rows] = results, in C
            for stats_key, (at, text) in errors.items():
                row = rows[at]
                if stats_key not in last or last[stats_key][0] < row:
                    last[stats_key] = (row, text)
        for stats_key, (_, text) in last.items():
            self.stats.last_error[stats_key] = text
        return out

    def _column(self, bus: str, key: int, datas: Sequence[bytes], flags: bytes | None,
                keyed: bool) -> tuple[list[Decoded | None],
                                      dict[tuple[str, int], tuple[int, str]]]:
        """:meth:`decode_column`'s results, and per ``(bus, id)`` of a decode error the
        position of the last one in the column and its text (for the caller to store).
        ``flags`` None: no flag set, and the key tells whether the id is extended if ``keyed``,
        else it is not."""
        table = self._tables.get(bus)
        if table is None:
            table = self._table(bus)
        n = len(datas)
        stats = self.stats
        stats.frames[bus] += n
        codec = table.get(key)
        if codec is None and bus in self._pgns:
            codec = self._match(bus, key)
        errors: dict[tuple[str, int], tuple[int, str]] = {}
        every = 0
        if flags is not None:
            for f in set(flags):
                every |= f
        if not every & (ERROR | REMOTE) and (
                not every & EXTENDED or flags is None or _EXTENDED_ONLY[0] not in
                flags.translate(_EXTENDED_ONLY)):
            # No error or remote frame, and all extended or none: one id (without flags, the
            # key alone tells whether it is extended)
            ident = key & ~EXTENDED_KEY if (keyed and flags is None) or every & EXTENDED else key
            if codec is None:
                stats.unknown[(bus, ident)] += n
                return [None] * n, errors
            return self._decode_codec(codec, bus, datas, None, ident, errors), errors
        # Row by row what decode() sorts by the flags; the rest decoded in one step.
        rows: list[int] = []
        results: list[Decoded | None] = [None] * n
        assert flags is not None
        for i, f in enumerate(flags):
            ident = key ^ EXTENDED_KEY if f & EXTENDED else key
            if codec is not None and not f & (ERROR | REMOTE):
                rows.append(i)
            elif f & ERROR:
                stats.error_frames[bus] += 1
            elif f & REMOTE:
                stats.remote_frames[bus] += 1
            else:
                stats.unknown[(bus, ident)] += 1
        if rows and codec is not None:
            ids = [key ^ EXTENDED_KEY if flags[i] & EXTENDED else key for i in rows]
            decoded = self._decode_codec(codec, bus, list(map(datas.__getitem__, rows)), ids,
                                         0, errors)
            for i, result in zip(rows, decoded, strict=True):
                results[i] = result
            # positions of errors are within ``rows``: make them the column's
            for stats_key, (at, text) in list(errors.items()):
                errors[stats_key] = (rows[at], text)
        return results, errors

    def _decode_codec(self, codec: MessageCodec, bus: str, datas: Sequence[bytes],
                      ids: list[int] | None, ident: int,
                      errors: dict[tuple[str, int], tuple[int, str]]) -> list[Decoded | None]:
        """``datas`` decoded by ``codec``; a decode error counted per ``(bus, id)`` (``ids``
        per row, else ``ident`` for all) and its last position and text put in ``errors``."""
        results, failed = codec._decode_many(datas)
        if not failed:
            return results  # type: ignore[return-value]  # no exception in it
        out: list[Decoded | None] = []
        stats = self.stats
        for at, result in enumerate(results):
            if type(result) is Decoded:
                out.append(result)
                continue
            stats_key = (bus, ident if ids is None else ids[at])
            stats.errors[stats_key] += 1
            errors[stats_key] = (at, f"{codec.message.name}: {type(result).__name__}: {result}")
            out.append(None)
        return out

    def knows(self, bus: str, key: int) -> bool:
        """Whether a database of ``bus`` defines the message of frame key ``key``
        (:func:`~bridge.frame.frame_key`): its id, or a J1939 message its PGN. What the decoder,
        the health counts and bring-up call a known id."""
        return self.message_of(bus, key) is not None

    def message_of(self, bus: str, key: int) -> DbcMessage | None:
        """The database message that frames of ``key`` on ``bus`` decode as, or None."""
        table = self._tables.get(bus)
        if table is None:
            table = self._table(bus)
        codec = table.get(key)
        if codec is None:
            codec = self._match(bus, key)
        return None if codec is None else codec.message

    def outcome(self, frame: Frame, decoded: Decoded | None) -> Outcome:
        """What :meth:`decode` made of ``frame``, given what it returned: for the latest frame
        it returned None for, the outcome it found (:attr:`undecoded`, :attr:`why`). A frame it
        did not just decode (a caller that feeds frames by hand) is sorted from its flags and
        its bus's databases, without decoding it: a frame of a message they define that was not
        decoded is a decode error."""
        if decoded is not None:
            return _DECODED
        if frame is self.undecoded:
            return self.why
        if frame.is_error:
            return _ERROR_FRAME
        if frame.is_remote:
            return _REMOTE
        table = self._tables.get(frame.bus)
        if table is None:
            table = self._table(frame.bus)
        # frame_key inlined (the health monitor's per-frame path, for frames fed by hand)
        key = frame.arbitration_id | EXTENDED_KEY if frame.is_extended else frame.arbitration_id
        return (_DECODE_ERROR if key in table or self._match(frame.bus, key) is not None
                else _UNKNOWN_ID)
