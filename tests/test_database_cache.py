"""The database cache (bridge/decode/cache.py) and a short convert's start-up (issue #36): a
database parsed once is the same database from the cache, a changed file is parsed again, a
damaged or unwritable cache is never an error, and a small input is read without a read-ahead
process."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import cantools
import pytest

from bridge.decode import cache
from bridge.decode.database import layout, load_database
from bridge.decode.decoder import Decoder
from bridge.io import readahead
from bridge.io.can_logs import LogSource
from bridge.pipeline.convert import convert
from bridge.resources import data_dir
from tests.conftest import ECOCAR_DBC, SHARED_DBC

SAMPLE = data_dir() / "ecocar_sample.blf"

DBC = """VERSION ""

BS_:

BU_: ECU

BO_ 256 Speed: 8 ECU
 SG_ Kph : 0|16@1+ (0.01,0) [0|655.35] "km/h" ECU
 SG_ Gear : 16|4@1+ (1,0) [0|15] "" ECU

VAL_ 256 Gear 0 "P" 1 "R" 2 "N" 3 "D" ;
"""


@pytest.fixture(autouse=True)
def own_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Each test with a cache of its own, and cantools' parses counted."""
    cache._save_all()  # the code other tests compiled goes to their cache, not this one
    home = tmp_path / "cache-home"
    monkeypatch.setenv("XDG_CACHE_HOME", str(home))
    yield home / "tankviz" / "databases"
    cache._save_all()


