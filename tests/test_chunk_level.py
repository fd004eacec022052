"""Chunk compression (#36 decision 4): offline ``convert`` (and ``batch``, which converts with
it) writes its chunks at :data:`OFFLINE_LEVEL`, a live drive's parts at zstandard's default level
3 (:data:`LIVE_LEVEL`), which mcap's own Writer uses; on an mcap release the fence does not know,
the recorder takes mcap's own Writer and level. A chunk's level is told by compressing its
contents again: zstd at one level gives the same bytes every time."""

from __future__ import annotations

import io
from collections.abc import Iterator
from pathlib import Path

import pytest
import zstandard
from foxglove_schemas_protobuf.Log_pb2 import Log
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

from bridge import fences
from bridge.frame import Frame
from bridge.pipeline.convert import convert
from bridge.resources import data_dir
from bridge.sinks.drives import PartsRecorder
from bridge.sinks.mcap import LIVE_LEVEL, OFFLINE_LEVEL, Recorder
from bridge.sinks.raw import cut


def chunk_levels(data: bytes) -> set[int | None]:
    """The zstd level each chunk was compressed at (of those tried; None: none of them)."""
    levels: set[int | None] = set()
    for record in StreamReader(io.BytesIO(data), skip_magic=False, emit_chunks=True).records:
        if isinstance(record, Chunk):
            assert record.compression == "zstd"
            contents = zstandard.ZstdDecompressor().decompress(
                record.data, max_output_size=record.uncompressed_size)
            levels.add(next((level for level in (LIVE_LEVEL, OFFLINE_LEVEL)
                             if zstandard.ZstdCompressor(level=level).compress(contents)
                             == record.data), None))
    return levels


def test_the_levels_differ_so_the_test_can_tell_them() -> None:
    assert OFFLINE_LEVEL != LIVE_LEVEL


def test_offline_convert_writes_its_chunks_at_the_offline_level(tmp_path: Path) -> None:
    out = tmp_path / "sample.mcap"
    convert([data_dir() / "ecocar_sample.blf"], out, [], profile="ecocar")
    assert chunk_levels(out.read_bytes()) == {OFFLINE_LEVEL}


def test_a_re_derived_drive_is_offline_too(tmp_path: Path) -> None:
    drive, again = tmp_path / "drive.mcap", tmp_path / "again.mcap"
    convert([data_dir() / "ecocar_sample.blf"], drive, [str(data_dir() / "ecocar.dbc")])
    convert([drive], again, [])
    assert chunk_levels(again.read_bytes()) == {OFFLINE_LEVEL}


def record_live(folder: Path) -> bytes:
    recorder = PartsRecorder(folder, lambda r, part: None)
    for i in range(2000):
        t = 1_700_000_000_000_000_000 + i * 1_000_000
        recorder.on_raw(cut([Frame(t, "can0", 0x100 + i % 7, bytes([i % 256, 1, 2, 3]))]))
    recorder.finish()
    (part,) = sorted(folder.glob("*.mcap"))
    return part.read_bytes()


def test_a_live_drive_keeps_level_3(tmp_path: Path) -> None:
    assert chunk_levels(record_live(tmp_path)) == {LIVE_LEVEL}


@pytest.fixture
def unknown_mcap(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setattr(fences, "installed_version", lambda distribution: "99.0")
    fences.forget()
    yield
    monkeypatch.undo()
    fences.forget()


def test_on_an_unknown_mcap_offline_chunks_are_at_mcaps_own_level(unknown_mcap: None) -> None:
    out = io.BytesIO()
    recorder = Recorder(out, level=OFFLINE_LEVEL)
    for n in range(200):
        recorder.write("/log", Log(message=f"line {n} " * 20), 1_000 + n)
    recorder.finish()
    assert recorder._writer.level == LIVE_LEVEL
    assert chunk_levels(out.getvalue()) == {LIVE_LEVEL}
