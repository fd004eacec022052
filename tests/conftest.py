"""Shared fixtures: bundled and public databases, and logs written with python-can's writers;
the tests' time budgets (TANKVIZ_TEST_TIMEOUT_SCALE), the goldens (TANKVIZ_REGENERATE_GOLDENS)
and hypothesis' CI profile."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import can
import cantools
import pytest
import waiting
from hypothesis import HealthCheck, settings

from bridge.resources import data_dir

SHARED_DBC = Path(__file__).resolve().parents[2] / "shared" / "data" / "dbc"
#: Where the public DBCs come from, for the reason of every test skipped without them.
SHARED_DBC_ORIGIN = ("they come from ../shared/data/dbc beside the project: public DBC files of "
                     "comma.ai's opendbc (MIT), not part of this repository")
ECOCAR_DBC = data_dir() / "ecocar.dbc"

# A test run's database cache (bridge/decode/cache.py) is its own, not the user's; the commands
# it runs in subprocesses share it.
_CACHE_HOME = tempfile.mkdtemp(prefix="tankviz-test-cache-")
os.environ["XDG_CACHE_HOME"] = _CACHE_HOME
atexit.register(shutil.rmtree, _CACHE_HOME, ignore_errors=True)

# Under CI (CI=true) no property test fails on hypothesis' per-example deadline or on slow data
# generation: a loaded machine is slow, not wrong. The examples are the same on every run
# (derandomize: a CI failure does not come and go), and a falsifying one is printed with the blob
# that replays it (@reproduce_failure). Spelled out in full rather than relying on the "ci"
# profile that recent hypothesis versions register themselves (not every version we accept does).
settings.register_profile("ci", settings.get_profile("default"), deadline=None,
                          derandomize=True, database=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow])
if os.environ.get("CI"):
    settings.load_profile("ci")


def timeout_scale() -> float:
    """:func:`waiting.timeout_scale`, a wrong value a usage error of pytest's."""
    try:
        return waiting.timeout_scale()
    except ValueError as e:
        raise pytest.UsageError(str(e)) from None


#: Where the goldens live: what a test's output must be, byte for byte.
GOLDEN = Path(__file__).resolve().parent / "golden"


def regenerating_goldens() -> bool:
    """TANKVIZ_REGENERATE_GOLDENS=1: a golden test writes what it got as the new golden (then
    compares, and passes). Any other value is refused, so that a typo never regenerates, nor
    silently compares."""
    raw = os.environ.get("TANKVIZ_REGENERATE_GOLDENS", "")
    if raw not in ("", "0", "1"):
        raise pytest.UsageError(f"TANKVIZ_REGENERATE_GOLDENS={raw!r}: expected 1 (or 0, unset)")
    return raw == "1"


def check_golden(path: Path, got: str, differs: str = "") -> None:
    """``got`` is the text of the golden file ``path`` (under :data:`GOLDEN`), or becomes it
    with TANKVIZ_REGENERATE_GOLDENS=1; ``differs`` says more where they differ."""
    if regenerating_goldens():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(got)
    name = path.relative_to(GOLDEN)
    assert path.exists(), f"no golden {name}: run with TANKVIZ_REGENERATE_GOLDENS=1"
    assert got == path.read_text(), (
        f"{differs or 'what the test got'} differs from the golden {name} (after a deliberate "
        "change, run with TANKVIZ_REGENERATE_GOLDENS=1 and review the diff)")


def summary_counts(path: Path) -> dict[str, int]:
    """Messages per topic of an MCAP file, as the Python mcap library reads its summary."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    return {summary.channels[i].topic: n
            for i, n in summary.statistics.channel_message_counts.items()}


T0 = 1_700_000_000.0  # an absolute start time, in python-can's float seconds


@pytest.fixture(scope="session")
def ecocar() -> cantools.database.can.Database:
    return cantools.database.load_file(ECOCAR_DBC)


@pytest.fixture(scope="session")
def sample_drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled sample log (ecocar_sample.blf) converted with the ecocar profile, once per
    run: read it, never change it."""
    from bridge.pipeline.convert import convert

    drive = tmp_path_factory.mktemp("sample") / "sample.mcap"
    convert([data_dir() / "ecocar_sample.blf"], drive, [], profile="ecocar")
    return drive


@pytest.fixture
def shared_dbc() -> Path:
    """The public DBCs beside the project (../shared); skipped where they are absent."""
    if not SHARED_DBC.is_dir():
        pytest.skip(f"public DBCs not found at {SHARED_DBC}: {SHARED_DBC_ORIGIN}")
    return SHARED_DBC


def message(db: cantools.database.can.Database, name: str, t: float, channel: object = 0,
            **values: float) -> can.Message:
    """A python-can message carrying ``values`` (others at 0) encoded with the DBC."""
    m = db.get_message_by_name(name)
    signals = {s.name: 0 for s in m.signals}
    signals.update(values)
    data = m.encode(signals, strict=False)
    return can.Message(timestamp=t, arbitration_id=m.frame_id, data=data, channel=channel,
                       is_extended_id=m.is_extended_frame, is_fd=m.is_fd, dlc=len(data))


WriteLog = Callable[[str, Iterable[can.Message]], Path]


@pytest.fixture
def write_log(tmp_path: Path) -> WriteLog:
    """Write messages with python-can's writer for the file's suffix; returns the path."""

    def write(name: str, messages: Iterable[can.Message]) -> Path:
        path = tmp_path / name
        with can.Logger(path) as logger:
            for m in messages:
                logger.on_message_received(m)
        return path

    return write


@pytest.fixture
def restore_stop_signals() -> Iterator[None]:
    """live, demo and replay take SIGINT and SIGTERM (live and demo SIGHUP too) to stop
    cleanly: given back after."""
    import signal

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    yield
    for s, handler in saved.items():
        signal.signal(s, handler)
