"""Many drives at once: which files make one drive, what each output is called, and the run of
one conversion per drive on a Dask cluster (``tankviz batch``).

Two drives with one output, or an output that is an input, are refused before anything runs; a
drive that fails gives its one-line error and the others go on; finished outputs are skipped
unless forced, so an interrupted batch resumes. Dask is imported only to run; without it the
error says what to install.
"""

from __future__ import annotations

import contextlib
import datetime
import glob
import importlib.util
import itertools
import logging
import os
import re
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from bridge.errors import BridgeError, UsageError, not_a_file, os_error_text, shown
from bridge.io.can_logs import LogSource

if TYPE_CHECKING:
    from distributed import Client

#: The one line a user without Dask gets.
MISSING_DASK = "runs on Dask, which is not installed: pip install 'tankviz[fleet]'"

#: Two files of one stem are one drive when the later starts at most this long after the earlier
#: ends (a logger's next part, a bus file that starts a little later).
ADJACENT_NS = 60 * 10**9

#: Trailing bus and part suffixes that a drive's files differ by.
_PART = re.compile(r"(?:[_-](?:can|canfd|bus|ch|part)\d+|\.\d{3})+$", re.IGNORECASE)
#: A URL scheme (``s3://``); ``file://`` is a path.
_URL = re.compile(r"^([A-Za-z][A-Za-z0-9+.-]*)://")

Span = tuple[int, int]
"""A file's first and last frame time, integer nanoseconds."""


def format_suffix(path: Path, suffixes: Iterable[str]) -> str | None:
    """The longest of ``suffixes`` the file's name ends with (any case), or None."""
    name = path.name.lower()
    return next((s for s in sorted(suffixes, key=len, reverse=True) if name.endswith(s)), None)


def drive_stem(path: Path, suffixes: Iterable[str]) -> str:
    """The name a drive's files share: without the format suffix and the bus/part suffixes
    (``trip_can0_part003.blf`` → ``trip``); a name that is nothing but such a suffix stays."""
    suffix = format_suffix(path, suffixes) or path.suffix
    base = path.name[:len(path.name) - len(suffix)]
    return _PART.sub("", base) or base


def _refuse_url(text: str) -> None:
    match = _URL.match(text)
    if match and match.group(1).lower() != "file":
        raise UsageError(text, "only local or shared-disk paths work (the CAN log readers "
                         "open files): mount the storage on every machine (NFS, SMB, s3fs, …) "
                         "and name its path")


def find_inputs(patterns: Sequence[str], suffixes: Sequence[str]) -> list[tuple[Path, Path]]:
    """Every file that ``patterns`` (files, folders searched recursively, globs; local paths only,
    a URL is refused) name, with the folder its output's subfolder is counted from; absolute,
    each once, in name order.
    """
    found: dict[Path, Path] = {}
    wanted = ", ".join(suffixes)

    def add_folder(folder: Path) -> int:
        files = [p for p in sorted(folder.rglob("*"))  # (a dangling link too: refused_inputs)
                 if not p.is_dir() and not p.name.startswith(".") and format_suffix(p, suffixes)]
        for p in files:
            found.setdefault(p, folder)
        return len(files)

    for text in patterns:
        _refuse_url(text)
        if text.lower().startswith("file://"):
            text = text[len("file://"):]
        path = Path(text).expanduser().absolute()
        if glob.has_magic(text):
            matches = [Path(m).absolute() for m in sorted(glob.glob(str(path), recursive=True))]
            if not matches:
                raise UsageError(text, "matches no file")
            for m in matches:
                if m.is_dir():
                    add_folder(m)
                elif format_suffix(m, suffixes):
                    found.setdefault(m, m.parent)
        elif path.is_dir():
            if not add_folder(path):
                raise UsageError(text, f"holds no {wanted} file")
        elif os.path.lexists(path):  # (a dangling link or a FIFO too: refused_inputs)
            found.setdefault(path, path.parent)
        else:
            raise UsageError(text, "no such file or folder")
    if not found:
        raise UsageError(" ".join(patterns), f"no {wanted} file found")
    return sorted(found.items())


