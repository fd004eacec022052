#!/usr/bin/env python3
"""A car on the network: the simulated ecocar drive played onto udp_multicast groups from a
process of its own, as a car's frames come from outside the bridge.

The drive (:func:`bridge.sim.ecocar.simulate`, every payload encoded with the bundled DBC) is
split by sensor as ``tools/bench_live.py`` splits it (``radar``: Radar*, ``camera``: Cam*,
``chassis``: the rest), each bus onto its own group (``--group radar=239.77.1.1``). The frames
keep the drive's order and its spacing, compressed to ``--rate`` frames/s over all buses (the
drive's own rate is about 2,300), sent in small batches (what is due every ``--batch-ms``),
each stamped with the wall clock when it is sent; the drive loops for ``--seconds``. At the end
it prints one JSON line: frames sent per bus, seconds, the worst lateness, its own CPU seconds.

    python tools/car_sender.py --rate 12000 --seconds 20 --group radar=239.77.1.1 ...
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

#: Seconds of simulated drive played (looped).
DRIVE_S = 60.0


def bus_of(name: str) -> str:
    """The bus a message of the ecocar DBC is sent on."""
    return "radar" if name.startswith("Radar") else "camera" if name.startswith("Cam") else \
        "chassis"


def drive(seconds: float = DRIVE_S) -> list[tuple[float, str, Any]]:
    """(seconds after the start at the drive's own rate, bus, message) of the simulated drive."""
    import can

    from bridge.sim.ecocar import simulate
    from bridge.sim.frames import load_ecocar

    names = {m.frame_id: m.name for m in load_ecocar().messages}
    out: list[tuple[float, str, Any]] = []
    t0: int | None = None
    for frame in simulate(duration_s=seconds):
        t0 = frame.timestamp_ns if t0 is None else t0
        out.append(((frame.timestamp_ns - t0) / 1e9, bus_of(names.get(frame.arbitration_id, "")),
                    can.Message(arbitration_id=frame.arbitration_id, data=frame.data,
                                is_extended_id=frame.is_extended, is_fd=frame.is_fd,
                                bitrate_switch=frame.bitrate_switch, dlc=frame.dlc)))
    return out


def play(groups: dict[str, str], rate: float, seconds: float, batch_s: float) -> dict[str, Any]:
    """Sends the drive onto ``groups`` (bus -> group) at ``rate`` frames/s for ``seconds``."""
    import can

    frames = drive()
    natural = len(frames) / DRIVE_S
    speed = rate / natural
    buses = {bus: can.Bus(interface="udp_multicast", channel=group)
             for bus, group in groups.items()}
    sends = {bus: b.send for bus, b in buses.items()}
    sent = dict.fromkeys(groups, 0)
    total = round(rate * seconds)
    n = len(frames)
    span = DRIVE_S / speed  # wall seconds of one loop of the drive
    late = 0.0
    clock, sleep, wall = time.monotonic, time.sleep, time.time
    cpu0 = time.process_time()
    start = clock()
    i = done = 0
    try:
        while done < total:
            now = clock() - start
            while done < total:
                loop, k = divmod(i, n)
                at = loop * span + frames[k][0] / speed
                if at > now:
                    break
                late = max(late, now - at)
                _, bus, message = frames[k]
                if bus in sends:
                    message.timestamp = wall()
                    sends[bus](message)
                    sent[bus] += 1
                    done += 1
                i += 1
            sleep(batch_s)
        elapsed = clock() - start
    finally:
        for b in buses.values():
            b.shutdown()
    return {"sent": sent, "seconds": elapsed, "late_max_s": late,
            "cpu_s": time.process_time() - cpu0, "speed": speed}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--group", action="append", required=True, metavar="BUS=GROUP")
    parser.add_argument("--rate", type=float, default=12_000.0, help="frames/s, all buses")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--batch-ms", type=float, default=1.0)
    args = parser.parse_args(argv)
    groups = dict(text.split("=", 1) for text in args.group)
    print("READY", flush=True)
    sys.stdin.readline()  # go
    print(json.dumps(play(groups, args.rate, args.seconds, args.batch_ms / 1e3)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
