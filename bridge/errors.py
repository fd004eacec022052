"""The bridge's error hierarchy.

Every error a user can cause is a :class:`BridgeError` whose message is one line naming the bad
value and where it came from (file, line or record, message, signal). The CLI prints it as
``error: <message>`` and exits non-zero; ``--debug`` shows the traceback.

The whole tree; five classes live here, the others next to the code that raises them (each is
still a :class:`BridgeError`, so the CLI reports it the same way)::

    Exception
    └── BridgeError                  bridge.errors
        ├── InputError               bridge.errors
        ├── DatabaseError            bridge.errors
        ├── OutputError              bridge.errors
        ├── UsageError               bridge.errors
        ├── ProfileError             bridge.profile.model
        ├── ExpressionError          bridge.profile.expr
        ├── LayoutError              bridge.apps.layouts
        ├── ServerError              bridge.sinks.server.live
        └── ViewerInputError         bridge.sinks.server.viewer_input

What each means:

- :class:`BridgeError`: the base of every error the bridge reports to its user.
- :class:`InputError`: a CAN log that is missing, of an unknown format, or unreadable at some
  place (``path:where: reason``).
- :class:`DatabaseError`: a DBC (or KCD/SYM/ARXML) file that cannot be loaded or that conflicts
  with another (``path: reason``).
- :class:`OutputError`: an output file that exists already or cannot be written
  (``path: reason``).
- :class:`UsageError`: a command-line argument or setting that does not make sense.
- :class:`~bridge.profile.model.ProfileError`: a profile that cannot be used
  (``path: key: reason``).
- :class:`~bridge.profile.expr.ExpressionError`: a rule (an expression of a profile) that does
  not parse: the rule, the column (1-based) and what was expected. The profile loader reports
  it as a :class:`~bridge.profile.model.ProfileError` naming the file and key.
- :class:`~bridge.apps.layouts.LayoutError`: a layout file that cannot be read or is not in
  Foxglove's layout format (``path: reason``).
- :class:`~bridge.sinks.server.ServerError`: the live server could not start (e.g. the port is
  taken).
- :class:`~bridge.sinks.server.ViewerInputError`: a message from a viewer that the server does
  not take. It never reaches the CLI: the viewer gets the protocol's ``status`` message and the
  console one warning line (:mod:`bridge.sinks.server.internals`).

Not in the tree, as they never reach the user as errors: ``bridge.apps.options.Stopped`` (a
``BaseException``, like ``KeyboardInterrupt``: a signal that ends a run),
``bridge.io.buses.BadTimestamp`` (a ``ValueError``: a frame stamped with something that is not a
time; the frame is stamped anew, and counted), and the private ``_Unread`` (bridge.profile.loader,
caught there) and ``_Unreadable`` (bridge.apps.recover_records, caught by the recover app).
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
