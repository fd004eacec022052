"""``tankviz batch``: the work of ``tankviz convert`` over many drives at once, on Dask.

``batch convert`` converts CAN logs and ``batch rederive`` re-derives drives, one Dask task per
drive (grouped and named by :mod:`bridge.fleet.batch`), on a local cluster or at
``--scheduler``; one line per drive, a summary, exit status 0 when every drive is written or
skipped, else 1.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import threading
import time
from pathlib import Path
from typing import TextIO

from bridge.apps.options import Subparsers, add_stage_options, dbc_option
from bridge.decode.database import parse_dbc_option
from bridge.errors import FileError, UsageError, shown
from bridge.fleet.batch import (
    ConvertJob,
    JobResult,
    Running,
    Settings,
    convert_task,
    dashboard,
    dask_client,
    find_inputs,
    finished,
    group_drives,
    input_bytes,
    input_issue_lines,
    plan_jobs,
    progress_line,
    progress_topic,
    refused_inputs,
    run_batch,
    slow_drives,
)
from bridge.io.can_logs import supported_suffixes
from bridge.pipeline.convert import convert


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "batch", help="convert many drives at once, on Dask (local cores or a cluster)",
        description="Run tankviz convert over many drives at once on Dask: one output per "
        "drive in --out; finished outputs are skipped on a re-run (unless --force).")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    for verb, what, help_text in (
            ("convert", "INPUTS", "CAN logs (files, folders searched recursively, globs)"),
            ("rederive", "DRIVES", "tankviz drives (.mcap: files, folders, globs), "
                                   "converted again (e.g. with a fixed profile)")):
        p = verbs.add_parser(verb, help=help_text, description=help_text)
        p.add_argument("inputs", nargs="+", metavar=what, help=help_text)
        p.add_argument("--out", type=Path, required=True, metavar="DIR",
                       help="folder for the outputs, one <drive>.mcap each")
        add_stage_options(p, profile_default=None)
        p.add_argument("--workers", type=int, metavar="N",
                       help="worker processes of the local cluster (default: one per core)")
        p.add_argument("--scheduler", metavar="ADDRESS",
                       help="use the Dask cluster at ADDRESS (tcp://host:8786); inputs and "
                       "--out must then be paths every worker sees")
        p.add_argument("--force", action="store_true",
                       help="convert again drives whose output exists")
        p.set_defaults(run=run)


def _absolute_dbc(text: str) -> str:
    """``--dbc [BUS=]PATH`` with PATH absolute (workers may run elsewhere)."""
    text = dbc_option(text)
    bus, path = parse_dbc_option(text)
    if not path.exists():
        return text
    return f"{bus}={path.absolute()}" if bus else str(path.absolute())


def _settings(args: argparse.Namespace) -> Settings:
    profile = args.profile
    if profile is not None and Path(profile).exists():
        profile = str(Path(profile).absolute())
    return Settings(tuple(_absolute_dbc(t) for t in args.dbc or []), profile, args.scene_rate,
                    args.force, bring_up=args.bring_up)


def _drives(n: int) -> str:
    return f"{n} drive" if n == 1 else f"{n} drives"


def run(args: argparse.Namespace) -> int:
    if args.workers is not None and (args.scheduler or args.workers < 1):
        raise UsageError("--workers", "a number ≥ 1, for the local cluster only (a --scheduler's "
                         "cluster has its own workers)")
    suffixes = supported_suffixes() if args.verb == "convert" else [".mcap"]
    files, refused = refused_inputs(find_inputs(args.inputs, suffixes))
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise FileError(out, "is not a folder")
    settings = _settings(args)
    jobs = plan_jobs(group_drives(files, suffixes, merge=args.verb == "convert"), out)
    todo, skipped = finished(jobs, force=args.force)
    for path, why in refused:  # each a drive that fails: its file cannot be read
        print(f"failed {shown(path)}: {why}")
    for job in skipped:
        print(f"skipped {shown(job.output)}: finished already (--force converts it again)")
    started = time.monotonic()
    results: list[JobResult] = []
    if todo:
        try:
            out.mkdir(parents=True, exist_ok=True)
            for job in todo:
                Path(job.output).parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FileError(out, f"cannot write: {exc.strerror or exc}") from None
        results = _run(args, todo, settings)
    failed = [r for r in results if r.error is not None]
    written = len(results) - len(failed)
    frames = sum(r.frames for r in results)
    seconds = time.monotonic() - started
    rate = frames / seconds if seconds > 0 else 0.0
    total, failures = len(jobs) + len(refused), len(failed) + len(refused)
    print(f"{_drives(total)}: {written} written, {len(skipped)} skipped, {failures} failed; "
          f"{frames:,} frames in {seconds:.1f} s ({rate:,.0f} frames/s)")
    for line in input_issue_lines(results):
        print(line)
    if failures:
        print(f"error: {failures} of {_drives(total)} failed", file=sys.stderr)
        return 1
    return 0


class _BatchProgress:
    """The batch's one progress line on a terminal, from drives finished and the progress events
    of the drives under way; and each drive's line as it finishes."""

    def __init__(self, todo: list[ConvertJob], stream: TextIO | None = None, hz: float = 5.0
                 ) -> None:
        self.stream = stream if stream is not None else sys.stderr  # (the one of the moment)
        self.tty = self.stream.isatty()
        self.total = len(todo)
        # (by output as shown: the progress events name it so)
        self.sizes = {shown(j.output): input_bytes(j) for j in todo}
        self.names = {shown(j.output): shown(j.name) for j in todo}
        self.total_bytes = sum(self.sizes.values()) or 1
        self.running: dict[str, tuple[int, float]] = {}
        #: when each drive under way sent its first event
        self.since: dict[str, float] = {}
        self.finished: set[str] = set()
        self.done = self.failed = self.frames = self.bytes = 0
        #: input bytes and seconds (on their workers) of the drives written: their throughput
        self.written_bytes = 0
        self.written_seconds = 0.0
        self.started = time.monotonic()
        self._interval = 1.0 / hz
        self._last = 0.0
        self._lock = threading.Lock()

    def _line(self) -> str:
        frames = self.frames + sum(f for f, _ in self.running.values())
        done_bytes = self.bytes + sum(fraction * self.sizes.get(output, 0)
                                      for output, (_, fraction) in self.running.items())
        now = time.monotonic()
        slow = slow_drives([Running(self.names.get(output, output), now - since,
                                    self.sizes.get(output, 0))
                            for output, since in self.since.items()],
                           done_bytes=self.written_bytes, done_seconds=self.written_seconds)
        return progress_line(done=self.done, failed=self.failed, total=self.total,
                             frames=frames, elapsed=now - self.started,
                             fraction=done_bytes / self.total_bytes, slow=slow)

    def _draw(self) -> None:
        if self.tty:
            self.stream.write("\r\033[K" + self._line())
            self.stream.flush()

    def progress(self, output: str, frames: int, fraction: float | None) -> None:
        with self._lock:
            if output in self.finished:  # an event that came after its drive's result
                return
            self.running[output] = (frames, fraction or 0.0)
            now = time.monotonic()
            self.since.setdefault(output, now)
            if now - self._last >= self._interval:
                self._last = now
                self._draw()

    def result(self, result: JobResult) -> None:
        job = result.job
        output = shown(job.output)
        with self._lock:
            self.running.pop(output, None)
            self.since.pop(output, None)
            self.finished.add(output)
            self.done += 1
            self.frames += result.frames
            self.bytes += self.sizes.get(output, 0)
            if self.tty:
                self.stream.write("\r\033[K")
                self.stream.flush()
            if result.error is None:
                self.written_bytes += self.sizes.get(output, 0)
                self.written_seconds += result.seconds
                worker = f" on worker {result.worker}" if result.worker else ""
                damaged = (f"; {result.issues:,} input "
                           f"{'issue' if result.issues == 1 else 'issues'}"
                           if result.issues else "")
                print(f"wrote {output}: {result.frames:,} frames from "
                      f"{', '.join(map(shown, job.inputs))} in {result.seconds:.1f} s{worker}"
                      f"{damaged}", flush=True)
                for text in result.warnings:
                    print(f"  warning: {text}", flush=True)
            else:
                self.failed += 1
                print(f"failed {output}: {result.error}", flush=True)
            self._draw()

    def close(self) -> None:
        with self._lock:
            if self.tty:
                self.stream.write("\n")
                self.stream.flush()


def _run(args: argparse.Namespace, todo: list[ConvertJob], settings: Settings) -> list[JobResult]:
    topic = progress_topic()
    task = functools.partial(convert_task, convert=convert,
                             settings=dataclasses.replace(settings, progress_topic=topic))
    with dask_client(workers=args.workers, scheduler=args.scheduler) as client:
        where = (f"the Dask scheduler {args.scheduler}" if args.scheduler
                 else f"a local Dask cluster of {len(client.scheduler_info()['workers'])} "
                      "worker processes")
        print(f"batch: {_drives(len(todo))} on {where}", file=sys.stderr)
        print(dashboard(client), file=sys.stderr)
        bar = _BatchProgress(todo)
        try:
            return run_batch(client, todo, task, bar.result, topic=topic,
                             on_progress=bar.progress)
        finally:
            bar.close()
