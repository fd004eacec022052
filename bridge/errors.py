"""The bridge's error hierarchy.

Every error a user can cause is a :class:`BridgeError` whose message is one line naming the bad
value and where it came from (file, line or record, message, signal). The CLI prints it as
``error: <message>`` and exits non-zero; ``--debug`` shows the traceback.
"""

from __future__ import annotations

from pathlib import Path


class BridgeError(Exception):
    """Base class of every error the bridge reports to its user."""


class InputError(BridgeError):
    """A CAN log that is missing, of an unknown format, or unreadable at some place."""

    def __init__(self, path: Path | str, reason: str, *, where: str | None = None) -> None:
        self.path = str(path)
        self.reason = reason
        self.where = where
        place = f"{self.path}:{where}" if where else self.path
        super().__init__(f"{place}: {reason}")


class DatabaseError(BridgeError):
    """A DBC (or KCD/SYM/ARXML) file that cannot be loaded or that conflicts with another."""

    def __init__(self, path: Path | str, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class OutputError(BridgeError):
    """An output file that exists already or cannot be written."""

    def __init__(self, path: Path | str, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class UsageError(BridgeError):
    """A command-line argument or setting that does not make sense."""
