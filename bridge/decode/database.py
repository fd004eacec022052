"""Signal databases loaded, checked and named: what a drive records of each, and what in one
would silence, move or round a message's signals, said once at load as a warning.

A database is loaded with cantools (DBC, KCD, SYM, ARXML); cantools' own log lines while it loads
become warnings of the file (none reaches the terminal by itself). One file that gives an id two
different messages is an error naming both, their lines and the id. A database parsed once is
taken from the cache next time (:mod:`bridge.decode.cache`): the same database, the same warnings.
"""

from __future__ import annotations

import codecs
import hashlib
import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cantools
from cantools.database.can.database import Database
from cantools.database.can.message import Message as DbcMessage
from cantools.database.errors import Error as CantoolsError

from bridge.decode.cache import CodeCache, cached, entry_key, store
from bridge.decode.proto_schema import rounded_range
from bridge.errors import DatabaseError, UsageError
from bridge.frame import frame_key
from bridge.topics import BUS_LEAVES, MOVED_SEGMENT

_BUS_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]*$")
#: a DBC message's line: ``BO_ <id> <name>:``
_DBC_MESSAGE = re.compile(rb"^[ \t]*BO_[ \t]+\d+[ \t]+([^\s:]+)[ \t]*:", re.MULTILINE)


@dataclass(frozen=True)
class DatabaseFile:
    """A loaded signal database and what identifies it in a drive archive."""

    path: Path
    name: str
    sha256: str
    content: bytes
    db: Database = field(repr=False, compare=False)
    #: what in it silences, moves or rounds a message (:func:`database_warnings`), one line each
    warnings: tuple[str, ...] = field(default=(), compare=False)
    #: the compiled code of its messages' generated functions (kept with the parsed database)
    code: CodeCache = field(default_factory=CodeCache, repr=False, compare=False)


def database_warnings(path: Path, db: Database) -> tuple[str, ...]:
    """A line for every message whose layout cantools' strict check refuses (overlapping
    signals, a signal that does not fit), saying when no frame of it can decode; for every
    message whose topic would be one of tankviz's own on every bus (it goes to
    ``/can/<bus>/msg/<Message>``); and for every integer signal stored as a double because its
    values fit no 64-bit integer (those beyond 2^53 are rounded)."""
    return tuple(f"{path}: {text}" for text in database_notes(db))


def database_notes(db: Database) -> tuple[str, ...]:
    """:func:`database_warnings` without the path they begin with (what the cache keeps)."""
    warnings = []
    for message in db.messages:
        try:
            message.refresh(strict=True)
            text = ""
        except CantoolsError as exc:
            text = str(exc).strip().rstrip(".")
        if text:
            message.refresh(strict=False)
            text = f"{text[:1].lower()}{text[1:]} (0x{message.frame_id:X})"
            if not message.is_multiplexed():  # a payload of zeros may name no multiplexed part
                try:
                    message.decode(bytes(message.length), decode_choices=False,
                                   allow_truncated=True)
                except Exception:  # cantools: DecodeError, bitstruct errors
                    text += "; cantools cannot decode any frame of it"
            warnings.append(text)
        what = BUS_LEAVES.get(message.name)
        if what is not None:
            moved = f"/can/<bus>/{MOVED_SEGMENT}/{message.name}"
            warnings.append(f"message {message.name} (0x{message.frame_id:X}) would take "
                            f"{what} topic /can/<bus>/{message.name}: its signals go to {moved}")
        for signal in message.signals:
            ends = rounded_range(signal)
            if ends is not None:
                warnings.append(
                    f"signal {signal.name} of message {message.name} "
                    f"(0x{message.frame_id:X}) ranges over {ends[0]}..{ends[1]}, beyond any "
                    "64-bit integer: it is stored as a double, so values beyond 2^53 are "
                    "rounded (the raw frames keep them exact)")
    return tuple(warnings)


