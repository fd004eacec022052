"""The fences around other libraries' private code (bridge/fences.py): the installed releases
are the checked ones, the private names are there, and on a release not checked the warning is
one clear line and the library's public path is taken."""

from __future__ import annotations

import io
import logging
from collections.abc import Iterator

import can
import pytest
from conftest import WriteLog
from mcap.reader import make_reader

from bridge import fences
from bridge.fences import FENCES, PYTHON_CAN, Fence
from bridge.io import buses
from bridge.io.can_logs import LogSource
from bridge.sinks.mcap import FastWriter, Recorder


@pytest.fixture
def unknown_releases(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Every library pretends to be a release no fence was checked on."""
    monkeypatch.setattr(fences, "installed_version", lambda distribution: "99.0")
    fences.forget()
    yield
    monkeypatch.undo()
    fences.forget()


@pytest.mark.parametrize("fence", FENCES, ids=lambda fence: fence.distribution)
def test_the_installed_release_is_one_the_fence_was_checked_on(fence: Fence) -> None:
    assert fence.unknown() is None, fence.unknown()


@pytest.mark.parametrize("fence", FENCES, ids=lambda fence: fence.distribution)
def test_pyproject_allows_the_checked_releases_only(fence: Fence) -> None:
    from pathlib import Path

    pyproject = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    assert f'"{fence.distribution}>={fence.lowest},<{fence.beyond}"' in pyproject


def test_the_private_names_are_there() -> None:
    """What the fences list, on the installed releases (the server's are checked one by one in
    tests/test_server.py, the mcap writer's byte for byte in tests/test_recorder.py)."""
    for name in ("_parse_data", "_recv_internal", "_matches_filters"):
        assert any(hasattr(cls, name) for cls in (can.BLFReader, can.BusABC)), name
    reader = can.BLFReader(io.BytesIO(_blf_of([])))
    assert hasattr(reader, "_tail") and hasattr(reader, "file")
    writer = FastWriter(io.BytesIO())
    assert writer._fast, "mcap's Writer no longer has the private names FastWriter uses"


def test_an_unknown_release_is_said_in_one_line_once(
        unknown_releases: None, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="tankviz.fences"):
        assert not PYTHON_CAN.holds() and not PYTHON_CAN.holds()
    assert [r.getMessage() for r in caplog.records] == [
        "python-can 99.0 is not a release tankviz was checked on (>=4.4,<4.7, "
        "bridge/fences.py): BLF logs are read by python-can's own reader (a damaged one is not "
        "read past its damage) and buses through recv"]


FRAMES = [can.Message(timestamp=1.0 + i / 100, arbitration_id=0x100 + i, data=bytes([i] * 8),
                      is_extended_id=False) for i in range(20)]


def _blf_of(messages: list[can.Message]) -> bytes:
    out = io.BytesIO()
    writer = can.BLFWriter(out)
    for message in messages:
        writer.on_message_received(message)
    writer.file.flush()
    data = out.getvalue()
    writer.stop()
    return data


def test_on_an_unknown_python_can_blf_is_read_by_python_cans_own_reader(
        unknown_releases: None, write_log: WriteLog) -> None:
    path = write_log("drive.blf", FRAMES)
    frames = list(LogSource(path))
    assert [(f.arbitration_id, f.data) for f in frames] == [
        (m.arbitration_id, bytes(m.data)) for m in FRAMES]


def test_on_an_unknown_python_can_a_bus_is_read_through_recv(unknown_releases: None) -> None:
    channel = "fence-test"
    with can.Bus(interface="virtual", channel=channel) as reader, \
            can.Bus(interface="virtual", channel=channel) as sender:
        for message in FRAMES[:5]:
            sender.send(message)
        calls = []
        recv = reader.recv

        def counted(timeout: float | None = None) -> can.Message | None:
            calls.append(timeout)
            return recv(timeout)

        reader.recv = counted  # type: ignore[method-assign]
        got = list(buses._received(reader, 100))
    assert [m.arbitration_id for m in got] == [m.arbitration_id for m in FRAMES[:5]]
    assert calls == [0] * 6  # python-can's public recv, until it has nothing


def test_on_an_unknown_mcap_the_recorder_writes_with_mcaps_own_writer(
        unknown_releases: None) -> None:
    from foxglove_schemas_protobuf.Log_pb2 import Log

    out = io.BytesIO()
    recorder = Recorder(out)
    assert not recorder._writer._fast
    for n in range(3):
        recorder.write("/log", Log(message=f"line {n}"), 1_000 + n)
        recorder.flush()  # (mcap's own flush: the chunk closed)
    recorder.finish()
    out.seek(0)
    messages = [(channel.topic, message.log_time)
                for _, channel, message in make_reader(out).iter_messages()]
    assert messages == [("/log", 1_000), ("/log", 1_001), ("/log", 1_002)]
