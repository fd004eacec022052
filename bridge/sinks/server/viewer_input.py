"""What the server takes from a viewer: ``subscribe``, ``unsubscribe`` and, on a server that takes
marks (``tankviz live``: capability ``clientPublish``), marks published on ``/marks``.

A mark is a JSON object (encoding ``json``, any schema name) with an optional ``"text"``
(:data:`UNNAMED` when empty or missing; at most :data:`TEXT_CHARS` characters) and an optional
``"category"`` (at most :data:`CATEGORY_CHARS`); ``timestamp``, ``number``, ``source`` and ``by``
are the server's to set and are ignored; any other field, a control character or a message over
:data:`MARK_BYTES` is refused. A viewer's marks are taken :data:`MARKS_AT_ONCE` at once, then
:data:`MARKS_PER_S` a second. Anything else is refused with a one-line :class:`ViewerInputError`
before foxglove-websocket sees it; :class:`ViewerInput` limits what is told (statuses
:data:`STATUSES_AT_ONCE` at once then :data:`STATUSES_PER_S` a second; too many marks once per run
of them; console lines :data:`REFUSALS_LOGGED`). A channel of another topic is taken in silence
when advertised; its first message is refused, the next ones ignored.
"""

from __future__ import annotations

import json
import struct
import unicodedata
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bridge.errors import ViewerInputError
from bridge.pb.marks_pb2 import Mark
from bridge.topics import MARKS_TOPIC

#: The ops a viewer may send; a server that takes marks takes PUBLISH_OPS too.
CLIENT_OPS = ("subscribe", "unsubscribe")
PUBLISH_OPS = ("advertise", "unadvertise")
#: The one encoding marks are published in (serverInfo's ``supportedEncodings``).
MARK_ENCODING = "json"
#: A mark's message at most (bytes); its text and its category at most (characters).
MARK_BYTES = 4096
TEXT_CHARS = 200
CATEGORY_CHARS = 40
#: A mark's text when none is given.
UNNAMED = "mark"
#: One viewer's marks: this many at once, then this many a second.
MARKS_AT_ONCE = 5
MARKS_PER_S = 1.0
#: Channels one viewer may have advertised (taken or refused) at a time.
CHANNELS_PER_VIEWER = 16
#: Status messages for one viewer's refusals: this many at once, then this many a second.
STATUSES_AT_ONCE = 20
STATUSES_PER_S = 1.0
#: Console lines for one viewer's refused messages (too many marks: one line).
REFUSALS_LOGGED = 20
#: The fields of a mark a viewer may send that the server sets itself (ignored).
SET_BY_SERVER = frozenset(f.name for f in Mark.DESCRIPTOR.fields) - {"text", "category"}

_CLIENT_MESSAGE = struct.Struct("<BI")  # opcode 1 (message data), the client's channel id


class TooManyMarks(ViewerInputError):
    """A mark beyond the viewer's :data:`MARKS_AT_ONCE` / :data:`MARKS_PER_S`."""


@dataclass(frozen=True)
class ViewerMark:
    """A mark a viewer asked for: its text, its category ("" for none) and the viewer."""

    text: str
    category: str
    by: str


def client_message(raw: str | bytes, *, marks: bool = False) -> dict[str, Any]:
    """A viewer's text message as a JSON object the server takes (with ``marks``, an
    ``advertise`` or ``unadvertise`` too), or :class:`ViewerInputError` saying in one line why
    not (nothing of the message but a short op name is repeated)."""
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
    ops = CLIENT_OPS + PUBLISH_OPS if marks else CLIENT_OPS
    if op not in ops:
        raise ViewerInputError(f"op {_shown(op)} is not taken here (only "
                               f"{', '.join(ops[:-1])} and {ops[-1]})")
    if op == "subscribe":
        subscriptions = message.get("subscriptions")
        if not (isinstance(subscriptions, list) and all(
                isinstance(sub, dict) and _is_int(sub.get("id"))
                and _is_int(sub.get("channelId")) for sub in subscriptions)):
            raise ViewerInputError('"subscriptions" must be a list of '
                                   '{"id": integer, "channelId": integer}', op=op)
    elif op == "advertise":
        channels = message.get("channels")
        if not (isinstance(channels, list) and all(
                isinstance(c, dict) and _is_int(c.get("id")) and isinstance(c.get("topic"), str)
                and isinstance(c.get("encoding"), str) for c in channels)):
            raise ViewerInputError('"channels" must be a list of {"id": integer, '
                                   '"topic": string, "encoding": string, "schemaName": string}',
                                   op=op)
    else:
        key = "subscriptionIds" if op == "unsubscribe" else "channelIds"
        ids = message.get(key)
        if not (isinstance(ids, list) and all(map(_is_int, ids))):
            raise ViewerInputError(f'"{key}" must be a list of integers', op=op)
    return message


