"""CAN logs (or a recorded drive) to one decoded, self-contained MCAP drive archive: the engine
of ``tankviz convert`` (:func:`convert`, which ``tankviz batch`` runs per drive) and
:func:`record_drive`, the conversion of open sources into an open output.

The archive holds every raw frame, every decoded message, the bring-up topics unless
``bring_up=False``, a ``tankviz`` metadata record and every database file as an attachment, so a
drive can be decoded again from the MCAP alone. An input ending in ``.mcap`` is a recorded drive,
re-derived through the whole pipeline with its attached databases and profile unless others are
given (:mod:`bridge.pipeline.rederive`); the same drive, databases and profile give the same
bytes. The output must end in ``.mcap`` and is never one of the inputs by any name; one file
given twice is refused, one log saved twice (its first :data:`OVERLAP_FRAMES` frames match) is
converted with a warning. A conversion that fails leaves no output file
(:func:`bridge.sinks.outputs.atomic_output`).
"""

from __future__ import annotations

import itertools
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from bridge.decode.decoder import Decoder
from bridge.errors import BridgeError, FileError, InputError
from bridge.io.can_logs import ISSUE_KINDS, LogSource, SourceIssue
from bridge.io.drives import ArchiveSource, is_drive, read_drive
from bridge.io.readahead import ReadAhead
from bridge.pb.marks_pb2 import Mark
from bridge.pipeline import DEFAULT_SCENE_RATE
from bridge.pipeline.drive import Drive, Stages, load_stages
from bridge.pipeline.rederive import (
    CarriedMarks,
    describe_rederive,
    recorded_scene_rate,
    rederive_stages,
    source_record,
    unreadable_marks,
)
from bridge.sinks.mcap import OFFLINE_LEVEL
from bridge.sinks.outputs import atomic_output, check_output, refuse_inputs, same_file

if TYPE_CHECKING:  # (a drive without a profile never loads its stages)
    from bridge.profile.model import Profile

#: How many source issues are kept in the metadata (all are counted).
MAX_ISSUES_RECORDED = 1000

Progress = Callable[[int, float | None], None]
"""Called now and then with (frames so far, fraction of the input read or None)."""

#: Where frames come from: CAN logs, or a recorded drive's raw frames.
Source = LogSource | ArchiveSource

#: How many first frames of two inputs are compared to tell one log given twice.
OVERLAP_FRAMES = 16
#: How far apart two frames' times may be and still be one frame (text formats keep µs and
#: round; BLF keeps ns).
OVERLAP_TOLERANCE_NS = 1_000_000

#: A frame as compared for overlap: time (ns), id, extended, data.
FrameKey = tuple[int, int, bool, bytes]


def refuse_repeated(inputs: Sequence[Path | str]) -> None:
    """Refuse a file given twice among ``inputs``, by one name or two (:func:`same_file`)."""
    for i, path in enumerate(inputs):
        for earlier in inputs[:i]:
            if same_file(earlier, path) and os.path.exists(path):
                how = ("is given twice" if str(earlier) == str(path)
                       else f"is the same file as the input {earlier} (given twice)")
                raise InputError(path, f"{how}: its frames would be recorded twice; name it "
                                 "once")


def same_frames(a: Sequence[FrameKey], b: Sequence[FrameKey], *,
                tolerance_ns: int = OVERLAP_TOLERANCE_NS) -> bool:
    """Whether two inputs' first frames are one log's: as many, none missing, each pair with one
    id, extended flag and data, and times at most ``tolerance_ns`` apart (pure)."""
    return bool(a) and len(a) == len(b) and all(
        abs(x[0] - y[0]) <= tolerance_ns and x[1:] == y[1:] for x, y in zip(a, b, strict=True))


def first_frames(path: Path, n: int = OVERLAP_FRAMES) -> list[FrameKey]:
    """The first ``n`` frames of a log, as compared for overlap; none where it cannot be read
    (the conversion itself says why)."""
    try:
        return [(f.timestamp_ns, f.arbitration_id, f.is_extended, f.data)
                for f in itertools.islice(LogSource(path), n)]
    except BridgeError:
        return []


