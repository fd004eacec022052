"""What the benchmarks in tools/ share: the code of a git revision, interleaved timing, the drive.

- :func:`worktree` checks a revision out once per run (a detached git worktree, removed at exit);
  :func:`modules_at` imports modules of it beside the working tree's, unchanged (no text is
  rewritten), and :func:`revision_env` runs a subprocess on it.
- :func:`interleaved` runs contenders round-robin (A, B, A, B, ...), so that a loaded machine
  slows each alike; :func:`best_of` keeps each one's best CPU time.
- :func:`ecocar_frames` and :func:`ecocar_log` are ``bridge/sim``'s ecocar drive (the one
  ``tankviz simulate`` writes), its message families on three buses; the logs are cached by
  frame count, seed and the simulator's source.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import hashlib
import importlib
import importlib.abc
import importlib.machinery
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from itertools import islice
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, TypeVar

import can

if TYPE_CHECKING:
    from bridge.frame import Frame

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

T = TypeVar("T")
MB = 1024 * 1024

# --------------------------------------------------------------------------------------------
# The code of a git revision

_worktrees: dict[str, Path] = {}


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True, capture_output=True,
                          text=True).stdout.strip()


def worktree(rev: str) -> Path:
    """The code at git revision ``rev``: a detached worktree in a temporary folder, made once per
    run for each commit and removed when the run ends."""
    commit = _git("rev-parse", "--verify", f"{rev}^{{commit}}")
    if commit not in _worktrees:
        folder = Path(tempfile.mkdtemp(prefix=f"tankviz-{commit[:8]}-")) / "tree"
        _git("worktree", "add", "--detach", "-q", str(folder), commit)
        _worktrees[commit] = folder
    return _worktrees[commit]


@atexit.register
def _remove_worktrees() -> None:
    for folder in _worktrees.values():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(folder)],
                       capture_output=True)
        shutil.rmtree(folder.parent, ignore_errors=True)
    _worktrees.clear()


def revision_env(rev: str) -> dict[str, str]:
    """The environment of a subprocess that imports ``bridge`` from ``rev``'s worktree."""
    tree = worktree(rev)
    return os.environ | {"PYTHONPATH": os.pathsep.join(
        [str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])}


def _below(name: str, roots: Sequence[str]) -> bool:
    return any(name == root or name.startswith(f"{root}.") for root in roots)


class _TreeFinder(importlib.abc.MetaPathFinder):
    """Finds the modules below ``taken`` in ``tree`` (a folder holding ``bridge``)."""

    def __init__(self, tree: Path, taken: Sequence[str]) -> None:
        self.tree = tree
        self.taken = taken

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if not _below(fullname, self.taken):
            return None
        folder = self.tree.joinpath(*fullname.split(".")[:-1])
        return importlib.machinery.PathFinder.find_spec(fullname, [str(folder)])


def take_modules(tree: Path, own: Sequence[str],
                 fresh: Sequence[str] = ()) -> list[importlib.abc.MetaPathFinder]:
    """From now on, import the modules below ``own`` from ``tree`` (a revision's worktree) and
    those below ``fresh`` from the working tree, before any other place: the finders put first
    in ``sys.meta_path`` (a subprocess calls it before it imports them)."""
    finders: list[importlib.abc.MetaPathFinder] = [_TreeFinder(tree, own), _TreeFinder(ROOT, fresh)]
    sys.meta_path[:0] = finders
    return finders


def modules_at(rev: str, names: Sequence[str], *, own: Sequence[str] = (),
               fresh: Sequence[str] = ()) -> dict[str, ModuleType]:
    """The modules ``names`` (e.g. ``"bridge.health.monitor"``) as revision ``rev`` has them,
    by name, beside the working tree's: ``sys.modules`` is as it was after.

    Every module below ``names`` and ``own`` (modules or packages) comes from ``rev``'s
    worktree, and those below ``fresh`` from the working tree, both imported anew at each call
    (two calls share nothing), so that they import each other; any other module is the working
    tree's, shared. An import the code makes later, inside a function, finds the tree's."""
    ours = (*names, *own)
    for name in (*names, *fresh):  # the tree's modules, loaded before they would bind to rev's
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    swapped = (*ours, *fresh)
    saved = {n: m for n, m in sys.modules.items() if _below(n, swapped)}
    before = set(sys.modules)
    for name in saved:
        del sys.modules[name]
    finders = take_modules(worktree(rev), ours, fresh)
    try:
        found = {n: importlib.import_module(n) for n in names}
    finally:
        for finder in finders:
            sys.meta_path.remove(finder)
        for name in [n for n in sys.modules if n not in before or n in saved]:
            del sys.modules[name]
        sys.modules.update(saved)
        for name in saved:  # ``import a.b`` set ``a.b`` to rev's module: the tree's again
            parent, _, leaf = name.rpartition(".")
            if parent in sys.modules:
                setattr(sys.modules[parent], leaf, saved[name])
    return found


