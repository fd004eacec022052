"""The decoder of a drive (:class:`Decoder`): frames to decoded messages by (bus, id), each bus
with its own databases, one frame at a time or a pack of frames a column at a time.

A J1939 message decodes by its PGN from any source address (:mod:`bridge.decode.j1939`: a codec
is made for each id of it seen, one topic and schema for all). Every frame has one
:data:`~bridge.decode.outcome.Outcome`; those that do not decode are counted in
:attr:`Decoder.stats`, never raised (the recorder keeps every raw frame). A pack decodes to what
its frames decode to one by one, with the same counts (tests/test_decode_packed.py). What would
silence, move or mix a message without a word is a warning (:meth:`Decoder.warnings`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from functools import partial
from typing import Any

from cantools.database.can.message import Message as DbcMessage
from google.protobuf import descriptor_pool

from bridge.decode.codec import Decoded, MessageCodec
from bridge.decode.compiled import DecodeColumn, compile_decoders
from bridge.decode.database import DatabaseFile, layout
from bridge.decode.j1939 import address_fields, is_j1939, pgn_key
from bridge.decode.outcome import DecodeStats, Outcome, Undecoded
from bridge.decode.proto_schema import MessageSchema, identifier, type_names
from bridge.errors import DatabaseError
from bridge.frame import EXTENDED_KEY, Frame, frame_key
from bridge.packed import ERROR, EXTENDED, REMOTE, PackedFrames
from bridge.topics import BUS_LEAVES, bus_segment, own_topic

# Why a frame did not decode, as module globals (the per-frame path).
_UNKNOWN_ID, _DECODE_ERROR = Undecoded.UNKNOWN_ID, Undecoded.DECODE_ERROR
_ERROR_FRAME, _REMOTE = Undecoded.ERROR_FRAME, Undecoded.REMOTE
#: bytes.translate table of pack flags: 1 where the frame is extended, else 0
_EXTENDED_ONLY = bytes(1 if f & EXTENDED else 0 for f in range(256))


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
                if key in owner and layout(owner[key][1]) != layout(message):
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
                                                        types[message.name],
                                                        database.code.compile, short=short)
        return schema

    def _decoders_of(self, database: DatabaseFile, message: DbcMessage
                     ) -> tuple[Callable[[bytes], Any], DecodeColumn | None]:
        made = self._decoders.get(id(message))
        if made is None:
            made = self._decoders[id(message)] = compile_decoders(
                message, database.code.compile) or (partial(
                    message.decode, decode_choices=False, allow_truncated=True), None)
        return made

    def _decoder(self, database: DatabaseFile, message: DbcMessage) -> Callable[[bytes], Any]:
        return self._decoders_of(database, message)[0]

    def _column_decoder(self, database: DatabaseFile, message: DbcMessage
                        ) -> DecodeColumn | None:
        return self._decoders_of(database, message)[1]

    def _codec(self, bus: str, f: DatabaseFile, message: DbcMessage, j1939_id: int | None,
               derived: bool = False) -> MessageCodec:
        return MessageCodec(message, f, partial(self._schema, f, message), bus,
                            partial(self._decoder, f, message),
                            partial(self._column_decoder, f, message),
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

    def decode(self, frame: Frame) -> Outcome:
        """Decode one frame, or count why it cannot be decoded and return that."""
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
                return _DECODE_ERROR
        if frame.is_error:
            self.stats.error_frames[bus] += 1
            return _ERROR_FRAME
        if frame.is_remote:
            self.stats.remote_frames[bus] += 1
            return _REMOTE
        self.stats.unknown[(bus, frame.arbitration_id)] += 1
        return _UNKNOWN_ID

    def decode_packed(self, pack: PackedFrames) -> list[Outcome]:
        """Decode every frame of ``pack``, a column per ``(bus, key)`` in one step: one
        outcome per row, in row order, what :meth:`decode` of the row's frame returns, with the
        same statistics afterwards as decoding the frames one by one in order."""
        n = len(pack)
        out: list[Outcome] = [_UNKNOWN_ID] * n
        if not n:
            return out
        payloads = pack.payloads()
        # (an FD or BRS bit alone changes nothing in decoding)
        flags = pack.flags if pack.all_flags() & (ERROR | REMOTE | EXTENDED) else None
        buses = pack.buses
        last: dict[tuple[str, int], tuple[int, str]] = {}
        for (bus_index, key), rows in pack.groups().items():
            whole = len(rows) == n
            if whole:
                datas, these = payloads, flags
            else:
                datas = list(map(payloads.__getitem__, rows))
                these = None if flags is None else bytes(map(flags.__getitem__, rows))
            results, errors = self._column(buses[bus_index], key, datas, these)
            if whole:
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

    def _column(self, bus: str, key: int, datas: Sequence[bytes], flags: bytes | None
                ) -> tuple[list[Outcome], dict[tuple[str, int], tuple[int, str]]]:
        """The outcomes of a column of frames of one ``bus`` and frame ``key`` (their payloads
        ``datas``, their ``flags`` as a pack has them; None: none set), and per ``(bus, id)``
        of a decode error the position of its last one and its text (for the caller to keep:
        the last of the pack)."""
        table = self._tables.get(bus)
        if table is None:
            table = self._table(bus)
        n = len(datas)
        stats = self.stats
        stats.frames[bus] += n
        codec = table.get(key)
        if codec is None and bus in self._pgns:
            codec = self._match(bus, key)
        every = 0
        if flags is not None:
            for f in set(flags):
                every |= f
        rows: list[int] | None = None  # the rows to decode (None: all)
        ids: list[int] | None = None  # their ids (None: ``ident`` for all)
        ident = key
        out: list[Outcome] = []
        mixed = (flags is not None and bool(every & EXTENDED)
                 and _EXTENDED_ONLY[0] in flags.translate(_EXTENDED_ONLY))
        if not every & (ERROR | REMOTE) and not mixed:
            # No error or remote frame, and all extended or none: one id
            ident = key & ~EXTENDED_KEY if every & EXTENDED else key
            if codec is None:
                stats.unknown[(bus, ident)] += n
                return [_UNKNOWN_ID] * n, {}
        else:
            # What decode() sorts by the flags, row by row; the rest decoded in one step. (A
            # standard id with bit 31 set, which a damaged archive has, shares its key with an
            # extended id: its flags tell them apart.)
            assert flags is not None
            out = [_UNKNOWN_ID] * n
            rows, ids = [], []
            for i, f in enumerate(flags):
                if f & ERROR:
                    stats.error_frames[bus] += 1
                    out[i] = _ERROR_FRAME
                elif f & REMOTE:
                    stats.remote_frames[bus] += 1
                    out[i] = _REMOTE
                elif codec is not None:
                    rows.append(i)
                    ids.append(key ^ EXTENDED_KEY if f & EXTENDED else key)
                else:
                    stats.unknown[(bus, key ^ EXTENDED_KEY if f & EXTENDED else key)] += 1
            if codec is None or not rows:
                return out, {}
        assert codec is not None
        results, failed = codec.decode_many(datas if rows is None
                                            else list(map(datas.__getitem__, rows)))
        errors: dict[tuple[str, int], tuple[int, str]] = {}
        if failed:
            for at, result in enumerate(results):
                if type(result) is not Decoded:
                    stats_key = (bus, ident if ids is None else ids[at])
                    stats.errors[stats_key] += 1
                    errors[stats_key] = (at if rows is None else rows[at],
                                         f"{codec.message.name}: {type(result).__name__}: {result}")
                    results[at] = _DECODE_ERROR  # type: ignore[call-overload]
        if rows is None:
            return results, errors  # type: ignore[return-value]  # (no exception left in it)
        deque(map(out.__setitem__, rows, results), 0)  # type: ignore[arg-type]
        return out, errors

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
