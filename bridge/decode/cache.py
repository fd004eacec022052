"""Parsed databases kept on disk, so that a database file is parsed once, not by every command.

:func:`cached` gives what :func:`store` kept for a database file's bytes (cantools' parsed
``Database`` and tankviz's notes of it), or None; a :class:`CodeCache` keeps the compiled code
of the functions generated for its messages (decoders, encoders), written when the process
exits. An entry is found by the file's content (its SHA-256), its suffix (which picks cantools'
parser) and the versions of cantools, Python's bytecode and this format, in
``$XDG_CACHE_HOME/tankviz/databases`` (``~/.cache/tankviz/databases`` without it). The cache
never fails a command: an entry that cannot be read, is damaged or belongs to other versions is
a miss (the file is parsed, the code compiled, the entry replaced), and one that cannot be
written (a read-only or full disk) is not kept.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import importlib.util
import marshal
import os
import pickle
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import CodeType

import cantools
from cantools.database.can.database import Database

#: What an entry holds; a change of it (or of what tankviz notes of a database) bumps it.
FORMAT = 1


def cache_dir() -> Path:
    """The folder of the entries: ``$XDG_CACHE_HOME/tankviz/databases`` (an absolute
    ``XDG_CACHE_HOME``; else ``~/.cache``)."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    root = Path(base) if os.path.isabs(base) else Path.home() / ".cache"
    return root / "tankviz" / "databases"


def entry_key(content: bytes, suffix: str) -> str:
    """The name of the entry of a database file's ``content`` whose name ends in ``suffix``."""
    digest = hashlib.sha256(f"{FORMAT}|{cantools.__version__}|"
                            f"{importlib.util.MAGIC_NUMBER.hex()}|{suffix.lower()}|".encode())
    digest.update(content)
    return digest.hexdigest()


def cached(content: bytes, suffix: str) -> tuple[Database, tuple[str, ...]] | None:
    """The database and notes kept for ``content`` (see :func:`store`), or None."""
    key = entry_key(content, suffix)
    try:
        data = (cache_dir() / f"{key}.pickle").read_bytes()
        entry = pickle.loads(data)
    except Exception:  # missing, unreadable, damaged, of another version: parse instead
        return None
    if (not isinstance(entry, tuple) or len(entry) != 3 or entry[0] != key
            or not isinstance(entry[1], Database) or not isinstance(entry[2], tuple)):
        return None
    return entry[1], entry[2]


def store(content: bytes, suffix: str, db: Database, notes: tuple[str, ...]) -> None:
    """Keep ``db`` and ``notes`` for ``content``, in one step (a reader never sees half an
    entry); nothing is kept where that fails."""
    key = entry_key(content, suffix)
    _write(f"{key}.pickle", lambda: pickle.dumps((key, db, notes), pickle.HIGHEST_PROTOCOL))


def _write(name: str, data: Callable[[], bytes]) -> None:
    """Write ``data()`` as the file ``name`` of the cache in one step, or nothing."""
    folder = cache_dir()
    temporary: str | None = None
    try:
        made = data()
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        handle, temporary = tempfile.mkstemp(dir=folder, prefix=f".{name[:16]}-",
                                             suffix=".partial")
        with os.fdopen(handle, "wb") as out:
            out.write(made)
        os.replace(temporary, folder / name)
        temporary = None
    except Exception:  # a read-only or full disk, what pickle refuses: made again next time
        pass
    finally:
        if temporary is not None:
            with contextlib.suppress(OSError):
                os.unlink(temporary)


#: Generated source to its code object, as ``exec`` would compile it.
Compile = Callable[[str], CodeType]


def compile_source(source: str) -> CodeType:
    """``source`` compiled, as ``exec(source, ...)`` compiles it (no cache)."""
    return compile(source, "<string>", "exec")


class CodeCache:
    """The compiled code of the functions generated for one database's messages, by their
    source: read from the cache on first use, the new ones written when the process exits
    (:meth:`save`). ``key``: the database's entry (:func:`entry_key`); None keeps nothing."""

    def __init__(self, key: str | None = None) -> None:
        self.key = key
        self._codes: dict[str, CodeType] | None = None
        self._new = False

    def _name(self) -> str:
        return f"{self.key}.code"

    def _read(self) -> dict[str, CodeType]:
        if self.key is None:
            return {}
        try:
            codes = marshal.loads((cache_dir() / self._name()).read_bytes())
        except Exception:  # missing, unreadable, damaged: compiled again
            return {}
        if not isinstance(codes, dict) or not all(
                isinstance(k, str) and isinstance(v, CodeType) for k, v in codes.items()):
            return {}
        return codes

    def compile(self, source: str) -> CodeType:
        """:func:`compile_source` of ``source``, compiled once for every run."""
        codes = self._codes
        if codes is None:
            codes = self._codes = self._read()
        code = codes.get(source)
        if code is None:
            code = codes[source] = compile_source(source)
            if not self._new and self.key is not None:
                self._new = True
                _unsaved.append(self)
        return code

    def save(self) -> None:
        """Write the code compiled here, with what another process wrote meanwhile."""
        if not self._new or self._codes is None:
            return
        self._new = False
        codes = {**self._read(), **self._codes}
        _write(self._name(), lambda: marshal.dumps(codes))


_unsaved: list[CodeCache] = []


@atexit.register
def _save_all() -> None:
    while _unsaved:
        _unsaved.pop().save()


def forget(content: bytes, suffix: str) -> None:
    """Remove the entry of ``content``, if there is one (for tests and tools)."""
    with contextlib.suppress(OSError):
        (cache_dir() / f"{entry_key(content, suffix)}.pickle").unlink()

