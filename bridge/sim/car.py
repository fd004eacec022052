"""``tankviz demo``: the simulated ecocar drive on a python-can ``virtual`` bus, in real time.

:class:`SimulatedCar` plays the scenario engine's frames onto a virtual bus at the pace they were
made, looping the scenario with fresh times; ``tankviz demo`` runs it next to the live pipeline,
so everything downstream is exactly what a real car's bus would give.
"""

from __future__ import annotations

import threading
import time

import can

from bridge.sim.ecocar import simulate

#: The virtual bus channel the demo car and the live pipeline share.
DEMO_CHANNEL = "tankviz-demo"


class SimulatedCar(threading.Thread):
    """Sends the simulated drive onto a virtual bus in real time until stopped."""

    def __init__(self, *, channel: str = DEMO_CHANNEL, seed: int = 0,
                 scenario_s: float = 60.0, speed: float = 1.0) -> None:
        super().__init__(name="tankviz-demo-car", daemon=True)
        self.channel = channel
        self.seed = seed
        self.scenario_s = scenario_s
        self.speed = speed
        self.stopping = threading.Event()
        self.sent = 0

    def stop(self) -> None:
        self.stopping.set()

    def run(self) -> None:
        bus = can.Bus(interface="virtual", channel=self.channel)
        try:
            while not self.stopping.is_set():
                self._play(bus)
        finally:
            bus.shutdown()

    def _play(self, bus: can.BusABC) -> None:
        start_ns = time.time_ns()
        started = time.monotonic()
        for frame in simulate(duration_s=self.scenario_s, seed=self.seed, start_ns=start_ns):
            due = started + (frame.timestamp_ns - start_ns) / 1e9 / self.speed
            delay = due - time.monotonic()
            if delay > 0 and self.stopping.wait(delay):
                return
            if self.stopping.is_set():
                return
            bus.send(can.Message(
                timestamp=frame.timestamp_ns / 1e9, arbitration_id=frame.arbitration_id,
                data=frame.data, is_extended_id=frame.is_extended, is_fd=frame.is_fd,
                bitrate_switch=frame.bitrate_switch, dlc=frame.dlc))
            self.sent += 1
