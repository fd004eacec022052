"""A car and ``tankviz live`` in one process, for the fault tests.

python-can's ``virtual`` buses connect only inside one process, so this script runs both::

    python tests/faults/livecar.py --inject FILE.py:FUNC --channel NAME -- LIVE-ARGS...

``FUNC()`` (from FILE.py) gives the car's script: ``(seconds after the start, what)`` in time
order, where ``what`` is a :class:`bridge.frame.Frame` (sent on the bus with its own stamp, so a
fault may stamp it as it likes), a string (printed as ``car: TEXT`` at that moment, e.g. where a
fault begins and ends), or a callable (called then: a fault that is not a frame). The car starts
once live listens on the bus, and stops live with SIGTERM one second after its last step. Live
runs as ``tankviz live --bus can0=virtual:NAME LIVE-ARGS...`` in the main thread, as the command
runs in a car. At the end the script prints ``car: sent N frames, at most S s late`` (S: how far
behind its script the car sent a frame: a car in a thread of a stalled process sends late, with
the stamps it planned, which a kernel never does) and exits with live's status.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import can
from can.interfaces import virtual

from bridge.cli import main
from bridge.frame import Frame


def load(spec: str) -> Callable[[], Iterable[tuple[float, Any]]]:
    path, name = spec.rsplit(":", 1)
    module_spec = importlib.util.spec_from_file_location(Path(path).stem, path)
    assert module_spec is not None and module_spec.loader is not None
    module = importlib.util.module_from_spec(module_spec)
    # as pytest runs it: its folder and tests/ (conftest, waiting) importable
    sys.path[:0] = [str(Path(path).parent), str(Path(__file__).resolve().parents[1])]
    module_spec.loader.exec_module(module)
    func: Callable[[], Iterable[tuple[float, Any]]] = getattr(module, name)
    return func


def drive(channel: str, script: Iterable[tuple[float, Any]], sent: list[int],
          late: list[float]) -> None:
    bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True,
                  receive_own_messages=False)
    try:
        from waiting import timeout_scale, wait_for  # (tests/ is on the path: see load)

        if not wait_for(lambda: len(virtual.channels.get(channel, ())) >= 2,  # live's bus too
                        60 * timeout_scale()):
            raise SystemExit(f"car: live never opened its bus {channel}")
        steps = iter(script)
        first = next(steps, None)  # (a script may take a while to make its frames: not late)
        start = time.monotonic()
        for at, what in itertools.chain([first] if first is not None else [], steps):
            delay = start + at - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:  # the process stalled (a loaded machine): live's wall clock ran on meanwhile
                late[0] = max(late[0], -delay)
            if isinstance(what, Frame):
                bus.send(can.Message(
                    timestamp=what.timestamp_ns / 1e9, arbitration_id=what.arbitration_id,
                    data=what.data, is_extended_id=what.is_extended, is_fd=what.is_fd,
                    bitrate_switch=what.bitrate_switch, dlc=what.dlc,
                    is_error_frame=what.is_error))
                sent[0] += 1
            elif isinstance(what, str):
                print(f"car: {what}", flush=True)
            else:
                what()
        time.sleep(1.0)
    finally:
        bus.shutdown()
        os.kill(os.getpid(), signal.SIGTERM)


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--inject", required=True, metavar="FILE.py:FUNC")
    parser.add_argument("--channel", required=True)
    parser.add_argument("live", nargs=argparse.REMAINDER)
    args = parser.parse_args()
    sent, late = [0], [0.0]
    car = threading.Thread(target=drive, args=(args.channel, load(args.inject)(), sent, late),
                           daemon=True)
    car.start()
    live_args = [a for a in args.live if a != "--"]
    code = main(["live", "--bus", f"can0=virtual:{args.channel}", *live_args])
    print(f"car: sent {sent[0]} frames, at most {late[0]:.3f} s late", flush=True)
    sys.exit(code)
