"""``tankviz demo``: the simulated ecocar drive, live.

The simulated car plays its drive onto a python-can ``virtual`` bus in real time and ``tankviz
live`` runs on that bus, exactly as in a car; on stop (SIGHUP as SIGTERM) the car stops first, so
every frame it sent is read and recorded.
"""

from __future__ import annotations

import argparse

from bridge.apps.live import output_may_vanish, run_live
from bridge.apps.options import (
    Subparsers,
    add_record_options,
    add_server_options,
    add_stage_options,
)
from bridge.io.buses import BusSpec
from bridge.sim.car import DEMO_CHANNEL, SimulatedCar


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "demo", help="the simulated ecocar drive, live: open Foxglove and watch",
        description="Play the simulated ecocar drive onto a python-can virtual bus in real time "
        "and run the live pipeline on it: serve Foxglove and record to ./drives.")
    parser.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    parser.add_argument("--scenario", type=float, default=60.0, metavar="S",
                        help="length of the scenario before it starts again (default 60 s)")
    add_stage_options(parser, profile_default="ecocar")
    add_server_options(parser)
    add_record_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    car = SimulatedCar(seed=args.seed, scenario_s=args.scenario)

    def stop_car() -> None:
        car.stop()
        if car.is_alive():
            car.join(2.0)

    with output_may_vanish():  # (its last line too, when the terminal went away)
        try:
            return run_live(args, [BusSpec("can0", "virtual", DEMO_CHANNEL)],
                            start_feed=car.start, stop_feed=stop_car)
        finally:
            stop_car()
            print(f"the simulated car sent {car.sent:,} frames")
