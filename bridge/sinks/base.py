"""The one output interface of the pipeline: a :class:`Sink` (python-can's ``Listener`` is the
model: the pipeline calls each sink in turn; a sink never calls back).

A drive's sinks get, in log time order:

- the raw frames, in blocks: each closed window's :class:`~bridge.sinks.raw.RawBlock`, one per
  bus, serialized once for all sinks (:mod:`bridge.sinks.raw`);
- every decoded message (its codec knows its topic and schema; its payload is serialized);
- the messages the pipeline makes at one log time (a scene tick, a health tick, a log line), as
  one batch of :class:`Serialized` messages, each serialized once for all sinks;
- before any frame, on live: every :class:`Channel` the drive can carry, so viewers see the
  topics at once (a file sink ignores this: its channels are written when first used);
- at the end, :meth:`Sink.finish`: a file is complete after it; a live server sends what is
  left and goes on serving (the next drive, a replay's next pass).

The recorder (:class:`bridge.sinks.mcap.Recorder`), a drive split into parts
(:class:`bridge.sinks.drives.PartsRecorder`) and the live server
(:class:`bridge.sinks.server.ViewerServer`) implement it, and so do test fakes. Subclass
:class:`Sink` to inherit methods that do nothing; a sink must not block the pipeline.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, ClassVar, NamedTuple, Protocol

from bridge.decode.decoder import Decoded
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
