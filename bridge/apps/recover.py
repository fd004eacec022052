"""``tankviz recover``: salvage what a power cut or a killed recorder left of a drive.

The recorder writes zstd chunks and flushes at least every second, so a drive cut by a power loss
or a SIGKILL is a valid header, a run of complete records (chunks, each followed by its message
indexes; metadata and attachments between them) and a partial last record, with no summary and no
footer; a file system may also leave zero bytes where the last data never reached the disk.
:func:`recover` reads such a file record by record with mcap's :class:`StreamReader`, steps over
damaged records where it can (below), stops cleanly at the first record it cannot read, and
writes every schema, channel, message (log time, publish time, sequence and data unchanged, in
file order), metadata record and attachment it found into a complete new MCAP (zstd chunks, with
a summary), plus a ``tankviz.recover`` metadata record saying what was recovered and where and why
reading stopped.

How a record is read. Before mcap parses a record, its 9-byte header (opcode, length) is checked:
a known opcode, and a length that fits in what is left of the file (so a cut record is recognised
without reading it, and a damaged length cannot make us allocate gigabytes). While mcap parses it,
no read goes past its declared end, and a record whose fields do not take exactly its length is
damaged (MCAP lets later versions append fields to a record, but the records tankviz copies have
none: extra bytes mean a damaged length, and skipping them would skip records unseen). Message
index records are not needed (the writer builds new ones): their fields are checked against their
length, and they are only counted; a file cut right after a chunk keeps every message of the chunk.
Where the file ends, where the disk cannot read it, or where the bytes are damaged and nothing
intact follows, reading stops: the record's offset and the reason are the report's ``stopped_at``
and ``stopped``.

A damaged record is stepped over, and reading goes on, wherever the file says where the next
record starts (only a file that can seek). If the file still has an intact summary (it ends with
a footer and the magic), its chunk, attachment and metadata indexes give where each of those
records, and each chunk's run of message indexes, starts and ends: a chunk, attachment or metadata
record whose header is damaged is read again with the opcode and length its index gives it (the
report's ``repaired``), and any other damaged record is stepped over to the end of what the index
says it is in (a damaged message index: to the end of its chunk's message indexes, losing no
message), or to the next record the indexes know. Without a summary (a drive cut before its end)
the next chunk, attachment, metadata or data end record that proves itself intact is searched for
byte by byte (a chunk or an attachment by its CRC, every one by fields that take exactly its
length). A record cut by the end of the file has nothing intact after it, so a cut file is read up
to its cut record exactly as before. So a cut never leads to a skip, and damage that is not a cut
(a byte changed on the disk or in a copy) loses only the damaged record.

A chunk whose CRC fails (or that does not decompress) is skipped and reading goes on: its record
framing being intact (known opcode, length within the file, its fields add up to exactly its
length), the damage is confined to the compressed payload that the CRC covers, the next record
starts where the length says, and every later chunk carries its own CRC: skipping loses the
messages of that one chunk (counted from the message indexes after it) instead of the rest of the
drive, which is what ``mcap recover`` does too. An attachment whose CRC fails is skipped the same
way. Messages whose channel was defined only in a skipped chunk are dropped and counted, unless
the file still has its summary, whose copies of the schemas and channels then stand in. Skipped
records are listed in the report (``skipped``, each with its offset, what was wrong and where
reading went on); a cut file never has any, so what it recovers is exactly a prefix of its
messages. Metadata records and attachments are copied wherever they are read intact: tankviz
writes a drive's databases and profile as attachments at its start, so a cut drive keeps them.

A file that does not start with the whole MCAP magic (an empty file, another format) is not
recovered: :class:`~bridge.errors.InputError`, and nothing is written.

The input is only ever read. The output is written as a hidden partial file of its own beside it
(:func:`bridge.sinks.outputs.atomic_output`) and renamed when the new MCAP is complete.

This module has the command, :func:`recover`, :func:`recover_file` and :func:`format_report`;
:mod:`bridge.apps.recover_salvage` reads and copies the records (its ``_Salvage``), and
:mod:`bridge.apps.recover_records` has the report (:class:`RecoverReport`, imported here) and the
checks of a record.
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
from bridge.errors import InputError, OutputError, check_input_path, shown
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
        raise OutputError(fixed, "is the file to recover; write the recovered drive to a new file")
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
