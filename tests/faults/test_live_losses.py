"""What live loses or mends between the interface and the pipeline is counted and said, never
taken for something else:

- a frame stamped NaN (a socketcand server sending ``nan``) is a bad timestamp, not a lost bus:
  stamped with the time it was received, recorded, counted on ``/log``, ``/health`` and in the
  drive's metadata;
- frames the kernel dropped because the bridge read too late (the socket's receive buffer
  overflowed) are counted from the kernel's own drop counter, where python-can exposes the socket
  (udp_multicast, socketcan), and said the same way; the receive buffer is raised first;
- a run that got no frame says so (and, on a ``virtual`` bus, that only this process can feed it);
  the end-of-run line about slow viewers stays short.
"""

from __future__ import annotations

import json
import os
import re
import socket
import struct
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest
from conftest import timeout_scale
from harness import Viewer, assert_survived, start, steady, with_fault
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from waiting import wait_for

from bridge.io.buses import (
    BusLink,
    BusSpec,
    kernel_drops,
    meminfo_drops,
    raise_receive_buffer,
)
from bridge.pb import health_pb2

FAULT = (1.5, 3.0)


def nan_stamps() -> Iterator[tuple[float, Any]]:
    """The steady drive, every 7th frame of the fault stamped NaN."""
    for i, (at, frame, inside) in enumerate(with_fault(steady(4.5), FAULT)):
        if inside and i % 7 == 0:
            frame = frame._replace(timestamp_ns=float("nan"))
            yield at, "nan"  # counted by the test
        yield at, frame


