"""Parsed databases kept on disk, so that a database file is parsed once, not by every command.

:func:`cached` gives what :func:`store` kept for a database file's bytes (cantools' parsed
``Database`` and tankviz's notes of it), or None. An entry is found by the file's content (its
SHA-256), its suffix (which picks cantools' parser) and the versions of cantools, Python and this
format, in ``$XDG_CACHE_HOME/tankviz/databases`` (``~/.cache/tankviz/databases`` without it). The
cache never fails a command: an entry that cannot be read, is damaged or belongs to other
versions is a miss (the file is parsed, the entry replaced), and one that cannot be written (a
read-only or full disk) is not kept.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import pickle
import sys
import tempfile
from pathlib import Path

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
    digest = hashlib.sha256(f"{FORMAT}|{cantools.__version__}|{sys.version_info[:2]}|"
                            f"{suffix.lower()}|".encode())
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
    folder = cache_dir()
    temporary: str | None = None
    try:
        data = pickle.dumps((key, db, notes), pickle.HIGHEST_PROTOCOL)
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        handle, temporary = tempfile.mkstemp(dir=folder, prefix=f".{key[:16]}-",
                                             suffix=".partial")
        with os.fdopen(handle, "wb") as out:
            out.write(data)
        os.replace(temporary, folder / f"{key}.pickle")
        temporary = None
    except Exception:  # a read-only or full disk, a database pickle refuses: parse next time
        pass
    finally:
        if temporary is not None:
            with contextlib.suppress(OSError):
                os.unlink(temporary)


def forget(content: bytes, suffix: str) -> None:
    """Remove the entry of ``content``, if there is one (for tests and tools)."""
    with contextlib.suppress(OSError):
        (cache_dir() / f"{entry_key(content, suffix)}.pickle").unlink()

