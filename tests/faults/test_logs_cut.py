"""Logs cut in their header, and logs with a block of zeros in their middle (issue #23, items 3
and 8): every reader finishes, with frames or one clear error, and every line that is not a
whole frame is reported with its line number.

The cut test reads thousands of files in one child process: a reader that hangs fails the test
when the child outlives its time (and the child is killed), instead of blocking the suite; the
child's heap is capped, so a reader whose memory grows without bound fails it sooner.
"""

from __future__ import annotations

import gzip
import importlib.util
import itertools
import json
import subprocess
import sys
import textwrap
import zlib
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import timeout_scale

from bridge.errors import InputError
from bridge.io.can_logs import LogSource, supported_suffixes
from bridge.sim.ecocar import simulate
from bridge.sinks.can_log_writer import write_log

#: The bytes of each log cut: every length from 0 to this (the header and the first frames).
CUT_BYTES = 600
#: What reading every cut of every format may take at most (they take a few seconds).
LIMIT_S = 120.0


def simulated(path: Path, seconds: float, frames: int | None = None) -> Path:
    """A log of the simulated car written as ``tankviz simulate`` writes it: its first
    ``frames`` classic frames (TRC has no CAN FD), or ``seconds`` of them all."""
    drive = simulate(duration_s=seconds)
    if frames is not None or path.suffix == ".trc":
        drive = (f for f in drive if not f.is_fd)
    if path.suffix == ".gz":  # (python-can writes no .blf.gz): the log, compressed
        plain = simulated(path.with_name("plain-" + path.stem), seconds, frames)
        path.write_bytes(gzip.compress(plain.read_bytes()))
        plain.unlink()
    else:
        write_log(itertools.islice(drive, frames), path, "".join(path.suffixes))
    return path


#: The child: for each (log, format) it is given, reads every cut of the log and prints one line
#: of JSON per cut: the frames read (and whether they are the log's first frames), the issues,
#: the error (a BridgeError), or the crash (any other exception, with its traceback).
CHILD = textwrap.dedent("""
    import json, resource, sys, traceback
    from pathlib import Path
    from bridge.errors import BridgeError
    from bridge.io.can_logs import LogSource
    limit = int(sys.argv[1])
    resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
    folder = Path(sys.argv[2])
    for name in sys.argv[3:]:
        log = folder / name
        whole = log.read_bytes()
        full = list(LogSource(log))
        cut = folder / ("cut-" + name)
        for size in range(min(len(whole), CUT_BYTES) + 1):
            print(json.dumps({"log": name, "size": size, "started": True}), flush=True)
            cut.write_bytes(whole[:size])
            out = {"log": name, "size": size}
            try:
                source = LogSource(cut)
                frames = list(source)
                out["frames"] = len(frames)
                out["prefix"] = frames == full[:len(frames)]
                out["issues"] = [str(i) for i in source.issues]
            except BridgeError as exc:
                out["error"] = str(exc)
            except BaseException as exc:
                out["crash"] = "".join(traceback.format_exception(exc))
            print(json.dumps(out), flush=True)
""").replace("CUT_BYTES", str(CUT_BYTES))


def cut_formats() -> list[str]:
    """Every format tankviz reads; MF4 only where its optional package is installed."""
    return [s for s in supported_suffixes()
            if s != ".mf4" or importlib.util.find_spec("asammdf") is not None]


@pytest.mark.slow
def test_every_format_cut_at_every_byte_of_its_header_reads_to_an_end(tmp_path: Path) -> None:
    names = [simulated(tmp_path / f"drive{suffix}", 1.0, frames=40).name
             for suffix in cut_formats()]
    heap = 1 << 30
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(heap), str(tmp_path), *names],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = child.communicate(timeout=LIMIT_S * timeout_scale())
    except subprocess.TimeoutExpired:
        child.kill()
        out, err = child.communicate()
    lines = [json.loads(line) for line in out.splitlines()]
    last = lines[-1] if lines else {}
    assert child.returncode == 0, (
        f"reading {last.get('log')} cut to {last.get('size')} bytes did not finish "
        f"(exit {child.returncode}): {err.strip()[-2000:]}")

    results = [line for line in lines if "started" not in line]
    assert {r["log"] for r in results} == set(names)
    assert len(results) == sum(min((tmp_path / n).stat().st_size, CUT_BYTES) + 1 for n in names)
    crashes = [f"{r['log']} cut to {r['size']} bytes: {r['crash']}" for r in results
               if "crash" in r]
    assert not crashes, crashes[0]
    for r in results:
        place = f"{r['log']} cut to {r['size']} bytes"
        if "error" in r:  # one line, naming the file
            assert r["error"].startswith(str(tmp_path / f"cut-{r['log']}")), place
            assert "\n" not in r["error"] and "Traceback" not in r["error"], place
        else:  # the log's first frames, nothing made of the cut
            assert r["frames"] > 0 and r["prefix"], place
            assert all("\n" not in issue for issue in r["issues"]), place


