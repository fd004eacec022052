"""The bridge's errors: one class per kind of failure a caller handles differently.

Every error a user can cause is a :class:`BridgeError` with a one-line message, built by its class
from fields, naming the bad value and where it came from; the CLI prints ``error: <message>`` and
exits non-zero (``--debug``: the traceback). The tree::

    Exception
    └── BridgeError                  bridge.errors (never raised itself)
        ├── FileError                bridge.errors: a file cannot be read or written as asked
        │   ├── InputError           bridge.errors: an input (the others may be read on)
        │   ├── DatabaseError        bridge.errors: a DBC (named anew when attached to a drive)
        │   └── ProfileError         bridge.profile.model: a profile (a TODO line named instead)
        ├── UsageError               bridge.errors: an argument or setting that makes no sense
        ├── MessagePathError         bridge.errors: a layout's message path (a layout problem)
        ├── ExpressionError          bridge.profile.expr: a rule (told as a ProfileError)
        ├── ServerError              bridge.errors: the live server cannot start
        ├── HelperDied               bridge.errors: a process of tankviz's ended without a word
        └── ViewerInputError         bridge.errors: a viewer's message (told to the viewer)
            └── TooManyMarks         bridge.sinks.server.viewer_input (told once per burst)

Not errors to the user, so not in it: ``bridge.apps.options.Stopped`` (a ``BaseException``, a
signal that ends a run), ``bridge.io.buses.BadTimestamp`` (the frame is stamped anew and counted)
and the private ``_Unread`` and ``_Unreadable``, caught where they are raised.
"""

from __future__ import annotations

import codecs
import errno
import os
import stat
from pathlib import Path

#: The longest name of one file (a part of a path), in bytes, on Linux's file systems...
NAME_MAX = 255
#: ... and the longest path (less one byte: C's string end).
PATH_MAX = 4096


class BridgeError(Exception):
    """Base class of every error the bridge reports to its user; only its subclasses are
    raised."""


class FileError(BridgeError):
    """A file that cannot be read or written as asked (an output that exists already, a folder
    that is not writable, a layout that is not JSON): ``path: reason``, or ``path:where: reason``
    at a place in it (a line, a record, an offset)."""

    def __init__(self, path: Path | str, reason: str, *, where: str | None = None) -> None:
        self.path = shown(path)
        self.reason = reason
        self.where = where
        place = f"{self.path}:{where}" if where else self.path
        super().__init__(f"{place}: {reason}")


class InputError(FileError):
    """An input (a CAN log, a recorded drive, a catalogue, a reference CSV) that is missing, of
    an unknown format, or unreadable at some place; a command given several may go on with the
    others."""


class DatabaseError(FileError):
    """A DBC (or KCD/SYM/ARXML) file that cannot be loaded or that conflicts with another."""


class UsageError(BridgeError):
    """A command-line argument or a setting that does not make sense: ``argument: reason``, or
    with the value given ``--option VALUE: reason`` (an option) and ``NAME=VALUE: reason`` (a
    setting: ``TANKVIZ_...``, a health setting)."""

    def __init__(self, argument: Path | str, reason: str, *, value: object = None) -> None:
        self.argument = shown(argument)
        self.reason = reason
        self.value = value
        given = self.argument
        if value is not None:
            given += f" {value}" if given.startswith("-") else f"={value}"
        super().__init__(f"{given}: {reason}")


class MessagePathError(BridgeError):
    """A Foxglove message path (of a layout's panel) that names nothing the bridge publishes:
    ``path: reason``."""

    def __init__(self, path: str, reason: str) -> None:
        self.path = path
        self.reason = reason
        super().__init__(f"{path}: {reason}")


class ServerError(BridgeError):
    """The live server could not start (e.g. the port is taken):
    ``cannot serve on host:port: reason``."""

    def __init__(self, host: str, port: int, reason: str) -> None:
        self.host = host
        self.port = port
        self.reason = reason
        super().__init__(f"cannot serve on {host}:{port}: {reason}")


class HelperDied(BridgeError):
    """A process tankviz started for part of its work ended without a word (killed, out of
    memory): ``the process <role> ended without a word (<how>); <instead>``."""

    def __init__(self, role: str, how: str, instead: str) -> None:
        self.role = role
        self.how = how
        super().__init__(f"the process {role} ended without a word ({how}); {instead}")