def package_at(rev: str, package: str, *, own: Sequence[str] = ()) -> dict[str, ModuleType]:
    """Every module of ``package`` (e.g. ``"bridge.health"``) as ``rev`` has it, by its name in
    the package (:func:`modules_at`, with ``own``)."""
    folder = worktree(rev).joinpath(*package.split("."))
    leaves = sorted(p.stem for p in folder.glob("*.py") if p.stem != "__init__")
    found = modules_at(rev, [f"{package}.{leaf}" for leaf in leaves], own=(package, *own))
    return {name.rpartition(".")[2]: module for name, module in found.items()}


# --------------------------------------------------------------------------------------------
# Interleaved timing


def interleaved(contenders: Mapping[str, Callable[[], T]], rounds: int, *,
                done: Callable[[str, int, T], None] | None = None) -> dict[str, list[T]]:
    """Run every contender once per round, in turn (A, B, A, B, ...), ``rounds`` rounds: what
    each returned, by name. ``done(name, round, result)`` after each run (progress)."""
    results: dict[str, list[T]] = {name: [] for name in contenders}
    for k in range(rounds):
        for name, run in contenders.items():
            results[name].append(run())
            if done is not None:
                done(name, k, results[name][-1])
    return results


def cpu_seconds(run: Callable[[], object]) -> Callable[[], float]:
    """``run`` timed: the CPU seconds of this process it takes (garbage collected first)."""
    def timed() -> float:
        gc.collect()
        started = time.process_time()
        run()
        return time.process_time() - started
    return timed


def best_of(contenders: Mapping[str, Callable[[], float]], rounds: int) -> dict[str, float]:
    """The least seconds each contender returned over ``rounds`` :func:`interleaved` rounds
    (a contender times itself, e.g. with :func:`cpu_seconds`)."""
    return {name: min(times) for name, times in interleaved(contenders, rounds).items()}


# --------------------------------------------------------------------------------------------
# The drive: bridge/sim's ecocar, on three buses

ECOCAR_DBC = ROOT / "bridge" / "data" / "ecocar.dbc"
#: The bus of each message family, by the start of its DBC name (the rest: ``can2``).
BUSES = {"Radar": "can0", "Cam": "can1"}
BUS_NAMES = {"can0": "radar", "can1": "camera", "can2": "vehicle"}
#: Frames per second of the drive, a little less than it makes (to simulate enough seconds).
FRAMES_PER_SECOND = 2_200


def _bus_of_id() -> dict[int, str]:
    from bridge.sim.frames import load_ecocar

    return {m.frame_id: next((bus for start, bus in BUSES.items() if m.name.startswith(start)),
                             "can2") for m in load_ecocar().messages}


def ecocar_frames(frames: int, seed: int = 1) -> Iterator[Frame]:
    """The first ``frames`` frames of ``bridge/sim``'s ecocar drive, the radar's on ``can0``,
    the camera's on ``can1``, the rest (the vehicle, fusion, gateway) on ``can2``."""
    from bridge.sim.ecocar import simulate

    bus = _bus_of_id()
    drive = simulate(duration_s=frames / FRAMES_PER_SECOND + 1.0, seed=seed)
    for frame in islice(drive, frames):
        yield frame._replace(bus=bus.get(frame.arbitration_id, "can2"))


def ecocar_drive(duration_s: float, seed: int = 1) -> Iterator[Frame]:
    """Every frame of ``duration_s`` seconds of ``bridge/sim``'s ecocar drive, on the three buses
    of :func:`ecocar_frames` (a drive of a given length, not a given frame count)."""
    from bridge.sim.ecocar import simulate

    bus = _bus_of_id()
    for frame in simulate(duration_s=duration_s, seed=seed):
        yield frame._replace(bus=bus.get(frame.arbitration_id, "can2"))


def _simulator_version() -> str:
    digest = hashlib.sha256(ECOCAR_DBC.read_bytes())
    for path in sorted((ROOT / "bridge" / "sim").glob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:10]


