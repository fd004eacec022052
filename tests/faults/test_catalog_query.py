"""``tankviz catalog query`` is read only and says what is wrong with a query in one line
(#33 items 10 and 11): nothing a query says writes a file or a database, and a query with no
statement in it is an error, not a traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.cli import main

pytest.importorskip("duckdb", reason="the catalogue needs the fleet extra (duckdb)")


@pytest.fixture(scope="module")
def catalogue(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("catalogue")
    drive = folder / "drive.mcap"
    assert main(["simulate", "-o", str(drive), "--duration", "1"]) == 0
    assert main(["catalog", str(drive), "-o", str(folder / "c.duckdb")]) == 0
    return folder / "c.duckdb"


@pytest.mark.slow
@pytest.mark.parametrize("sql", [
    "COPY (SELECT 1) TO '{victim}'",
    "COPY drives TO '{victim}' (FORMAT csv)",
    "EXPORT DATABASE '{folder}/exported'",
    "ATTACH '{folder}/other.duckdb' AS other",
    "INSTALL httpfs",
    "LOAD httpfs",
    "CREATE TABLE t AS SELECT 1",
    "DELETE FROM drives",
    "SET enable_external_access = true",
])
def test_a_query_writes_nothing(catalogue: Path, capsys: pytest.CaptureFixture[str],
                                sql: str) -> None:
    victim = catalogue.parent / "victim.mcap"
    victim.write_bytes(b"a drive" * 1000)
    before = sorted(p.name for p in catalogue.parent.iterdir())
    size = catalogue.stat().st_size
    text = sql.format(victim=victim, folder=catalogue.parent)
    assert main(["catalog", "query", str(catalogue), text]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    assert victim.read_bytes() == b"a drive" * 1000
    assert sorted(p.name for p in catalogue.parent.iterdir()) == before
    assert catalogue.stat().st_size == size
    assert main(["catalog", "query", str(catalogue), "SELECT count(*) FROM drives"]) == 0


@pytest.mark.parametrize("sql", ["", "   ", ";", "-- only a comment", "/* nothing */ ;"])
def test_a_query_without_a_statement_is_one_line(catalogue: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 sql: str) -> None:
    assert main(["catalog", "query", str(catalogue), sql]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "no statement" in err and "\n" not in err