class _Collect(logging.Handler):
    """cantools' log lines while a database loads."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(" ".join(record.getMessage().split()))


@contextmanager
def _cantools_lines() -> Iterator[list[str]]:
    """cantools' warnings while inside, collected instead of printed."""
    logger = logging.getLogger("cantools")
    handler = _Collect()
    propagate = logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        yield handler.lines
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate


def _check_ids(path: Path, content: bytes, db: Database) -> None:
    """Refuse a file that gives one id two different messages (cantools keeps the last)."""
    owner: dict[int, DbcMessage] = {}
    for message in db.messages:
        key = frame_key(message.frame_id, message.is_extended_frame)
        other = owner.setdefault(key, message)
        if other is not message and layout(other) != layout(message):
            lines = {m.group(1).decode("latin-1"): content.count(b"\n", 0, m.start()) + 1
                     for m in reversed(list(_DBC_MESSAGE.finditer(content)))}
            a, b = (f"{m.name} (line {lines[m.name]})" if m.name in lines else m.name
                    for m in (other, message))
            raise DatabaseError(path, f"messages {a} and {b} both have id 0x{message.frame_id:X}: "
                                      "a database gives an id one message; remove or renumber one")


def load_database(path: Path | str, *, name: str | None = None) -> DatabaseFile:
    """Load a DBC (or KCD, SYM, ARXML: whatever cantools loads) file, with its warnings: as
    parsed before, from the cache (:mod:`bridge.decode.cache`), where it holds the file."""
    path = Path(path)
    try:
        content = path.read_bytes()
    except FileNotFoundError:
        raise DatabaseError(path, "no such file") from None
    except OSError as exc:
        raise DatabaseError(path, f"cannot read: {exc.strerror or exc}") from None
    sha256 = hashlib.sha256(content).hexdigest()
    found = cached(content, path.suffix)
    if found is not None:
        return DatabaseFile(path, name or path.stem, sha256, content, found[0],
                            tuple(f"{path}: {text}" for text in found[1]),
                            CodeCache(entry_key(content, path.suffix)))
    # a UTF-8 byte-order mark (editors on Windows write one): read as UTF-8 without it
    encoding = "utf-8-sig" if content.startswith(codecs.BOM_UTF8) else None
    with _cantools_lines() as said:
        try:
            db = cantools.database.load_file(str(path), strict=False, encoding=encoding)
        except Exception as exc:  # cantools raises many types; its text is the useful part
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise DatabaseError(path, f"cantools cannot load it: {reason}") from None
    if not isinstance(db, Database):
        raise DatabaseError(path, "not a CAN database (cantools loaded a diagnostics database)")
    _check_ids(path, content, db)
    # cantools' "Overwriting message ..." is the id check's (an identical twin is harmless)
    told = tuple(f"{path}: cantools: {line}" for line in said
                 if not line.startswith("Overwriting message"))
    notes = database_notes(db)
    if not told:  # (what cantools says may name the file: such a database is parsed each time)
        store(content, path.suffix, db, notes)
    return DatabaseFile(path, name or path.stem, sha256, content, db,
                        tuple(f"{path}: {text}" for text in notes) + told,
                        CodeCache(entry_key(content, path.suffix)))


def parse_dbc_option(text: str) -> tuple[str | None, Path]:
    """``[BUS=]PATH`` from the command line: the bus (None for every bus) and the path."""
    bus, sep, rest = text.partition("=")
    if sep and bus and _BUS_NAME.match(bus) and not Path(text).exists():
        if not rest:
            raise UsageError("--dbc", f"no path after '{bus}='", value=text)
        return bus, Path(rest)
    return None, Path(text)


def layout(message: DbcMessage) -> tuple[Any, ...]:
    """Everything that decides how a message decodes, to tell real conflicts from duplicates."""
    return (
        message.name,
        message.length,
        tuple(
            (s.name, s.start, s.length, s.byte_order, s.is_signed, s.is_float, s.scale, s.offset,
             s.is_multiplexer, tuple(s.multiplexer_ids or ()), s.multiplexer_signal)
            for s in message.signals
        ),
    )
