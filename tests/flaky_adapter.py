"""A CAN adapter a test unplugs and whose clock it steps, through files in a folder, so that it
works the same in live's own process and in its reading process (it is pickled into that one).

It receives a frame every millisecond, numbered from 1 in its payload across every opening, so
a recording with all of them holds each number once, in order. Unplugged (:meth:`unplug`), a bus
open breaks (``CanOperationError``) and opening fails (``CanInitializationError``). Its frames
are stamped with the wall clock plus the offset of :meth:`step_clock`. ``sent`` and ``opens``
count in the process that opens it.
"""

from __future__ import annotations

import time
from pathlib import Path

import can

from bridge.io.buses import BusSpec


class FlakyAdapter:
    def __init__(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        self.unplugged = folder / "unplugged"
        self.clock = folder / "clock"
        self.sent = 0
        self.opens = 0

    def unplug(self) -> None:
        self.unplugged.touch()

    def plug_in(self) -> None:
        self.unplugged.unlink()

    def step_clock(self, offset_s: float) -> None:
        """From now on its frames are stamped ``offset_s`` from the wall clock."""
        self.clock.write_text(str(offset_s))

    def offset_s(self) -> float:
        try:
            return float(self.clock.read_text())
        except (OSError, ValueError):  # (none yet, or being written)
            return 0.0

    def open(self, spec: BusSpec) -> can.BusABC:
        self.opens += 1
        if self.unplugged.exists():
            raise can.CanInitializationError("no such device")
        return _Bus(self)


class _Bus(can.BusABC):
    def __init__(self, adapter: FlakyAdapter) -> None:
        self.adapter = adapter
        self.next_at = time.monotonic()
        super().__init__(channel="flaky")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.adapter.unplugged.exists():
            raise can.CanOperationError("adapter unplugged")
        wait = self.next_at - time.monotonic()
        if wait > (timeout or 0.0):
            time.sleep(timeout or 0.0)
            return None, False
        time.sleep(max(wait, 0.0))
        self.next_at += 0.001
        self.adapter.sent += 1
        return can.Message(timestamp=time.time() + self.adapter.offset_s(), arbitration_id=0x100,
                           data=self.adapter.sent.to_bytes(8, "little")), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise NotImplementedError
