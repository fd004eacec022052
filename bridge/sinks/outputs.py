"""Output files: every file a command writes appears only complete, and never over one of its
inputs.

An output that is an input by any name is refused even with ``--force``, one that exists unless
``--force``; two runs never mix their bytes (with ``--force`` the last to finish wins, without it
the second fails saying so), and a killed run's partial files are removed by the next run.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import secrets
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO

try:
    import fcntl
except ImportError:  # Windows: no locks, so no partial file is ever taken for stale
    fcntl = None  # type: ignore[assignment]

from bridge.errors import NAME_MAX, FileError

#: What tells one run's partial output from another's: ``<pid>-<random>``.
_TOKEN = re.compile(r"\d+-[0-9a-f]+")
#: What ``os.link`` raises on a file system without hard links.
_NO_LINKS = {errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EMLINK,
             errno.EXDEV}


def partial_name(name: str, token: str) -> str:
    """The hidden name an output ``name`` is written under by one run (``token``: the run's); a
    name too long to take the additions is cut in it (:func:`fitted_name`)."""
    return f".{fitted_name(name, _PARTIAL_ROOM)}.{token}.partial"


#: The room a partial file's name keeps for ``.``, ``.<token>`` (25 bytes) and ``.partial``.
_PARTIAL_ROOM = 1 + 1 + 25 + len(".partial")


def fitted_name(name: str, room: int) -> str:
    """``name``, or where it leaves less than ``room`` bytes of a file's name
    (:data:`~bridge.errors.NAME_MAX`), its start with ``~`` and a hash of the whole: what the
    hidden file an output is written under holds of the output's name."""
    if len(os.fsencode(name)) + room <= NAME_MAX:
        return name
    digest = hashlib.sha256(os.fsencode(name)).hexdigest()[:12]
    left = NAME_MAX - room - 1 - len(digest)
    kept, size = [], 0
    for char in name:
        size += len(os.fsencode(char))
        if size > left:
            break
        kept.append(char)
    return f"{''.join(kept)}~{digest}"


def is_partial_of(file_name: str, name: str) -> bool:
    """Whether ``file_name`` is a partial file of the output ``name``: one run's
    (:func:`partial_name`), or the bare ``.<name>.partial`` that earlier versions wrote."""
    head, tail = f".{fitted_name(name, _PARTIAL_ROOM)}.", ".partial"
    if not (file_name.startswith(head) and file_name.endswith(tail)):
        return file_name == f".{name}.partial"
    token = file_name[len(head):len(file_name) - len(tail)]
    return file_name == f".{name}.partial" or _TOKEN.fullmatch(token) is not None


def same_file(a: Path | str, b: Path | str) -> bool:
    """Whether two paths name one file: the same path, a symbolic link to it, a hard link to it
    (the same device and inode); two paths that do not exist are compared as real paths."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def lock(fd: int, *, wait: bool) -> bool:
    """An exclusive advisory lock on an open file (held until it is closed); False where it is
    held by another run, or where the file system has no locks. A file being written holds it
    (a partial output, a part of a drive being recorded: :func:`being_written`)."""
    if fcntl is None:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except OSError:
        return False
    return True


def being_written(path: Path | str) -> bool:
    """Whether a run holds the lock of the file ``path`` while it writes it (:func:`lock`)."""
    if fcntl is None:
        return False
    try:  # (O_NONBLOCK: a FIFO does not wait for a writer)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # a file system without locks
        return False
    finally:
        os.close(fd)
    return False


def remove_stale_partials(path: Path) -> list[Path]:
    """Remove the partial outputs of ``path`` that no run is writing (left by a run that was
    killed or lost its power); returns them. A run holds a lock on its partial file while it
    writes it; a partial that cannot be locked (being written, or on a file system without
    locks) is left alone."""
    removed: list[Path] = []
    try:
        entries = list(os.scandir(path.parent if str(path.parent) else "."))
    except OSError:
        return removed
    for entry in entries:
        if not is_partial_of(entry.name, path.name):
            continue
        try:
            fd = os.open(entry.path, os.O_RDWR)  # (NFS locks a file open for writing only)
        except OSError:
            continue
        try:
            if lock(fd, wait=False) and os.stat(entry.path).st_ino == os.fstat(fd).st_ino:
                os.unlink(entry.path)
                removed.append(Path(entry.path))
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed


def _create_partial(path: Path, made: list[Path]) -> tuple[Path, IO[bytes]]:
    """A new partial file of its own for ``path``, locked (:func:`remove_stale_partials`). Its
    name is in ``made`` before the file is, so that the caller removes it whenever it is
    interrupted (a signal's handler runs between any two bytecodes)."""
    while True:
        partial = path.with_name(partial_name(path.name, f"{os.getpid()}-{secrets.token_hex(4)}"))
        made.append(partial)
        try:
            fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # (another's: not ours to remove)
            made.pop()
            continue
        try:
            locked = lock(fd, wait=True)
            # Another run's cleanup may have taken it between its creation and its lock.
            if not locked or os.stat(partial).st_ino == os.fstat(fd).st_ino:
                return partial, os.fdopen(fd, "wb")
        except FileNotFoundError:
            pass
        except BaseException:
            os.close(fd)
            partial.unlink(missing_ok=True)
            raise
        os.close(fd)


def publish(partial: Path, path: Path, *, replace: bool) -> None:
    """Give the complete file ``partial`` its name ``path``, atomically: a reader sees no file or
    the whole of one. ``replace``: an existing ``path`` is replaced (``os.replace``); else a file
    that appeared at ``path`` meanwhile (another run's) is kept and this is an
    :class:`~bridge.errors.FileError` (``os.link``, which never replaces; on a file system
    without hard links, a check just before ``os.replace``)."""
    if replace:
        os.replace(partial, path)
        return
    try:
        os.link(partial, path)
    except FileExistsError:
        raise FileError(path, APPEARED) from None
    except OSError as exc:
        if exc.errno not in _NO_LINKS:
            raise
        if os.path.lexists(path):
            raise FileError(path, APPEARED) from None
        os.replace(partial, path)
        return
    with contextlib.suppress(FileNotFoundError):
        os.unlink(partial)


#: Why a run does not publish its output (:func:`publish`).
APPEARED = ("was written by another run while this one was writing it: that file is kept "
            "(--force replaces it)")


@contextlib.contextmanager
def atomic_output(path: Path, *, force: bool | None = None) -> Iterator[IO[bytes]]:
    """An output file that appears only complete.

    Each run writes a hidden partial file of its own beside it
    (``.<name>.<pid>-<random>.partial``, locked while it is written), and gives it the output's
    name when the block succeeds (:func:`publish`); after any failure no file of it is left
    behind, and partial files of ``path`` that no run is writing any more (a killed run's) are
    removed first (:func:`remove_stale_partials`). So two runs writing one output never mix
    their bytes: with ``force`` the last to finish replaces the other's complete file; without,
    the second keeps the first's and fails. ``force`` None (the default): replace what existed
    when the block began (the caller's :func:`check_output` allowed it), nothing that appears
    later.
    """
    replace = os.path.lexists(path) if force is None else force
    remove_stale_partials(path)
    made: list[Path] = []  # the partial files this run made (one, unless a race took one)
    try:
        partial, stream = _create_partial(path, made)
        with stream:  # closed (its lock released) only once it has its name
            yield stream
            stream.flush()
            publish(partial, path, replace=replace)
    except OSError as exc:
        _remove(made)
        raise FileError(path, f"cannot write: {exc.strerror or exc}") from exc
    except BaseException:
        _remove(made)
        raise


def _remove(partials: Iterable[Path]) -> None:
    for partial in partials:
        partial.unlink(missing_ok=True)


def refuse_inputs(path: Path, inputs: Iterable[Path | str]) -> None:
    """Refuse an output that is one of ``inputs``: the same file by any name (:func:`same_file`),
    whatever ``--force`` says."""
    for source in inputs:
        if same_file(path, source):
            raise FileError(path, f"is the same file as the input {source}: tankviz never "
                            "writes over its inputs; name a new output file")


def check_output(path: Path, *, force: bool, inputs: Iterable[Path | str] = ()) -> None:
    """Refuse an output that is one of ``inputs`` (:func:`refuse_inputs`), that exists (unless
    ``force``) or that cannot be written."""
    refuse_inputs(path, inputs)
    if path.is_dir():
        raise FileError(path, "is a directory")
    if path.exists() and not force:
        raise FileError(path, "exists already; use --force to overwrite it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileError(path, f"cannot write: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise FileError(path, f"cannot write: folder {parent} is not writable")