def refused_inputs(files: Sequence[tuple[Path, Path]]
                   ) -> tuple[list[tuple[Path, Path]], list[tuple[Path, str]]]:
    """The files of :func:`find_inputs` that can be read, and those that cannot with why (a
    symbolic link to nothing, a FIFO: :func:`~bridge.errors.not_a_file`)."""
    usable: list[tuple[Path, Path]] = []
    refused: list[tuple[Path, str]] = []
    for path, base in files:
        why = not_a_file(path)
        if why is None:
            usable.append((path, base))
        else:
            refused.append((path, why))
    return usable, refused


def file_span(path: Path) -> Span:
    """The first and last frame time of a log or drive: from the BLF header or the MCAP summary
    where they tell it, else by reading the file through."""
    name = path.name.lower()
    if name.endswith(".blf"):
        import can

        with can.BLFReader(path) as reader:
            start, stop = reader.start_timestamp, reader.stop_timestamp
        if 0 < start <= stop:
            return round(start * 1e6) * 1000, round(stop * 1e6) * 1000
    if name.endswith(".mcap"):
        from mcap.reader import make_reader

        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
        if summary is not None and summary.statistics is not None:
            return summary.statistics.message_start_time, summary.statistics.message_end_time
    times = [frame.timestamp_ns for frame in LogSource(path)]
    return min(times), max(times)


@dataclass(frozen=True)
class BatchDrive:
    """The files of one drive, and the name of its output under the output folder."""

    name: str
    inputs: tuple[Path, ...]


def _utc(ns: int) -> str:
    moment = datetime.datetime.fromtimestamp(ns / 1e9, tz=datetime.timezone.utc)
    return moment.strftime("%Y-%m-%dT%H-%M-%SZ")


def group_drives(files: Sequence[tuple[Path, Path]], suffixes: Sequence[str], *,
                 span: Callable[[Path], Span] = file_span,
                 merge: bool = True) -> list[BatchDrive]:
    """The drives that ``files`` (from :func:`find_inputs`) make: one stem in one folder, with
    overlapping or adjacent time spans (only files sharing a stem are asked their ``span``).
    Without ``merge`` every file is a drive of its own, named after the file (tankviz drives:
    ``tankviz convert`` re-derives one at a time)."""
    by_stem: dict[tuple[Path, str], list[Path]] = {}
    base_of = dict(files)
    for path, _ in files:
        suffix = format_suffix(path, suffixes) or path.suffix
        stem = drive_stem(path, suffixes) if merge else path.name[:len(path.name) - len(suffix)]
        by_stem.setdefault((path.parent, stem), []).append(path)
    drives: list[BatchDrive] = []
    for (folder, stem), paths in by_stem.items():
        rel = folder.relative_to(base_of[paths[0]]).as_posix()
        prefix = "" if rel == "." else f"{rel}/"
        if len(paths) == 1:
            drives.append(BatchDrive(prefix + stem, (paths[0],)))
            continue
        spans = sorted((span(p), p) for p in paths)
        groups: list[tuple[int, int, list[Path]]] = []
        for (start, end), p in spans:
            if groups and start <= groups[-1][1] + ADJACENT_NS:
                first, last, members = groups[-1]
                groups[-1] = (first, max(last, end), [*members, p])
            else:
                groups.append((start, end, [p]))
        for start, _, members in groups:
            name = stem if start == groups[0][0] else f"{stem}_{_utc(start)}"
            drives.append(BatchDrive(prefix + name, tuple(sorted(members))))
    return sorted(drives, key=lambda d: d.name)


@dataclass(frozen=True)
class ConvertJob:
    """One task: the drive's input files and its output, absolute paths as text."""

    name: str
    inputs: tuple[str, ...]
    output: str


def plan_jobs(drives: Sequence[BatchDrive], out: Path) -> list[ConvertJob]:
    """One job per drive, writing ``OUT/<name>.mcap``; refuses two drives with one output and an
    output that is an input."""
    out = out.expanduser().absolute()
    jobs: dict[Path, ConvertJob] = {}
    inputs = _identities(p for d in drives for p in d.inputs)
    for drive in drives:
        output = out / f"{drive.name}.mcap"
        if output in jobs:
            raise UsageError(output, f"both {jobs[output].inputs[0]} and {drive.inputs[0]} "
                             "would be written there: convert them into different --out folders")
        for key in _identities([output]):
            if key in inputs:
                raise UsageError(output, f"is an input ({inputs[key]}) and would be "
                                 "overwritten: choose another --out folder")
        jobs[output] = ConvertJob(drive.name, tuple(str(p) for p in drive.inputs), str(output))
    return list(jobs.values())


