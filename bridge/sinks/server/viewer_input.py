"""What the server takes from a viewer: ``subscribe`` and ``unsubscribe``, nothing else.

The server advertises no capability that takes input. Anything else — text that is not JSON,
JSON that is not such a message, another op, any binary message — is refused by
:func:`client_message` with a :class:`ViewerInputError` saying in one line what was wrong,
before foxglove-websocket sees it (see :mod:`bridge.sinks.server.internals` for what the viewer
and the console are told).
"""

from __future__ import annotations

import json
from typing import Any

from bridge.errors import BridgeError

#: The ops a viewer may send (the server advertises no capability that takes more).
CLIENT_OPS = ("subscribe", "unsubscribe")


class ViewerInputError(BridgeError):
    """A message from a viewer that the server does not take (the reason, in one line)."""


def client_message(raw: str | bytes) -> dict[str, Any]:
    """A viewer's message as a JSON object the server takes, or :class:`ViewerInputError` saying
    in one line why not (nothing of the message but a short op name is repeated)."""
    if not isinstance(raw, str):
        raise ViewerInputError(f"a binary message ({len(raw)} bytes): this server takes none "
                               "(no client publishing, no services)")
    try:
        message = json.loads(raw)
    except ValueError as exc:  # json.JSONDecodeError, or a number too long to convert
        raise ViewerInputError(f"not JSON ({exc})") from None
    if not isinstance(message, dict):
        raise ViewerInputError(f"a JSON {type(message).__name__}, not an object with an \"op\"")
    op = message.get("op")
    if not isinstance(op, str):
        raise ViewerInputError("a JSON object without an \"op\" string")
    if op not in CLIENT_OPS:
        shown = json.dumps(op[:40] + ("…" if len(op) > 40 else ""), ensure_ascii=True)
        raise ViewerInputError(f"op {shown} is not taken here (only {' and '.join(CLIENT_OPS)})")
    if op == "subscribe":
        subscriptions = message.get("subscriptions")
        if not (isinstance(subscriptions, list) and all(
                isinstance(sub, dict) and _is_int(sub.get("id"))
                and _is_int(sub.get("channelId")) for sub in subscriptions)):
            raise ViewerInputError('subscribe: "subscriptions" must be a list of '
                                   '{"id": integer, "channelId": integer}')
    else:
        ids = message.get("subscriptionIds")
        if not (isinstance(ids, list) and all(map(_is_int, ids))):
            raise ViewerInputError('unsubscribe: "subscriptionIds" must be a list of integers')
    return message


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