def overlapping_inputs(inputs: Sequence[Path],
                       head: Callable[[Path], Sequence[FrameKey]] = first_frames) -> list[str]:
    """One warning per pair of inputs that are one log given twice (:func:`same_frames` of
    their ``head``), naming both."""
    heads = [head(p) for p in inputs]
    return [f"{inputs[i]} and {inputs[j]} hold the same frames (their first {len(heads[i])} "
            "match in id, data and time): the drive records each of them twice; convert one of "
            "the two"
            for i, j in itertools.combinations(range(len(inputs)), 2)
            if same_frames(heads[i], heads[j])]


def check_mcap_output(output: Path) -> None:
    """The output of convert is an MCAP drive archive: its name ends in ``.mcap``."""
    if output.suffix.lower() != ".mcap":
        raise FileError(output, "convert writes an MCAP drive archive: the output's name must "
                        "end in .mcap")


def recorded_issues(issues: Sequence[SourceIssue]) -> dict[str, Any]:
    """The drive's ``input_issues`` metadata: how many, and the first
    :data:`MAX_ISSUES_RECORDED` of them, the gravest kind first (a stop is never left out for
    the skips before it: :data:`~bridge.io.can_logs.ISSUE_KINDS`), each kind in file order."""
    gravest = sorted(issues, key=lambda i: ISSUE_KINDS.index(i.kind))
    return {"count": len(issues), "first": [str(i) for i in gravest[:MAX_ISSUES_RECORDED]]}


@dataclass
class ConvertReport:
    """What a conversion did: counts, decode statistics and what was skipped."""

    output: Path | None
    frames: int
    messages: int
    seconds: float
    statistics: dict[str, Any]
    issues: list[SourceIssue] = field(default_factory=list)
    #: what silenced messages (:meth:`bridge.decode.decoder.Decoder.warnings`), also in the metadata
    warnings: list[str] = field(default_factory=list)
    #: a re-derived drive: what it was re-derived from and with
    rederived: str = ""
    #: inputs that are one log given twice (:func:`overlapping_inputs`), also in ``warnings``
    input_warnings: list[str] = field(default_factory=list)


def record_drive(sources: Sequence[Source], decoder: Decoder, output: IO[bytes], *,
                 profile: Profile | None = None, scene_rate: float = DEFAULT_SCENE_RATE,
                 progress: Progress | None = None, every: int = 16384,
                 extra: Mapping[str, Any] | None = None,
                 attachment_time_ns: int | None = None,
                 read_ahead: bool = True,
                 input_warnings: Iterable[str] = (), bring_up: bool = True,
                 marks: Sequence[Mark] = ()) -> ConvertReport:
    """Convert ``sources`` into an MCAP written to the open binary ``output``.

    With a profile, the drive also gets the scene and perception topics at ``scene_rate``.
    ``extra`` goes into the metadata record; ``attachment_time_ns`` fixes the attachments' time;
    ``input_warnings`` join the decoder's warnings (in the metadata and the report).
    ``read_ahead``: a second process reads the sources where it can
    (:class:`~bridge.io.readahead.ReadAhead`); the output is the same either way.
    ``bring_up``: the bring-up topics (:mod:`bridge.bringup.monitor`).
    ``marks``: a re-derived drive's marks, made again where its frames reach them
    (:class:`~bridge.pipeline.rederive.CarriedMarks`).
    """
    started = time.perf_counter()
    drive = Drive(Stages(decoder, profile), scene_rate=scene_rate, extra=extra,
                  bring_up=bring_up)
    recorder = drive.record(output, attachment_time_ns=attachment_time_ns, level=OFFLINE_LEVEL)
    reading = ReadAhead(sources, ahead=read_ahead)

    def report_progress(frames: int) -> None:
        assert progress is not None
        done, total = reading.progress()
        progress(frames, done / total if total else None)

    carried = CarriedMarks(marks, drive.pipeline) if marks else None
    blocks = reading.packs() if carried is None else carried.packs(reading.packs())
    frames = drive.run_packed(blocks, progress=report_progress if progress else None,
                              every=every)
    if carried is not None:
        carried.finish()
    if progress is not None:
        progress(frames, 1.0)
    issues = [i for s in sources for i in s.issues]
    said = list(input_warnings)
    warnings = [*decoder.warnings(), *said]
    if said:
        drive.extra["warnings"] = warnings
    drive.extra.update({
        "inputs": [{"path": str(s.path), "frames": s.frames, "skipped": len(s.issues),
                    "backwards_jumps": s.backwards} for s in sources],
        "input_issues": recorded_issues(issues),
    })
    drive.finish()
    return ConvertReport(None, frames, recorder.messages, time.perf_counter() - started,
                         drive.statistics, issues, warnings, input_warnings=said)


