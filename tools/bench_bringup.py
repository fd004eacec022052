#!/usr/bin/env python3
"""What the bring-up topics cost (a report, not a test): archive size and convert CPU with and
without them, and the live per-frame cost, measured in the same run.

Two drives, each written as a BLF first:

- ``toyota``: tests/toyota_log.py's Toyota (every message of ../shared/data/dbc/
  toyota_2017_pt.dbc at its cycle time, ~320 frames/s) converted with that DBC less every other
  message (by id) until half the frames are of ids it does not define;
- ``highway``: ``tankviz simulate --car highway``'s drive (four ids its databases do not
  define), converted with the highway profile.

Each is converted with the bring-up topics and with ``--no-bring-up``, interleaved, best of
``--runs`` (3) in CPU time (this process; the read-ahead is off, so that the reading is counted
too, the same for both), and the ratios printed first; then each bring-up topic's messages and
what leaving it out of the archive saves (the archive written again without it, with the
recorder's chunk size and zstd). The live per-frame cost is ``Pipeline.process_many`` of the
highway drive in reads of 50 ms, with a recorder and a viewer (a sink that records no file: it
gets every frame of the unknown ids) and with a recorder alone, with and without bring-up,
interleaved, best of ``--runs``, the garbage collector off.

    python tools/bench_bringup.py                 # 60 s drives
    python tools/bench_bringup.py --seconds 20 --runs 1
"""

from __future__ import annotations

import argparse
import collections
import gc
import io
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # tests/toyota_log.py

from mcap.reader import make_reader  # noqa: E402
from mcap.writer import CompressionType, Writer  # noqa: E402

from bridge.frame import NS, Frame  # noqa: E402
from bridge.pipeline.convert import convert  # noqa: E402
from bridge.pipeline.drive import Drive, load_stages  # noqa: E402
from bridge.sim.highway import simulate_highway  # noqa: E402
from bridge.sinks.base import Sink  # noqa: E402
from bridge.sinks.can_log_writer import write_log  # noqa: E402
from bridge.topics import BITS_LABELS_TOPIC, BITS_TOPIC  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import best_of, cpu_seconds  # noqa: E402

#: The goals: growth of the archive, and of convert's CPU time, with the bring-up topics.
SIZE_GOAL = 0.10
CPU_GOAL = 0.10


def toyota(folder: Path, seconds: float) -> tuple[Path, list[str], str]:
    """The Toyota's log and a DBC that defines the messages of half its frames."""
    import toyota_log

    drive = toyota_log.toyota_drive(seconds)
    log = toyota_log.write_log(drive, folder / "toyota.blf")
    messages = sorted(toyota_log.load_toyota().messages, key=lambda m: m.frame_id)
    rate = {m.name: 1.0 / toyota_log.cycle_time(m) for m in messages}
    total = sum(rate.values())
    dbc, removed, names = toyota_log.TOYOTA_DBC, 0.0, []
    for m in messages[::2]:
        if removed >= total / 2:
            break
        dbc = toyota_log.dbc_without(m.name, folder / f"toyota_{len(names)}.dbc", source=dbc)
        removed += rate[m.name]
        names.append(m.name)
    what = (f"toyota, {len(names)} of {len(messages)} messages ({removed / total:.0%} of the "
            "frames) unknown")
    return log, [str(dbc)], what


def highway(folder: Path, seconds: float) -> tuple[Path, list[str], str]:
    log = folder / "highway.blf"
    write_log(simulate_highway(duration_s=seconds, seed=0), log, ".blf")
    return log, [], "highway (simulated; 4 ids unknown)"


def best(runs: int, *contenders: Callable[[], Any]) -> list[float]:
    """The best CPU time of each contender over ``runs`` interleaved rounds."""
    named = {str(i): cpu_seconds(run) for i, run in enumerate(contenders)}
    return list(best_of(named, runs).values())


def without(path: Path, left_out: Sequence[str]) -> int:
    """The archive's bytes written again (the recorder's chunk size, zstd) without these
    topics."""
    out = io.BytesIO()
    writer = Writer(out, chunk_size=4 * 1024 * 1024, compression=CompressionType.ZSTD)
    writer.start()
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    with path.open("rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            if channel.topic in left_out:
                continue
            if channel.id not in channels:
                assert schema is not None
                if schema.id not in schemas:
                    schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                                schema.data)
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id])
            writer.add_message(channels[channel.id], message.log_time, message.data,
                               message.publish_time, message.sequence)
    writer.finish()
    return len(out.getvalue())