def mark_content(payload: bytes) -> tuple[str, str]:
    """A published mark's text and category, or :class:`ViewerInputError` saying why not."""
    if len(payload) > MARK_BYTES:
        raise ViewerInputError(f"a mark of {len(payload):,} bytes: at most {MARK_BYTES:,}")
    try:
        content = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ViewerInputError(f"a mark that is not JSON in UTF-8 ({exc})") from None
    if not isinstance(content, dict):
        raise ViewerInputError(f"a mark is a JSON object ({{\"text\": …, \"category\": …}}), "
                               f"not a {type(content).__name__}")
    unknown = sorted(set(content) - SET_BY_SERVER - {"text", "category"})
    if unknown:
        raise ViewerInputError(f"a mark takes \"text\" and \"category\", not "
                               f"{', '.join(_shown(k) for k in unknown[:3])}")
    text = _words(content.get("text", ""), "text", TEXT_CHARS) or UNNAMED
    return text, _words(content.get("category", ""), "category", CATEGORY_CHARS)


def _words(value: object, name: str, limit: int) -> str:
    if not isinstance(value, str):
        raise ViewerInputError(f"a mark's {name} is a string, not {type(value).__name__}")
    value = value.strip()
    if len(value) > limit:
        raise ViewerInputError(f"a mark's {name} of {len(value):,} characters: at most {limit}")
    bad = next((c for c in value if unicodedata.category(c) in ("Cc", "Zl", "Zp")), None)
    if bad is not None:
        raise ViewerInputError(f"a mark's {name} holds a control character (U+{ord(bad):04X})")
    return value


@dataclass
class Budget:
    """A token bucket: ``at_once`` at first, refilled ``per_s`` a second (``now``: seconds)."""

    at_once: int
    per_s: float
    tokens: float = field(init=False)
    at: float | None = None

    def __post_init__(self) -> None:
        self.tokens = float(self.at_once)

    def take(self, now: float) -> bool:
        if self.at is not None:
            self.tokens = min(float(self.at_once), self.tokens + (now - self.at) * self.per_s)
        self.at = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