def _identities(paths: Iterable[Path]) -> dict[object, Path]:
    """Each path's real path and, for a file that exists, its device and inode (the same file
    by any name: a symbolic or hard link), to the path."""
    keys: dict[object, Path] = {}
    for path in paths:
        keys.setdefault(os.path.realpath(path), path)
        with contextlib.suppress(OSError):
            info = os.stat(path)
            keys.setdefault((info.st_dev, info.st_ino), path)
    return keys


def finished(jobs: Sequence[ConvertJob], *, force: bool
             ) -> tuple[list[ConvertJob], list[ConvertJob]]:
    """The jobs to run and those skipped: an output that exists is complete (it is written
    atomically), so it is skipped unless ``force``."""
    if force:
        return list(jobs), []
    done = [j for j in jobs if Path(j.output).exists()]
    return [j for j in jobs if j not in done], done


def input_bytes(job: ConvertJob) -> int:
    """The size of a drive's inputs, for the batch's ETA."""
    return sum(os.path.getsize(p) for p in job.inputs if os.path.exists(p))


# --- in the workers ------------------------------------------------------------------------------

class Converted(Protocol):
    """What a conversion tells: the frames it converted, what it skipped in the inputs (each
    with its place), and the inputs that are one log twice over."""

    @property
    def frames(self) -> int: ...

    @property
    def issues(self) -> Sequence[object]: ...

    @property
    def input_warnings(self) -> Sequence[str]: ...


class ConvertFunction(Protocol):
    """``tankviz convert``'s function (:func:`bridge.pipeline.convert.convert`)."""

    def __call__(self, inputs: Sequence[Path | str], output: Path | str,
                 dbc_options: Sequence[str], *, profile: str | Path | None,
                 scene_rate: float | None, force: bool,
                 progress: Callable[[int, float | None], None] | None,
                 bring_up: bool = True) -> Converted: ...


@dataclass(frozen=True)
class Settings:
    """What every drive of a batch is converted with (paths absolute: workers see them)."""

    dbc_options: tuple[str, ...]
    profile: str | None
    scene_rate: float | None
    force: bool
    #: the Dask event topic each task tells its progress on (:func:`run_batch`), or None
    progress_topic: str | None = None
    #: whether the drives have the bring-up topics (``--no-bring-up``: not)
    bring_up: bool = True

#: Seconds between two progress events of one task.
PROGRESS_EVERY_S = 0.5


@dataclass(frozen=True)
class JobResult:
    """How one drive went: frames written, or its one-line error."""

    job: ConvertJob
    frames: int = 0
    seconds: float = 0.0
    error: str | None = None
    worker: str = ""
    #: the issues of the inputs (damaged or unreadable parts skipped, ...): how many, the first
    issues: int = 0
    first_issue: str = ""
    #: inputs that are one log twice over (:func:`bridge.pipeline.convert.overlapping_inputs`)
    warnings: tuple[str, ...] = ()


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().name)
    except (ImportError, ValueError):
        return ""


def _progress_events(job: ConvertJob, topic: str | None
                     ) -> Callable[[int, float | None], None] | None:
    """A progress callback that logs Dask events (``{"output", "frames", "fraction"}``) on
    ``topic`` at most every :data:`PROGRESS_EVERY_S`; None outside a Dask worker."""
    if topic is None:
        return None
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return None
    last = [0.0]

    def progress(frames: int, fraction: float | None) -> None:
        now = time.monotonic()
        if now - last[0] >= PROGRESS_EVERY_S or fraction == 1.0:
            last[0] = now
            worker.log_event(topic, {"output": shown(job.output), "frames": frames,
                                     "fraction": fraction})

    return progress


