#!/usr/bin/env python3
"""Issues #15 and #26's table and #36's budgets as Markdown: run the benchmarks, write one
comparable report.

Runs ``tools/bench_convert.py`` (in a subprocess, with every argument this script does not know
passed on, e.g. ``--quick`` or ``--frames 5000``; its output is shown as it runs) and, with
``--live``, ``tools/bench_live.py --quick`` too, then writes Markdown to ``--out`` (default
``bench-report.md``):

- a header: date (UTC), machine (host, CPU model, cores, Python), the git commit of this
  checkout (``+ uncommitted changes`` when ``git status --porcelain`` lists any), the 1-minute
  load average before, during (bench_convert's range) and after, and the commands run;
- the table ``| measure | now | goal | ok |``: bench_convert's ratios (convert with the scene and
  raw + decoded vs the naive converter, vs bare reading, archive size / BLF size, the share of a
  short convert spent importing, RSS growth, one hour of driving) and, with ``--live``, every
  bench_live row that has a target plus its CPU references and garbage-collection pauses;
- issue #36's budgets (unless ``--no-budgets``), before (the code at ``--budgets-before``,
  default 304ae15, the revision #36 starts from) and now, each with its goal, met or not,
  measured by the benches' own functions, and printed at the end too: the archive (raw and
  full archive / the log, ``tools/bench_size.py``, on the simulated BLF, the highway car and a
  Toyota candump), the reading process (LogSource's own CPU over python-can's reader,
  ``tools/bench_reading.py``) and start-up (a short convert / its imports and ``tankviz
  --help``, ``tools/bench_startup.py``); ``--quick`` or ``--budget-frames``,
  ``--budget-seconds``, ``--budget-runs`` make them smaller;
- bench_live's whole table (with ``--live``) and bench_convert's details, verbatim.

With ``--before REV`` the same benchmarks also measure the code at git revision REV, checked out
into a temporary worktree (these tools, their fixed references, measure both: the worktree's
``bridge`` comes first, on ``PYTHONPATH`` and as the working folder), and the table gets a
``before`` column, and ``tankviz convert`` of both runs on the same log, interleaved (the most
direct before/after); with ``--scene``, ``tools/bench_scene.py --ref REV`` adds the scene tick of
both (issue #26's table: ``--before a6fe390``, the code before it).

The figures are ratios measured in one run (on CPU time unless bench_convert's ``--clock wall``
is passed on); the load average says how noisy that run was.

    python tools/bench_report.py --out before.md --quick
    python tools/bench_report.py --out after.md --live
    python tools/bench_report.py --out issue26.md --before a6fe390 --scene --live --quick \\
        --clock cpu
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

TOOLS = Path(__file__).resolve().parent
sys.path.insert(0, str(TOOLS))
from benchlib import ROOT, add_workdir, interleaved, revision_env, worktree  # noqa: E402

#: bench_live rows that go into the main table even though they have no target.
LIVE_EXTRA = ("reference: the pipeline alone", "garbage collections")


def cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit(repo: Path) -> str:
    """The checkout's commit, ``+ uncommitted changes`` when the tree differs (read-only git)."""
    try:
        head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], check=True,
                              capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain"], check=True,
                               capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head + (" + uncommitted changes" if dirty else "")


