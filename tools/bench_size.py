#!/usr/bin/env python3
"""Archive size: what a drive's MCAP costs against the BLF of the same frames (a report, not a
test).

It converts ``bridge/sim``'s ecocar drive on three buses (``benchlib.ecocar_log``, cached in
``--workdir``) three ways with ``tankviz convert`` — raw frames only, raw + decoded
(``--dbc ecocar``), with the scene (``--profile ecocar``) — and prints for each:

- the archive size and its ratio to the BLF (issue #26's goals: raw ≤ 1.0x, with decoded +
  scene ≤ 4x); for raw frames also as packed columns, the layout not taken (one array per
  field instead of a row per frame: ``docs/archive.md`` says why);
- bytes and count per MCAP record type, read with mcap's StreamReader (chunks not opened), and
  what the file would be without its MessageIndex records;
- the uncompressed message bytes per topic family (``frames``, decoded, ``/scene``, others);
- for the decoded topics: how many payload bytes are zero-valued fields written for explicit
  presence (proto3 ``optional``: absent ≠ 0, so a zero is written), read from the wire format.

``--levels`` also re-compresses each archive's chunk contents at other zstd levels and chunk
sizes, and prints size and compression time as ratios to the level and chunk size tankviz uses
(zstandard's default level 3, 4 MiB), measured in the same run, best of 3.
``budget_drives`` and ``archive_ratios`` measure issue #36's archive budget (tools/bench_report.py).

    python tools/bench_size.py                  # 650 s of driving (1.44 M frames)
    python tools/bench_size.py --frames 200000  # about 90 s, to iterate
"""

from __future__ import annotations

import argparse
import struct
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import zstandard
from mcap.opcode import Opcode
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import ECOCAR_DBC, ROOT, add_workdir, ecocar_log

KINDS = {"raw": [], "raw + decoded": ["--dbc", str(ECOCAR_DBC)],
         "with scene": ["--profile", "ecocar"]}
_RECORD = struct.Struct("<BQ")
_NAMES = {int(op): op.name for op in Opcode}


def convert(log: Path, output: Path, extra: list[str], env: Mapping[str, str] | None = None,
            cwd: Path | None = None) -> None:
    """``tankviz convert`` of ``log``; ``env`` and ``cwd``: those of the code run (``python -m
    bridge`` takes the package of the working folder first, e.g. a revision's worktree)."""
    command = [sys.executable, "-m", "bridge", "convert", str(log), "-o", str(output),
               "--quiet", "--force", *extra]
    subprocess.run(command, check=True, stderr=subprocess.DEVNULL,
                   env=dict(env) if env is not None else None, cwd=cwd)


def budget_drives(workdir: Path, frames: int, seconds: float, seed: int = 1
                  ) -> list[tuple[str, Path, list[str]]]:
    """Issue #36's three drives for its archive budget, each with the options of its full
    archive: the simulated ecocar BLF of ``frames`` frames (cached; ``--profile ecocar``), the
    highway car (``seconds`` of ``bridge/sim/highway``, BLF; ``--profile highway``) and a Toyota
    candump (``seconds`` of tests/toyota_log.py's drive; raw + decoded with
    ../shared/data/dbc/toyota_2017_pt.dbc, no profile), left out when that DBC is missing. The
    highway and Toyota logs are written anew in ``workdir``."""
    from bridge.sim.highway import simulate_highway
    from bridge.sinks.can_log_writer import write_log

    sys.path.insert(0, str(ROOT / "tests"))
    import toyota_log

    blf, meta = ecocar_log(workdir, frames, seed)
    drives = [(f"simulated ecocar BLF, {meta['frames']:,} frames", blf,
               ["--profile", "ecocar"])]
    highway = workdir / f"budget-highway-{seconds:g}s.blf"
    write_log(simulate_highway(duration_s=seconds, seed=0), highway, ".blf")
    drives.append((f"highway car BLF, {seconds:g} s", highway, ["--profile", "highway"]))
    if toyota_log.TOYOTA_DBC.is_file():
        toyota = toyota_log.write_log(toyota_log.toyota_drive(seconds),
                                      workdir / f"budget-toyota-{seconds:g}s.log")
        drives.append((f"Toyota candump, {seconds:g} s (raw + decoded: no profile)", toyota,
                       ["--dbc", str(toyota_log.TOYOTA_DBC)]))
    return drives


def archive_ratios(log: Path, full: list[str], workdir: Path,
                   env: Mapping[str, str] | None = None, cwd: Path | None = None
                   ) -> tuple[float, float]:
    """Issue #36's archive figures of ``log``: (raw archive, full archive converted with
    ``full``) / the log's size, in bytes; ``env`` and ``cwd`` as :func:`convert` takes them."""
    size = log.stat().st_size
    ratios = []
    for kind, extra in (("raw", []), ("full", full)):
        output = workdir / f"budget-{log.stem}-{kind}.mcap"
        convert(log, output, extra, env, cwd)
        ratios.append(output.stat().st_size / size)
    return ratios[0], ratios[1]


