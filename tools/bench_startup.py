#!/usr/bin/env python3
"""Benchmark issue #36's start-up budget: a short ``tankviz convert`` against its imports alone.

It converts ``bridge/sim``'s ecocar drive cut to ``--frames`` frames (default 1,123, a BLF cached
by ``benchlib.ecocar_log``) with ``--dbc ecocar`` and the default options, each run a new process
(tankviz's bytecode compiled first, as pip installs it), and times them interleaved (A, B, C, A,
B, C, ...), best of ``--runs`` (default 7), in CPU time (user + system, the process and its
children: a read-ahead process counts):

- ``imports``: ``python -c "import can, cantools, mcap_protobuf.writer"``, the yardstick;
- ``convert``: ``tankviz convert LOG -o OUT --dbc ecocar --quiet --force``;
- ``help``: ``tankviz --help`` (goal: under 0.1 s; its wall time too);
- ``interpreter``: ``python -c pass``.

It prints each one's best CPU seconds, the ratio convert / imports (goal ≤ 1.5x) and, with
``--ref REV``, the same convert and ``--help`` at a git revision (a worktree of it,
``benchlib.revision_env``), interleaved with the others, and its ratio. The database cache
(``$XDG_CACHE_HOME/tankviz``) is warmed before the clock starts (``--cold``: a fresh empty cache
folder for every run instead).

    python tools/bench_startup.py
    python tools/bench_startup.py --runs 11 --ref main
"""

from __future__ import annotations

import argparse
import compileall
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchlib import ROOT, WORKDIR, ecocar_log, interleaved, revision_env, worktree

#: The frames of the short drive: the issue's example (about half a second of the ecocar).
FRAMES = 1_123
#: Goals: convert / imports, and ``tankviz --help`` in CPU seconds.
RATIO_GOAL = 1.5
HELP_GOAL_S = 0.1
IMPORTS = "import can, cantools, mcap_protobuf.writer"


def timed(command: list[str], env: Mapping[str, str] | None = None, cwd: Path = ROOT
          ) -> Callable[[], tuple[float, float]]:
    """A run of ``command`` in a new process in ``cwd`` (``python -m bridge`` imports the
    ``bridge`` there first): its CPU seconds (user + system, its children's included) and its
    wall seconds; a failure ends the benchmark."""
    def run() -> tuple[float, float]:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        started = time.perf_counter()
        done = subprocess.run(command, env=dict(env) if env is not None else None, cwd=cwd,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        wall = time.perf_counter() - started
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if done.returncode != 0:
            raise SystemExit(f"failed ({done.returncode}): {' '.join(command)}\n"
                             + done.stderr.decode(errors="replace"))
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return cpu, wall
    return run


def measure(frames: int = FRAMES, runs: int = 7, ref: str | None = None, cold: bool = False,
            workdir: Path = WORKDIR, *, say: bool = False
            ) -> tuple[dict[str, float], dict[str, float], dict[str, Any]]:
    """Every contender's best CPU and best wall seconds, interleaved, best of ``runs`` (each
    warmed once first), and the log's statistics (``benchlib.ecocar_log``). With ``ref``,
    ``convert at REF`` and ``help at REF`` run the code of that git revision (its worktree).
    ``say``: print the heading before the clock starts."""
    log, meta = ecocar_log(workdir, frames)
    out = workdir / "startup"
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(tempfile.mkdtemp(prefix="tankviz-bench-cache-"))
    env = os.environ | {"XDG_CACHE_HOME": str(cache)}
    python = sys.executable

    def convert(output: Path) -> list[str]:
        return [python, "-m", "bridge", "convert", str(log), "-o", str(output), "--dbc",
                "ecocar", "--quiet", "--force"]

    contenders: dict[str, Callable[[], tuple[float, float]]] = {
        "interpreter": timed([python, "-c", "pass"]),
        "imports": timed([python, "-c", IMPORTS]),
        "convert": timed(convert(out / "now.mcap"), env),
        "help": timed([python, "-m", "bridge", "--help"]),
    }
    if cold:
        def cold_convert() -> tuple[float, float]:
            with tempfile.TemporaryDirectory(prefix="tankviz-bench-cold-") as fresh:
                fresh_env = os.environ | {"XDG_CACHE_HOME": fresh}
                return timed(convert(out / "now.mcap"), fresh_env)()
        contenders["convert"] = cold_convert
    compileall.compile_dir(str(ROOT / "bridge"), quiet=1)  # as pip installs it
    if ref:
        tree = worktree(ref)
        compileall.compile_dir(str(tree / "bridge"), quiet=1)
        ref_env = revision_env(ref) | {"XDG_CACHE_HOME": str(cache)}
        contenders[f"convert at {ref}"] = timed(convert(out / "ref.mcap"), ref_env, tree)
        contenders[f"help at {ref}"] = timed([python, "-m", "bridge", "--help"], ref_env, tree)
    for run in contenders.values():  # warm: the page cache, bytecode, the database cache
        run()
    if say:
        print(f"tankviz start-up (issue #36): {log.name}, {meta['frames']:,} frames, --dbc "
              f"ecocar; best of {runs} interleaved runs, CPU seconds (user + system)", flush=True)
    results = interleaved(contenders, runs)
    best = {name: min(cpu for cpu, _ in done) for name, done in results.items()}
    walls = {name: min(wall for _, wall in done) for name, done in results.items()}
    return best, walls, meta


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--frames", type=int, default=FRAMES, help=f"frames ({FRAMES:,})")
    parser.add_argument("--runs", type=int, default=7, help="interleaved rounds, best of (7)")
    parser.add_argument("--ref", metavar="REV", help="also time the convert at git revision REV")
    parser.add_argument("--cold", action="store_true",
                        help="an empty database cache for every convert (the first run's cost)")
    parser.add_argument("--workdir", type=Path, default=WORKDIR,
                        help="where the log is cached and outputs written")
    args = parser.parse_args(argv)
    best, walls, _ = measure(args.frames, args.runs, args.ref, args.cold, args.workdir, say=True)
    for name, cpu in best.items():
        print(f"  {name:<28}{cpu:7.3f} s cpu  {walls[name]:7.3f} s wall")
    ratio = best["convert"] / best["imports"]
    ok = "ok" if ratio <= RATIO_GOAL else "MISSED"
    print(f"convert / imports ({'cold cache' if args.cold else 'warm cache'}): {ratio:.2f}x  "
          f"goal ≤ {RATIO_GOAL}x  {ok}")
    if args.ref:
        then = best[f"convert at {args.ref}"] / best["imports"]
        print(f"convert at {args.ref} / imports: {then:.2f}x")
    help_ok = "ok" if best["help"] < HELP_GOAL_S else "MISSED"
    print(f"tankviz --help: {best['help']:.3f} s cpu, {walls['help']:.3f} s wall  "
          f"goal < {HELP_GOAL_S} s  {help_ok}")
    print(f"1-min load average: {os.getloadavg()[0]:.2f} ({os.cpu_count()} cores)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