class ViewerInputError(BridgeError):
    """A message from a viewer that the server does not take: ``reason``, or ``op: reason`` for
    an operation of the protocol (``advertise``, ``subscribe``, ...). It never reaches the CLI:
    the viewer gets the protocol's ``status`` message and the console one warning line."""

    def __init__(self, reason: str, *, op: str | None = None) -> None:
        self.op = op
        self.reason = reason
        super().__init__(f"{op}: {reason}" if op else reason)


# --- how errors name files ----------------------------------------------------------------------

def shown(path: Path | str) -> str:
    """A path as text to print or store (msgpack, DuckDB, JSON): as it is where it is Unicode;
    the bytes of a name that is not (a latin-1 ``bad\\xe9.blf`` on a UTF-8 system, which Python
    holds as surrogates) as ``\\xNN``."""
    text = str(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        try:
            return os.fsencode(text).decode("utf-8", "backslashreplace")
        except UnicodeEncodeError:  # a surrogate no file name decoded into
            return text.encode("utf-8", "backslashreplace").decode("ascii")
    return text


def _shown_on_encode(exc: UnicodeError) -> tuple[str, int]:
    """The codec error handler :data:`SHOWN_ERRORS`: a byte of a name that is not UTF-8 (held as
    a surrogate) as ``\\xNN``, any other character the output cannot hold as Python escapes it."""
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    text = exc.object[exc.start:exc.end]
    return "".join(f"\\x{ord(c) - 0xDC00:02x}" if "\udc80" <= c <= "\udcff"
                   else c.encode("ascii", "backslashreplace").decode("ascii")
                   for c in text), exc.end


#: The errors handler of the command's output: what it prints of a name that is not UTF-8 (or
#: of any text its terminal cannot show) reads as :func:`shown` writes it, never a traceback.
SHOWN_ERRORS = "tankviz.shown"
codecs.register_error(SHOWN_ERRORS, _shown_on_encode)


def name_too_long(path: Path | str) -> str | None:
    """Why ``path`` cannot name a file: a part of it over :data:`NAME_MAX` bytes, or the whole
    over :data:`PATH_MAX`; None when neither."""
    parts = Path(path).parts
    long = [part for part in parts if len(os.fsencode(part)) > NAME_MAX]
    if long:
        whose = "its name" if long[0] == parts[-1] else f"its folder's name {shown(long[0])}"
        return (f"{whose} is {len(os.fsencode(long[0]))} bytes long: a name has at most "
                f"{NAME_MAX} bytes; name it shorter")
    if (size := len(os.fsencode(str(path)))) >= PATH_MAX:
        return f"the path is {size} bytes long: at most {PATH_MAX - 1}; name it shorter"
    return None


def os_error_text(exc: OSError) -> str:
    """An error of the system about a file as one line naming it (``path: reason``)."""
    if exc.filename is None:
        return exc.strerror or str(exc)
    name = exc.filename if isinstance(exc.filename, (str, Path)) else os.fsdecode(exc.filename)
    if exc.errno == errno.ENAMETOOLONG:
        return f"{shown(name)}: {name_too_long(name) or 'its name is too long'}"
    return f"{shown(name)}: {(exc.strerror or str(exc)).lower()}"


def not_a_file(path: Path | str) -> str | None:
    """Why ``path`` cannot be read as a file (no such file, a dangling symbolic link, a FIFO, a
    device, a folder, a name too long), or None for a regular file (or a link to one)."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            return name_too_long(path) or "its name is too long"
        if os.path.islink(path):
            return f"is a symbolic link to {shown(os.readlink(path))}, which does not exist"
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return "no such file"
        return f"cannot read: {(exc.strerror or str(exc)).lower()}"
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "is a folder, not a file"
    kind = ("a FIFO (a named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a device")
    return (f"is {kind}, not a file: tankviz reads files it can go back in (save the stream to "
            "a file first; tankviz live reads a bus as it comes)")


def check_input_path(path: Path | str) -> None:
    """Refuse, before it is opened, an input whose name is too long, or that is a FIFO, a socket
    or a device (:func:`not_a_file`): opening one waits for a writer, and its bytes cannot be
    read again. Anything else (no such file, a folder) is told by the caller as it opens it."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            raise InputError(path, name_too_long(path) or "its name is too long") from None
        return
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise InputError(path, str(not_a_file(path)))