def record_bytes(path: Path) -> Counter[str]:
    """Bytes per record type (opcode, length and body), walking the file's record headers."""
    data = path.read_bytes()
    sizes: Counter[str] = Counter()
    at, end = 8, len(data) - 8  # between the magics
    while at + _RECORD.size <= end:
        opcode, length = _RECORD.unpack_from(data, at)
        sizes[_NAMES.get(opcode, f"opcode {opcode:#x}")] += _RECORD.size + length
        at += _RECORD.size + length
    return sizes


def record_counts(path: Path) -> Counter[str]:
    """Records per type, as mcap's StreamReader reads them (chunks not opened)."""
    with path.open("rb") as stream:
        return Counter(type(r).__name__ for r in
                       StreamReader(stream, skip_magic=False, emit_chunks=True).records)


def family(topic: str) -> str:
    if topic.startswith("/can/"):
        return "raw frames" if topic.endswith("/frames") else "decoded"
    return "scene" if topic.startswith("/scene") else "other"


def _varint(data: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, at


def zero_field_bytes(payload: bytes) -> tuple[int, int]:
    """(bytes of zero-valued fields, their number) in a flat protobuf message."""
    at, zero_bytes, zeros = 0, 0, 0
    while at < len(payload):
        start = at
        key, at = _varint(payload, at)
        wire = key & 7
        if wire == 0:
            value, at = _varint(payload, at)
            zero = value == 0
        elif wire == 1:
            zero = payload[at:at + 8] in (bytes(8), b"\0" * 7 + b"\x80")  # 0.0 and -0.0
            at += 8
        elif wire == 5:
            zero = payload[at:at + 4] in (bytes(4), b"\0\0\0\x80")
            at += 4
        elif wire == 2:
            length, at = _varint(payload, at)
            at += length
            zero = False
        else:
            raise ValueError(f"wire type {wire} in a decoded payload")
        if zero:
            zeros += 1
            zero_bytes += at - start
    return zero_bytes, zeros


def messages_report(path: Path) -> tuple[Counter[str], Counter[str], list[int]]:
    """Uncompressed message bytes and counts per topic family, and the decoded payloads'
    [bytes, zero-field bytes, zero fields, messages]."""
    sizes: Counter[str] = Counter()
    counts: Counter[str] = Counter()
    decoded = [0, 0, 0, 0]
    topics: dict[int, str] = {}
    with path.open("rb") as stream:
        for record in StreamReader(stream, skip_magic=False).records:
            if isinstance(record, Message):
                topic = family(topics[record.channel_id])
                sizes[topic] += 31 + len(record.data)  # record header and fields, and the data
                counts[topic] += 1
                if topic == "decoded":
                    zb, zn = zero_field_bytes(record.data)
                    decoded[0] += len(record.data)
                    decoded[1] += zb
                    decoded[2] += zn
                    decoded[3] += 1
            elif type(record).__name__ == "Channel":
                topics[record.id] = record.topic  # type: ignore[attr-defined]
    return sizes, counts, decoded


def chunk_contents(path: Path) -> bytes:
    with path.open("rb") as stream:
        return b"".join(zstandard.ZstdDecompressor().decompress(
            r.data, max_output_size=r.uncompressed_size)
            for r in StreamReader(stream, skip_magic=False, emit_chunks=True).records
            if isinstance(r, Chunk))


def levels_report(path: Path) -> None:
    raw = chunk_contents(path)
    cases = [(size, level) for size in (256 << 10, 1 << 20, 4 << 20, 16 << 20)
             for level in (1, 3, 6, 9)] + [(4 << 20, 12), (4 << 20, 19)]
    best = {case: (0, float("inf")) for case in cases}
    for _ in range(3):  # interleaved, best of 3
        for size, level in cases:
            pieces = [raw[i:i + size] for i in range(0, len(raw), size)]
            started = time.perf_counter()
            n = sum(len(zstandard.compress(p, level)) for p in pieces)
            best[size, level] = (n, min(best[size, level][1], time.perf_counter() - started))
    ref_n, ref_t = best[4 << 20, 3]
    print(f"  zstd on {len(raw):,} bytes of chunk contents (ratios to level 3, 4 MiB chunks):")
    for (size, level), (n, t) in best.items():
        print(f"    chunks {size >> 10:>6} KiB  level {level:>2}: size {n / ref_n:5.3f}  "
              f"time {t / ref_t:6.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--frames", type=int, default=1_440_000,
                        help="frames of the simulated drive (default: about 650 s)")
    parser.add_argument("--seed", type=int, default=1)
    add_workdir(parser)
    parser.add_argument("--levels", action="store_true",
                        help="also measure zstd levels and chunk sizes")
    parser.add_argument("--kinds", default=",".join(KINDS),
                        help=f"which conversions, comma-separated (default: {','.join(KINDS)})")
    args = parser.parse_args(argv)
    args.workdir.mkdir(parents=True, exist_ok=True)
    log, meta = ecocar_log(args.workdir, args.frames, args.seed)
    blf = log.stat().st_size
    print(f"BLF {log.name}: {blf:,} bytes, {meta['frames']:,} frames, "
          f"{meta['seconds_of_driving']:.0f} s of driving")
    rows = []
    for kind in [k.strip() for k in args.kinds.split(",")]:
        output = args.workdir / f"size-{log.stem}-{kind.replace(' ', '').replace('+', '-')}.mcap"
        convert(log, output, KINDS[kind])
        size = output.stat().st_size
        by_record, counts = record_bytes(output), record_counts(output)
        families, family_counts, decoded = messages_report(output)
        without = size - by_record["MESSAGE_INDEX"]
        rows.append((kind, size, without))
        print(f"\n{kind}: {size:,} bytes = {size / blf:.2f}x the BLF "
              f"(without MessageIndex records {without / blf:.2f}x)")
        for name, n in by_record.most_common():
            print(f"  {name:<17} {n:>12,} bytes {n / size:6.1%}  "
                  f"{counts.get(_record_class(name), 0):>9,} records")
        for name, n in families.most_common():
            print(f"  messages {name:<11} {family_counts[name]:>9,} messages, "
                  f"{n:>12,} bytes uncompressed")
        if decoded[3]:
            print(f"  decoded payloads: {decoded[0] / decoded[3]:.1f} bytes a message, of which "
                  f"{decoded[1] / decoded[3]:.1f} are {decoded[2] / decoded[3]:.1f} zero-valued "
                  f"fields ({decoded[1] / decoded[0]:.0%} of the payload bytes)")
        if args.levels:
            levels_report(output)
        if kind == "raw":
            columns = output.with_name(output.stem + "-columns.mcap")
            write_columns(output, columns)
            rows.append(("raw, as packed columns (not taken)", columns.stat().st_size,
                         columns.stat().st_size - record_bytes(columns)["MESSAGE_INDEX"]))
    print("\n| archive | size | x BLF | x BLF without MessageIndex |\n|---|---|---|---|")
    for kind, size, without in rows:
        print(f"| {kind} | {size / 1e6:.1f} MB | {size / blf:.2f} | {without / blf:.2f} |")
    return 0


def columns_class() -> Any:
    """The alternative to tankviz.CanFrameBlock's rows: one packed array per field."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    F = descriptor_pb2.FieldDescriptorProto
    file = descriptor_pb2.FileDescriptorProto(name="bench_columns.proto", package="bench",
                                              syntax="proto3")
    message = file.message_type.add(name="CanFrameColumns")
    for number, (name, kind, repeated) in enumerate(
            [("bus", F.TYPE_STRING, False), ("id", F.TYPE_UINT32, True),
             ("offset_ns", F.TYPE_UINT32, True), ("length", F.TYPE_UINT32, True),
             ("flags", F.TYPE_UINT32, True), ("data", F.TYPE_BYTES, False)], start=1):
        message.field.add(name=name, number=number, type=kind,
                          label=F.LABEL_REPEATED if repeated else F.LABEL_OPTIONAL)
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("bench.CanFrameColumns"))


def write_columns(raw: Path, output: Path) -> None:
    """The raw archive's blocks again, each as packed columns (same blocks, same recorder)."""
    from bridge.io.drives import ArchiveSource
    from bridge.pb.can_frame_pb2 import CanFrameBlock
    from bridge.sinks.mcap import Recorder
    from bridge.sinks.raw import cut

    columns = columns_class()
    with output.open("wb") as f:
        recorder = Recorder(f)
        for block in cut(ArchiveSource(raw)):
            rows = CanFrameBlock.FromString(block.payload).frames
            message = columns(
                bus=block.bus, id=[r.id for r in rows], offset_ns=[r.offset_ns for r in rows],
                length=[len(r.data) for r in rows], data=b"".join(r.data for r in rows),
                flags=[r.extended | r.fd << 1 | r.bitrate_switch << 2
                       | r.error_state_indicator << 3 | r.error << 4 | r.remote << 5
                       for r in rows])
            recorder.write(f"/can/{block.bus}/frames", message, block.t_ns)
        recorder.finish()


def _record_class(opcode_name: str) -> str:
    return "".join(part.capitalize() for part in opcode_name.split("_"))


if __name__ == "__main__":
    sys.exit(main())
