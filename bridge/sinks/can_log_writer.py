"""Frames written as a CAN log (:func:`write_log`), with python-can's writer for the log's suffix.

Every frame given is written on its bus's channel, so that read back the log gives the frames
written on the same buses (CSV and SQLite have no channel nor CAN FD flags: they read back on
``can0``). The log appears only complete, and two runs writing one output never mix their bytes.
"""

from __future__ import annotations

import os
import re
import secrets
import time
from collections.abc import Iterator
from pathlib import Path

import can

from bridge.errors import FileError
from bridge.frame import Frame
from bridge.sinks.outputs import fitted_name, publish


class _CompleteSqliteWriter(can.SqliteWriter):
    """python-can's SQLite writer, writing everything it is given.

    Its writer thread ends on ``stop()`` after at most one more batch (~500 frames), and whatever
    is still queued is lost; this one waits for the queue to be taken first.
    """

    def stop(self) -> None:
        thread = self._writer_thread
        while not self.buffer.empty() and thread.is_alive():
            time.sleep(0.01)
        super().stop()


def log_channel(bus: str) -> int | str:
    """The python-can channel a bus is written on: N for ``can<N>`` (read back as ``can<N>``:
    :func:`bridge.io.can_logs.bus_name`), else the bus name itself."""
    return int(bus[3:]) if re.fullmatch(r"can\d+", bus) else bus


def write_log(frames: Iterator[Frame], output: Path, suffix: str, *,
              force: bool | None = None) -> tuple[int, int]:
    """Write ``frames`` with python-can's writer for ``suffix``, under a hidden name of its own
    given its name when every frame is written (``force``: as
    :func:`bridge.sinks.outputs.atomic_output` takes it). Returns how many frames, and how many of
    them CAN FD."""
    replace = os.path.lexists(output) if force is None else force
    # python-can chooses its writer by the suffixes (exactly two for gzip): keep only those
    base = fitted_name(output.name[:-len(suffix)].replace('.', '_'),
                       len(f"._partial_{'9' * 16}-{'f' * 8}{suffix}"))  # (a name of 255 bytes)
    partial = output.with_name(f".{base}_partial_{os.getpid()}-{secrets.token_hex(4)}{suffix}")
    count = fd = 0
    try:
        try:
            writer: can.Listener = (_CompleteSqliteWriter(partial) if suffix == ".db"
                                    else can.Logger(partial))
        except NotImplementedError as exc:  # MF4 without asammdf
            raise FileError(output, f"{exc}; pip install 'tankviz[mf4]'") from None
        try:
            for frame in frames:
                writer.on_message_received(can.Message(
                    timestamp=frame.timestamp_ns / 1e9, arbitration_id=frame.arbitration_id,
                    data=frame.data, is_extended_id=frame.is_extended, is_fd=frame.is_fd,
                    bitrate_switch=frame.bitrate_switch, dlc=frame.dlc,
                    channel=log_channel(frame.bus)))
                count += 1
                fd += frame.is_fd
        finally:
            writer.stop()
        if isinstance(writer, can.SqliteWriter) and writer.num_frames != count:
            raise FileError(output, f"python-can's SQLite writer wrote {writer.num_frames:,} "
                            f"of {count:,} frames")
        publish(partial, output, replace=replace)
    except OSError as exc:
        raise FileError(output, f"cannot write: {exc.strerror or exc}") from exc
    finally:
        partial.unlink(missing_ok=True)
    return count, fd
