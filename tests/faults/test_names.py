"""File names and paths a user may give any command (issue #33, items 2, 10 and 12).

- A name that is not UTF-8 (``bad\\xe9.blf``, copied from a latin-1 USB stick) is carried end to
  end: batch converted every drive but broke its Dask connection (msgpack refuses surrogates,
  0 written), catalog gave a DuckDB traceback. It is shown as ``bad\\xe9.blf``.
- A name over 255 bytes gave a traceback in every command that takes a file; now one line.
  A legal 251 to 255 byte output name was refused, as its partial file's name was longer.
- A FIFO given as input said "no such file" (convert) or hung (inspect, replay, recover,
  catalog opened it and waited for a writer): one line says what it is.
- A dangling symbolic link in a batch or catalog folder was left out in silence.
- A drive being recorded by ``tankviz live`` was called cut by ``catalog`` (exit 1).
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from conftest import T0, WriteLog

from bridge.cli import main
from bridge.frame import Frame
from bridge.sinks.drives import PartsRecorder
from bridge.sinks.outputs import atomic_output, is_partial_of, partial_name, remove_stale_partials
from bridge.sinks.raw import cut

BAD = b"bad\xe9"  # latin-1 é: no UTF-8
SHOWN = "bad\\xe9"  # how it is shown


def frames(n: int, start: float = T0) -> list[can.Message]:
    return [can.Message(timestamp=start + i * 0.001, arbitration_id=0x100 + i % 64,
                        data=i.to_bytes(4, "big") * 2, channel=0, is_extended_id=False)
            for i in range(n)]


def bytes_name(folder: Path, name: bytes) -> Path:
    """The path of ``folder``/``name``, a name that need not be UTF-8."""
    return Path(os.fsdecode(os.path.join(os.fsencode(folder), name)))


def printable(text: str) -> str:
    """The text, which must be printable on a strict UTF-8 terminal (no surrogates)."""
    text.encode("utf-8")
    return text


@pytest.fixture
def drives(tmp_path: Path, write_log: WriteLog) -> Path:
    """A folder of two converted drives, ``good.mcap`` and ``bad\\xe9.mcap``."""
    folder = tmp_path / "drives"
    folder.mkdir()
    log = write_log("one.blf", frames(500))
    assert main(["convert", str(log), "-o", str(folder / "good.mcap")]) == 0
    assert main(["convert", str(log), "-o", str(bytes_name(folder, BAD + b".mcap"))]) == 0
    return folder


# --- names that are not UTF-8 ------------------------------------------------------------------

@pytest.mark.slow
def test_a_batch_with_a_name_that_is_not_utf8_writes_every_drive(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    for i, name in enumerate("abcd"):
        with can.Logger(logs / f"{name}.blf") as logger:
            for m in frames(300, T0 + 10 * i):
                logger.on_message_received(m)
    os.rename(logs / "a.blf", bytes_name(logs, BAD + b".blf"))
    with can.Logger(logs / "a.blf") as logger:
        for m in frames(300, T0 + 100):
            logger.on_message_received(m)
    out = tmp_path / "out"
    assert main(["batch", "convert", str(logs), "--out", str(out), "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert sorted(os.listdir(os.fsencode(out))) == [
        b"a.mcap", b"b.mcap", BAD + b".mcap", b"c.mcap", b"d.mcap"]
    lines = printable(captured.out).splitlines()
    assert f"wrote {out}/{SHOWN}.mcap: 300 frames from {logs}/{SHOWN}.blf" in "\n".join(lines)
    assert lines[-1].startswith("5 drives: 5 written, 0 skipped, 0 failed")
    assert "Traceback" not in captured.err
    printable(captured.err)


@pytest.mark.slow
@pytest.mark.parametrize("workers", [[], ["--workers", "1"]])
def test_a_catalogue_indexes_a_drive_whose_name_is_not_utf8(
        drives: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        workers: list[str]) -> None:
    catalogue = tmp_path / "c.duckdb"
    capsys.readouterr()
    assert main(["catalog", str(drives), "-o", str(catalogue), *workers]) == 0
    assert printable(capsys.readouterr().out).strip() == (
        f"{catalogue}: 2 new, 0 changed, 0 unchanged, 0 removed, 0 not indexed")
    # indexed under the name shown, and found again as it is
    assert main(["catalog", str(drives), "-o", str(catalogue)]) == 0
    assert capsys.readouterr().out.strip() == (
        f"{catalogue}: 0 new, 0 changed, 2 unchanged, 0 removed, 0 not indexed")
    assert main(["catalog", "query", str(catalogue), "SELECT path FROM drives ORDER BY path"]) == 0
    out = printable(capsys.readouterr().out)
    assert f"{drives.resolve()}/{SHOWN}.mcap" in out
    # the open hint names the file as a shell reads it back
    assert main(["catalog", "query", str(catalogue), "--topic", "/can/can0/frames"]) == 0
    out = printable(capsys.readouterr().out)
    assert f"tankviz replay $'{drives.resolve()}/bad\\xe9.mcap' --start" in out
    os.unlink(bytes_name(drives, BAD + b".mcap"))
    assert main(["catalog", str(drives), "-o", str(catalogue)]) == 0
    assert capsys.readouterr().out.strip() == (
        f"{catalogue}: 0 new, 0 changed, 1 unchanged, 1 removed, 0 not indexed")


def test_an_error_about_a_name_that_is_not_utf8_shows_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = bytes_name(tmp_path, BAD + b".blf")
    assert main(["convert", str(missing), "-o", str(tmp_path / "o.mcap")]) == 1
    err = printable(capsys.readouterr().err).strip().splitlines()
    assert err[-1] == f"error: {tmp_path}/{SHOWN}.blf: no such file"


def test_every_command_prints_a_name_that_is_not_utf8_readably(
        drives: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """(capsys encodes strictly, as Python does on a UTF-8 terminal but in the C locale.)"""
    bad = bytes_name(drives, BAD + b".mcap")
    log = bytes_name(tmp_path, BAD + b".blf")
    capsys.readouterr()
    for argv, line in (
            (["simulate", "-o", str(log), "--duration", "1"], f"wrote {tmp_path}/{SHOWN}.blf"),
            (["convert", str(log), "-o", str(bytes_name(tmp_path, BAD + b"2.mcap"))],
             f"wrote {tmp_path}/{SHOWN}2.mcap"),
            (["inspect", str(bad)], f"file:      {drives}/{SHOWN}.mcap"),
            (["recover", str(bad), "-o", str(bytes_name(tmp_path, BAD + b"3.mcap"))],
             f"wrote {tmp_path}/{SHOWN}3.mcap")):
        assert main(argv) == 0, argv
        out = printable(capsys.readouterr().out)
        assert line in out, (argv, out)


# --- names too long ----------------------------------------------------------------------------

LONG = "x" * 260


def commands(tmp_path: Path, log: Path, drive: Path) -> list[list[str]]:
    long = str(tmp_path / LONG)
    return [
        ["convert", f"{long}.blf", "-o", str(tmp_path / "o.mcap")],
        ["convert", str(log), "-o", f"{long}.mcap"],
        ["recover", f"{long}.mcap", "-o", str(tmp_path / "r.mcap")],
        ["recover", str(drive), "-o", f"{long}.mcap"],
        ["replay", f"{long}.mcap"],
        ["inspect", f"{long}.mcap"],
        ["simulate", "-o", f"{long}.blf", "--duration", "1"],
        ["profile", "new", "--dbc", "ecocar", "-o", f"{long}.toml"],
        ["layouts", "--export", long],
        ["catalog", f"{long}.mcap", "-o", str(tmp_path / "c.duckdb")],
        ["catalog", str(drive), "-o", f"{long}.duckdb"],
        ["batch", "convert", f"{long}.blf", "--out", str(tmp_path / "out")],
        ["batch", "convert", str(log), "--out", long],
        ["ids", f"{long}.blf"],
    ]


def test_a_name_over_255_bytes_is_one_line_in_every_command(
        tmp_path: Path, write_log: WriteLog, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_log("trip.blf", frames(200))
    drive = tmp_path / "trip.mcap"
    assert main(["convert", str(log), "-o", str(drive)]) == 0
    capsys.readouterr()
    for argv in commands(tmp_path, log, drive):
        assert main(argv) == 1, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("error: "), (argv, err)
        assert LONG[:20] in err[-1] and "is 26" in err[-1], (argv, err)
        assert "bytes long" in err[-1], (argv, err)
        assert "at most 255 bytes" in err[-1], (argv, err)
        assert not any("Traceback" in line for line in err), (argv, err)


@pytest.mark.parametrize("length", [251, 255])
def test_an_output_name_of_up_to_255_bytes_is_written(
        tmp_path: Path, write_log: WriteLog, capsys: pytest.CaptureFixture[str],
        length: int) -> None:
    log = write_log("trip.blf", frames(200))
    name = "é" * ((length - 5) // 2) + "y" * ((length - 5) % 2) + ".mcap"
    assert len(name.encode()) == length
    assert main(["convert", str(log), "-o", str(tmp_path / name)]) == 0
    assert (tmp_path / name).is_file()
    assert main(["simulate", "-o", str(tmp_path / name.replace(".mcap", ".blf")),
                 "--duration", "1"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_the_partial_file_of_a_long_name_fits_and_is_known_as_its_own(tmp_path: Path) -> None:
    long, other = "a" * 250 + ".mcap", "a" * 250 + ".mcaq"
    partial = partial_name(long, "123456-deadbeef")
    assert len(partial.encode()) <= 255
    assert is_partial_of(partial, long) and not is_partial_of(partial, other)
    # a killed run's partial of a long name is removed by the next run
    (tmp_path / partial).write_bytes(b"cut short")
    assert remove_stale_partials(tmp_path / long) == [tmp_path / partial]
    with atomic_output(tmp_path / long) as stream:
        stream.write(b"whole")
    assert [p.name for p in tmp_path.iterdir()] == [long]


# --- files that are not regular files ----------------------------------------------------------

@contextlib.contextmanager
def fifos(*paths: Path) -> Iterator[None]:
    """FIFOs, each with a writer that opens and closes it again and again: a command that opens
    one for reading sees it end at once rather than wait for a writer."""
    stop = threading.Event()

    def writer(path: Path) -> None:
        while not stop.is_set():
            with open(path, "wb"):
                pass

    for path in paths:
        os.mkfifo(path)
        threading.Thread(target=writer, args=(path,), daemon=True).start()
    try:
        yield
    finally:
        stop.set()
        for path in paths:  # release a writer waiting for a reader
            os.close(os.open(path, os.O_RDONLY | os.O_NONBLOCK))


def test_a_fifo_is_named_as_one_in_every_command_that_reads_a_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log, mcap = tmp_path / "stream.log", tmp_path / "stream.mcap"
    with fifos(log, mcap):
        for argv in (["convert", str(log), "-o", str(tmp_path / "o.mcap")],
                     ["ids", str(log)],
                     ["inspect", str(mcap)],
                     ["replay", str(mcap)],
                     ["recover", str(mcap), "-o", str(tmp_path / "r.mcap")],
                     ["catalog", str(mcap), "-o", str(tmp_path / "c.duckdb")]):
            assert main(argv) == 1, argv
            captured = capsys.readouterr()
            lines = (captured.err + captured.out).strip().splitlines()
            assert any("is a FIFO (a named pipe), not a file" in line for line in lines), (
                argv, lines)
            assert not any("Traceback" in line for line in lines), (argv, lines)


@pytest.mark.slow
def test_a_dangling_link_in_a_batch_folder_is_a_failed_drive(
        tmp_path: Path, write_log: WriteLog, capsys: pytest.CaptureFixture[str]) -> None:
    write_log("good.blf", frames(300))
    (tmp_path / "gone.blf").symlink_to(tmp_path / "usb" / "gone.blf")
    out = tmp_path / "out"
    assert main(["batch", "convert", str(tmp_path), "--out", str(out), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    assert f"failed {tmp_path / 'gone.blf'}: is a symbolic link to {tmp_path / 'usb' / 'gone.blf'}"\
           ", which does not exist" in captured.out.splitlines()
    assert "2 drives: 1 written, 0 skipped, 1 failed" in captured.out
    assert captured.err.strip().splitlines()[-1] == "error: 1 of 2 drives failed"
    assert [p.name for p in out.iterdir()] == ["good.mcap"]


def test_a_dangling_link_in_a_catalogued_folder_is_not_indexed_and_says_why(
        drives: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (drives / "gone.mcap").symlink_to(tmp_path / "usb" / "gone.mcap")
    catalogue = tmp_path / "c.duckdb"
    capsys.readouterr()
    assert main(["catalog", str(drives), "-o", str(catalogue)]) == 1
    captured = capsys.readouterr()
    assert captured.err.strip() == (f"skipped: {drives / 'gone.mcap'}: is a symbolic link to "
                                    f"{tmp_path / 'usb' / 'gone.mcap'}, which does not exist")
    assert "2 new" in captured.out and "1 not indexed" in captured.out


# --- a drive being recorded --------------------------------------------------------------------

@pytest.mark.slow
def test_catalog_skips_a_drive_being_recorded_and_indexes_it_once_finished(
        drives: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    recorder = PartsRecorder(drives, lambda r, part: r.add_metadata(dict(part)))
    frame = Frame(int(T0 * 1e9), "can0", 0x100, b"\x01\x02", False, False, False, False, False,
                  False, 2)
    recorder.on_raw(cut([frame] * 100))
    recorder.tick()
    (part,) = recorder.files
    catalogue = tmp_path / "c.duckdb"
    capsys.readouterr()
    try:
        assert main(["catalog", str(drives), "-o", str(catalogue)]) == 0
        captured = capsys.readouterr()
        assert captured.err.strip() == (f"skipped {part}: being recorded (a recording is "
                                        "writing it): index it once the drive has ended")
        assert captured.out.strip() == (f"{catalogue}: 2 new, 0 changed, 0 unchanged, 0 "
                                        "removed, 0 not indexed, 1 being recorded")
    finally:
        recorder.finish()
    assert main(["catalog", str(drives), "-o", str(catalogue)]) == 0
    assert capsys.readouterr().out.strip() == (
        f"{catalogue}: 1 new, 0 changed, 2 unchanged, 0 removed, 0 not indexed")
