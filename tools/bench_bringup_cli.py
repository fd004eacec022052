"""Time ``tankviz ids``, ``bits`` and ``find-signal`` on a drive the size of a real 2017 RAV4's
60 s (four buses, 175 ids, about 135,000 frames: the simulated highway car plus made-up traffic,
139 ids no database knows) against python-can reading the same log bare (the fixed reference),
interleaved, best of ``--runs`` (:func:`benchlib.interleaved`), and print each command's peak
memory; ``--minutes N`` makes the drive N minutes long.

    python tools/bench_bringup_cli.py [--runs 3] [--minutes 1]
"""

from __future__ import annotations

import argparse
import heapq
import math
import random
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))
from benchlib import interleaved  # noqa: E402

from bridge.frame import NS, Frame  # noqa: E402
from bridge.resources import data_dir  # noqa: E402
from bridge.sim.highway import simulate_highway  # noqa: E402
from bridge.sinks.can_log_writer import write_log  # noqa: E402

#: Made-up ids: (bus, how many, first id, cycle ms).
EXTRA = (("can0", 35, 0x300, 100), ("can2", 50, 0x100, 100), ("can3", 50, 0x400, 150))
#: The fixed reference's row.
REFERENCE = "python-can reads the log (reference)"


def _extra(bus: str, ident: int, cycle_ms: int, seconds: float, seed: int) -> Iterator[Frame]:
    rng = random.Random(seed)
    kind = seed % 4
    counter = rng.randrange(256)
    phase = rng.uniform(0, 2 * math.pi)
    period = rng.uniform(2, 30)
    start = 1_700_000_000 * NS + rng.randrange(cycle_ms * 1000) * 1000
    for k in range(int(seconds * 1000 / cycle_ms)):
        t = start + k * cycle_ms * 1_000_000 + rng.randrange(100) * 1000
        counter = (counter + 1) & 0xFF
        smooth = int(2000 + 1500 * math.sin(phase + k * cycle_ms / 1000 / period * 2 * math.pi))
        if kind == 0:
            body = [0x12, 0x00, counter & 0x0F, 0, 0, 0x40, 0]
        elif kind == 1:
            body = [smooth >> 8, smooth & 0xFF, counter, rng.randrange(4), 0, 0, 0]
        elif kind == 2:
            body = [rng.randrange(256), rng.randrange(256), 0, 0, smooth & 0xFF, smooth >> 8, 0]
        else:
            body = [0, 0, 0, 0, 0, 0, counter]
        data = bytes([*body, (ident + sum(body) + 8) & 0xFF])
        yield Frame(t, bus, ident, data, False, False, False, False, False, False, 8)


def rav4_like(minutes: float) -> list[Frame]:
    seconds = minutes * 60
    families: list[Iterator[Frame]] = [simulate_highway(duration_s=seconds,
                                                        start_ns=1_700_000_000 * NS)]
    for bus, count, first, cycle in EXTRA:
        families += [_extra(bus, first + i, cycle, seconds, i + first) for i in range(count)]
    return list(heapq.merge(*families))


#: Runs a Python command line (``-m bridge ...`` or ``-c CODE``) and prints its own peak RSS
#: (VmHWM: the high-water mark of this program, not of the process it was forked from).
_PEAK = ("import atexit, runpy, sys\n"
         "def peak():\n"
         "    for line in open('/proc/self/status'):\n"
         "        if line.startswith('VmHWM:'):\n"
         "            print(int(line.split()[1]), file=sys.stderr)\n"
         "atexit.register(peak)\n"
         "sys.argv = sys.argv[1:]\n"
         "if sys.argv[0] == '-m':\n"
         "    sys.argv = sys.argv[1:]\n"
         "    runpy.run_module(sys.argv[0], run_name='__main__')\n"
         "else:\n"
         "    exec(sys.argv[1])\n")


def peak_of(argv: list[str]) -> float:
    """Run a Python command (``[python, -m|-c, ...]``) in a child: its peak RSS in MB."""
    done = subprocess.run([argv[0], "-c", _PEAK, *argv[1:]], check=False,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode:
        raise SystemExit(f"{' '.join(argv[1:])} failed:\n{done.stderr}")
    return int(done.stderr.strip().splitlines()[-1]) / 1024


def timed(argv: list[str]) -> Callable[[], tuple[float, float]]:
    """A run of the command ``argv``: its wall seconds and its peak RSS (MB)."""
    def run() -> tuple[float, float]:
        started = time.perf_counter()
        peak = peak_of(argv)
        return time.perf_counter() - started, peak
    return run


def commands(log: Path, minutes: float) -> dict[str, list[str]]:
    """The commands timed, by row name: the reference first."""
    dbcs = ["--dbc", f"can0={data_dir() / 'highway_car.dbc'}",
            "--dbc", f"can1={data_dir() / 'highway_radar.dbc'}"]
    tankviz = [sys.executable, "-m", "bridge"]
    # around the first brake press (14 s), or early in a drive too short for it
    windows = (["12.5:13.9", "14.1:15.5"] if minutes * 60 > 16 else ["1:2", "3:4"])
    return {
        REFERENCE: [
            sys.executable, "-c", f"import can\nfor m in can.LogReader({str(log)!r}): pass"],
        "tankviz ids": [*tankviz, "ids", str(log), *dbcs, "-q"],
        "tankviz bits --id": [*tankviz, "bits", str(log), "--id", "can0/0x2C4", "-q"],
        "tankviz bits --compare": [*tankviz, "bits", str(log), *dbcs, "--compare",
                                   *windows, "-q"],
        "tankviz find-signal": [*tankviz, "find-signal", str(log), *dbcs, "--like",
                                "can0/SPEED.SPEED", "-q"],
    }



def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--minutes", type=float, default=1.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        log = Path(folder) / "rav4-like.blf"
        frames = rav4_like(args.minutes)
        write_log(iter(frames), log, ".blf")
        ids = {(f.bus, f.arbitration_id) for f in frames}
        print(f"drive: {len(frames):,} frames, {len(ids)} ids, {args.minutes:g} min, "
              f"{log.stat().st_size / 1e6:.1f} MB BLF")
        runs = interleaved({name: timed(argv) for name, argv in
                            commands(log, args.minutes).items()}, args.runs)
    best = {name: min(seconds for seconds, _ in done) for name, done in runs.items()}
    peaks = {name: done[-1][1] for name, done in runs.items()}  # the last run's
    print(f"{'command (best of ' + str(args.runs) + ', wall)':<40}{'s':>8}{'x reference':>13}"
          f"{'peak MB':>10}")
    for name in runs:
        print(f"{name:<40}{best[name]:>8.2f}{best[name] / best[REFERENCE]:>13.2f}"
              f"{peaks[name]:>10.0f}")
    print(f"find-signal goal: <= 60 s for 60 s of this drive on a 2-core machine: "
          f"{'ok' if best['tankviz find-signal'] <= 60 * args.minutes else 'MISSED'}")


if __name__ == "__main__":
    main()