def convert_task(job: ConvertJob, convert: ConvertFunction, settings: Settings) -> JobResult:
    """Convert one drive with ``convert``; any failure is the result's one-line error. In a Dask
    worker, its progress goes out as events on ``settings.progress_topic``."""
    started = time.perf_counter()
    progress = _progress_events(job, settings.progress_topic)
    if progress is not None:
        progress(0, 0.0)  # under way: the client times the drive from here
    try:
        if (twice := one_log_twice(job.inputs)) is not None:
            return JobResult(job, error=twice, worker=_worker_name())
        report = convert(list(job.inputs), job.output, list(settings.dbc_options),
                         profile=settings.profile, scene_rate=settings.scene_rate,
                         force=settings.force, progress=progress, bring_up=settings.bring_up)
    except BridgeError as exc:
        return JobResult(job, error=shown(str(exc)), worker=_worker_name())
    except OSError as exc:
        error = os_error_text(exc) if exc.filename is not None else f"{job.inputs[0]}: {exc}"
        return JobResult(job, error=shown(error), worker=_worker_name())
    except Exception as exc:  # a bug must not stop the other drives: it is reported with them
        return JobResult(job, error=shown(f"{job.inputs[0]}: {type(exc).__name__}: {exc}"),
                           worker=_worker_name())
    return JobResult(job, report.frames, time.perf_counter() - started,
                       worker=_worker_name(), issues=len(report.issues),
                       first_issue=shown(str(report.issues[0])) if report.issues else "",
                       warnings=tuple(shown(w) for w in report.input_warnings))


def one_log_twice(inputs: Sequence[str]) -> str | None:
    """Why a drive's files are not converted when two of them are one log saved twice (as BLF
    and as ASC: :func:`bridge.pipeline.convert.same_frames` of their first frames), or None: a
    drive made of both would record every frame twice, so the drive is refused, naming both."""
    if len(inputs) < 2:
        return None
    from bridge.pipeline.convert import first_frames, same_frames

    heads = [first_frames(Path(p)) for p in inputs]
    for i, j in itertools.combinations(range(len(inputs)), 2):
        if same_frames(heads[i], heads[j]):
            return (f"{shown(inputs[i])} and {shown(inputs[j])} are one log saved twice (their "
                    f"first {len(heads[i])} frames match in id, data and time): not converted, "
                    "as the drive would hold every frame twice; convert one of them (tankviz "
                    "convert FILE -o OUTPUT), or move the other out of the folder")
    return None


def input_issue_lines(results: Sequence[JobResult]) -> list[str]:
    """The batch summary's lines on input issues: how many drives, then each written drive whose
    inputs had issues, with their count, the first and where all are listed (pure, for tests)."""
    written = [r for r in results if r.error is None]
    damaged = [r for r in written if r.issues]
    if not damaged:
        return []
    lines = [f"input issues in {len(damaged)} of {len(written)} drives written (what a log "
             "could not give was skipped, the rest converted):"]
    for r in sorted(damaged, key=lambda r: r.job.name):
        lines.append(f"  {shown(r.job.name)}: {r.issues:,} "
                     f"{'issue' if r.issues == 1 else 'issues'}, the first {r.first_issue}; "
                     f"tankviz inspect {shown(r.job.output)} lists them")
    return lines


# --- the batch, from the client ------------------------------------------------------------------

#: A drive under way is slow when it has taken this many times what its size allows at the
#: throughput of the drives done so far...
SLOW_FACTOR = 5.0
#: ... and at least this long (seconds): a small drive a little late is not named.
SLOW_AFTER_S = 30.0


@dataclass(frozen=True)
class Running:
    """A drive under way, as the progress line sees it."""

    name: str
    seconds: float
    bytes: int


def slow_drives(running: Sequence[Running], *, done_bytes: int, done_seconds: float,
                factor: float = SLOW_FACTOR, after_s: float = SLOW_AFTER_S) -> list[str]:
    """The drives under way that take far longer than their size allows, as the progress line
    names them (``trip7 (4 min, 12 MB)``), slowest first (pure, for tests). What a drive's size
    allows: its input bytes at the throughput of the drives done so far (their input bytes over
    the seconds each took on its worker); far longer: more than ``factor`` times that, and more
    than ``after_s``. Nothing is slow before a drive is done."""
    if done_bytes <= 0 or done_seconds <= 0:
        return []
    per_byte = done_seconds / done_bytes
    slow = [r for r in running
            if r.seconds > after_s and r.seconds > factor * r.bytes * per_byte]
    return [f"{r.name} ({_duration(r.seconds)}, {_size(r.bytes)})"
            for r in sorted(slow, key=lambda r: -r.seconds)]


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _size(n: int) -> str:
    for unit, scale in (("GB", 10**9), ("MB", 10**6), ("kB", 10**3)):
        if n >= scale:
            return f"{n / scale:.0f} {unit}"
    return f"{n} B"