def convert(inputs: Sequence[Path | str], output: Path | str, dbc_options: Sequence[str], *,
            profile: str | Path | None = None, scene_rate: float | None = None,
            force: bool = False, strict: bool = False,
            progress: Progress | None = None,
            warn: Callable[[str], None] | None = None,
            read_ahead: bool = True, bring_up: bool = True) -> ConvertReport:
    """Convert log files into ``output``; everything is checked before the output is touched.
    ``warn`` is told the databases' warnings as soon as they are loaded; ``read_ahead`` and
    ``bring_up``: see :func:`record_drive`."""
    output = Path(output)
    refuse_inputs(output, inputs)
    check_mcap_output(output)
    refuse_repeated(inputs)
    drives = [Path(p) for p in inputs if is_drive(p)]
    if drives:
        if len(inputs) > 1:
            raise InputError(drives[0], "re-derive one drive at a time, without logs beside it "
                             f"({len(inputs)} inputs given)")
        return rederive(drives[0], output, dbc_options, profile=profile, scene_rate=scene_rate,
                        force=force, strict=strict, progress=progress, warn=warn,
                        read_ahead=read_ahead, bring_up=bring_up)
    check_output(output, force=force, inputs=inputs)
    decoder, loaded_profile = load_stages(dbc_options, profile)
    if warn is not None:
        for text in decoder.warnings():
            warn(text)
    sources = [LogSource(Path(p), strict=strict) for p in inputs]
    overlaps = overlapping_inputs([s.path for s in sources]) if len(sources) > 1 else []
    if warn is not None:
        for text in overlaps:
            warn(text)
    with atomic_output(output, force=force) as stream:
        report = record_drive(sources, decoder, stream, profile=loaded_profile,
                              scene_rate=DEFAULT_SCENE_RATE if scene_rate is None
                              else scene_rate, progress=progress,
                              read_ahead=read_ahead, input_warnings=overlaps,
                              bring_up=bring_up)
    report.output = output
    return report


def rederive(drive_path: Path | str, output: Path | str, dbc_options: Sequence[str], *,
             profile: str | Path | None = None, scene_rate: float | None = None,
             force: bool = False, strict: bool = False, progress: Progress | None = None,
             warn: Callable[[str], None] | None = None,
             read_ahead: bool = True, bring_up: bool = True) -> ConvertReport:
    """Run the raw frames of a recorded drive through the whole pipeline again, into ``output``
    (see the module's description), at ``scene_rate``, else the drive's own."""
    output = Path(output)
    check_mcap_output(output)
    check_output(output, force=force, inputs=[drive_path])
    drive = read_drive(drive_path)
    with tempfile.TemporaryDirectory(prefix="tankviz-rederive-") as folder:
        stages = rederive_stages(drive, dbc_options, profile, Path(folder))
        if warn is not None:
            for text in stages.decoder.warnings():
                warn(text)
        sources = [ArchiveSource(drive.path, strict=strict)]
        rate = scene_rate if scene_rate is not None else recorded_scene_rate(drive)
        with atomic_output(output, force=force) as stream:
            report = record_drive(sources, stages.decoder, stream, profile=stages.profile,
                                  scene_rate=rate, progress=progress,
                                  extra=source_record(drive), attachment_time_ns=0,
                                  read_ahead=read_ahead, bring_up=bring_up,
                                  input_warnings=unreadable_marks(drive), marks=drive.marks)
    report.output = output
    report.rederived = describe_rederive(drive, stages, dbc_options, profile)
    return report