def topics(path: Path) -> dict[str, tuple[int, int]]:
    """Messages and bytes of each bring-up topic of an archive."""
    counts: dict[str, list[int]] = collections.defaultdict(lambda: [0, 0])
    with path.open("rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            t = channel.topic
            if t.endswith(("/ids", "/unknown")) or t in (BITS_TOPIC, BITS_LABELS_TOPIC):
                counts[t][0] += 1
                counts[t][1] += len(message.data)
    return {t: (n, b) for t, (n, b) in sorted(counts.items())}


class Viewer(Sink):
    """Stands for live's server: records no file, so it gets every unknown frame."""


def live_cost(frames: list[Frame], runs: int) -> list[float]:
    """µs per frame of ``process_many`` in reads of 50 ms: with bring-up and a viewer, without
    bring-up and a viewer, with bring-up and a recorder alone, without."""
    reads: list[list[Frame]] = []
    for frame in frames:
        if not reads or frame.timestamp_ns - reads[-1][0].timestamp_ns >= NS // 20:
            reads.append([])
        reads[-1].append(frame)

    def feed(bring_up: bool, viewer: bool) -> Callable[[], None]:
        def run() -> None:
            drive = Drive(load_stages([], "highway"), [Viewer()] if viewer else [],
                          bring_up=bring_up)
            drive.record(io.BytesIO(), attachment_time_ns=0)
            process = drive.pipeline.process_many
            collecting = gc.isenabled()
            gc.disable()
            try:
                for read in reads:
                    process(read)
                drive.finish()
            finally:
                if collecting:
                    gc.enable()
        return run

    times = best(runs, feed(True, True), feed(False, True), feed(True, False),
                 feed(False, False))
    return [t / len(frames) * 1e6 for t in times]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="each drive's length")
    parser.add_argument("--runs", type=int, default=3, help="rounds; the best counts")
    parser.add_argument("--workdir", type=Path,
                        help="write the logs and archives here (default: a temporary folder)")
    args = parser.parse_args()
    rows: list[tuple[str, str, str]] = []
    details: list[str] = []
    with tempfile.TemporaryDirectory(prefix="bench-bringup-") as tmp:
        folder = args.workdir or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for make in (toyota, highway):
            log, dbcs, what = make(folder, args.seconds)
            profile = "highway" if make is highway else None
            outputs = {on: folder / f"{log.stem}-{'on' if on else 'off'}.mcap"
                       for on in (True, False)}

            def conversion(on: bool, log: Path = log, dbcs: list[str] = dbcs,
                           profile: str | None = profile,
                           outputs: dict[bool, Path] = outputs) -> Callable[[], None]:
                return lambda: convert([log], outputs[on], dbcs, profile=profile, force=True,
                                       read_ahead=False, bring_up=on)

            cpu_on, cpu_off = best(args.runs, conversion(True), conversion(False))
            size_on, size_off = (outputs[on].stat().st_size for on in (True, False))
            growth, cpu = size_on / size_off - 1, cpu_on / cpu_off - 1
            rows.append((f"archive size with / without bring-up, {what}",
                         f"{growth:+.1%} ({size_on / 1e3:,.0f} / {size_off / 1e3:,.0f} kB)",
                         f"≤ +{SIZE_GOAL:.0%}  {'ok' if growth <= SIZE_GOAL else 'MISSED'}"))
            rows.append((f"convert CPU with / without bring-up, {what}",
                         f"{cpu:+.1%} ({cpu_on:.2f} / {cpu_off:.2f} s)",
                         f"≤ +{CPU_GOAL:.0%}  {'ok' if cpu <= CPU_GOAL else 'MISSED'}"))
            found = topics(outputs[True])
            whole = without(outputs[True], [])
            details.append(f"{what}, {log.stat().st_size / 1e3:,.0f} kB of BLF:")
            for topic, (count, size) in found.items():
                saved = whole - without(outputs[True], [topic])
                details.append(f"  {topic:<22} {count:>7,} messages {size / 1e3:>9,.1f} kB "
                               f"serialized; {saved / 1e3:>7,.1f} kB of the archive")
            saved = whole - without(outputs[True], list(found))
            details.append(f"  all of them: {saved / 1e3:,.1f} kB of the archive")
        frames = list(simulate_highway(duration_s=args.seconds, seed=0))
        viewer_on, viewer_off, alone_on, alone_off = live_cost(frames, args.runs)
        rows.append(("live per frame with / without bring-up, highway, a viewer and a recorder",
                     f"{viewer_on / viewer_off - 1:+.1%} ({viewer_on:.1f} / {viewer_off:.1f} µs)",
                     ""))
        rows.append(("live per frame with / without bring-up, highway, a recorder alone",
                     f"{alone_on / alone_off - 1:+.1%} ({alone_on:.1f} / {alone_off:.1f} µs)", ""))
    width = max(len(r[0]) for r in rows)
    now_width = max(len(r[1]) for r in rows)
    print(f"{'measure (same run)':<{width}}  {'now':<{now_width}}  goal")
    for measure, now, goal in rows:
        print(f"{measure:<{width}}  {now:<{now_width}}  {goal}".rstrip())
    print()
    print("\n".join(details))
    return 0


if __name__ == "__main__":
    sys.exit(main())
