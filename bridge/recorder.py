"""The recorder sink: everything the pipeline produces, into one MCAP file (mcap + mcap_protobuf).

It takes an already-open binary writer, so tests can record into ``BytesIO``. Channels are
registered when their first message arrives; protobuf schemas are FileDescriptorSets built the
way mcap_protobuf builds them. Chunks are zstd-compressed.
"""

from __future__ import annotations

import json
import time
from typing import IO, Any

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import build_file_descriptor_set

from bridge import __version__
from bridge.decode import Decoded, MessageCodec
from bridge.frame import Frame
from bridge.pb.can_frame_pb2 import CanFrame
from bridge.topics import frames_topic

#: MCAP metadata record written by tankviz (see :func:`Recorder.add_metadata`).
METADATA_NAME = "tankviz"

_MEDIA_TYPES = {".dbc": "application/x-dbc", ".kcd": "application/xml",
                ".arxml": "application/xml", ".sym": "text/plain"}


def media_type(file_name: str) -> str:
    """The attachment media type of a signal database file."""
    suffix = file_name[file_name.rfind("."):].lower() if "." in file_name else ""
    return _MEDIA_TYPES.get(suffix, "application/octet-stream")


class Recorder:
    """Writes frames, decoded messages and any protobuf message into one MCAP stream."""

    def __init__(self, output: IO[bytes], *, chunk_size: int = 4 * 1024 * 1024,
                 compression: CompressionType = CompressionType.ZSTD) -> None:
        self._writer = McapWriter(output, chunk_size=chunk_size, compression=compression)
        self._writer.start(profile="", library=f"tankviz {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._frame_channels: dict[str, int] = {}
        self._codec_channels: dict[MessageCodec, int] = {}
        self._frame_schema: int | None = None
        self.messages = 0
        self._finished = False

    def _schema(self, name: str, data: bytes) -> int:
        schema_id = self._schemas.get(name)
        if schema_id is None:
            schema_id = self._writer.register_schema(name, SchemaEncoding.Protobuf, data)
            self._schemas[name] = schema_id
        return schema_id

    def channel(self, topic: str, schema_name: str, schema_data: bytes) -> int:
        """The id of a protobuf channel, registered on first use."""
        channel_id = self._channels.get(topic)
        if channel_id is None:
            channel_id = self._writer.register_channel(
                topic, MessageEncoding.Protobuf, self._schema(schema_name, schema_data)
            )
            self._channels[topic] = channel_id
        return channel_id

    def write_frame(self, frame: Frame) -> None:
        """A raw frame on ``/can/<bus>/frames``."""
        channel_id = self._frame_channels.get(frame.bus)
        if channel_id is None:
            channel_id = self._frame_channels[frame.bus] = self.channel(
                frames_topic(frame.bus), CanFrame.DESCRIPTOR.full_name,
                build_file_descriptor_set(CanFrame).SerializeToString())
        t = frame.timestamp_ns
        data = CanFrame(
            timestamp_ns=t, bus=frame.bus, id=frame.arbitration_id, extended=frame.is_extended,
            fd=frame.is_fd, bitrate_switch=frame.bitrate_switch,
            error_state_indicator=frame.error_state_indicator, error=frame.is_error,
            remote=frame.is_remote, dlc=frame.dlc, data=frame.data,
        ).SerializeToString()
        self._writer.add_message(channel_id, t, data, t)
        self.messages += 1

    def write_decoded(self, timestamp_ns: int, decoded: Decoded) -> None:
        """A decoded message on ``/can/<bus>/<Message>``."""
        codec = decoded.codec
        channel_id = self._codec_channels.get(codec)
        if channel_id is None:
            channel_id = self._codec_channels[codec] = self.channel(
                codec.topic, codec.schema.full_name, codec.schema.file_descriptor_set())
        self._writer.add_message(channel_id, timestamp_ns, decoded.payload, timestamp_ns)
        self.messages += 1

    def write(self, topic: str, message: Any, timestamp_ns: int) -> None:
        """Any protobuf message (scene, semantic, health) on its topic."""
        channel_id = self._channels.get(topic)
        if channel_id is None:
            cls = type(message)
            channel_id = self.channel(topic, cls.DESCRIPTOR.full_name,
                                      build_file_descriptor_set(cls).SerializeToString())
        self._writer.add_message(channel_id, timestamp_ns, message.SerializeToString(),
                                 timestamp_ns)
        self.messages += 1

    def add_metadata(self, values: dict[str, Any], name: str = METADATA_NAME) -> None:
        """A metadata record; values that are not strings are stored as JSON."""
        self._writer.add_metadata(
            name, {k: v if isinstance(v, str) else json.dumps(v, sort_keys=True)
                   for k, v in values.items()})

    def add_attachment(self, name: str, data: bytes, *, media: str | None = None,
                       log_time: int = 0) -> None:
        self._writer.add_attachment(time.time_ns(), log_time, name, media or media_type(name),
                                    data)

    def finish(self) -> None:
        """Write the summary and footer; the file is complete after this."""
        if not self._finished:
            self._finished = True
            self._writer.finish()  # type: ignore[no-untyped-call]
