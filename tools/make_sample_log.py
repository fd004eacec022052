"""Write the bundled sample log ``bridge/data/ecocar_sample.blf``: 10 s of simulated ecocar
traffic (seed 0, bus ``can0``) from :func:`bridge.sim.ecocar.simulate`, as python-can's BLF writer
stores it.

    python tools/make_sample_log.py [OUTPUT]

Simulated timestamps are whole microseconds, so reading the log back (which rounds python-can's
float seconds to the microsecond) gives exactly the simulated frames.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from pathlib import Path

import can

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bridge.frame import Frame  # noqa: E402
from bridge.sim.ecocar import simulate  # noqa: E402

DEFAULT_OUTPUT = ROOT / "bridge" / "data" / "ecocar_sample.blf"
DURATION_S = 10.0
SEED = 0
BUS = "can0"


def channel(bus: str) -> int:
    """python-can's channel number for a bus name: ``can0`` -> 0 (BLF stores numbers)."""
    digits = bus.removeprefix("can")
    if not digits.isdigit():
        raise ValueError(f"bus {bus!r} has no channel number (BLF needs one, e.g. 'can0')")
    return int(digits)


def to_message(frame: Frame) -> can.Message:
    return can.Message(
        timestamp=frame.timestamp_ns / 1e9,
        arbitration_id=frame.arbitration_id,
        data=frame.data,
        dlc=frame.dlc or len(frame.data),
        channel=channel(frame.bus),
        is_extended_id=frame.is_extended,
        is_fd=frame.is_fd,
        bitrate_switch=frame.bitrate_switch,
        error_state_indicator=frame.error_state_indicator,
        is_error_frame=frame.is_error,
        is_remote_frame=frame.is_remote,
    )


def write_blf(path: Path, frames: Iterable[Frame]) -> int:
    """Write ``frames`` to the BLF file ``path``; returns how many."""
    count = 0
    with can.Logger(str(path)) as logger:
        for frame in frames:
            logger.on_message_received(to_message(frame))
            count += 1
    return count


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    path = Path(args[0]) if args else DEFAULT_OUTPUT
    count = write_blf(path, simulate(duration_s=DURATION_S, seed=SEED, bus=BUS))
    print(f"wrote {path} ({count} frames, {path.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