def ecocar_log(workdir: Path, frames: int, seed: int = 1) -> tuple[Path, dict[str, Any]]:
    """:func:`ecocar_frames` as a BLF cached in ``workdir``, and its statistics (``frames``,
    ``seconds_of_driving``, ``frames_per_bus``, how often payloads repeat, ...)."""
    stem = f"ecocar-3bus-{frames}f-seed{seed}-sim{_simulator_version()}"
    path, meta_path = workdir / f"{stem}.blf", workdir / f"{stem}.json"
    if path.is_file() and meta_path.is_file():
        meta: dict[str, Any] = json.loads(meta_path.read_text())
        return path, meta | {"cached": True}
    workdir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    partial = workdir / f".{stem}.blf.partial"
    per_bus = dict.fromkeys(BUS_NAMES, 0)
    same_as_last = in_last_16 = 0
    recent: dict[tuple[str, int], deque[bytes]] = {}
    first = last = 0
    with can.BLFWriter(str(partial)) as writer:
        for frame in ecocar_frames(frames, seed):
            writer.on_message_received(can.Message(
                timestamp=frame.timestamp_ns / 1e9, arbitration_id=frame.arbitration_id,
                data=frame.data, is_extended_id=frame.is_extended, is_fd=frame.is_fd,
                bitrate_switch=frame.bitrate_switch, dlc=frame.dlc, channel=int(frame.bus[3:])))
            per_bus[frame.bus] += 1
            history = recent.setdefault((frame.bus, frame.arbitration_id), deque(maxlen=16))
            if history:
                same_as_last += history[-1] == frame.data
                in_last_16 += frame.data in history
            history.append(frame.data)
            first, last = first or frame.timestamp_ns, frame.timestamp_ns
    os.replace(partial, path)
    meta = {
        "frames": frames, "seed": seed, "seconds_of_driving": (last - first) / 1e9,
        "frames_per_bus": {f"{bus} ({BUS_NAMES[bus]})": n for bus, n in per_bus.items()},
        "repeat_previous_payload_of_id": same_as_last / frames,
        "repeat_one_of_last_16_payloads_of_id": in_last_16 / frames,
        "generation_seconds": time.perf_counter() - started,
        "bytes": path.stat().st_size,
    }
    meta_path.write_text(json.dumps(meta, indent=1))
    return path, meta | {"cached": False}


def log_copy(blf: Path, suffix: str) -> Path:
    """The same frames as ``blf`` in another format, cached beside it: ``.asc`` (python-can's
    ASCWriter) or ``.log`` (candump, its CanutilsLogWriter, channels named ``can0``...)."""
    path = blf.with_suffix(suffix)
    if path.is_file():
        return path
    partial = blf.with_name(f".{blf.stem}{suffix}.partial")
    candump = suffix == ".log"
    with (can.CanutilsLogWriter if candump else can.ASCWriter)(str(partial)) as writer:
        for msg in can.BLFReader(str(blf)):
            if candump:
                msg.channel = f"can{msg.channel}"
            writer.on_message_received(msg)
    os.replace(partial, path)
    return path


#: Where the benchmarks cache their logs and write their outputs, unless told (``--workdir``).
WORKDIR = Path(tempfile.gettempdir()) / "tankviz-bench"


def add_workdir(parser: Any, what: str = "where logs are cached") -> None:
    """The ``--workdir`` option of a benchmark's ``argparse`` parser (default :data:`WORKDIR`)."""
    parser.add_argument("--workdir", type=Path, default=WORKDIR, help=what)


#: The simulated cars the health and scene benchmarks drive: (car, profile, log format).
SIMULATED_DRIVES = (("ecocar", "ecocar", "asc"), ("highway", "highway", "blf"))


def simulated_logs(folder: Path, seconds: float) -> Iterator[tuple[str, str, Path]]:
    """Each of :data:`SIMULATED_DRIVES` simulated for ``seconds`` into ``folder`` (``tankviz
    simulate``): the car, its profile's name and its log."""
    for car, profile_name, ext in SIMULATED_DRIVES:
        log = folder / f"{car}.{ext}"
        subprocess.run([sys.executable, "-m", "bridge", "simulate", "--car", car, "-o", str(log),
                        "--duration", f"{seconds:g}"], cwd=ROOT, check=True, capture_output=True)
        yield car, profile_name, log
