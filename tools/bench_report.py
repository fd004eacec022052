#!/usr/bin/env python3
"""Issue #15's table as Markdown: run the benchmarks, write one report a reader can compare.

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
- bench_live's whole table (with ``--live``) and bench_convert's details, verbatim.

The figures are ratios measured in one run (on CPU time unless bench_convert's ``--clock wall``
is passed on); the load average says how noisy that run was.

    python tools/bench_report.py --out before.md --quick
    python tools/bench_report.py --out after.md --live
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

TOOLS = Path(__file__).resolve().parent
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
             live_text: str | None, header: dict[str, str]) -> str:
    """The report: header, the table, the live table and the details."""
    out = ["# tankviz speed and size (issue #15)", ""]
    out += [f"- **{k}:** {v}" for k, v in header.items()]
    out += ["", "Every figure is a ratio against reference code run in the same run, "
            "interleaved, best of the runs.", "",
            "| measure (same run, same machine) | now | goal | ok |", "|---|---|---|---|"]
    for r in convert["rows"]:
        ok = "" if r["ok"] is None else "ok" if r["ok"] else "**missed**"
        out.append(f"| {_cell(r['measure'])} | {_cell(r['now'])} | {_cell(r['goal'])} | {ok} |")
    if live is not None:
        for metric, value, target, ok in live:
            name = metric.strip()
            if target or any(name.startswith(e) for e in LIVE_EXTRA):
                ok_cell = "ok" if ok == "ok" else "**missed**" if ok else ""
                out.append(f"| live (bench_live --quick): {_cell(name)} | {_cell(value)} | "
                           f"{_cell(target)} | {ok_cell} |")
    if live is not None:
        out += ["", "## Live: tools/bench_live.py --quick", "",
                "| metric | value | target | ok? |", "|---|---|---|---|"]
        out += [f"| {_cell(m)} | {_cell(v)} | {_cell(t)} | {o} |" for m, v, t, o in live]
        if not live and live_text is not None:
            out += ["", "bench_live printed no table; its output:", "", "```text",
                    live_text.rstrip(), "```"]
    out += ["", "## Details: tools/bench_convert.py", "", "```text",
            *convert["details"], "```", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0] if __doc__ else None,
        epilog="Other arguments go to tools/bench_convert.py (see its --help).")
    parser.add_argument("--out", type=Path, default=Path("bench-report.md"),
                        help="the Markdown file to write (bench-report.md)")
    parser.add_argument("--live", action="store_true",
                        help="also run tools/bench_live.py --quick (about a minute)")
    args, convert_args = parser.parse_known_args(argv)
    load_before = os.getloadavg()[0]
    started = datetime.datetime.now(datetime.timezone.utc)
    with tempfile.TemporaryDirectory() as tmp:
        result = Path(tmp) / "convert.json"
        command = [sys.executable, str(TOOLS / "bench_convert.py"), *convert_args,
                   "--json", str(result)]
        proc = subprocess.run(command)
        if proc.returncode != 0 or not result.is_file():
            print(f"error: tools/bench_convert.py failed (status {proc.returncode})",
                  file=sys.stderr)
            return 1
        convert = json.loads(result.read_text())
    live: list[tuple[str, str, str, str]] | None = None
    live_text: str | None = None
    commands = ["tools/bench_convert.py " + " ".join(convert_args)]
    if args.live:
        live_proc = subprocess.run([sys.executable, str(TOOLS / "bench_live.py"), "--quick"],
                                   capture_output=True, text=True)
        live_text = live_proc.stdout
        print(live_text, end="")
        if live_proc.returncode != 0:
            print(live_proc.stderr, file=sys.stderr, end="")
        live = live_table(live_text)
        commands.append("tools/bench_live.py --quick")
    lo, hi = convert["load"]
    header = {
        "date": started.strftime("%Y-%m-%d %H:%M UTC"),
        "machine": f"{platform.node()}, {cpu_model()}, {os.cpu_count()} cores, "
                   f"Python {platform.python_version()} ({platform.machine()})",
        "git commit": git_commit(TOOLS.parent),
        "load average (1 min)": f"{load_before:.2f} before, {lo:.2f}..{hi:.2f} during the "
                                f"convert runs, {os.getloadavg()[0]:.2f} after "
                                f"({os.cpu_count()} cores)",
        "runs": f"best of {convert['runs']}, interleaved, {convert['clock']} time; "
                f"frames {convert['frames'][0]:,} "
                f"(simulated), {convert['frames'][1]:,} (longer drive), "
                f"{convert['frames'][2]:,} (real-format log)",
        "commands": "; ".join(f"`{c.strip()}`" for c in commands),
    }
    args.out.write_text(markdown(convert, live, live_text, header))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