@dataclass
class ViewerInput:
    """What one viewer (``name``: its address) sent that the server keeps: its channels (taken:
    True, refused: False), its budgets of marks and statuses, its refusals. ``clock`` is
    ``time.monotonic`` in the server."""

    name: str
    marks: bool
    clock: Callable[[], float]
    #: its channels: True (marks), or why its messages are refused (a text, until the first
    #: message is refused with it: then None)
    channels: dict[int, bool | str | None] = field(default_factory=dict)
    mark_budget: Budget = field(default_factory=lambda: Budget(MARKS_AT_ONCE, MARKS_PER_S))
    status_budget: Budget = field(default_factory=lambda: Budget(STATUSES_AT_ONCE,
                                                                 STATUSES_PER_S))
    refusals: int = 0
    #: marks refused as too many, and whether the latest mark was one (told once per run)
    too_many: int = 0
    in_too_many: bool = False
    #: messages on refused channels (the first of each told, the others ignored without a word)
    ignored: int = 0

    def text(self, raw: str) -> dict[str, Any] | None:
        """A text message: the subscribe or unsubscribe for foxglove-websocket, or None once
        an advertise or unadvertise is handled here; :class:`ViewerInputError` if refused."""
        message = client_message(raw, marks=self.marks)
        if message["op"] == "advertise":
            self._advertise(message["channels"])
        elif message["op"] == "unadvertise":
            self._unadvertise(message["channelIds"])
        else:
            return message
        return None

    def binary(self, raw: bytes) -> ViewerMark | None:
        """A binary message: the mark to take, or None when it is ignored (on a refused
        channel); :class:`ViewerInputError` if refused."""
        if not self.marks:
            client_message(raw)  # (raises: this server takes no binary message)
        if len(raw) < _CLIENT_MESSAGE.size:
            raise ViewerInputError(f"a binary message of {len(raw)} bytes: a message on a "
                                   "channel has an opcode and a channel id (5 bytes) first")
        opcode, channel = _CLIENT_MESSAGE.unpack_from(raw)
        if opcode != 1:
            raise ViewerInputError(f"binary opcode {opcode}: only 1 (a message on an "
                                   "advertised channel) is taken here (no services)")
        if channel not in self.channels:
            raise ViewerInputError(f"a message on channel {channel}, which it did not advertise")
        taken = self.channels[channel]
        if taken is not True:
            self.ignored += 1
            if taken is None:
                return None
            self.channels[channel] = None  # told once
            raise ViewerInputError(str(taken))
        size = len(raw) - _CLIENT_MESSAGE.size
        if size > MARK_BYTES:  # (before any other work)
            raise ViewerInputError(f"a mark of {size:,} bytes: at most {MARK_BYTES:,}")
        if not self.mark_budget.take(self.clock()):
            self.too_many += 1
            raise TooManyMarks(f"too many marks: {MARKS_AT_ONCE} at once, then "
                               f"{MARKS_PER_S:g} a second; this one and the next are refused "
                               "until one is taken")
        text, category = mark_content(raw[_CLIENT_MESSAGE.size:])
        self.in_too_many = False
        return ViewerMark(text, category, self.name)

    def refused(self, problem: ViewerInputError) -> tuple[bool, bool]:
        """A refusal: whether to tell the viewer (a status) and the console (a line)."""
        if isinstance(problem, TooManyMarks):
            told, self.in_too_many = not self.in_too_many, True
            return told and self.status_budget.take(self.clock()), self.too_many == 1
        self.refusals += 1
        return self.status_budget.take(self.clock()), self.refusals <= REFUSALS_LOGGED

    def _advertise(self, channels: list[dict[str, Any]]) -> None:
        problems = []
        for channel in channels:
            channel_id, topic, encoding = channel["id"], channel["topic"], channel["encoding"]
            if channel_id in self.channels:
                problems.append(f"channel {channel_id} is advertised already")
            elif len(self.channels) >= CHANNELS_PER_VIEWER:
                problems.append(f"channel {channel_id}: at most {CHANNELS_PER_VIEWER} channels "
                                "at a time")
            elif topic != MARKS_TOPIC:  # (Studio's 3D panel advertises its click topics)
                self.channels[channel_id] = (f"{_shown(topic)}: only {MARKS_TOPIC} is taken "
                                             "here (marks); this channel's messages are ignored")
            elif encoding != MARK_ENCODING:
                self.channels[channel_id] = (f"{MARKS_TOPIC} in {_shown(encoding)}: marks are "
                                             f"{MARK_ENCODING!r}; this channel's messages are "
                                             "ignored")
            else:
                self.channels[channel_id] = True
        if problems:
            raise ViewerInputError("; ".join(problems), op="advertise")

    def _unadvertise(self, ids: list[int]) -> None:
        unknown = [i for i in ids if self.channels.pop(i, None) is None]
        if unknown:
            raise ViewerInputError(f"channel {unknown[0]} was not advertised", op="unadvertise")


def _shown(text: str) -> str:
    """A viewer's word, shown safely: quoted, ASCII, at most 40 characters."""
    return json.dumps(text[:40] + ("…" if len(text) > 40 else ""), ensure_ascii=True)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
