"""``tankviz convert``: CAN logs to one decoded, self-contained MCAP drive archive.

The archive holds every raw frame (``/can/<bus>/frames``), every decoded message
(``/can/<bus>/<Message>``), a ``tankviz`` metadata record (version, inputs, databases with their
SHA-256, bus → database map, frame and decode statistics, what was skipped in the inputs) and every
database file as an attachment, so a drive can be decoded again from the MCAP alone.

A conversion that fails leaves no output file (:func:`bridge.sinks.mcap.atomic_output`).
"""

from __future__ import annotations

import gc
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from bridge.decode.decoder import DatabaseFile, Decoder, load_database, parse_dbc_option
from bridge.errors import OutputError
from bridge.io.logs import LogSource, SourceIssue, merge
from bridge.pipeline.perception import DEFAULT_SCENE_RATE
from bridge.pipeline.pipeline import Pipeline, describe_drive, new_health_monitor
from bridge.profile.model import Profile, load_profile, read_profile_databases, resolve_profile
from bridge.sinks.mcap import Recorder, atomic_output

#: How many source issues are kept in the metadata (all are counted).
MAX_ISSUES_RECORDED = 1000

Progress = Callable[[int, float | None], None]
"""Called now and then with (frames so far, fraction of the input read or None)."""


@dataclass
class ConvertReport:
    """What a conversion did: counts, decode statistics and what was skipped."""

    output: Path | None
    frames: int
    messages: int
    seconds: float
    statistics: dict[str, Any]
    issues: list[SourceIssue] = field(default_factory=list)


def build_decoder(dbc_options: Sequence[str]) -> Decoder:
    """A decoder from ``[BUS=]PATH`` options; each file is loaded once even if named twice."""
    loaded: dict[Path, DatabaseFile] = {}
    by_bus: dict[str | None, list[DatabaseFile]] = {}
    for option in dbc_options:
        bus, path = parse_dbc_option(option)
        key = path.resolve()
        if key not in loaded:
            loaded[key] = load_database(path)
        by_bus.setdefault(bus, []).append(loaded[key])
    return Decoder(by_bus)


def build_stages(dbc_options: Sequence[str],
                 profile: str | Path | None) -> tuple[Decoder, Profile | None]:
    """The decoder and the profile; without --dbc options the profile's own databases are used."""
    if profile is None:
        return build_decoder(dbc_options), None
    path = resolve_profile(profile)
    if not dbc_options:
        dbc_options = [str(p) if bus == "*" else f"{bus}={p}"
                       for bus, paths in read_profile_databases(path).items() for p in paths]
    decoder = build_decoder(dbc_options)
    return decoder, load_profile(path, [f.db for f in decoder.files])


def record_drive(sources: Sequence[LogSource], decoder: Decoder, output: IO[bytes], *,
                 profile: Profile | None = None, scene_rate: float = DEFAULT_SCENE_RATE,
                 progress: Progress | None = None, every: int = 16384) -> ConvertReport:
    """Convert ``sources`` into an MCAP written to the open binary ``output``.

    With a profile, the drive also gets the scene and perception topics at ``scene_rate``.
    """
    started = time.perf_counter()
    recorder = Recorder(output)
    health = new_health_monitor(decoder, profile)
    pipeline = Pipeline(decoder, profile=profile, scene_rate=scene_rate, recorder=recorder,
                        health=health)
    process = pipeline.process
    total_bytes = sum(s.progress()[1] for s in sources)
    frames = 0
    # The hot loop makes millions of short-lived tuples and no reference cycles: the cyclic
    # garbage collector would only walk the long-lived caches over and over (about 8 %).
    collecting = gc.isenabled()
    gc.disable()
    try:
        for frame in merge(sources):
            process(frame)
            frames += 1
            if progress is not None and frames % every == 0:
                done = sum(s.progress()[0] for s in sources)
                progress(frames, done / total_bytes if total_bytes else None)
    finally:
        if collecting:
            gc.enable()
    pipeline.finish()
    if progress is not None:
        progress(frames, 1.0)
    issues = [i for s in sources for i in s.issues]
    statistics = describe_drive(recorder, decoder, profile, scene_rate, {
        "inputs": [{"path": str(s.path), "frames": s.frames, "skipped": len(s.issues),
                    "backwards_jumps": s.backwards} for s in sources],
        "input_issues": {"count": len(issues),
                         "first": [str(i) for i in issues[:MAX_ISSUES_RECORDED]]},
        "alarms": health.event_records(),
    })
    recorder.finish()
    return ConvertReport(None, frames, recorder.messages, time.perf_counter() - started,
                         statistics, issues)


def check_output(path: Path, *, force: bool) -> None:
    """Refuse an output that exists (unless ``force``) or that cannot be written."""
    if path.is_dir():
        raise OutputError(path, "is a directory")
    if path.exists() and not force:
        raise OutputError(path, "exists already; use --force to overwrite it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(path, f"cannot write: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputError(path, f"cannot write: folder {parent} is not writable")


def convert(inputs: Sequence[Path | str], output: Path | str, dbc_options: Sequence[str], *,
            profile: str | Path | None = None, scene_rate: float = DEFAULT_SCENE_RATE,
            force: bool = False, strict: bool = False,
            progress: Progress | None = None) -> ConvertReport:
    """Convert log files into ``output``; everything is checked before the output is touched."""
    output = Path(output)
    check_output(output, force=force)
    decoder, loaded_profile = build_stages(dbc_options, profile)
    sources = [LogSource(Path(p), strict=strict) for p in inputs]
    with atomic_output(output) as stream:
        report = record_drive(sources, decoder, stream, profile=loaded_profile,
                              scene_rate=scene_rate, progress=progress)
    report.output = output
    return report