# --- a block of zeros in the middle of a text log ---


def lines_of(blob: bytes) -> list[tuple[int, bytes]]:
    """(byte offset, text) of each line."""
    out, at = [], 0
    for line in blob.splitlines(keepends=True):
        out.append((at, line))
        at += len(line)
    return out


def frame_lines(suffix: str, lines: list[tuple[int, bytes]]) -> list[int]:
    """The indexes of the lines that hold a frame, in order."""
    if suffix == ".csv":
        return list(range(1, len(lines)))  # after the column names
    return [i for i, (_, text) in enumerate(lines) if not text.startswith(b";") and text.strip()]


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".csv", ".trc"])
@pytest.mark.parametrize("where", ["mid-line", "at a line's start"])
def test_4_kib_of_zeros_lose_only_the_lines_they_hit_and_each_is_reported(
        tmp_path: Path, suffix: str, where: str) -> None:
    path = simulated(tmp_path / f"drive{suffix}", 3.0)
    whole = path.read_bytes()
    original = list(LogSource(path))
    lines = lines_of(whole)
    framed = frame_lines(suffix, lines)
    assert len(framed) == len(original)
    start = len(whole) // 2
    if where == "at a line's start":
        start = whole.rindex(b"\n", 0, start) + 1
    damaged = bytearray(whole)
    damaged[start:start + 4096] = bytes(4096)
    path.write_bytes(damaged)
    # the zeros join the line they begin in to the line they end in: one line of the file now
    first = whole.rindex(b"\n", 0, start) + 1
    end = damaged.index(b"\n", start + 4096)
    hit = [i for i, (offset, _) in enumerate(lines) if first <= offset <= end]
    line = hit[0] + 1  # numbered from 1, as the lines before are whole

    source = LogSource(path)
    frames = list(source)

    lost = {framed.index(i) for i in hit if i in framed}
    assert len(lost) >= 30  # 4 KiB is tens of lines
    assert frames == [f for n, f in enumerate(original) if n not in lost]  # no mixed lines
    (issue,) = source.issues
    assert issue.where == f"line {line}"
    assert issue.reason.startswith("damaged data: 4096 zero bytes in this line")




@pytest.mark.parametrize(("content", "line", "how"), [
    (";$FILEVERSION=2.1\r\n;", 2, "in the middle of this line (no newline)"),  # issue #23
    (";$FILEVERSION=2.1\r\n;$STARTTIME=45000.5\r\n", 2, "after this line"),
])
def test_a_trc_cut_in_its_header_is_one_error_saying_where_it_ends(
        tmp_path: Path, content: str, line: int, how: str) -> None:
    path = tmp_path / "cut.trc"
    path.write_bytes(content.encode())
    with pytest.raises(InputError) as error:
        list(LogSource(path))
    assert str(error.value) == (
        f"{path}: no CAN frames in this file (line {line}: the file ends {how}: cut short, "
        "python-can cannot read it (ValueError: File has no column information))")


# --- a gzipped log cut short (issue #33, item 6) ---

#: Where a gzipped log is cut: its byte count, from the size of the whole .gz.
GZ_CUTS: dict[str, Callable[[int], int]] = {
    "in the gzip header": lambda size: 5,
    "in the middle": lambda size: size // 2,
    "a third in": lambda size: size // 3,
    "just before the gzip trailer": lambda size: size - 8,  # the data whole, no CRC and size
    "in the gzip trailer": lambda size: size - 3,
}


def gzipped_formats() -> list[str]:
    return [s for s in supported_suffixes() if s.endswith(".gz")]


