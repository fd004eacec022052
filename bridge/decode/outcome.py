"""What the decoder made of each frame, and of all of them.

A frame's :data:`Outcome` is its :class:`~bridge.decode.codec.Decoded` message, or why it has
none (:class:`Undecoded`: an unknown id, a decode error, an error frame, a remote frame), one
for each frame whether it came alone or in a block (the health monitor counts them as they are).
:class:`DecodeStats` counts those that did not decode, per bus or per (bus, id).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, TypeAlias

from bridge.decode.codec import Decoded, MessageCodec


class Undecoded(Enum):
    """Why a frame was not decoded (as cantools' monitor has ``MessageFormattingResult``)."""

    #: no database of its bus defines its id
    UNKNOWN_ID = "unknown_id"
    #: a message of its bus's databases that cantools cannot decode
    DECODE_ERROR = "decode_error"
    ERROR_FRAME = "error_frame"
    REMOTE = "remote"


#: What the decoder made of a frame: its decoded message, or why there is none.
Outcome: TypeAlias = Decoded | Undecoded


@dataclass
class DecodeStats:
    """What happened to every frame, per bus and per (bus, id)."""

    frames: Counter[str] = field(default_factory=Counter)
    error_frames: Counter[str] = field(default_factory=Counter)
    remote_frames: Counter[str] = field(default_factory=Counter)
    unknown: Counter[tuple[str, int]] = field(default_factory=Counter)
    errors: Counter[tuple[str, int]] = field(default_factory=Counter)
    last_error: dict[tuple[str, int], str] = field(default_factory=dict)

    def to_dict(self, codecs: Iterable[MessageCodec]) -> dict[str, Any]:
        """A JSON-ready summary (stored in the MCAP metadata, printed by ``inspect``)."""

        def ids(counter: Counter[tuple[str, int]]) -> dict[str, int]:
            return {f"{bus}/0x{i:X}": n for (bus, i), n in sorted(counter.items())}

        codecs = sorted(codecs, key=lambda c: c.topic)  # (a J1939 message's: one topic)
        decoded: Counter[str] = Counter()
        truncated: Counter[str] = Counter()
        longer: dict[str, dict[str, int]] = {}
        non_finite: Counter[str] = Counter()
        for c in codecs:
            decoded[c.topic] += c.decoded
            truncated[c.topic] += c.truncated
            if c.longer:
                seen = longer.setdefault(c.topic, {"frames": 0, "message_bytes": c.length,
                                                   "longest": 0})
                seen["frames"] += c.longer
                seen["longest"] = max(seen["longest"], c.longest)
            for name, n in sorted(c.non_finite.items()):
                non_finite[f"{c.bus}/{c.message.name}.{name}"] += n
        return {
            "frames": dict(sorted(self.frames.items())),
            "decoded": {topic: n for topic, n in decoded.items() if n},
            "truncated": {topic: n for topic, n in truncated.items() if n},
            "longer": longer,
            "unknown_ids": ids(self.unknown),
            "decode_errors": ids(self.errors),
            "last_decode_error": {f"{bus}/0x{i:X}": text
                                  for (bus, i), text in sorted(self.last_error.items())},
            "error_frames": dict(sorted(self.error_frames.items())),
            "remote_frames": dict(sorted(self.remote_frames.items())),
            "non_finite": dict(non_finite),
        }