def live_table(text: str) -> list[tuple[str, str, str, str]]:
    """The rows (metric, value, target, ok?) of bench_live's printed table.

    The columns are found from the positions of its header ``metric  value  target  ok?``; the
    table ends at the first empty line after the dashed rule."""
    lines = text.splitlines()
    at = next((i for i, line in enumerate(lines) if line.startswith("metric")
               and all(h in line for h in ("value", "target", "ok?"))), None)
    if at is None:
        return []
    cols = [lines[at].index(h) for h in ("value", "target", "ok?")]
    rows = []
    for line in lines[at + 2:]:
        if not line.strip():
            break
        cells = (line[:cols[0]], line[cols[0]:cols[1]], line[cols[1]:cols[2]], line[cols[2]:])
        metric, value, target, ok = (c.strip() for c in cells)
        rows.append((metric, value, target, ok))
    return rows


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown(convert: dict[str, Any], live: list[tuple[str, str, str, str]] | None,
             live_text: str | None, header: dict[str, str],
             before: dict[str, Any] | None = None,
             live_before: list[tuple[str, str, str, str]] | None = None,
             scene: list[tuple[str, str, str, str, str]] | None = None,
             budgets: list[str] | None = None) -> str:
    """The report: header, the table (with a ``before`` column when the code at ``--before``
    was measured too), issue #36's budgets (``budgets``: :func:`budgets_markdown`), the live
    table and the details."""
    out = ["# tankviz speed and size", ""]
    out += [f"- **{k}:** {v}" for k, v in header.items()]
    out += ["", "Every figure is a ratio against reference code run in the same run, "
            "interleaved, best of the runs.", ""]
    was: dict[str, str] = {}
    if before is not None:
        was = {r["measure"]: r["now"] for r in before["rows"]}
        for metric, value, _, _ in live_before or []:
            was[f"live (bench_live --quick): {metric.strip()}"] = value
        out += ["| measure (same run, same machine) | before | now | goal | ok |",
                "|---|---|---|---|---|"]
    else:
        out += ["| measure (same run, same machine) | now | goal | ok |", "|---|---|---|---|"]

    def line(measure: str, now: str, goal: str, ok: str) -> str:
        cells = [measure, *([was.get(measure, "")] if before is not None else []), now, goal]
        return "| " + " | ".join(_cell(c) for c in cells) + f" | {ok} |"

    for r in convert["rows"]:
        ok = "" if r["ok"] is None else "ok" if r["ok"] else "**missed**"
        out.append(line(r["measure"], r["now"], r["goal"], ok))
    for measure, old, now, goal, ok in scene or []:
        was[measure] = old
        out.append(line(measure, now, goal, ok))
    if live is not None:
        for metric, value, target, ok in live:
            name = metric.strip()
            if target or any(name.startswith(e) for e in LIVE_EXTRA):
                ok_cell = "ok" if ok == "ok" else "**missed**" if ok else ""
                out.append(line(f"live (bench_live --quick): {name}", value, target, ok_cell))
        cpu = _live_ratio(live_before, live) if live_before is not None else None
        if cpu is not None:
            out.append(line("live bridge CPU, now / before", f"{cpu:.2f}x", "≤ 0.7x",
                            "ok" if cpu <= 0.7 else "**missed**"))
    if budgets:
        out += ["", *budgets]
    if live is not None:
        out += ["", "## Live: tools/bench_live.py --quick", "",
                "| metric | value | target | ok? |", "|---|---|---|---|"]
        out += [f"| {_cell(m)} | {_cell(v)} | {_cell(t)} | {o} |" for m, v, t, o in live]
        if not live and live_text is not None:
            out += ["", "bench_live printed no table; its output:", "", "```text",
                    live_text.rstrip(), "```"]
    out += ["", "## Details: tools/bench_convert.py", "", "```text",
            *convert["details"], "```", ""]
    if before is not None:
        out += ["## Details: tools/bench_convert.py on the code before", "", "```text",
                *before["details"], "```", ""]
    return "\n".join(out)


#: bench_live's row of the bridge's own CPU
LIVE_CPU = "bridge CPU (process - senders - harness)"


def _live_ratio(before: list[tuple[str, str, str, str]],
                now: list[tuple[str, str, str, str]]) -> float | None:
    """The bridge's CPU now / before, from two bench_live tables."""
    def percent(rows: list[tuple[str, str, str, str]]) -> float | None:
        for metric, value, _, _ in rows:
            if metric.strip() == LIVE_CPU:
                try:
                    return float(value.split("%")[0])
                except ValueError:
                    return None
        return None

    a, b = percent(before), percent(now)
    return b / a if a and b is not None else None


def run_convert(convert_args: list[str], env: dict[str, str] | None = None,
                cwd: Path | None = None) -> dict[str, Any] | None:
    """bench_convert's JSON result (None when it failed). ``env`` and ``cwd``: those of the
    code measured (``python -m bridge`` takes the package of the working folder first)."""
    with tempfile.TemporaryDirectory() as tmp:
        result = Path(tmp) / "convert.json"
        command = [sys.executable, str(TOOLS / "bench_convert.py"), *convert_args,
                   "--json", str(result)]
        proc = subprocess.run(command, env=env, cwd=cwd)
        if proc.returncode != 0 or not result.is_file():
            return None
        data: dict[str, Any] = json.loads(result.read_text())
        return data


def run_live(env: dict[str, str] | None = None, cwd: Path | None = None
             ) -> tuple[list[tuple[str, str, str, str]], str]:
    live_proc = subprocess.run([sys.executable, str(TOOLS / "bench_live.py"), "--quick"],
                               capture_output=True, text=True, env=env, cwd=cwd)
    print(live_proc.stdout, end="")
    if live_proc.returncode != 0:
        print(live_proc.stderr, file=sys.stderr, end="")
    return live_table(live_proc.stdout), live_proc.stdout


