"""``tankviz simulate``: the simulated ecocar drive written as a file.

``.mcap`` is the drive converted as ``tankviz convert`` would convert it (ecocar profile, the
simulation's seed and duration in the metadata); any other suffix that python-can writes
(.blf .asc .log .trc .csv .db) is a CAN log of the same frames. The output is checked before
anything is simulated and appears only complete.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import can

from bridge.apps.options import Subparsers
from bridge.errors import BridgeError
from bridge.io.logs import supported_suffixes
from bridge.pipeline.drive import Drive, load_stages
from bridge.sim.drive import simulate
from bridge.sinks.mcap import atomic_output, check_output


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "simulate", help="write the simulated ecocar drive as a CAN log or an MCAP",
        description="Write the simulated ecocar drive: a CAN log (.blf .asc .log .trc .csv .db) "
        "or a converted drive (.mcap with the ecocar profile).")
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--duration", type=float, default=60.0, metavar="S",
                        help="seconds of driving (default 60)")
    parser.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    output: Path = args.output
    check_output(output, force=args.force)
    frames = simulate(duration_s=args.duration, seed=args.seed)
    if output.suffix.lower() == ".mcap":
        drive = Drive(load_stages([], "ecocar"),
                      extra={"simulated": {"seed": args.seed, "duration_s": args.duration}})
        with atomic_output(output) as stream:
            drive.record(stream)
            count = drive.run(frames)
            drive.finish()
    else:
        if not any(str(output).lower().endswith(s) for s in supported_suffixes()):
            raise BridgeError(f"{output}: unknown log format; write .blf, .asc, .log, .trc, "
                              ".csv, .db or .mcap")
        count = 0
        with can.Logger(output) as logger:
            for frame in frames:
                logger.on_message_received(can.Message(
                    timestamp=frame.timestamp_ns / 1e9, arbitration_id=frame.arbitration_id,
                    data=frame.data, is_extended_id=frame.is_extended, is_fd=frame.is_fd,
                    bitrate_switch=frame.bitrate_switch, dlc=frame.dlc, channel=0))
                count += 1
    print(f"wrote {output}: {count:,} frames, {args.duration:g} s of the simulated ecocar drive "
          f"(seed {args.seed})")
    return 0
