"""The one output interface of the pipeline: a :class:`Sink` (as python-can's ``Listener``: the
pipeline calls each sink in turn; a sink never calls back, and must not block the pipeline).

A sink gets, in log time order, raw frame blocks, decoded messages and batches of serialized
messages (each serialized once for all sinks), on live every channel first, and at the end
:meth:`Sink.finish`, after which a file is complete. :class:`Sink`'s own methods do nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar, NamedTuple, Protocol

from bridge.decode.codec import Decoded
from bridge.sinks.raw import RawBlock


class Serialized(NamedTuple):
    """A message the pipeline made: topic, protobuf message class, serialized bytes, log time."""

    topic: str
    message_class: Any
    payload: bytes
    t_ns: int


class Channel(NamedTuple):
    """A topic a drive can carry, with its protobuf schema (a FileDescriptorSet, built only
    when asked for)."""

    topic: str
    schema_name: str
    schema: Callable[[], bytes]


class Sink(Protocol):
    """Where a drive's frames, decoded messages and made messages go."""

    #: Whether the sink records the drive into files: the pipeline hands it fewer of the
    #: messages made per frame (bring-up's ``/can/<bus>/unknown``: :mod:`bridge.bringup.monitor`).
    records: ClassVar[bool] = False

    def on_raw(self, blocks: Sequence[RawBlock], /) -> None:
        """The raw frames of one closed window, a block per bus."""
        return None

    def on_decoded(self, t_ns: int, decoded: Decoded, /) -> None:
        """A decoded message at log time ``t_ns``."""
        return None

    def on_decoded_many(self, messages: Sequence[tuple[int, Decoded]], /) -> None:
        """Decoded messages ``(log time, decoded)``, in order: :meth:`on_decoded` of each
        (offline, the pipeline hands over a run of a block's frames at once)."""
        for t_ns, decoded in messages:
            self.on_decoded(t_ns, decoded)

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        """The messages made at one log time (scene, perception, health, log), in order."""
        return None

    def advertise(self, channels: Sequence[Channel], /) -> None:
        """Every channel the drive can carry, before its first frame (live)."""
        return None

    def finish(self) -> None:
        """The drive is over: a file is complete after this; a server sends what is left."""
        return None
