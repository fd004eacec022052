"""LogSource's batches (a BLF run of intact objects parsed and converted at once) give the frames
and issues, at the same places, that reading one message at a time gives, whatever is in the
run: times going back or beyond 2262, python-can's warnings, a failing parser, damage, --strict
(issue #36)."""

from __future__ import annotations

import random
import struct
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from conftest import T0, WriteLog
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.errors import InputError
from bridge.frame import Frame
from bridge.io import can_logs
from bridge.io.blf import BlfReader
from bridge.io.can_logs import LogSource, SourceIssue


def one_at_a_time(self: LogSource, reader: BlfReader, run: bytes,
                  ) -> Iterator[tuple[can.Message, ...]]:
    for message in reader._parse_data(run):
        yield (message,)


def read(path: Path, careful: bool, strict: bool = False,
         ) -> tuple[list[Frame], list[SourceIssue], int, str | None]:
    """Frames, issues, frames counted and the error of reading ``path``; ``careful``: one
    message at a time, as before batches."""
    with pytest.MonkeyPatch.context() as patch:
        if careful:
            patch.setattr(can_logs, "_converted", lambda *args: None)
            patch.setattr(LogSource, "_parsed", one_at_a_time)
        source = LogSource(path, strict=strict)
        frames: list[Frame] = []
        error = None
        try:
            for frame in source:
                frames.append(frame)
        except InputError as exc:
            error = str(exc)
        return frames, source.issues, source.frames, error


def same(path: Path, strict: bool = False) -> tuple[list[Frame], list[SourceIssue]]:
    batched = read(path, careful=False, strict=strict)
    careful = read(path, careful=True, strict=strict)
    assert batched == careful
    assert all(type(f) is Frame for f in batched[0])
    return batched[0], batched[1]


def drive(n: int, seed: int, odd: float) -> list[can.Message]:
    """``n`` frames of every kind; a share ``odd`` of them stamped back in time, at an impossible
    time, or with ids that CAN has not."""
    pick = random.Random(seed)
    out = []
    for i in range(n):
        fd = pick.random() < 0.2
        t = T0 + i * 0.001
        if pick.random() < odd:
            t = pick.choice([T0 - 5.0, T0 + i * 0.001 - 0.0005, 9.3e9, T0 + 0.3])  # 9.3e9: 2264
        out.append(can.Message(
            timestamp=t, arbitration_id=pick.randrange(0x20000000 if i % 7 == 0 else 0x800),
            is_extended_id=i % 7 == 0, is_fd=fd, bitrate_switch=fd and pick.random() < 0.5,
            error_state_indicator=fd and pick.random() < 0.1,
            is_error_frame=not fd and pick.random() < 0.02,
            is_remote_frame=not fd and pick.random() < 0.02,
            data=pick.randbytes(pick.choice([0, 8, 12, 64]) if fd else pick.randint(0, 8)),
            channel=pick.randrange(4)))
    return out


def test_an_intact_blf_is_read_in_batches_as_one_at_a_time(write_log: WriteLog) -> None:
    path = write_log("drive.blf", drive(20_000, 1, 0.0))
    frames, issues = same(path)
    assert len(frames) == 20_000 and not issues


@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32), odd=st.sampled_from([0.0, 0.0005, 0.01]),
       damage=st.lists(st.tuples(st.floats(0.0, 1.0), st.binary(min_size=1, max_size=64)),
                       max_size=3), strict=st.booleans())
def test_any_blf_reads_in_batches_as_one_at_a_time(
        tmp_path_factory: pytest.TempPathFactory, seed: int, odd: float,
        damage: list[tuple[float, bytes]], strict: bool) -> None:
    path = tmp_path_factory.mktemp("blf") / "drive.blf"
    with can.Logger(path) as logger:
        for message in drive(5000, seed, odd):
            logger.on_message_received(message)
    data = bytearray(path.read_bytes())
    for where, junk in damage:
        at = 144 + int(where * (len(data) - 145))
        data[at:at + len(junk)] = junk[:len(data) - at]
    path.write_bytes(bytes(data))
    same(path, strict=strict)


def test_a_python_can_warning_in_a_run_is_placed_at_its_frame(write_log: WriteLog) -> None:
    path = write_log("drive.blf", drive(3000, 2, 0.0))
    whole = bytearray(path.read_bytes())
    import zlib

    # an object of header version 3 in the second container: python-can warns and skips it
    offset = 144
    size = struct.unpack_from("<L", whole, offset + 8)[0]
    offset += size + size % 4
    size = struct.unpack_from("<L", whole, offset + 8)[0]
    inner = bytearray(zlib.decompress(whole[offset + 32:offset + size]))
    odd = inner.find(b"LOBJ", 600 * 48)  # in the third batch of the run
    struct.pack_into("<H", inner, odd + 6, 3)
    body = struct.pack("<H6xL4x", 2, len(inner)) + zlib.compress(bytes(inner))
    new_size = 16 + len(body)
    obj = struct.pack("<4sHHLL", b"LOBJ", 16, 1, new_size, 10) + body + bytes(new_size % 4)
    path.write_bytes(bytes(whole[:offset]) + obj + bytes(whole[offset + size + size % 4:]))

    frames, issues = same(path)

    (issue,) = issues
    assert "Unknown object header version" in issue.reason and issue.where.startswith("frame ")
    assert len(frames) == 2999


def test_a_parser_failing_in_a_run_keeps_the_frames_before_it(
        write_log: WriteLog, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write_log("drive.blf", drive(8000, 3, 0.0))
    parse = BlfReader._parse_data

    def failing(self: BlfReader, data: bytes) -> Iterator[can.Message]:
        for message in parse(self, data):
            if message.timestamp == T0 + 3.0:  # frame 3000, inside a run
                raise struct.error("a failure of python-can's")
            yield message

    monkeypatch.setattr(BlfReader, "_parse_data", failing)
    batched = read(path, careful=False)
    careful = read(path, careful=True)

    assert batched == careful
    frames, issues, _, _ = batched
    assert "a failure of python-can's" in issues[0].reason and len(frames) < 8000
