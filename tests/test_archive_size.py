"""What a drive's indexes let readers do: seek from a start time with mcap's Python reader,
``tankviz replay --start`` and @mcap/core (the reader of the Foxglove app), all giving the same
messages; and why the recorder keeps the per-message MessageIndex records (16 bytes a message,
the larger part of a raw archive): @mcap/core refuses a chunk that has messages but no message
indexes, so the Foxglove app could not open the drive.

The @mcap/core tests run ``node tests/browser/seek.mjs`` and skip with a reason when node or the
packages of tests/browser are missing."""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
from foxglove_schemas_protobuf.Log_pb2 import Log
from mcap.reader import make_reader
from mcap.writer import IndexType

from bridge.apps.replay import _mcap_messages
from bridge.frame import Frame
from bridge.sinks.mcap import Recorder
from bridge.sinks.raw import cut

BROWSER = Path(__file__).resolve().parent / "browser"
T0_NS = 1_700_000_000_000_000_000
STEP_NS = 1_000_000  # a frame a millisecond on each bus


def record_drive(path: Path, **writer: Any) -> None:
    """Two buses of a car that is not the ecocar, and a log topic, over several chunks."""
    out = io.BytesIO()
    recorder = Recorder(out, chunk_size=8 * 1024, **writer)
    for i in range(3000):
        t = T0_NS + i * STEP_NS
        recorder.on_raw(cut([Frame(t, "chassis", 0x1F0 + i % 4, bytes([i % 256, 7, 0, 1]))]))
        recorder.on_raw(cut([Frame(t + 300_000, "powertrain", 0x18FF00 | i % 3,
                                   i.to_bytes(8, "little"), is_extended=True)]))
        if i % 100 == 0:
            recorder.write("/log", Log(message=f"second {i // 1000}"), t + 500_000)
    recorder.finish()
    path.write_bytes(out.getvalue())


def python_messages(path: Path, start_ns: int) -> list[tuple[str, int, str]]:
    with path.open("rb") as stream:
        return [(channel.topic, message.log_time, hashlib.sha256(message.data).hexdigest())
                for _, channel, message in make_reader(stream).iter_messages(
                    starting_at=start_ns, log_time_order=True)]


def node_seek(path: Path, start_ns: int) -> dict[str, Any]:
    if shutil.which("node") is None:
        pytest.skip("node is not installed (Node >= 20, for @mcap/core, the Foxglove app's reader)")
    if not (BROWSER / "node_modules" / "@mcap" / "core").is_dir() or not (
            BROWSER / "node_modules" / "@mcap" / "support").is_dir():
        pytest.skip("@mcap/core and @mcap/support are not installed: run npm ci in tests/browser")
    run = subprocess.run(["node", str(BROWSER / "seek.mjs"), str(path), str(start_ns)],
                         cwd=BROWSER, capture_output=True, text=True, timeout=120, check=False)
    assert run.stdout, run.stderr
    found: dict[str, Any] = json.loads(run.stdout)
    return found


def test_a_recorded_drive_has_chunk_indexes_and_a_message_index_per_chunk_and_channel(
        tmp_path: Path) -> None:
    path = tmp_path / "drive.mcap"
    record_drive(path)
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    assert len(summary.chunk_indexes) == summary.statistics.chunk_count > 3
    for chunk in summary.chunk_indexes:
        assert chunk.message_index_length > 0
        assert set(chunk.message_index_offsets) <= set(summary.channels)
    assert summary.statistics.message_count == 2 * 3000 + 30


def test_every_reader_seeks_to_the_same_messages_from_the_middle_of_a_drive(
        tmp_path: Path) -> None:
    path = tmp_path / "drive.mcap"
    record_drive(path)
    start_ns = T0_NS + 1234 * STEP_NS + 1  # inside a chunk, between two frames
    expected = python_messages(path, start_ns)
    assert expected[0][1] == T0_NS + 1234 * STEP_NS + 300_000  # the powertrain frame after it
    assert len(expected) == 2 * (3000 - 1234) - 1 + 17  # frames after it, and the logs
    assert {topic for topic, _, _ in expected} == {"/can/chassis/frames",
                                                     "/can/powertrain/frames", "/log"}

    replayed = [(topic, log_ns, hashlib.sha256(data).hexdigest())
                for topic, _, _, _, data, log_ns in _mcap_messages(path, 1.234 + 1e-9)]
    assert replayed == expected  # tankviz replay DRIVE --start 1.234

    found = node_seek(path, start_ns)
    assert "error" not in found, found
    assert sorted((topic, int(log_ns), digest) for topic, log_ns, digest in found["messages"]) == (
        sorted(expected))


def test_without_message_indexes_the_foxglove_reader_refuses_a_drive(tmp_path: Path) -> None:
    """Why the recorder keeps them: with chunk indexes only, mcap's Python reader still seeks
    (it decompresses each chunk whole), but @mcap/core, which the Foxglove app uses for any file
    with chunk indexes, refuses every chunk that has messages."""
    path = tmp_path / "chunks-only.mcap"
    record_drive(path, index_types=IndexType.ALL & ~IndexType.MESSAGE)
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.chunk_indexes
    assert all(c.message_index_length == 0 for c in summary.chunk_indexes)
    start_ns = T0_NS + 1234 * STEP_NS + 1
    reference = tmp_path / "drive.mcap"
    record_drive(reference)
    assert python_messages(path, start_ns) == python_messages(reference, start_ns)
    found = node_seek(path, start_ns)
    assert "without message indexes" in found.get("error", ""), found