def progress_line(*, done: int, failed: int, total: int, frames: int, elapsed: float,
                  fraction: float | None, width: int = 20, slow: Sequence[str] = ()) -> str:
    """The batch's one progress line: drives done, frames/s overall, ETA, and the drives under
    way that are slow (:func:`slow_drives`) (pure, for tests)."""
    rate = frames / elapsed if elapsed > 0 else 0.0
    eta = "--:--"
    filled = 0
    if fraction is not None:
        fraction = min(max(fraction, 0.0), 1.0)
        filled = round(fraction * width)
        if fraction > 0:
            seconds = int(elapsed * (1 - fraction) / fraction)
            eta = f"{seconds // 60:02d}:{seconds % 60:02d}"
    failures = f" ({failed} failed)" if failed else ""
    slow_text = f"; slow: {', '.join(slow)}" if slow else ""
    return (f"[{'#' * filled}{'.' * (width - filled)}] {done}/{total} drives{failures}  "
            f"{frames:,} frames  {rate:,.0f} frames/s  ETA {eta}{slow_text}")


@contextlib.contextmanager
def dask_client(*, workers: int | None = None, scheduler: str | None = None) -> Iterator[Client]:
    """A Dask client: of the cluster at ``scheduler``, else of a local cluster of ``workers``
    processes with one thread each (default: one per core), closed after the block."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise UsageError("tankviz batch", MISSING_DASK) from None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=30)  # type: ignore[no-untyped-call]
        except (OSError, TimeoutError, ValueError) as exc:
            raise UsageError("--scheduler", f"cannot connect: {exc}",
                             value=scheduler) from None
        with client:
            yield client
        return
    cluster = LocalCluster(  # type: ignore[no-untyped-call]
        n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
        dashboard_address=":0", silence_logs=logging.ERROR)
    with cluster, Client(cluster) as client:  # type: ignore[no-untyped-call]
        yield client


def dashboard(client: Client) -> str:
    """Where each worker's speed is seen: the Dask dashboard's link and its page of workers
    (which works without bokeh; the dashboard's graphs need it where the scheduler runs)."""
    services: dict[str, Any] = client.scheduler_info().get("services", {})
    if "dashboard" not in services:
        return "Dask dashboard: none (the scheduler serves no HTTP)"
    link = str(client.dashboard_link)
    workers = link.removesuffix("/status") + "/info/main/workers.html"
    text = f"Dask dashboard: {link} (workers: {workers})"
    if importlib.util.find_spec("bokeh") is None:
        text += "; its graphs need bokeh where the scheduler runs: pip install 'bokeh>=3.1'"
    return text


def progress_topic() -> str:
    """A Dask event topic of its own for one batch's progress events."""
    return f"tankviz-batch-{uuid.uuid4().hex[:12]}"


def run_batch(client: Client, jobs: Sequence[ConvertJob],
              task: Callable[[ConvertJob], JobResult],
              on_result: Callable[[JobResult], None] | None = None, *,
              topic: str | None = None,
              on_progress: Callable[[str, int, float | None], None] | None = None
              ) -> list[JobResult]:
    """Run ``task`` for every job on the cluster, one Dask task each and no retries, and return
    the results as they complete; a task that raises or whose worker dies is a failed result.
    ``on_progress`` (output, frames, fraction) is told the progress events of ``topic`` (from
    Dask's event loop thread)."""
    from distributed import as_completed

    if topic is not None and on_progress is not None:
        def handler(event: tuple[float, dict[str, Any]]) -> None:
            msg = event[1]
            on_progress(str(msg["output"]), int(msg["frames"]), msg["fraction"])

        client.subscribe_topic(topic, handler)  # type: ignore[no-untyped-call]
    token = uuid.uuid4().hex[:8]
    futures = {client.submit(task, job, key=f"tankviz-drive-{shown(job.name)}-{token}", pure=False,
                             retries=0): job for job in jobs}
    results = []
    try:
        for future in as_completed(futures):  # type: ignore[no-untyped-call]
            job = futures[future]
            try:
                result: JobResult = future.result()
            except Exception as exc:  # the worker died (KilledWorker), or the task did not run
                result = JobResult(job, error=shown(f"{job.inputs[0]}: {type(exc).__name__}: "
                                                    f"{exc}"))
            results.append(result)
            if on_result is not None:
                on_result(result)
    finally:
        if topic is not None and on_progress is not None:
            client.unsubscribe_topic(topic)  # type: ignore[no-untyped-call]
    return results
