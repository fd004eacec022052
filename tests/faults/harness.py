"""What every live fault test does: run a car with a fault and ``tankviz live`` in a subprocess
(tests/faults/livecar.py), watch it as a Foxglove viewer, and check that live survived.

A live fault test asserts all of :func:`assert_survived`: the process was alive until the car
stopped it (and then exited 0), viewers got a scene within 1 s of the fault's end, every frame
the car sent is in the recording, and the fault is on ``/log``.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import websockets
from conftest import timeout_scale
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from waiting import wait_for

from bridge.frame import NS, Frame
from bridge.sim.ecocar import simulate

LIVECAR = Path(__file__).resolve().parent / "livecar.py"
SUBPROTOCOL = websockets.Subprotocol("foxglove.websocket.v1")


def steady(duration_s: float, *, seed: int = 0) -> Iterator[tuple[float, Frame]]:
    """The simulated ecocar's frames as the car sends them: at their time after the start,
    stamped with the wall clock of that moment (as socketcan and virtual buses stamp)."""
    frames = list(simulate(duration_s=duration_s, seed=seed))
    t0 = frames[0].timestamp_ns
    now = time.time_ns()
    for frame in frames:
        yield (frame.timestamp_ns - t0) / NS, frame._replace(
            timestamp_ns=now + frame.timestamp_ns - t0)



def with_fault(drive: Iterator[tuple[float, Any]], fault: tuple[float, float],
               ) -> Iterator[tuple[float, Any, bool]]:
    """The car's ``drive`` with the lines ``fault begins`` and ``fault ends`` (what the harness
    waits for) at the times of ``fault`` (seconds after the start); each item also says whether
    it is inside the fault."""
    began = ended = False
    for at, item in drive:
        if not began and at >= fault[0]:
            began = True
            yield at, "fault begins", False
        if not ended and at >= fault[1]:
            ended = True
            yield at, "fault ends", False
        yield at, item, began and not ended


class Opener:
    """An adapter whose opening fails as told, counting the attempts."""

    def __init__(self, error: Exception) -> None:
        self.error = error
        self.opens = 0

    def __call__(self, spec: Any) -> Any:
        self.opens += 1
        raise self.error

@dataclass
class LiveCar:
    """tankviz live with a car in a subprocess; its output lines with their arrival times."""

    process: subprocess.Popen[str]
    drives: Path
    url: str = ""
    lines: list[tuple[float, str]] = field(default_factory=list)

    def when(self, text: str, timeout: float = 60.0) -> float:
        """The wall time the line containing ``text`` was printed (waits for it, ``timeout``
        times timeout_scale() at most)."""

        def printed_or_ended() -> bool:
            return (any(text in line for _, line in list(self.lines))
                    or (self.process.poll() is not None and not self._reader.is_alive()))

        wait_for(printed_or_ended, timeout * timeout_scale(), step=0.02)
        for at, line in list(self.lines):
            if text in line:
                return at
        raise AssertionError(f"never printed {text!r}:\n{self.output}")

    @property
    def output(self) -> str:
        return "".join(line for _, line in self.lines)

    @property
    def late_s(self) -> float:
        """How far behind its script the car sent a frame, at most (once it has ended)."""
        return float(re.search(r"car: sent \d+ frames, at most ([\d.]+) s late",  # type: ignore[index]
                               self.output)[1])

    def wait(self, timeout: float = 120.0) -> int:
        code = self.process.wait(timeout * timeout_scale())
        self._reader.join(5.0)
        return code

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append((time.time(), line))


def start(tmp_path: Path, inject: str, *live_args: str) -> LiveCar:
    """Run the car script ``inject`` (``FILE.py:FUNC``) and tankviz live (ecocar profile unless
    ``live_args`` name one; port 0; drives into ``tmp_path/drives``)."""
    drives = tmp_path / "drives"
    args = list(live_args)
    if "--profile" not in args and "--dbc" not in args:
        args += ["--profile", "ecocar"]
    if "--drives" not in args:
        args += ["--drives", str(drives)]
    channel = f"fault-{os.getpid()}-{time.monotonic_ns()}"
    process = subprocess.Popen(
        [sys.executable, str(LIVECAR), "--inject", inject, "--channel", channel, "--",
         "--port", "0", *args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    car = LiveCar(process, drives)
    car._reader = threading.Thread(target=car._read, daemon=True)  # type: ignore[attr-defined]
    car._reader.start()  # type: ignore[attr-defined]
    if "--no-server" not in args:
        car.when("Foxglove: open connection")
        car.url = re.search(r"ws://\S+", car.output)[0]  # type: ignore[index]
    return car


@dataclass
class Viewer:
    """A Foxglove viewer in a thread: subscribes to ``topics`` and notes each message's arrival
    (wall time, topic, payload)."""

    url: str
    topics: tuple[str, ...] = ("/scene/ego", "/log", "/health")
    got: list[tuple[float, str, bytes]] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)

    def __post_init__(self) -> None:
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self) -> None:
        async with websockets.connect(self.url, subprotocols=[SUBPROTOCOL]) as ws:
            names: dict[int, str] = {}
            while not self._stop.is_set():
                try:
                    raw = await asyncio.wait_for(ws.recv(), 0.2)
                except asyncio.TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    return
                if isinstance(raw, str):
                    message = json.loads(raw)
                    if message["op"] == "advertise":
                        wanted = [c for c in message["channels"] if c["topic"] in self.topics]
                        for c in wanted:
                            names[c["id"]] = c["topic"]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": c["id"], "channelId": c["id"]} for c in wanted]}))
                elif raw[0] == 1:
                    sub = int.from_bytes(raw[1:5], "little")
                    self.got.append((time.time(), names.get(sub, "?"), raw[13:]))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def scenes_after(self, t: float, topic: str = "/scene/ego") -> list[float]:
        return [at for at, name, _ in self.got if name == topic and at >= t]


def recorded(drives: Path) -> dict[str, list[Any]]:
    """Every message of every drive in ``drives``, decoded, by topic (in file order)."""
    out: dict[str, list[Any]] = {}
    for path in sorted(drives.glob("*.mcap")):
        with path.open("rb") as f:
            for _, channel, _, message in make_reader(
                    f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
                out.setdefault(channel.topic, []).append(message)
    return out


def assert_survived(car: LiveCar, viewer: Viewer | None, *, fault_ended: float,
                    on_log: str | None) -> dict[str, list[Any]]:
    """Live went on through the fault: see the module docstring. Returns the recording."""
    code = car.wait()
    if viewer is not None:
        viewer.stop()
    assert code == 0, car.output
    assert "Traceback" not in car.output, car.output
    sent = int(re.search(r"car: sent (\d+) frames", car.output)[1])  # type: ignore[index]
    recording = recorded(car.drives)
    frames = sum(len(block.frames) for block in recording.get("/can/can0/frames", []))
    assert frames == sent, f"{sent} frames sent, {frames} recorded"
    if viewer is not None:
        after = viewer.scenes_after(fault_ended)  # (1 s on a machine that is not loaded)
        assert after and after[0] - fault_ended < 1.0 * timeout_scale(), (
            f"no scene within {timeout_scale():g} s of the fault's end (next after {after[:1]})")
    if on_log is not None:
        logs = [m.message for m in recording.get("/log", [])]
        assert any(on_log in text for text in logs), f"{on_log!r} not on /log: {logs}"
    return recording
