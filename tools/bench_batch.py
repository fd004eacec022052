"""Benchmark ``tankviz batch`` (a report, not a test): ``--drives`` simulated ecocar drives (seeds
and fault scenarios, BLF logs cached in ``--workdir``) converted with the ecocar profile through
the very task of ``tankviz batch`` on a local Dask cluster of 1 worker and of N (default: the
cores), timed from the first task submitted to the last result (the cluster's start apart),
the worker counts in turn (:func:`benchlib.interleaved`; ``--runs`` rounds, the fastest kept).
It prints the speed-up per added core, then the table; on a shared machine the figures say what
the machine gave, not what the code can do.

    python tools/bench_batch.py                 # 8 drives of 20 s, 1 vs all cores
    python tools/bench_batch.py --drives 16 --duration 60 --workers 4
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import interleaved

from bridge.fleet.batch import (
    ConvertJob,
    Settings,
    convert_task,
    dask_client,
    run_batch,
)
from bridge.pipeline.convert import convert
from bridge.sim.ecocar import simulate
from bridge.sim.scenario import SCENARIOS
from bridge.sinks.can_log_writer import write_log


def make_drives(folder: Path, count: int, duration: float) -> list[Path]:
    """``count`` simulated drives as BLF logs (cached in ``folder``)."""
    folder.mkdir(parents=True, exist_ok=True)
    scenarios = list(SCENARIOS)
    logs = []
    for i in range(count):
        scenario = scenarios[i % len(scenarios)]
        log = folder / f"drive{i:03d}_{scenario}_{duration:g}s.blf"
        if not log.exists():
            write_log(simulate(duration_s=duration, seed=i, scenario=scenario), log, ".blf")
        logs.append(log)
    return logs


def run(logs: list[Path], out: Path, workers: int) -> dict[str, float]:
    out.mkdir(parents=True, exist_ok=True)
    jobs = [ConvertJob(log.stem, (str(log),), str(out / f"{log.stem}.mcap")) for log in logs]
    task = functools.partial(convert_task, convert=convert,
                             settings=Settings((), "ecocar", 20.0, True))
    started = time.perf_counter()
    with dask_client(workers=workers) as client:
        ready = time.perf_counter()
        results = run_batch(client, jobs, task)
        seconds = time.perf_counter() - ready
    failed = [r.error for r in results if r.error]
    if failed:
        sys.exit(f"bench_batch: {len(failed)} drives failed: {failed[0]}")
    frames = sum(r.frames for r in results)
    return {"workers": workers, "drives": len(jobs), "start": ready - started,
            "seconds": seconds, "drives_per_min": len(jobs) / seconds * 60,
            "frames": frames, "frames_per_s": frames / seconds}


def fastest(logs: list[Path], workdir: Path, counts: list[int], runs: int
            ) -> list[dict[str, float]]:
    """:func:`run` for each worker count in turn, ``runs`` rounds: each count's fastest run."""
    done = interleaved({str(n): functools.partial(run, logs, workdir / f"out{n}", n)
                        for n in counts}, runs)
    return [min(rows, key=lambda r: r["seconds"]) for rows in done.values()]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split(":")[0])
    parser.add_argument("--drives", type=int, default=8)
    parser.add_argument("--duration", type=float, default=20.0, help="seconds per drive")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                        help="N, the worker count compared with 1 (default: cores)")
    parser.add_argument("--workdir", type=Path,
                        default=Path(tempfile.gettempdir()) / "tankviz-bench-batch")
    parser.add_argument("--runs", type=int, default=1,
                        help="rounds of every worker count, the fastest kept (1)")
    args = parser.parse_args()
    logs = make_drives(args.workdir / "logs", args.drives, args.duration)
    rows = fastest(logs, args.workdir, sorted({1, args.workers}), args.runs)
    one, many = rows[0], rows[-1]
    speedup = many["seconds"] and one["seconds"] / many["seconds"]
    added = many["workers"] - one["workers"]
    if added:
        print(f"speed-up per added core: {(speedup - 1) / added:.2f} "
              f"({many['workers']:.0f} workers vs 1: {speedup:.2f}x; 1.00 would be linear)")
    print(f"cores {os.cpu_count()}, load average {os.getloadavg()[0]:.1f} at the end; "
          f"{args.drives} drives of {args.duration:g} s")
    print(f"{'workers':>7} {'drives':>6} {'cluster start s':>15} {'seconds':>8} "
          f"{'drives/min':>10} {'frames':>9} {'frames/s':>9}")
    for r in rows:
        print(f"{r['workers']:>7.0f} {r['drives']:>6.0f} {r['start']:>15.1f} {r['seconds']:>8.1f} "
              f"{r['drives_per_min']:>10.1f} {r['frames']:>9,.0f} {r['frames_per_s']:>9,.0f}")


if __name__ == "__main__":
    main()