def metadata(drives: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for path in sorted(drives.glob("*.mcap")):
        with path.open("rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == "tankviz":
                    out = {k: _json(v) for k, v in record.metadata.items()}
    return out


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text  # a string value


@pytest.mark.slow
def test_frames_stamped_nan_are_kept_stamped_when_received_and_counted(tmp_path: Path) -> None:
    car = start(tmp_path, f"{__file__}:nan_stamps")
    viewer = Viewer(car.url)
    ended = car.when("car: fault ends")

    recording = assert_survived(car, viewer, fault_ended=ended, on_log="stamped nan")

    bad = car.output.count("car: nan")
    assert bad > 10
    assert "bus can0 lost" not in car.output  # not taken for a lost bus
    assert metadata(car.drives)["bus_receive"]["can0"]["bad_timestamps"] == bad
    alarms = {a.id: a for h in recording["/health"] for a in h.alarms if a.active}
    assert alarms["bus.can0.bad_timestamps"].kind == health_pb2.ALARM_KIND_BAD_TIMESTAMPS
    counted = [b.bad_timestamps_total for h in recording["/health"] for b in h.buses]
    assert 0 < max(counted) <= bad
    logs = [m.message for m in recording["/log"] if m.message.startswith("bus can0: ")]
    assert re.fullmatch(r"bus can0: [\d,]+ frames? stamped nan s so far: each stamped with the "
                        r"time it was received instead, and recorded", logs[0]), logs


# --- the kernel's drop counter -----------------------------------------------------------------

def test_the_drop_counter_is_read_from_the_socket_memory_info() -> None:
    """SO_MEMINFO: the kernel's u32 counters of a socket; the drops (what SO_RXQ_OVFL reports)
    are the ninth."""
    assert meminfo_drops(struct.pack("9I", 7488, 8192, 0, 212992, 704, 0, 48, 0, 1991)) == 1991
    assert meminfo_drops(struct.pack("8I", *range(8))) is None  # a kernel without the counter


def overflow(sock: socket.socket, datagrams: int) -> None:
    """Send ``datagrams`` small datagrams to a local UDP socket that is not read."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for _ in range(datagrams):
            tx.sendto(b"x", sock.getsockname())


def test_a_local_udp_socket_counts_what_overflowed_its_buffer() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        assert kernel_drops(rx) == 0
        overflow(rx, 500)
        received = 0
        rx.setblocking(False)
        while True:
            try:
                rx.recv(16)
            except BlockingIOError:
                break
            received += 1
        assert received + (kernel_drops(rx) or 0) == 500
        assert received < 500


def test_the_receive_buffer_is_raised_as_far_as_the_os_allows() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        before = s.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        size = raise_receive_buffer(s, 4 << 20)
        assert size == s.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) >= before


def backlog_drops() -> int:
    """The packets this host dropped before any socket: the kernel's per-CPU input queue
    (netdev_max_backlog) was full, as a loopback's multicast finds it when the machine is too
    busy to empty it (``/proc/net/softnet_stat``, its second column; 0 where it is not)."""
    try:
        lines = Path("/proc/net/softnet_stat").read_text().split("\n")
    except OSError:
        return 0
    return sum(int(line.split()[1], 16) for line in lines if line.strip())


@pytest.mark.slow
def test_a_udp_multicast_bus_counts_the_frames_the_kernel_dropped() -> None:
    group = f"239.74.{os.getpid() % 250}.{time.monotonic_ns() % 250}"
    try:
        probe = can.Bus(interface="udp_multicast", channel=group)
    except Exception as exc:  # pragma: no cover - a machine without multicast
        pytest.skip(f"no udp_multicast here: {exc}")
    probe.shutdown()
    link = BusLink(BusSpec("can0", "udp_multicast", group), __import__("queue").SimpleQueue())
    link.start()
    assert link.opened.wait(10 * timeout_scale())
    sent = 60_000
    backlog_before = backlog_drops()
    with can.Bus(interface="udp_multicast", channel=group) as tx:
        for i in range(sent):
            tx.send(can.Message(arbitration_id=i & 0x7FF, data=b"12345678"))
            if i % 200 == 199:
                time.sleep(0.0005)  # the kernel's input queue empties (the socket is not read)
    received = 0

    def all_read() -> bool:
        nonlocal received
        got = len(link.poll())
        received += got
        return not got and received + link.receive.kernel_drops >= sent - lost_before

    # Each frame is in the socket or counted as dropped there, but for those the host dropped
    # before any socket (its input queue was full on a loaded machine): none where nothing was.
    lost_before = backlog_drops() - backlog_before
    assert wait_for(all_read, 30 * timeout_scale(), step=0.05)
    link.stop()
    link.close()
    assert link.receive.receive_buffer_bytes and link.receive.receive_buffer_bytes > 212992
    assert link.receive.kernel_drops > 0
    assert sent - lost_before <= received + link.receive.kernel_drops <= sent, lost_before


class SocketBus(can.BusABC):
    """A bus with a real (local UDP) socket beside its frames, as python-can's socketcan and
    udp_multicast buses have: what overflows that socket is what the kernel drops."""

    def __init__(self, frames: list[can.Message]) -> None:
        super().__init__(channel="x")
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.frames = frames

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return (self.frames.pop(0) if self.frames else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise NotImplementedError

    def shutdown(self) -> None:
        self.socket.close()
        super().shutdown()


@pytest.mark.slow
def test_frames_the_kernel_dropped_are_on_log_health_and_in_the_metadata(
        tmp_path: Path) -> None:
    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.live_engine import Live

    messages = [can.Message(timestamp=time.time() + i * 0.001, arbitration_id=0x7FF,
                            data=b"\0" * 8) for i in range(3000)]
    opened: list[SocketBus] = []

    def open_bus(spec: BusSpec) -> can.BusABC:
        opened.append(SocketBus(messages))
        return opened[-1]

    live = Live([BusSpec("can0", "fake", "x")], load_stages([], "ecocar"), drives=tmp_path,
                open_bus=open_bus, say=lambda text: None)
    runner = threading.Thread(target=live.run)
    runner.start()
    assert wait_for(lambda: bool(opened), 10 * timeout_scale())
    overflow(opened[0].socket, 60_000)  # more than the receive buffer takes
    dropped = kernel_drops(opened[0].socket)
    assert dropped
    health = live.drive.health
    assert health is not None
    assert wait_for(lambda: "bus.can0.frames_lost" in {a.id for a in health.active_alarms()},
                    10 * timeout_scale())  # a health check raised it
    # ... and a /health made since says so (it is made once a second: a drive stopped before
    # then would record the /log line only)
    next_health = (health.last_tick_ns // health.publish_ns + 1) * health.publish_ns
    assert wait_for(lambda: health.last_tick_ns >= next_health, 10 * timeout_scale())
    live.stop()
    runner.join(20)

    (drive,) = tmp_path.glob("*.mcap")
    with drive.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        found = list(reader.iter_decoded_messages(topics=["/log", "/health"]))
    logs = [m.message for _, c, _, m in found if c.topic == "/log"]
    lost = [text for text in logs if text.startswith("bus can0: ")]
    assert lost and re.fullmatch(
        r"bus can0: [\d,]+ frames lost in the receive buffer so far \(the kernel dropped them: "
        r"tankviz read too late; receive buffer [\d,]+ KB\)", lost[0]), logs
    alarms = {a.id: a for _, c, _, m in found if c.topic == "/health" for a in m.alarms}
    assert "bus.can0.frames_lost" in alarms
    assert alarms["bus.can0.frames_lost"].raised_count >= 1
    assert alarms["bus.can0.frames_lost"].kind == health_pb2.ALARM_KIND_FRAMES_LOST
    assert 0 < max(b.receive_dropped_total for _, c, _, m in found if c.topic == "/health"
                   for b in m.buses) <= dropped
    receive = metadata(tmp_path)["bus_receive"]["can0"]
    assert receive["kernel_drops"] == dropped
    assert receive["receive_buffer_bytes"] > 0


# --- the end of a run --------------------------------------------------------------------------

@pytest.mark.slow
def test_a_run_that_got_no_frame_says_so(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "bridge", "live", "--bus", f"can0=virtual:none-{os.getpid()}",
         "--profile", "ecocar", "--drives", str(tmp_path / "drives"), "--no-server",
         "--for", "1"], capture_output=True, text=True, cwd=tmp_path, timeout=90)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "no frame came on any bus: nothing was recorded" in result.stdout
    assert ("can0 is a python-can virtual bus: only this same process can send onto it"
            in result.stdout), result.stdout
    assert not list((tmp_path / "drives").glob("*.mcap"))


def test_the_slow_viewers_line_is_short() -> None:
    from bridge.apps.live import dropped_report
    from bridge.sinks.server import ClientStats

    stats = [ClientStats(f"10.0.0.{v}:5{v:04d}", sent=10_000, dropped=4000 + v,
                         topics=Counter({f"/can/can0/Message{i:03d}": 100 + i + v
                                         for i in range(40)}))
             for v in range(12)]
    line = dropped_report(stats)
    assert len(line) < 600, line
    assert line.startswith(f"{sum(s.dropped for s in stats):,} messages dropped for slow "
                           "viewers: 10.0.0.11:50011 lost 4,011 (/can/can0/Message039 150, ")
    assert "and 37 more topics" in line
    assert line.endswith("and 9 more viewers")
    assert re.search(r"10\.0\.0\.0:", line) is None


# --- a bus lost and back: the frames it missed ---------------------------------------------------

class FailingBus(can.BusABC):
    """A bus with ``frames`` to read that fails (as a socket does: an ``OSError``) once
    ``fail`` is set."""

    def __init__(self, frames: int) -> None:
        super().__init__(channel="x")
        self.frames = [can.Message(timestamp=time.time(), arbitration_id=1) for _ in range(frames)]
        self.fail = False

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.fail:
            raise can.CanOperationError("Failed to wait for IP/UDP socket") from OSError(5, "EIO")
        return (self.frames.pop() if self.frames else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise NotImplementedError


def test_a_bus_back_after_a_loss_says_about_how_many_frames_it_missed() -> None:
    """A bus read at 100 frames/s for 5 s, lost for 2 s: about 200 frames missed, an estimate
    from its rate before (on the link's clock, set by the test), said as such; a loss before a
    second of the bus was seen is not estimated."""
    import queue

    from bridge.io.buses import BusEvent

    now = [0.0]
    opened: list[FailingBus] = []
    may_open = threading.Event()
    may_open.set()

    def open_bus(spec: BusSpec) -> can.BusABC:
        assert may_open.wait(30)
        opened.append(FailingBus(500 if not opened else 0))
        return opened[-1]

    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    link = BusLink(BusSpec("radar", "fake", "x"), events, open_bus=open_bus,
                   backoff=(0.01, 0.01), clock=lambda: now[0])
    link.start()
    assert link.opened.wait(30)
    now[0] = 5.0
    assert len(link.poll()) == 500
    may_open.clear()
    opened[-1].fail = True
    assert link.poll() == []
    lost = events.get(timeout=30)
    assert not lost.up and lost.reason == "CanOperationError: Failed to wait for IP/UDP socket"
    now[0] = 7.0
    may_open.set()
    back = events.get(timeout=30)
    assert back.up and back.missed == 200 and back.rate == 100.0
    assert link.receive.missed_estimate == 200
    link.stop()
    link.close()
    # the end-of-run line says it is an estimate
    from bridge.apps.live import receive_report
    assert receive_report({"radar": link.receive}) == [
        "bus radar: about 200 frames missed while the bus was down (an estimate: its frame "
        "rate before times how long it was down)"]


def test_a_bus_lost_before_its_rate_is_known_says_the_frames_missed_are_not_known() -> None:
    import queue

    from bridge.io.buses import BusEvent

    now = [0.0]
    opened: list[FailingBus] = []

    def open_bus(spec: BusSpec) -> can.BusABC:
        opened.append(FailingBus(10))
        return opened[-1]

    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    link = BusLink(BusSpec("radar", "fake", "x"), events, open_bus=open_bus,
                   backoff=(0.01, 0.01), clock=lambda: now[0])
    link.start()
    assert link.opened.wait(30)
    now[0] = 0.5  # half a second: no rate to estimate with
    opened[-1].fail = True
    link.poll()
    assert not events.get(timeout=30).up
    back = events.get(timeout=30)
    link.stop()
    link.close()
    assert back.up and back.missed is None and link.receive.missed_estimate == 0