def run_scene(rev: str) -> list[tuple[str, str, str, str, str]]:
    """bench_scene's ms per tick before (``rev``) and now, as table rows (measure, before, now,
    goal, ok)."""
    proc = subprocess.run([sys.executable, str(TOOLS / "bench_scene.py"), "--ref", rev,
                           "--clock", "cpu", "--repeat", "3", "--duration", "30"],
                          capture_output=True, text=True)
    print(proc.stdout, end="")
    rows = []
    for found in re.finditer(r"^(\w+)\s+\d+ ticks: reference ([\d.]+) ms/tick, current "
                             r"([\d.]+) ms/tick, ratio [\d.]+; (.*)$", proc.stdout, re.M):
        drive, old, new, same = found.groups()
        share = float(new) / float(old)
        rows.append((f"scene tick, {drive} (bench_scene, ms a tick; {same})", old,
                     f"{new} ({share:.2f}x)", "≤ 0.5x",
                     "ok" if share <= 0.5 and same == "same bytes" else "**missed**"))
    return rows


def cpu_and_wall(command: list[str], cwd: Path, env: dict[str, str] | None
                 ) -> tuple[float, float]:
    """``command`` run in ``cwd``: its CPU seconds (user + system, its children's too) and
    wall seconds."""
    import resource

    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    subprocess.run(command, cwd=cwd, env=env, check=True, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    done = resource.getrusage(resource.RUSAGE_CHILDREN)
    return done.ru_utime + done.ru_stime - used.ru_utime - used.ru_stime, wall


def run_ab(old: Path, env: dict[str, str], seconds: float = 60.0,
           runs: int = 3) -> list[tuple[str, str, str, str, str]]:
    """``tankviz convert`` of the code before (its worktree ``old``) and now on the same log
    (``seconds`` of the simulated ecocar drive, BLF), interleaved, best of ``runs``: CPU (user +
    system of the convert and its read-ahead) and wall seconds, as rows (measure, before, now,
    goal, ok). The most direct before/after there is: no reference between them."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        log, out = Path(tmp) / "drive.blf", Path(tmp) / "out.mcap"
        subprocess.run([sys.executable, "-m", "bridge", "simulate", "-o", str(log),
                        "--duration", f"{seconds:g}"], cwd=TOOLS.parent, check=True,
                       stdout=subprocess.DEVNULL)
        for kind, extra in (("raw + decoded", ["--dbc", "ecocar"]),
                            ("with the scene", ["--profile", "ecocar"])):
            command = [sys.executable, "-m", "bridge", "convert", str(log), "-o", str(out),
                       "--force", "--quiet", *extra]
            runs_of = interleaved({"before": partial(cpu_and_wall, command, old, env),
                                   "now": partial(cpu_and_wall, command, TOOLS.parent, None)},
                                  runs)
            (cpu_old, wall_old), (cpu_new, wall_new) = (
                (min(c for c, _ in runs_of[name]), min(w for _, w in runs_of[name]))
                for name in ("before", "now"))
            rows.append((f"tankviz convert {kind}, {seconds:g} s simulated (s, best of {runs}; "
                         "cpu, wall)",
                         f"{cpu_old:.2f}, {wall_old:.2f}",
                         f"{cpu_new:.2f}, {wall_new:.2f} ({cpu_old / cpu_new:.2f}x cpu, "
                         f"{wall_old / wall_new:.2f}x wall faster)", "", ""))
    return rows

#: The revision issue #36 starts from: the ``before`` of its budgets.
BUDGETS_BEFORE = "304ae15"
#: A row of the budgets' table: (budget, before, now, goal, met).
Budget = tuple[str, str, str, str, str]


def _met(value: float, goal: float, *, below: bool = False) -> str:
    return "ok" if (value < goal if below else value <= goal) else "**missed**"


def run_budgets(rev: str | None, workdir: Path, frames: int, seconds: float,
                runs: int) -> list[Budget]:
    """Issue #36's three budgets, before (the code at ``rev``, when given) and now, with the
    benches' own measuring code: the archive (tools/bench_size.py: raw and full archive / the
    log, on the simulated ecocar BLF of ``frames`` frames, ``seconds`` of the highway car and of
    a Toyota candump), the reading process (tools/bench_reading.py: LogSource's own CPU over
    python-can's reader, per format, ``frames`` frames, LogSource of ``rev`` interleaved in the
    same process) and start-up (tools/bench_startup.py: a short convert / its imports, and
    ``tankviz --help``, ``rev``'s in its worktree, interleaved); best of ``runs``."""
    import bench_reading
    import bench_size
    import bench_startup

    def was(value: float | None) -> str:
        return "—" if value is None else f"{value:.2f}x"

    old = worktree(rev) if rev else None
    env = revision_env(rev) if rev else None
    rows: list[Budget] = []
    print("#36 budgets: archive size (tools/bench_size.py)", flush=True)
    for name, log, full in bench_size.budget_drives(workdir, frames, seconds):
        raw_now, full_now = bench_size.archive_ratios(log, full, workdir, cwd=ROOT)
        raw_old, full_old = (bench_size.archive_ratios(log, full, workdir, env, old)
                             if old is not None else (None, None))
        rows.append((f"archive, full (raw + decoded + scene) / log: {name}", was(full_old),
                     f"{full_now:.2f}x", "≤ 4.0x", _met(full_now, 4.0)))
        rows.append((f"archive, raw / log: {name}", was(raw_old), f"{raw_now:.2f}x", "≤ 1.0x",
                     _met(raw_now, 1.0)))
    print("#36 budgets: the reading process (tools/bench_reading.py)", flush=True)
    old_source = bench_reading.log_source_at(rev) if rev else None
    labels = {"blf": "BLF", "asc": "ASC", "log": "candump"}
    for fmt, path in bench_reading.logs(workdir, frames).items():
        best, n = bench_reading.measure(path, runs, old_source, "before", packing=False)
        now = bench_reading.overhead(best)
        then = bench_reading.overhead(best, "before") if old_source is not None else None
        rows.append((f"reading, LogSource's own CPU / python-can's reader: {labels[fmt]}, "
                     f"{n:,} simulated frames", was(then), f"{now:.2f}x",
                     f"≤ {bench_reading.GOAL}x", _met(now, bench_reading.GOAL)))
    print("#36 budgets: start-up (tools/bench_startup.py)", flush=True)
    cpu, wall, meta = bench_startup.measure(runs=runs, ref=rev, workdir=workdir)
    ratio = cpu["convert"] / cpu["imports"]
    rows.append((f"start, a short convert ({meta['frames']:,} frames, --dbc ecocar) / "
                 "python -c 'import can, cantools, mcap_protobuf.writer' (CPU)",
                 was(cpu[f"convert at {rev}"] / cpu["imports"] if rev else None),
                 f"{ratio:.2f}x", f"≤ {bench_startup.RATIO_GOAL}x",
                 _met(ratio, bench_startup.RATIO_GOAL)))
    help_then = (f"{cpu[f'help at {rev}']:.3f} s ({wall[f'help at {rev}']:.3f} s wall)"
                 if rev else "—")
    rows.append(("start, tankviz --help (CPU seconds; wall)", help_then,
                 f"{cpu['help']:.3f} s ({wall['help']:.3f} s wall)",
                 f"< {bench_startup.HELP_GOAL_S} s",
                 _met(cpu["help"], bench_startup.HELP_GOAL_S, below=True)))
    return rows


def budgets_markdown(rows: list[Budget], rev: str | None) -> list[str]:
    """The budgets' table, under its heading."""
    before = f"the code at {rev}" if rev else "not measured"
    out = [f"## Issue #36's budgets: before ({before}) and now", "",
           "| budget (same run, same machine) | before | now | goal | met |",
           "|---|---|---|---|---|"]
    out += ["| " + " | ".join(_cell(c) for c in row[:4]) + f" | {row[4]} |" for row in rows]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0] if __doc__ else None,
        epilog="Other arguments go to tools/bench_convert.py (see its --help).")
    parser.add_argument("--out", type=Path, default=Path("bench-report.md"),
                        help="the Markdown file to write (bench-report.md)")
    parser.add_argument("--live", action="store_true",
                        help="also run tools/bench_live.py --quick (about a minute)")
    parser.add_argument("--before", metavar="REV",
                        help="also measure the code at git revision REV: a before column")
    parser.add_argument("--ab-seconds", type=float, default=60.0,
                        help="with --before: seconds of the log both convert (60)")
    parser.add_argument("--ab-runs", type=int, default=3,
                        help="with --before: rounds of those converts, best of (3)")
    parser.add_argument("--scene", action="store_true",
                        help="with --before: tools/bench_scene.py --ref REV too")
    parser.add_argument("--quick", action="store_true",
                        help="smaller budgets (and bench_convert --quick, passed on)")
    add_workdir(parser, "where logs are cached and outputs written (passed on too)")
    parser.add_argument("--no-budgets", action="store_true", help="leave issue #36's budgets out")
    parser.add_argument("--budgets-before", metavar="REV", default=BUDGETS_BEFORE,
                        help=f"the budgets' before: git revision REV ({BUDGETS_BEFORE})")
    parser.add_argument("--budget-frames", type=int, metavar="N",
                        help="simulated frames of the archive and reading budgets "
                        "(200,000; --quick 50,000)")
    parser.add_argument("--budget-seconds", type=float, metavar="S",
                        help="seconds of the highway car and the Toyota (60; --quick 20)")
    parser.add_argument("--budget-runs", type=int, metavar="N",
                        help="interleaved rounds of the budgets' timings, best of (5; --quick 3)")
    args, convert_args = parser.parse_known_args(argv)
    convert_args += ["--workdir", str(args.workdir), *(["--quick"] if args.quick else [])]
    load_before = os.getloadavg()[0]
    started = datetime.datetime.now(datetime.timezone.utc)
    before: dict[str, Any] | None = None
    live_before: list[tuple[str, str, str, str]] | None = None
    scene: list[tuple[str, str, str, str, str]] | None = None
    env: dict[str, str] | None = None
    if args.before is not None:
        old = worktree(args.before)
        env = revision_env(args.before)
        before = run_convert(convert_args, env, old)
        if before is None:
            print(f"error: tools/bench_convert.py failed on {args.before}", file=sys.stderr)
            return 1
    convert = run_convert(convert_args, cwd=TOOLS.parent)
    if convert is None:
        print("error: tools/bench_convert.py failed", file=sys.stderr)
        return 1
    live: list[tuple[str, str, str, str]] | None = None
    live_text: str | None = None
    commands = ["tools/bench_convert.py " + " ".join(convert_args)]
    if args.live:
        if args.before is not None:
            live_before, _ = run_live(env, old)
        live, live_text = run_live(cwd=TOOLS.parent)
        commands.append("tools/bench_live.py --quick")
    if args.before is not None:
        scene = run_ab(old, env or {}, args.ab_seconds, args.ab_runs)
    if args.scene and args.before is not None:
        scene = (scene or []) + run_scene(args.before)
        commands.append(f"tools/bench_scene.py --ref {args.before} --clock cpu")
    budgets: list[str] | None = None
    if not args.no_budgets:
        rev: str | None = args.budgets_before
        try:
            worktree(args.budgets_before)
        except subprocess.CalledProcessError:
            print(f"warning: no git revision {args.budgets_before} here (a shallow clone?): "
                  "the budgets are measured now only", file=sys.stderr)
            rev = None
        frames = args.budget_frames or (50_000 if args.quick else 200_000)
        seconds = args.budget_seconds or (20.0 if args.quick else 60.0)
        runs = args.budget_runs or (3 if args.quick else 5)
        budgets = budgets_markdown(run_budgets(rev, args.workdir, frames, seconds, runs), rev)
        commands.append(f"issue #36's budgets: {frames:,} frames, {seconds:g} s, best of {runs}, "
                        f"before {rev or '—'} (tools/bench_size.py, bench_reading.py, "
                        "bench_startup.py)")
    lo, hi = convert["load"]
    header = {
        "date": started.strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{platform.node()}, {cpu_model()}, {os.cpu_count()} cores, "
                   f"Python {platform.python_version()} ({platform.machine()})",
        "git commit": git_commit(TOOLS.parent),
        **({"before": f"{args.before} (measured in the same run, by the same tools)"}
           if args.before else {}),
        "load average (1 min)": f"{load_before:.2f} before, {lo:.2f}..{hi:.2f} during the "
                                f"convert runs, {os.getloadavg()[0]:.2f} after "
                                f"({os.cpu_count()} cores)",
        "runs": f"best of {convert['runs']}, interleaved, {convert['clock']} time; "
                f"frames {convert['frames'][0]:,} "
                f"(simulated), {convert['frames'][1]:,} (longer drive), "
                f"{convert['frames'][2]:,} (real-format log)",
        "commands": "; ".join(f"`{c.strip()}`" for c in commands),
    }
    args.out.write_text(markdown(convert, live, live_text, header, before, live_before, scene,
                                 budgets))
    if budgets:
        print("", *budgets, sep="\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
