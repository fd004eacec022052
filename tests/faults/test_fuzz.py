"""Fuzzing every input format: random bytes, and real logs overwritten, cut, shortened or grown
at random places. Each conversion finishes within a time limit, with a report or a one-line
error: never a hang, never a traceback (issue #13, "Tests and proof" and item 6).

The car is not ecocar: the logs carry random data in every frame of opendbc's ESR.dbc (a Delphi
radar), converted with its profile (tests/profiles/delphi_esr.toml), so the damage also goes
through decoding and the scene.
"""

from __future__ import annotations

import gzip
import random
from pathlib import Path

import can
import cantools
import pytest
from conftest import SHARED_DBC, SHARED_DBC_ORIGIN, T0
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_logs import within_limit

from bridge.errors import BridgeError
from bridge.pipeline.convert import ConvertReport, convert

PROFILE = Path(__file__).resolve().parents[1] / "profiles" / "delphi_esr.toml"
DBC = SHARED_DBC / "ESR.dbc"

#: Every format python-can reads here (.mf4 needs asammdf: without it, a one-line error too).
FORMATS = [".blf", ".asc", ".log", ".trc", ".csv", ".db", ".blf.gz", ".asc.gz", ".log.gz",
           ".trc.gz", ".csv.gz", ".mf4"]
#: The formats tankviz has a writer for, whose real logs get damaged.
WRITTEN = [f for f in FORMATS if f != ".mf4"]

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not DBC.is_file(),
                                 reason=f"public DBC not found at {DBC}: {SHARED_DBC_ORIGIN}")]

# The same examples on every run (a failure does not come and go); no deadline (a loaded machine
# is slow, not wrong: the time limit of within_limit catches hangs).
FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def radar_drive(n: int = 600) -> list[can.Message]:
    """``n`` frames of the ESR radar, random data in each of its messages, 2 ms apart."""
    db = cantools.database.load_file(DBC)
    rng = random.Random(13)
    messages = [m for m in db.messages if m.length <= 8]
    return [can.Message(timestamp=T0 + i * 0.002, arbitration_id=m.frame_id,
                        is_extended_id=m.is_extended_frame, data=rng.randbytes(m.length),
                        channel=0)
            for i, m in ((i, messages[i % len(messages)]) for i in range(n))]


_LOGS: dict[str, bytes] = {}


def real_log(suffix: str, folder: Path) -> bytes:
    """The bytes of the radar drive as python-can writes it in ``suffix`` (made once)."""
    if suffix not in _LOGS:
        plain = folder / f"real{suffix.removesuffix('.gz')}"
        with can.Logger(plain) as logger:
            for m in radar_drive():
                logger.on_message_received(m)
        data = plain.read_bytes()
        _LOGS[suffix] = gzip.compress(data, mtime=0) if suffix.endswith(".gz") else data
    return _LOGS[suffix]


def convert_within_limit(path: Path) -> ConvertReport | BridgeError:
    """The conversion of ``path``: its report, or the one-line error it ended with."""
    def run() -> ConvertReport | BridgeError:
        try:
            return convert([path], path.with_suffix(".mcap"), [str(DBC)], profile=PROFILE,
                           force=True)
        except BridgeError as exc:
            return exc
    result = within_limit(run)
    assert isinstance(result, (ConvertReport, BridgeError))
    if isinstance(result, BridgeError):
        assert "\n" not in str(result) and str(result).startswith(str(path))
    else:
        assert result.frames > 0
    return result


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@FUZZ
@given(suffix=st.sampled_from(FORMATS), data=st.binary(max_size=3000))
def test_random_bytes_in_any_format_end_in_a_report_or_one_line(
        folder: Path, suffix: str, data: bytes) -> None:
    path = folder / f"random{suffix}"
    path.write_bytes(data)
    convert_within_limit(path)


@FUZZ
@given(suffix=st.sampled_from(WRITTEN), where=st.floats(0.0, 1.0),
       how=st.sampled_from(["overwrite", "insert", "delete", "cut"]),
       size=st.integers(1, 300), seed=st.integers(0, 2**32 - 1),
       text=st.booleans())
def test_a_damaged_real_log_in_any_format_ends_in_a_report_or_one_line(
        folder: Path, suffix: str, where: float, how: str, size: int, seed: int,
        text: bool) -> None:
    whole = real_log(suffix, folder)
    at = int(where * len(whole))
    rng = random.Random(seed)
    junk = (bytes(rng.choice(b"0123456789abcdefABCDEF .#()-:;,\n\tRxTx") for _ in range(size))
            if text else rng.randbytes(size))
    damaged = {"overwrite": whole[:at] + junk + whole[at + size:],
               "insert": whole[:at] + junk + whole[at:],
               "delete": whole[:at] + whole[at + size:],
               "cut": whole[:at]}[how]
    path = folder / f"damaged{suffix}"
    path.write_bytes(damaged)

    convert_within_limit(path)