def said(source: LogSource) -> list[tuple[str, str, str, str]]:
    """The issues of a source without its path: (where, reason, kind, group)."""
    return [(i.where, i.reason, i.kind, i.group) for i in source.issues]


@pytest.mark.slow
@pytest.mark.parametrize("where", GZ_CUTS)
@pytest.mark.parametrize("suffix", gzipped_formats())
def test_a_gzipped_log_cut_keeps_every_frame_before_the_cut_and_says_it_is_cut(
        tmp_path: Path, suffix: str, where: str) -> None:
    path = simulated(tmp_path / f"drive{suffix}", 4.0)
    full = list(LogSource(path))
    packed = path.read_bytes()
    cut = packed[:GZ_CUTS[where](len(packed))]
    path.write_bytes(cut)
    # the same bytes unzipped: every byte of the log before the cut
    plain = tmp_path / f"plain{suffix.removesuffix('.gz')}"
    plain.write_bytes(zlib.decompressobj(zlib.MAX_WBITS | 16).decompress(cut))

    if where == "in the gzip header":
        with pytest.raises(InputError) as error:
            list(LogSource(path))
        assert str(error.value) == (
            f"{path}: no CAN frames in this file (the file is cut short: it ends inside its gzip "
            "compression, after 0 bytes of the log; what followed is lost)")
        return
    source = LogSource(path)
    frames = list(source)

    assert frames == full[:len(frames)]
    unzipped = LogSource(plain)
    assert frames == list(unzipped)  # all the frames the same bytes unzipped give
    if where in {"in the middle", "a third in"}:  # told as a cut of the unzipped log is
        assert said(source) == said(unzipped)
        assert [i.group for i in source.issues] == ["file cut short"]
        assert len(frames) > len(full) // 4
    else:  # every frame is there, but the file is still cut (its check is lost)
        assert frames == full
        assert said(source) == [(
            f"line {plain.read_text().count(chr(10))}" if suffix != ".blf.gz" else
            f"byte {plain.stat().st_size}",
            f"the file is cut short: it ends inside its gzip compression, after "
            f"{plain.stat().st_size:,} bytes of the log; what followed is lost", "stop",
            "file cut short")]


@pytest.mark.parametrize("suffix", gzipped_formats())
def test_a_gzipped_log_cut_in_its_first_two_bytes_says_it_is_cut(tmp_path: Path,
                                                                 suffix: str) -> None:
    path = tmp_path / f"drive{suffix}"
    path.write_bytes(b"\x1f")
    with pytest.raises(InputError, match=r"no CAN frames in this file .the file is cut short"):
        list(LogSource(path))


@pytest.mark.parametrize("suffix", [".log.gz", ".blf.gz"])
def test_a_gz_that_is_no_gzip_or_fails_its_check_is_one_line(tmp_path: Path, suffix: str) -> None:
    path = simulated(tmp_path / f"drive{suffix}", 1.0)
    full = list(LogSource(path))
    packed = bytearray(path.read_bytes())
    packed[-8] ^= 0xFF  # the CRC of the data
    path.write_bytes(packed)
    source = LogSource(path)
    frames = list(source)
    assert frames == full  # the frames are kept, but the check is told
    (issue,) = source.issues
    assert "fails its check" in issue.reason and issue.kind == "damage"

    path.write_bytes(b"this is no gzip at all\n")
    with pytest.raises(InputError, match=r"no CAN frames in this file .*it is no gzip data"):
        list(LogSource(path))


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".asc", ".log", ".trc", ".csv"])
def test_a_text_log_cut_in_any_line_says_once_it_is_cut(tmp_path: Path, suffix: str) -> None:
    path = simulated(tmp_path / f"drive{suffix}", 1.0)
    whole = path.read_bytes()
    for at in range(len(whole) // 2, len(whole) // 2 + 120, 7):  # every part of a few lines
        path.write_bytes(whole[:at])
        source = LogSource(path)
        frames = list(source)
        whole_line = whole[at - 1] in b"\r\n"  # (a CR of a CR LF is a newline too)
        lines = tmp_path / f"lines{suffix}"  # its whole lines
        lines.write_bytes(whole[:at] if whole_line else whole[:whole.rindex(b"\n", 0, at) + 1])
        assert frames == list(LogSource(lines))
        groups = [i.group for i in source.issues]
        assert groups == ([] if whole_line else ["file cut short"]), (at, whole[at - 30:at])
