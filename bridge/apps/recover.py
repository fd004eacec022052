"""``tankviz recover``: salvage what a power cut or a killed recorder left of a drive.

:func:`recover` copies every record of a cut or damaged MCAP it can read into a complete new
MCAP, with a ``tankviz.recover`` record saying what was recovered, skipped, and where and why
reading stopped: a cut file gives exactly a prefix of its messages, other damage loses only the
damaged record. The input is only read; the output appears only complete.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import IO

from mcap.writer import CompressionType

from bridge.apps.options import Subparsers
from bridge.apps.progress import ProgressBar
from bridge.apps.recover_records import (
    CHUNK_SIZE,
    MAGIC,
    METADATA_NAME,
    Progress,
    RecoverReport,
    _Input,
    _Unreadable,
)
from bridge.apps.recover_salvage import _Salvage
from bridge.errors import FileError, InputError, check_input_path, shown
from bridge.frame import format_time
from bridge.sinks.mcap import FastWriter as Writer  # mcap's Writer, faster add_message
from bridge.sinks.outputs import atomic_output, check_output


def recover(broken: IO[bytes], fixed: IO[bytes], *, source_name: str = "",
            progress: Progress | None = None) -> RecoverReport:
    """Copy every complete record of the MCAP ``broken`` into a complete new MCAP on ``fixed``.

    Reads ``broken`` from its current position; a cut or damaged file never raises, its report
    says where and why reading stopped. Raises :class:`InputError` (naming ``source_name``) if
    ``broken`` does not start like an MCAP at all; then nothing is written to ``fixed``.
    """
    name = source_name or "input"
    start, total = 0, None
    if broken.seekable():
        start = broken.tell()
        total = broken.seek(0, os.SEEK_END) - start
        broken.seek(start)
    source = _Input(broken)
    try:
        head = source.peek(len(MAGIC))
    except _Unreadable as exc:
        raise InputError(name, f"cannot read: {exc}") from None
    if not head:
        raise InputError(name, "not an MCAP file (it is empty)")
    if head != MAGIC[:len(head)]:
        raise InputError(name, f"not an MCAP file (it starts with {head!r}, not {MAGIC!r})")
    if len(head) < len(MAGIC):
        raise InputError(name, f"not an MCAP file (its {len(head)} bytes are the start of the "
                         "MCAP magic, nothing more)")
    report = RecoverReport()
    writer = Writer(fixed, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
    salvage = _Salvage(broken, source, writer, start, total, report, progress)
    try:
        salvage.run()
    except _Unreadable as exc:  # reading the rest to count it, or the closing magic
        salvage.stop(source.count, f"the disk cannot read the file here: {exc}")
    salvage.finish()
    writer.add_metadata(METADATA_NAME, salvage.record(source_name))
    writer.finish()  # type: ignore[no-untyped-call]
    if progress is not None:
        progress(report.messages, 1.0)
    return report


def recover_file(broken: Path | str, fixed: Path | str, *, force: bool = False,
                 progress: Progress | None = None) -> RecoverReport:
    """Recover the MCAP file ``broken`` into ``fixed``, which is refused if it exists (unless
    ``force``) or is ``broken`` itself; a failed recovery leaves no output file."""
    broken, fixed = Path(broken), Path(fixed)
    if not broken.exists():
        raise InputError(broken, "no such file")
    if broken.is_dir():
        raise InputError(broken, "is a directory, not an MCAP file")
    check_input_path(broken)
    if fixed.exists() and fixed.resolve() == broken.resolve():
        raise FileError(fixed, "is the file to recover; write the recovered drive to a new file")
    check_output(fixed, force=force, inputs=[broken])  # a hard link to it, too
    try:
        source = broken.open("rb")
    except OSError as exc:
        raise InputError(broken, f"cannot read: {exc.strerror or exc}") from None
    with source, atomic_output(fixed, force=force) as stream:
        return recover(source, stream, source_name=shown(broken), progress=progress)


def format_report(report: RecoverReport, broken_path: Path | str, fixed_path: Path | str) -> str:
    """The lines ``tankviz recover`` prints."""
    r = report
    topics = len(r.per_topic)
    if r.messages and r.first_ns is not None and r.last_ns is not None:
        lines = [f"recovered {r.messages:,} messages in {topics} topic{'s' * (topics != 1)} "
                 f"spanning {r.duration_s:.3f} s (from {format_time(r.first_ns)} to "
                 f"{format_time(r.last_ns)})"]
    else:
        lines = ["recovered no messages"]
    width = max((len(t) for t in r.per_topic), default=0)
    digits = max((len(f"{n:,}") for n in r.per_topic.values()), default=0)
    lines += [f"  {topic:<{width}}  {n:>{digits},}" for topic, n in r.per_topic.items()]
    lines.append(f"  {r.metadata} metadata record{'s' * (r.metadata != 1)}, "
                 f"{r.attachments} attachment{'s' * (r.attachments != 1)}")
    share = ""
    if r.bytes_total:  # rounded down: a file that was not read to its end never shows 100.0 %
        share = f" ({math.floor(1000 * r.bytes_read / r.bytes_total) / 10:.1f} %)"
    lines.append(f"read {r.bytes_read:,} of {r.bytes_total:,} bytes of {broken_path}{share}")
    if r.stopped is None:
        lines.append("the file was complete"
                     + (", but damaged inside" if r.skipped or r.repaired else ""))
        if r.bytes_read < r.bytes_total:
            lines.append(f"  {r.bytes_total - r.bytes_read:,} bytes after its end were ignored")
    else:
        lines.append(f"stopped at byte {r.stopped_at or 0:,}: {r.stopped}")
    for text in r.skipped:
        lines.append(f"skipped the damaged {text}")
    for text in r.repaired:
        lines.append(f"repaired the damaged {text}")
    if r.dropped:
        lines.append(f"dropped {r.dropped:,} messages whose channel was defined only in a "
                     "skipped chunk")
    lines.append(f"wrote {fixed_path} (its {METADATA_NAME} metadata record says what was "
                 "recovered)")
    return "\n".join(lines)


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "recover", help="salvage a drive (MCAP) cut short by a power loss or a crash",
        description="Copy every complete record of an MCAP file that was cut short (power loss, "
        "killed recorder) into a complete new MCAP, and say what was recovered and where and why "
        "reading stopped. Damaged records are skipped (or repaired from the file's indexes) and "
        "reported.")
    parser.add_argument("input", type=Path, metavar="BROKEN.mcap",
                        help="the cut drive (left as it is: nothing is written into it)")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="FIXED.mcap",
                        help="the complete MCAP to write")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no report")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    bar = ProgressBar(sys.stderr, unit="messages") if not args.quiet else None
    try:
        report = recover_file(args.input, args.output, force=args.force, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        print(format_report(report, args.input, args.output))
    return 0
