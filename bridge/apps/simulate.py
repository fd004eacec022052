"""``tankviz simulate``: a simulated drive written as a file.

An ``.mcap`` is the drive converted as ``tankviz convert`` would, any other suffix python-can
writes a CAN log that reads back exactly the frames written; a format that cannot hold the drive
(:data:`CANNOT_HOLD`) is refused before anything is simulated, and the output appears only
complete, also when the run is stopped.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from bridge.apps.options import (
    Stopped,
    Subparsers,
    add_bring_up_option,
    seconds_above_zero,
    stopped_by_signals,
)
from bridge.apps.progress import ProgressBar
from bridge.errors import FileError, UsageError
from bridge.frame import NS, Frame
from bridge.io.can_logs import supported_suffixes
from bridge.pipeline.drive import Drive, load_stages
from bridge.sim.ecocar import simulate
from bridge.sim.highway import ROADS, simulate_highway
from bridge.sinks.can_log_writer import write_log
from bridge.sinks.outputs import atomic_output, check_output

#: Log formats that cannot hold a simulated drive, and why.
CANNOT_HOLD = {".blf.gz": "python-can cannot write BLF into gzip"}
#: ... and those that cannot hold the ecocar's drive (it has CAN FD frames).
CANNOT_HOLD_FD = {
    ".trc": "python-can's TRC writer cannot write CAN FD frames, and the drive has them",
    ".trc.gz": "python-can's TRC writer cannot write CAN FD frames, and the drive has them",
}
#: Log formats without a column for the CAN FD flags (FD, bitrate switch).
NO_FD_FLAGS = {".csv": "CSV", ".csv.gz": "CSV", ".db": "SQLite"}
#: Log formats without a column for the channel: every frame is read back on can0.
NO_CHANNEL = NO_FD_FLAGS
_HOLDS = ".blf, .asc, .log, .csv, .db (or .asc.gz, .log.gz, .csv.gz) or .mcap"
#: The cars that can be simulated; each is also the name of its bundled profile.
CARS = ("ecocar", "highway")


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        # the summary is also cli.SUMMARIES["simulate"] (tankviz --help loads no command)
        "simulate",
        help="write a simulated drive (ecocar, or the highway car) as a CAN log or an MCAP",
        description="Write a simulated drive: a CAN log (.blf .asc .log .csv .db) "
        "or a converted drive (.mcap with the car's profile).")
    parser.add_argument("-o", "--output", type=Path, required=True,
                        help="the file to write; its suffix says what: a CAN log (.blf, .asc, "
                        ".log, .csv, .db; .asc.gz, .log.gz, .csv.gz) or .mcap, the drive "
                        "converted with the car's profile")
    parser.add_argument("--car", choices=CARS, default="ecocar",
                        help="ecocar (default: the student test car, one bus) or highway (a "
                        "production car with a 16-slot radar on can1, chassis on can0)")
    parser.add_argument("--road", choices=list(ROADS), default=None,
                        help="the highway car's road: curve (default: one left-hand curve), "
                        "winding (five curves of 1 to 2 deg/s), straight, or weaving (straight, "
                        "the ego changing lanes)")
    parser.add_argument("--duration", default="60", metavar="S",
                        help="seconds of driving (default 60)")
    parser.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")
    add_bring_up_option(parser)  # (an .mcap's topics; a log has none)
    parser.set_defaults(run=run)


def duration_seconds(text: str) -> float:
    """``--duration``: a finite number of seconds > 0."""
    return seconds_above_zero("--duration", text)


def log_format(output: Path, car: str = "ecocar") -> str:
    """The log suffix of ``output`` (``.asc.gz`` for a gzipped one), refused where python-can
    cannot write the drive of ``car`` into it."""
    name = output.name.lower()
    suffix = next((s for s in sorted(supported_suffixes(), key=len, reverse=True)
                   if name.endswith(s)), None)
    if suffix is None:
        suffix = next((s for s in CANNOT_HOLD if name.endswith(s)), None)
    if suffix is None:
        raise FileError(output, f"unknown log format; write {_HOLDS}")
    cannot = {**CANNOT_HOLD, **CANNOT_HOLD_FD} if car == "ecocar" else CANNOT_HOLD
    if suffix in cannot:
        raise FileError(output, f"{cannot[suffix]}; write {_HOLDS}")
    return suffix


def with_progress(frames: Iterable[Frame], duration_s: float,
                  progress: Callable[[int, float | None], None], *,
                  every: int = 4096) -> Iterator[Frame]:
    """``frames``, calling ``progress(count, fraction of the drive's time)`` every ``every``
    frames and at the end (``fraction`` 1.0)."""
    count, first = 0, None
    for frame in frames:
        if first is None:
            first = frame.timestamp_ns
        count += 1
        if count % every == 0:
            progress(count, min((frame.timestamp_ns - first) / NS / duration_s, 1.0))
        yield frame
    progress(count, 1.0)


def _noting_buses(frames: Iterable[Frame], buses: set[str]) -> Iterator[Frame]:
    for frame in frames:
        buses.add(frame.bus)
        yield frame


def run(args: argparse.Namespace) -> int:
    output: Path = args.output
    duration = duration_seconds(args.duration)
    car: str = args.car
    suffix = None if output.suffix.lower() == ".mcap" else log_format(output, car)
    check_output(output, force=args.force)
    if args.road is not None and car != "highway":
        raise UsageError("--road", "only the highway car has other roads "
                         "(--car highway)", value=args.road)
    frames = (simulate(duration_s=duration, seed=args.seed) if car == "ecocar"
              else simulate_highway(duration_s=duration, seed=args.seed,
                                    road=args.road or "curve"))
    simulated: dict[str, object] = {"seed": args.seed, "duration_s": duration}
    if car != "ecocar":  # an ecocar drive's metadata stays as it was
        simulated["car"] = car
    if args.road is not None:  # the highway's default drive's metadata stays as it was
        simulated["road"] = args.road
    bar = ProgressBar(sys.stderr)  # silent off a terminal
    frames = with_progress(frames, duration, bar)
    fd = 0
    buses: set[str] = set()
    try:
        with stopped_by_signals():
            if suffix is None:
                drive = Drive(load_stages([], car), extra={"simulated": simulated},
                              bring_up=args.bring_up)
                with atomic_output(output, force=args.force) as stream:
                    drive.record(stream)
                    count = drive.run(frames)
                    drive.finish()
            else:
                count, fd = write_log(_noting_buses(frames, buses), output, suffix,
                                      force=args.force)
    except Stopped as stop:
        print(f"{stop}: {output} not written", file=sys.stderr)
        return 128 + stop.signum
    finally:
        bar.close()
    if suffix in NO_FD_FLAGS and fd:
        print(f"warning: {output}: {NO_FD_FLAGS[suffix]} has no column for the CAN FD flags: "
              f"its {fd:,} CAN FD frames are read back without the FD flag and the bitrate "
              "switch (id, time and data are kept)", file=sys.stderr)
    if suffix in NO_CHANNEL and len(buses) > 1:
        print(f"warning: {output}: {NO_CHANNEL[suffix]} has no column for the bus: the frames "
              f"of {', '.join(sorted(buses))} are all read back on can0", file=sys.stderr)
    print(f"wrote {output}: {count:,} frames, {duration:g} s of the simulated {car} drive "
          f"(seed {args.seed})")
    return 0