@pytest.fixture
def parses(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The files cantools parses from now on."""
    seen: list[str] = []
    load_file = cantools.database.load_file

    def counted(filename: str, *args: object, **kwargs: object) -> object:
        seen.append(filename)
        return load_file(filename, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(cantools.database, "load_file", counted)
    return seen


def decoded(path: Path) -> list[tuple[str, bytes]]:
    """Every message of the database's first payloads of zeros and of ones, as the decoder
    makes them (topic, encoded message)."""
    decoder = Decoder({None: [load_database(path)]})
    out = []
    for codec in decoder.codecs_for("can0"):
        for fill in (0x00, 0xFF):
            data = bytes([fill]) * codec.message.length
            try:
                result = codec.decode(data)
            except Exception as exc:  # (a message cantools cannot decode: the same both ways)
                out.append((codec.topic, repr(exc).encode()))
                continue
            out.append((codec.topic, result.payload))
    return out


@pytest.mark.slow
def test_a_database_is_parsed_once_and_the_cache_gives_the_same_database(
        tmp_path: Path, parses: list[str], own_cache: Path) -> None:
    parsed = load_database(ECOCAR_DBC)
    assert len(parses) == 1 and list(own_cache.glob("*.pickle"))
    again = load_database(ECOCAR_DBC)
    assert len(parses) == 1  # from the cache
    assert again.db is not parsed.db
    assert again.db.as_dbc_string() == parsed.db.as_dbc_string()
    assert [layout(m) for m in again.db.messages] == [layout(m) for m in parsed.db.messages]
    assert (again.sha256, again.warnings, again.name) == (parsed.sha256, parsed.warnings,
                                                          parsed.name)
    # the same messages decoded and encoded, the second time with the kept compiled code
    first = decoded(ECOCAR_DBC)
    cache._save_all()
    assert list(own_cache.glob("*.code"))
    assert decoded(ECOCAR_DBC) == first


def test_the_cache_gives_the_same_warnings_at_another_path(tmp_path: Path,
                                                           parses: list[str]) -> None:
    """A database with warnings: each copy's warnings name its own path."""
    if not SHARED_DBC.is_dir():
        pytest.skip("no ../shared/data/dbc")
    source = next((p for p in sorted(SHARED_DBC.glob("*.dbc"))
                   if load_database(p).warnings), None)
    if source is None:
        pytest.skip("no public DBC with warnings")
    a, b = tmp_path / "a.dbc", tmp_path / "b.dbc"
    a.write_bytes(source.read_bytes())
    b.write_bytes(source.read_bytes())
    first, second = load_database(a), load_database(b)
    assert second.warnings == tuple(w.replace(str(a), str(b)) for w in first.warnings)
    assert all(str(b) in w for w in second.warnings)


def test_a_changed_database_is_parsed_again(tmp_path: Path, parses: list[str]) -> None:
    path = tmp_path / "car.dbc"
    path.write_text(DBC)
    assert [m.name for m in load_database(path).db.messages] == ["Speed"]
    path.write_text(DBC.replace("256", "257").replace("Speed", "Pace"))
    changed = load_database(path)
    assert [(m.name, m.frame_id) for m in changed.db.messages] == [("Pace", 257)]
    assert len(parses) == 2
    path.write_text(DBC)
    assert [m.name for m in load_database(path).db.messages] == ["Speed"]
    assert len(parses) == 2  # the first version's entry is still there


def test_a_damaged_cache_entry_is_ignored_and_replaced(tmp_path: Path, parses: list[str],
                                                      own_cache: Path) -> None:
    path = tmp_path / "car.dbc"
    path.write_text(DBC)
    load_database(path)
    Decoder({None: [load_database(path)]}).codecs_for("can0")[0].decode(bytes(8))
    cache._save_all()
    (entry,) = own_cache.glob("*.pickle")
    (code,) = own_cache.glob("*.code")
    for damaged in (b"", b"\x80\x05 not a pickle", entry.read_bytes()[:100]):
        entry.write_bytes(damaged)
        code.write_bytes(damaged)
        found = load_database(path)
        assert [m.name for m in found.db.messages] == ["Speed"]
        assert Decoder({None: [found]}).codecs_for("can0")[0].decode(
            bytes([0x10, 0x27, 0x03] + [0] * 5)).signals == {"Kph": 100.0, "Gear": 3}
        assert cache.cached(path.read_bytes(), ".dbc") is not None  # replaced
    assert len(parses) == 4
    # another database's entry under this one's name (a file copied by hand) is a miss too
    other = tmp_path / "other.dbc"
    other.write_text(DBC.replace("Speed", "Other"))
    load_database(other)
    entry.write_bytes(
        (own_cache / f"{cache.entry_key(other.read_bytes(), '.dbc')}.pickle").read_bytes())
    assert [m.name for m in load_database(path).db.messages] == ["Speed"]
    assert len(parses) == 6


@pytest.mark.slow
def test_an_unwritable_cache_fails_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           parses: list[str]) -> None:
    """A cache folder that cannot be made (a file in its way, as a read-only or full disk
    refuses it): every load parses, and a convert works."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    path = tmp_path / "car.dbc"
    path.write_text(DBC)
    load_database(path)
    load_database(path)
    assert len(parses) == 2
    report = convert([SAMPLE], tmp_path / "out.mcap", [str(ECOCAR_DBC)])
    cache._save_all()
    assert report.frames > 0 and (tmp_path / "out.mcap").stat().st_size > 0
    assert blocker.read_text() == ""


def test_a_failed_write_leaves_no_partial_entry(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                own_cache: Path) -> None:
    def full(source: str, target: str) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    path = tmp_path / "car.dbc"
    path.write_text(DBC)
    assert [m.name for m in load_database(path).db.messages] == ["Speed"]
    assert list(own_cache.iterdir()) == []


@pytest.mark.slow
def test_a_small_input_is_read_without_a_read_ahead_process(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Under MIN_BYTES a process would cost more than it saves: the frames are read here."""
    assert SAMPLE.stat().st_size < readahead.MIN_BYTES
    assert not readahead.ReadAhead([LogSource(SAMPLE)]).ahead

    def no_child(self: readahead.ReadAhead) -> Iterator[object]:
        raise AssertionError("a read-ahead process was started for a small input")

    monkeypatch.setattr(readahead.ReadAhead, "_from_child", no_child)
    report = convert([SAMPLE], tmp_path / "out.mcap", [str(ECOCAR_DBC)])
    assert report.frames > 1000
