#!/usr/bin/env python3
"""Benchmark ``tankviz live`` under a heavy three-bus load (a report, not a test): three python-can
``virtual`` buses carry 4,000 frames/s each of ``bridge/sim``'s ecocar drive into the live bridge
(ecocar profile, scene at 50 Hz, drives recorded) while three WebSocket clients read every
``/scene/*`` topic and a fourth stalls. It prints one table (metric, value, target, ok?): send
rates, frames recorded / sent, the bridge's CPU against references measured in the same run,
latency from a frame to the scene at the clients, GC pauses, RSS; a ``TARGET MISSED: ...`` line
per missed target; it exits 0 regardless. How each figure is taken: :class:`Sender`,
:func:`measure_references`, :func:`cpu_use`, :func:`analyse` and :func:`latency_rows`.

    python tools/bench_live.py --quick            # 10 s
    python tools/bench_live.py                    # 60 s
    python tools/bench_live.py --stages 120000    # the pipeline alone, stage by stage
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import os
import resource
import struct
import subprocess
import sys
import tempfile
import threading
import time
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

_path = list(sys.path)
sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import best_of, ecocar_drive  # noqa: E402

# benchlib puts the working tree first on the path: this bench measures the ``bridge`` the path
# had (``bench_report.py --before`` runs it on a revision's).
sys.path[:] = _path

if TYPE_CHECKING:
    import cProfile
    import pstats

    from bridge.frame import Frame
    from bridge.io.buses import BusSpec
    from bridge.pipeline.live_engine import Live
    from bridge.pipeline.pipeline import Pipeline
    from bridge.sinks.base import Sink
    from bridge.sinks.server import ViewerServer

MS = 1_000_000
NS = 1_000_000_000
BUSES = ("radar", "camera", "chassis")
#: This bench's name of each of benchlib's buses.
SENSOR = {"can0": "radar", "can1": "camera", "can2": "chassis"}
SCENE_RATE = 50.0
WARMUP_S = 0.5
TAIL_S = 0.1
#: Issue #15: a third of the 57 % of one core the bridge took when it was filed.
CPU_TARGET = 20.0
REFERENCE_FRAMES = 24_000
LATENCY_MARGIN_MS = 5.0
SUBPROTOCOL = "foxglove.websocket.v1"
_HEADER = struct.Struct("<BIQ")  # opcode, subscription id, timestamp (ns)


# --- the clients' process ---------------------------------------------------------------------

async def run_clients(url: str, out_path: str, readers: int, stalled_topics: str) -> None:
    """``readers`` clients read every /scene/* topic, one stalls; results go to ``out_path``.
    Runs in a process of its own (``--client``), so that the clients' CPU is not the bridge's."""
    clients: list[dict[str, Any]] = []
    tasks: list[asyncio.Task[None]] = []
    for _ in range(readers):
        client, task = await _reader(*await _connect(url))
        clients.append(client)
        tasks.append(task)
    stalled, client = await _stalled(url, stalled_topics)
    clients.append(client)
    print("READY " + json.dumps([c["address"] for c in clients]), flush=True)

    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)  # say stop
    for task in tasks:
        task.cancel()
    stalled.transport.abort()
    Path(out_path).write_text(json.dumps({"clients": clients}))
    print("DONE", flush=True)
    os._exit(0)  # the readers' sockets need no goodbye


async def _connect(url: str, **options: Any) -> tuple[Any, dict[str, int]]:
    """A connected client and the channels advertised to it (once the scene's are)."""
    import websockets

    ws = await websockets.connect(url, subprotocols=[websockets.Subprotocol(SUBPROTOCOL)],
                                  max_size=None, compression=None, **options)
    channels: dict[str, int] = {}
    while "/scene/radar" not in channels:
        message = await asyncio.wait_for(ws.recv(), 10)
        if isinstance(message, str):
            data = json.loads(message)
            if data.get("op") == "advertise":
                channels.update({c["topic"]: c["id"] for c in data["channels"]})
    return ws, channels


def _address(ws: Any) -> str:
    host, port = ws.local_address[:2]
    return f"{host}:{port}"


async def _reader(ws: Any, channels: dict[str, int]
                  ) -> tuple[dict[str, Any], asyncio.Task[None]]:
    """Subscribe ``ws`` to every /scene/* topic: its record and the task that reads it."""
    scene = sorted(t for t in channels if t.startswith("/scene/"))
    subscriptions = {i: topic for i, topic in enumerate(scene, start=1)}
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": channels[t]} for i, t in subscriptions.items()]}))
    got: dict[str, list[list[int]]] = {t: [] for t in scene}
    client = {"role": "reader", "address": _address(ws), "scenes": got, "messages": 0}
    task = asyncio.get_running_loop().create_task(_read(ws, subscriptions, got, client))
    return client, task


async def _read(ws: Any, subscriptions: dict[int, str], got: dict[str, list[list[int]]],
                client: dict[str, Any]) -> None:
    """Note (timestamp, wall-clock arrival) of every message, by topic."""
    clock = time.time_ns
    unpack = _HEADER.unpack_from
    while True:
        data = await ws.recv()
        now = clock()
        if isinstance(data, bytes) and data[0] == 1:
            _, sub, t_ns = unpack(data)
            got[subscriptions[sub]].append([t_ns, now])
            client["messages"] += 1


async def _stalled(url: str, stalled_topics: str) -> tuple[Any, dict[str, Any]]:
    """A client that subscribes to every channel (or the scene's) and then never reads."""
    # No keepalive pings from the stalled one (a browser sends none): the server's pong to a
    # client it cannot write to fails with an AssertionError in websockets' legacy protocol.
    # (The server's own keepalive ping, 20 s in, fails the same way and logs a traceback; the
    # connection stays registered and is fed until the end, so it still counts as stalled.)
    stalled, channels = await _connect(url, ping_interval=None)
    if stalled_topics == "scene":
        channels = {t: c for t, c in channels.items() if t.startswith("/scene/")}
    await stalled.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": c} for i, c in enumerate(channels.values(), start=1)]}))
    stalled.transport.pause_reading()
    return stalled, {"role": "stalled", "address": _address(stalled),
                     "subscribed": len(channels)}


# --- the car: three senders -----------------------------------------------------------------

def traffic(duration_s: float) -> dict[str, list[can.Message]]:
    """The simulated ecocar drive (:func:`benchlib.ecocar_drive`, every payload encoded with the
    bundled DBC) as python-can messages, split by sensor: ``radar`` carries RadarObj*/
    RadarHeader/RadarStatus, ``camera`` CamObstacle*/CamLane*, ``chassis`` everything else."""
    out: dict[str, list[can.Message]] = {bus: [] for bus in BUSES}
    for frame in ecocar_drive(duration_s, seed=0):
        out[SENSOR[frame.bus]].append(can.Message(
            arbitration_id=frame.arbitration_id, data=frame.data,
            is_extended_id=frame.is_extended, is_fd=frame.is_fd,
            bitrate_switch=frame.bitrate_switch, dlc=frame.dlc))
    return out


@dataclass
class Sender:
    """One bus of the car: cycles through its messages at ``rate`` frames/s for ``duration_s``,
    paced in real time in small batches (``batch_s``): it sleeps to its schedule and sends what
    is due; the achieved rate and the worst lateness are noted. The virtual bus stamps each
    frame with the wall clock at ``send``, so a frame's timestamp is when the car sent it. Its
    CPU (``time.thread_time()`` around the send loop) is subtracted from the bridge's; its
    contention for the GIL is not (a real adapter costs the bridge no GIL)."""

    bus: str
    channel: str
    messages: list[can.Message]
    rate: float
    duration_s: float
    batch_s: float
    sent: int = 0
    cpu_s: float = 0.0
    elapsed_s: float = 0.0
    late_max_s: float = 0.0
    thread: threading.Thread | None = None

    def start(self, go: threading.Event, start_at: list[float], opened: threading.Barrier) -> None:
        self.thread = threading.Thread(target=self._run, args=(go, start_at, opened),
                                       name=f"bench-sender-{self.bus}", daemon=True)
        self.thread.start()

    def _run(self, go: threading.Event, start_at: list[float],
             opened: threading.Barrier) -> None:
        bus = can.Bus(interface="virtual", channel=self.channel)
        opened.wait()
        go.wait()
        cpu0 = time.thread_time()
        t0 = start_at[0]
        total = round(self.rate * self.duration_s)
        messages, n, rate, batch = self.messages, len(self.messages), self.rate, self.batch_s
        send, monotonic, sleep = bus.send, time.monotonic, time.sleep
        i = sent = 0
        late = 0.0
        try:
            while sent < total:
                now = monotonic()
                due = min(total, int((now - t0) * rate))
                if due > sent:
                    late = max(late, now - (t0 + sent / rate))
                while sent < due:
                    send(messages[i])
                    i += 1
                    if i == n:
                        i = 0
                    sent += 1
                wake = t0 + (sent // max(1, round(batch * rate)) + 1) * batch
                delay = wake - monotonic()
                if delay > 0:
                    sleep(delay)
            self.elapsed_s = monotonic() - t0
        finally:
            self.sent = sent
            self.late_max_s = late
            bus.shutdown()
            self.cpu_s = time.thread_time() - cpu0


@dataclass
class Car:
    """The senders, one a bus, each waiting for :meth:`drive` on its open bus."""

    senders: list[Sender]
    go: threading.Event
    start_at: list[float]

    def drive(self) -> None:
        self.start_at[0] = time.monotonic()
        self.go.set()

    def driving(self) -> bool:
        return any(s.thread is not None and s.thread.is_alive() for s in self.senders)

    def join(self) -> None:
        for sender in self.senders:
            assert sender.thread is not None
            sender.thread.join()

    @property
    def sent(self) -> int:
        return sum(s.sent for s in self.senders)


def start_car(channels: dict[str, str], messages: dict[str, list[can.Message]], rate: float,
              seconds: float, batch_s: float, opened: threading.Barrier,
              go: threading.Event) -> Car:
    """A :class:`Sender` on each bus (``channels``: bus -> virtual channel), its bus open when
    this returns (``opened``: one party per sender and one for this thread, more if others
    wait too); they send once ``go`` is set (:meth:`Car.drive`)."""
    start_at = [0.0]
    senders = [Sender(bus, channel, messages[bus], rate, seconds, batch_s)
               for bus, channel in channels.items()]
    for sender in senders:
        sender.start(go, start_at, opened)
    opened.wait()
    return Car(senders, go, start_at)


# --- measuring ------------------------------------------------------------------------------

CLK_TCK = os.sysconf("SC_CLK_TCK")


def process_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def thread_cpu() -> dict[int, float]:
    """CPU seconds (utime + stime) of every thread of this process, by native thread id."""
    out: dict[int, float] = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            stat = Path(f"/proc/self/task/{tid}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        out[int(tid)] = (int(fields[11]) + int(fields[12])) / CLK_TCK
    return out


def other_processes_cpu(exclude: set[int]) -> dict[int, float]:
    """CPU seconds (utime + stime) of every other process on the machine, by pid."""
    out: dict[int, float] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and int(entry) not in exclude:
            cpu = child_cpu(int(entry))
            if cpu:
                out[int(entry)] = cpu
    return out


def child_cpu(pid: int) -> float:
    """CPU seconds (utime + stime) of another process of ours."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0.0
    fields = stat[stat.rindex(")") + 2:].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def rss_now_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@dataclass
class CpuMark:
    """The clocks at one end of the window: wall, this process, the harness (main thread),
    each thread of this process, every other process, the clients' process."""

    wall: float
    process: float
    harness: float
    threads: dict[int, float]
    others: dict[int, float]
    clients: float


def mark_start(clients_pid: int) -> CpuMark:
    """The clocks just before the car drives (this process's and the wall clock last)."""
    threads = thread_cpu()
    others = other_processes_cpu({os.getpid(), clients_pid})
    clients = child_cpu(clients_pid)
    process, harness = process_cpu(), time.thread_time()
    return CpuMark(time.monotonic(), process, harness, threads, others, clients)


def mark_end(clients_pid: int) -> CpuMark:
    """The clocks once everything is passed on (the wall clock and this process's first)."""
    wall = time.monotonic()
    process, harness = process_cpu(), time.thread_time()
    threads = thread_cpu()
    return CpuMark(wall, process, harness, threads,
                   other_processes_cpu({os.getpid(), clients_pid}), child_cpu(clients_pid))


@dataclass
class CpuUse:
    """CPU seconds over the window, by whom (see :func:`cpu_use`)."""

    wall: float
    process: float
    senders: float
    harness: float
    by_thread: dict[str, float]
    clients: float
    others: float

    def pct(self, seconds: float) -> float:
        """``seconds`` of CPU over the window, as % of one core."""
        return 100 * seconds / self.wall

    @property
    def bridge_pct(self) -> float:
        return self.pct(self.process - self.senders - self.harness)

    @property
    def bridge_threads_pct(self) -> float:
        return self.pct(sum(v for k, v in self.by_thread.items() if k.startswith("tankviz-")))


def thread_names(senders: Sequence[Sender]) -> dict[int, str]:
    """The name of every thread of this process (the senders' too), by native id."""
    names = {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}
    names.update({s.thread.native_id: s.thread.name for s in senders
                  if s.thread is not None and s.thread.native_id is not None})
    names[threading.main_thread().native_id or 0] = "harness (main thread)"
    return names


def cpu_use(start: CpuMark, end: CpuMark, senders: Sequence[Sender],
            names: dict[int, str]) -> CpuUse:
    """``bridge CPU = Δ process CPU (getrusage, all threads) - Σ sender CPU - Δ CPU of the
    harness (the main thread: it sleeps and samples backlogs every 50 ms)`` over the window
    from just before the senders start until everything is processed and passed on, divided by
    its wall time: % of one core; the clients' process is not included. The cross-check sums
    ``/proc/self/task/<tid>/stat`` of the bridge's own threads over the same window. The CPU
    of other processes (those alive at both ends) says how loaded the machine was."""
    by_thread: dict[str, float] = {}
    for tid, after in end.threads.items():
        name = names.get(tid, f"thread {tid}")
        by_thread[name] = by_thread.get(name, 0.0) + after - start.threads.get(tid, 0.0)
    others = sum(cpu - start.others[pid] for pid, cpu in end.others.items()
                 if pid in start.others)
    return CpuUse(end.wall - start.wall, end.process - start.process,
                  sum(s.cpu_s for s in senders), end.harness - start.harness, by_thread,
                  end.clients - start.clients, others)


class GcWatch:
    """Every garbage collection's pause (a ``gc.callbacks`` entry): in wall time (what the
    pipeline and the server wait) and in the collecting thread's CPU time (what the collector
    itself costs, whatever else the machine runs)."""

    def __init__(self) -> None:
        self.pauses: list[tuple[int, float]] = []  # (generation, wall seconds)
        self.cpu: list[float] = []
        self._started = (0.0, 0.0)

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._started = time.perf_counter(), time.thread_time()
        else:
            self.pauses.append((info["generation"], time.perf_counter() - self._started[0]))
            self.cpu.append(time.thread_time() - self._started[1])

    @property
    def longest_ms(self) -> float:
        return 1e3 * max((d for _, d in self.pauses), default=0)


def percentile(values: Sequence[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, int(q * len(ordered) + 0.5) - 1))]


def spread(values: Sequence[float]) -> str:
    """``p50 / p99 / max ms`` of ``values`` (ms)."""
    return (f"{percentile(values, 0.5):.1f} / {percentile(values, 0.99):.1f} / "
            f"{max(values, default=float('nan')):.1f} ms")


class Histogram:
    """Latencies in 10 µs bins (exact maximum kept), for millions of frames."""

    BIN_NS = 10_000

    def __init__(self) -> None:
        self.bins: dict[int, int] = {}
        self.count = 0
        self.max_ns = -(1 << 62)
        self.min_ns = 1 << 62

    def add(self, latency_ns: int, n: int = 1) -> None:
        key = latency_ns // self.BIN_NS
        self.bins[key] = self.bins.get(key, 0) + n
        self.count += n
        self.max_ns = max(self.max_ns, latency_ns)
        self.min_ns = min(self.min_ns, latency_ns)

    def quantile_ms(self, q: float) -> float:
        if not self.count:
            return float("nan")
        rank = max(1, int(q * self.count + 0.5))
        seen = 0
        for key in sorted(self.bins):
            seen += self.bins[key]
            if seen >= rank:
                return (key + 1) * self.BIN_NS / MS  # upper edge of the bin
        return self.max_ns / MS


@dataclass
class DriveAnalysis:
    frames_by_bus: dict[str, int]
    scenes: int
    frame_latency: Histogram
    delivery_ms: list[float] = field(default_factory=list)
    delivery_at: list[int] = field(default_factory=list)  # the tick of each delivery_ms
    oldest_ms: list[float] = field(default_factory=list)
    frames_in_window: int = 0
    frames_without_scene: int = 0  # in the window, but their scene never reached a reader
    scenes_in_window: int = 0
    scenes_missed: list[int] = field(default_factory=list)  # per reader, scenes in the window
    complete: list[dict[int, int]] = field(default_factory=list)  # per reader: tick -> received


def summary_frame_counts(files: Sequence[Path]) -> dict[str, int]:
    """Frames per bus the drive's parts hold (a tankviz from before raw frames were written in
    blocks, as ``bench_report.py --before`` measures it: one frame a message)."""
    from mcap.reader import make_reader

    raw_frame_counts: Callable[[Any], dict[str, int]]
    try:
        from bridge.io.drives import raw_frame_counts
    except ImportError:
        raw_frame_counts = _message_counts
    counts: dict[str, int] = {}
    for path in files:
        with path.open("rb") as f:
            for bus, n in raw_frame_counts(make_reader(f)).items():
                counts[bus] = counts.get(bus, 0) + n
    return counts


def _message_counts(reader: Any) -> dict[str, int]:
    summary = reader.get_summary()
    out: dict[str, int] = {}
    for channel_id, n in summary.statistics.channel_message_counts.items():
        topic = summary.channels[channel_id].topic
        if topic.startswith("/can/") and topic.endswith("/frames"):
            out[topic.split("/")[2]] = out.get(topic.split("/")[2], 0) + n
    return out


def scene_contents(files: Sequence[Path], frames_before: dict[int, int],
                   window: tuple[int, int]) -> list[tuple[int, array[int]]]:
    """Each tick and the stamps of the frames its scene contains (those in the window): the
    drive's frames, read back from their blocks (:class:`bridge.io.drives.ArchiveSource`), in
    order, cut where the pipeline had processed ``frames_before[tick]`` of them."""
    from bridge.io.drives import ArchiveSource

    lo, hi = window
    stamps = array("q", (f.timestamp_ns for path in files for f in ArchiveSource(path)))
    scenes: list[tuple[int, array[int]]] = []
    done = 0
    for tick, before in sorted(frames_before.items()):
        scenes.append((tick, array("q", (t for t in stamps[done:before] if lo <= t < hi))))
        done = max(done, before)
    return scenes


def scene_parts_recorded(files: Sequence[Path]) -> dict[int, int]:
    """Tick -> how many /scene/* messages the drive recorded with that time."""
    from mcap.reader import make_reader

    recorded: dict[int, int] = {}
    for path in files:
        with path.open("rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            topics = [c.topic for c in summary.channels.values()
                      if c.topic.startswith("/scene/")] if summary is not None else []
            for _, _, message in reader.iter_messages(topics=topics):
                recorded[message.log_time] = recorded.get(message.log_time, 0) + 1
    return recorded


def analyse(files: Sequence[Path], received: list[dict[int, tuple[int, int]]],
            window: tuple[int, int], frames_before: dict[int, int]) -> DriveAnalysis:
    """Which scene contains which frame, and the latencies at the readers.

    The scene tick T is emitted when the pipeline processes the first frame stamped >= T (or at
    its read of the buses just after T) and contains exactly the frames processed before it
    (``frames_before``: tick -> that count, :func:`time_scene_stages`), so a frame stamped
    before T but read after scene T went out lands in the next scene. ``received``: per
    reading client, tick -> (when the last of its /scene/* messages stamped T arrived, how many
    arrived); a client has scene T when it got as many as the drive recorded. Then per frame
    and reader ``latency = receive time of the containing scene - frame timestamp`` (the same
    wall clock), pooled in 10 µs bins; frames outside ``window`` (warm-up, tail) left out."""
    result = DriveAnalysis(summary_frame_counts(files), 0, Histogram(),
                           scenes_missed=[0] * len(received))
    scenes = scene_contents(files, frames_before, window)
    recorded = scene_parts_recorded(files)
    result.scenes = len(scenes)
    result.complete = [
        {t: at for t, (at, n) in got.items() if n >= recorded.get(t, 0)} for got in received]
    for tick, frames in scenes:
        _add_scene(result, tick, frames, window)
    return result


def _add_scene(result: DriveAnalysis, tick: int, frames: array[int],
               window: tuple[int, int]) -> None:
    """Scene ``tick`` (containing ``frames``) as each reader received it, or did not."""
    lo, hi = window
    in_window = lo <= tick < hi
    result.scenes_in_window += in_window
    if not frames and not in_window:
        return
    result.frames_in_window += len(frames)
    oldest = min(frames) if frames else None
    for r, got in enumerate(result.complete):
        at = got.get(tick)
        if at is None:
            result.scenes_missed[r] += in_window
            result.frames_without_scene += len(frames)
            continue
        if in_window:
            result.delivery_ms.append((at - tick) / MS)
            result.delivery_at.append(tick)
        if oldest is not None:
            result.oldest_ms.append((at - oldest) / MS)
        for t in frames:
            result.frame_latency.add(at - t)


def scene_receipts(client: dict[str, Any]) -> dict[int, tuple[int, int]]:
    """Tick -> (when the last of its /scene/* messages arrived, how many arrived)."""
    last: dict[int, int] = {}
    parts: dict[int, int] = {}
    for rows in client["scenes"].values():
        for t_ns, at in rows:
            parts[t_ns] = parts.get(t_ns, 0) + 1
            last[t_ns] = max(last.get(t_ns, 0), at)
    return {t: (at, parts[t]) for t, at in last.items()}


def time_scene_stages(pipeline: Pipeline) -> dict[int, list[int]]:
    """Wall times of each scene tick inside the bridge: tick -> [the pipeline starts computing
    it, computed, serialised + recorded + handed to the server, and the frames processed before
    it (the frames its scene contains)]. Wraps two methods of this
    pipeline's instances (50 calls a second; the bridge's code is unchanged): the perception's
    ``tick`` (one scene tick) and the pipeline's ``emit``."""
    stages: dict[int, list[int]] = {}
    perception: Any = pipeline.perception
    tick, emit = perception.tick, pipeline.emit

    def timed_tick(t_ns: int) -> Any:
        start = time.time_ns()
        before = pipeline.frames
        out = tick(t_ns)
        stages[t_ns] = [start, time.time_ns(), 0, before]
        return out

    def timed_emit(outputs: Any, **options: Any) -> None:
        outputs = list(outputs)
        emit(outputs, **options)
        noted = stages.get(outputs[0].t_ns) if outputs else None
        if noted is not None and not noted[2]:  # the scene's emit, not the health's after it
            noted[2] = time.time_ns()

    perception.tick = timed_tick
    pipeline.emit = timed_emit  # type: ignore[method-assign]
    return stages


#: Where the pipeline thread's time goes: (label, module file ending, function name).
PROFILE_PARTS = (
    ("perception feed (notes the newest message)", "perception.py", "feed"),
    ("scene ticks (observe, world, lanes, scene, semantic)", "perception.py", "tick"),
    ("scene emit (serialise, record, publish)", "pipeline.py", "emit"),
    ("decode (cantools, protobuf)", "decoder.py", "decode"),
    ("cut raw frames into blocks", "raw.py", "add"),
    ("record raw blocks", "mcap.py", "write_raw"),
    ("record decoded messages", "mcap.py", "write_decoded"),
    ("publish to the server", "server/viewer_server.py", "publish"),
    ("recorder tick (flush)", "drives.py", "tick"),
)


def print_profile_summary(stats: pstats.Stats) -> None:
    """Inclusive CPU time of the pipeline's stages, as a share of the thread's CPU time."""
    entries: dict[Any, Any] = stats.stats  # type: ignore[attr-defined]
    total = sum(e[2] for e in entries.values()) or 1.0
    print(f"\npipeline thread under cProfile: {total:.1f} s CPU; inclusive share per stage "
          "(scene emit includes its publish):")
    for label, module, function in PROFILE_PARTS:
        # the outermost of same-named functions (Decoder.decode calls MessageCodec.decode)
        found = [e for (file, _, name), e in entries.items()
                 if file.endswith(module) and name == function]
        cum, calls = max(((e[3], e[1]) for e in found), default=(0.0, 0))
        print(f"  {100 * cum / total:5.1f} %  {label}  ({calls:,} calls)")


# --- the run: set-up ----------------------------------------------------------------------------

def prepared_traffic(traffic_s: float) -> dict[str, list[can.Message]]:
    """:func:`traffic`, said so."""
    t = time.perf_counter()
    messages = traffic(traffic_s)
    print("traffic: " + ", ".join(f"{b} cycles {len(m):,} simulated frames"
                                  for b, m in messages.items())
          + f" (prepared in {time.perf_counter() - t:.1f} s)")
    return messages


@dataclass(frozen=True)
class References:
    """The same work without live, µs per frame, and bare receive, % of one core."""

    pipeline_us: float
    paced_us: float
    bare_pct: float
    frames_per_s: float

    @property
    def pipeline_pct(self) -> float:
        return self.pipeline_us * self.frames_per_s / 1e4

    @property
    def paced_pct(self) -> float:
        return self.paced_us * self.frames_per_s / 1e4


def measure_references(args: argparse.Namespace) -> References:
    """The references, measured now on this machine as it is, in a process of its own (so that
    its memory is not this one's; ``--reference``): the fixed reference of issue #15, bare
    python-can receive of the same traffic on the same virtual buses (:func:`bare_receive_pct`);
    the same pipeline alone in one thread over 24,000 frames of the same traffic at the same
    rate (bridge / reference: what live adds to the work itself); and the same pipeline paced
    as live reads (bridge / paced: what live adds beyond doing that work in 150 short bursts a
    second). Each the best of three, interleaved (:func:`benchlib.best_of`)."""
    pipeline_us, paced_us, bare_pct = map(float, subprocess.run(
        [sys.executable, __file__, "--reference", str(REFERENCE_FRAMES), "--traffic-s",
         str(args.traffic_s), "--rate", str(args.rate), "--batch-ms", str(args.batch_ms)],
        check=True, capture_output=True, text=True).stdout.split())
    return References(pipeline_us, paced_us, bare_pct, len(BUSES) * args.rate)


@dataclass
class Bridge:
    """The live bridge under test: its server, buses and pipeline thread."""

    live: Live
    server: ViewerServer
    specs: list[BusSpec]
    runner: threading.Thread
    stages: dict[int, list[int]]  # time_scene_stages
    outcome: dict[str, Any]  # "report" (live.run's), "profile" (with --cprofile)
    said: list[str]
    drives: Path
    rss_before: float


def start_bridge(drives: Path, cprofile: bool) -> Bridge:
    """``tankviz live`` on three virtual buses (the ecocar profile, scene at 50 Hz, recording
    into ``drives``), serving on a free port, its pipeline running in a thread."""
    from bridge.io.buses import BusSpec
    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.live_engine import Live
    from bridge.sinks.server import ViewerServer

    ecocar = load_stages([], "ecocar")
    said: list[str] = []
    rss_before = peak_rss_mb()
    server = ViewerServer(port=0)
    server.start()
    specs = [BusSpec(bus, "virtual", f"bench-live-{os.getpid()}-{bus}") for bus in BUSES]
    live = Live(specs, ecocar, scene_rate=SCENE_RATE, drives=drives,
                server=server, say=said.append)
    live.start()
    outcome: dict[str, Any] = {}
    stages = time_scene_stages(live.pipeline)
    runner = threading.Thread(target=run_pipeline, args=(live, outcome, cprofile),
                              name="tankviz-pipeline")
    runner.start()
    return Bridge(live, server, specs, runner, stages, outcome, said, drives, rss_before)


def run_pipeline(live: Live, outcome: dict[str, Any], cprofile: bool) -> None:
    """``live.run()``, under cProfile (thread CPU time, not GIL waits) if asked."""
    profiler: cProfile.Profile | None = None
    if cprofile:
        import cProfile

        profiler = cProfile.Profile(time.thread_time)
        outcome["profile"] = profiler
        profiler.enable()
    try:
        outcome["report"] = live.run()
    finally:
        if profiler is not None:
            profiler.disable()


@dataclass
class Clients:
    """The clients' process (``--client``) and each client's address (the stalled one last)."""

    process: subprocess.Popen[str]
    addresses: list[str]
    results: Path

    @property
    def stalled(self) -> str:
        return self.addresses[-1]

    def stop(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.write("stop\n")
        self.process.stdin.flush()
        self.process.wait(30)

    def readers(self) -> list[dict[str, Any]]:
        """What each reading client received (once stopped)."""
        data = json.loads(self.results.read_text())
        return [c for c in data["clients"] if c["role"] == "reader"]


def start_clients(server: ViewerServer, folder: Path, stalled_topics: str) -> Clients:
    """The four WebSocket clients, in a process of their own, subscribed."""
    from tests.waiting import wait_for

    results = folder / "clients.json"
    process = subprocess.Popen(
        [sys.executable, os.path.abspath(__file__), "--client", server.url, str(results),
         "--stalled-topics", stalled_topics],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    line = process.stdout.readline()
    if not line.startswith("READY "):
        raise SystemExit(f"the clients did not start: {line!r}, exit {process.wait()}")
    wait_for(lambda: len(server._wanted) > 0, timeout=5)  # subscriptions have landed
    time.sleep(0.5)
    return Clients(process, json.loads(line[len("READY "):]), results)


# --- the run: the window ------------------------------------------------------------------------

@dataclass
class Measured:
    """Everything the table says, taken over one drive."""

    senders: list[Sender]
    cpu: CpuUse
    gc: GcWatch
    lag_ms: list[float]
    inbox: list[int]
    drained: bool
    stats: dict[str, Any]  # the server's ClientStats, by address
    send_start_ns: int
    window: tuple[int, int]
    stages: dict[int, list[int]]  # time_scene_stages
    files: list[Path]
    analysis: DriveAnalysis
    analyse_s: float
    rss: tuple[float, float, float]  # before the bridge, peak, at the end (MB)


def sample_while_driving(car: Car, bridge: Bridge) -> tuple[list[float], list[int]]:
    """Every 50 ms while the car drives: how far behind the pipeline is (wall clock minus the
    newest frame processed, ms) and the backlog of the server's inbox."""
    lag_ms: list[float] = []
    inbox: list[int] = []
    while car.driving():
        time.sleep(0.05)
        last = bridge.live.pipeline.last_ns
        if last is not None:
            lag_ms.append((time.time_ns() - last) / MS)
        inbox.append(len(bridge.server._inbox))
    car.join()
    return lag_ms, inbox


def wait_delivered(bridge: Bridge, sent: int, stalled: str) -> bool:
    """Wait (at most 60 s) until the pipeline has processed every frame sent and the server has
    passed on everything queued for the reading clients: whether it did."""
    from tests.waiting import wait_for

    server = bridge.server

    def delivered() -> bool:
        return (bridge.live.pipeline.frames >= sent and not server._inbox
                and all(not c.queue for c in list(server._clients.values())
                        if c.stats.address != stalled))

    return wait_for(delivered, timeout=60, step=0.002)


def stop(bridge: Bridge, clients: Clients) -> None:
    clients.stop()
    bridge.live.stop()
    bridge.runner.join(60)
    bridge.server.stop()


def measure(bridge: Bridge, clients: Clients, car: Car) -> Measured:
    """Drive the car, time the window (senders start → everything passed on), stop everyone,
    read the drive back: the senders stop first, then the clients, then the bridge."""
    watch = GcWatch()
    gc.callbacks.append(watch)
    start = mark_start(clients.process.pid)
    send_start_ns = time.time_ns()
    car.drive()
    lag_ms, inbox = sample_while_driving(car, bridge)
    send_end_ns = time.time_ns()
    drained = wait_delivered(bridge, car.sent, clients.stalled)
    end = mark_end(clients.process.pid)
    gc.callbacks.remove(watch)
    cpu = cpu_use(start, end, car.senders, thread_names(car.senders))
    time.sleep(0.2)  # the idle timer's last scene reaches the clients
    stats = {s.address: s for s in bridge.server.client_stats()}
    stop(bridge, clients)
    rss = (bridge.rss_before, peak_rss_mb(), rss_now_mb())
    receipts = [scene_receipts(c) for c in clients.readers()]
    window = (send_start_ns + round(WARMUP_S * NS), send_end_ns - round(TAIL_S * NS))
    report = bridge.outcome.get("report")
    files = list(report.files) if report is not None else sorted(bridge.drives.glob("*.mcap"))
    t = time.perf_counter()
    analysis = analyse(files, receipts, window,
                       {tick: noted[3] for tick, noted in bridge.stages.items()})
    return Measured(car.senders, cpu, watch, lag_ms, inbox, drained, stats, send_start_ns,
                    window, bridge.stages, files, analysis, time.perf_counter() - t, rss)


# --- the run: the table -------------------------------------------------------------------------

class Table:
    """Rows (metric, value, target, ok?) and the targets missed."""

    HEADER = ("metric", "value", "target", "ok?")

    def __init__(self) -> None:
        self.rows: list[tuple[str, str, str, str]] = []
        self.missed: list[str] = []

    def row(self, metric: str, value: str, target: str = "", ok: bool | None = None) -> None:
        self.rows.append((metric, value, target, "" if ok is None else ("ok" if ok else "MISSED")))
        if ok is False:
            self.missed.append(f"{metric}: {value} (target {target})")

    def print(self, caption: str) -> None:
        width = [max(len(r[i]) for r in [*self.rows, self.HEADER]) for i in range(4)]
        print()
        print(caption)
        line = "  ".join(f"{h:<{w}}" for h, w in zip(self.HEADER, width, strict=True))
        print(line)
        print("-" * len(line))
        for r in self.rows:
            print("  ".join(f"{c:<{w}}" for c, w in zip(r, width, strict=True)).rstrip())


def sender_rows(table: Table, m: Measured, rate: float) -> None:
    """Each sender's achieved rate, and the frames the drive recorded of what it sent (the
    ``/can/<bus>/frames`` counts of the drive's summary)."""
    for s in m.senders:
        achieved = s.sent / s.elapsed_s if s.elapsed_s else float("nan")
        table.row(f"send rate {s.bus}", f"{achieved:,.0f} frames/s (max late "
                  f"{s.late_max_s * 1e3:.1f} ms)", f"{rate:,.0f} frames/s",
                  abs(achieved - rate) <= 0.01 * rate)
    for s in m.senders:
        recorded = m.analysis.frames_by_bus.get(s.bus, 0)
        table.row(f"frames recorded / sent {s.bus}", f"{recorded:,} / {s.sent:,}", "equal",
                  recorded == s.sent)
    recorded_total = sum(m.analysis.frames_by_bus.values())
    sent_total = sum(s.sent for s in m.senders)
    table.row("frames recorded / sent, total", f"{recorded_total:,} / {sent_total:,}", "equal",
              recorded_total == sent_total)


def cpu_rows(table: Table, cpu: CpuUse, refs: References) -> None:
    """The bridge's CPU (:func:`cpu_use`), against the references (:func:`measure_references`)."""
    bridge = cpu.bridge_pct
    table.row("bridge CPU (process - senders - harness)", f"{bridge:.1f} % of one core",
              f"< {CPU_TARGET:g} %", bridge < CPU_TARGET)
    table.row("  cross-check: bridge threads (/proc)", f"{cpu.bridge_threads_pct:.1f} %")
    table.row("  reference: bare python-can receive, same run", f"{refs.bare_pct:.1f} %; "
              f"bridge / bare receive = {bridge / refs.bare_pct:.2f}")
    table.row("  reference: the pipeline alone, same run", f"{refs.pipeline_pct:.1f} % "
              f"({refs.pipeline_us:.1f} µs/frame); bridge / reference = "
              f"{bridge / refs.pipeline_pct:.2f}")
    table.row("  reference paced as live reads, same run", f"{refs.paced_pct:.1f} % "
              f"({refs.paced_us:.1f} µs/frame); bridge / paced = {bridge / refs.paced_pct:.2f}")
    table.row("  senders (subtracted)", f"{cpu.pct(cpu.senders):.1f} %")


def latency_rows(table: Table, m: Measured, duration: float) -> None:
    """Latency from a frame's timestamp to a reader having the scene that contains it
    (:func:`analyse`): a frame sent just after a tick waits for the next one, so it spans
    0 ... one scene period + the delivery delay; the target is p99 < period + 5 ms. Then the
    scene delivery delay (receive - tick: the newest frame a scene can contain), per stretch
    of the run, the latency of each scene's oldest frame, and where the delay goes."""
    period_ms = 1000 / SCENE_RATE
    target_ms = period_ms + LATENCY_MARGIN_MS
    hist, analysis = m.analysis.frame_latency, m.analysis
    table.row("latency frame → scene at client p50", f"{hist.quantile_ms(0.5):.1f} ms")
    table.row("latency frame → scene at client p99", f"{hist.quantile_ms(0.99):.1f} ms",
              f"< {target_ms:g} ms ({period_ms:g} + {LATENCY_MARGIN_MS:g})",
              hist.quantile_ms(0.99) < target_ms)
    table.row("latency frame → scene at client max", f"{hist.max_ns / MS:.1f} ms")
    table.row("  scene delivery (receive - tick) p50 / p99 / max", spread(analysis.delivery_ms))
    segment_s = 10 if duration > 10 else 2
    segments: dict[int, list[float]] = {}
    for tick, ms in zip(analysis.delivery_at, analysis.delivery_ms, strict=True):
        segments.setdefault((tick - m.send_start_ns) // (segment_s * NS), []).append(ms)
    table.row(f"  scene delivery p99 per {segment_s} s of the run",
              " ".join(f"{percentile(v, 0.99):.0f}" for _, v in sorted(segments.items()))
              + " ms")
    table.row("  oldest frame of a scene p50 / p99 / max", spread(analysis.oldest_ms))
    labels = ("tick → the pipeline starts the scene", "the scene is computed (perception tick)",
              "serialised, recorded, handed to the server",
              "server thread → client has the whole scene")
    for label, part in zip(labels, delivery_parts(m), strict=True):
        table.row(f"    where: {label}", spread(part))


def delivery_parts(m: Measured) -> list[list[float]]:
    """Where each scene's delivery delay goes (ms, scenes in the window): the tick to the
    pipeline starting it, computing it, serialising + recording + handing it to the server
    (:func:`time_scene_stages`), then the server and the network to the reader."""
    lo, hi = m.window
    parts: list[list[float]] = [[], [], [], []]
    for received_at in m.analysis.complete:
        for tick, (start, computed, emitted, _) in m.stages.items():
            at = received_at.get(tick)
            if at is None or not emitted or not lo <= tick < hi:
                continue
            for i, ns in enumerate((start - tick, computed - start, emitted - computed,
                                    at - emitted)):
                parts[i].append(ns / MS)
    return parts


def health_rows(table: Table, m: Measured, stalled_topics: str, clients: Clients) -> None:
    """How the bridge kept up: the pipeline's lag and the server's backlog (sampled while the
    car drove), GC pauses (:class:`GcWatch`; the target: none > 5 ms), the scenes each reader
    got, the messages dropped."""
    table.row("pipeline lag (now - newest frame processed) p50 / p99 / max", spread(m.lag_ms))
    table.row("backlog max: server inbox", f"{max(m.inbox, default=0):,} messages")
    pauses = m.gc.pauses
    full = [d for g, d in pauses if g == 2]
    table.row("garbage collections: all / full (gen 2), longest pause",
              f"{len(pauses):,} / {len(full)}, {m.gc.longest_ms:.1f} ms")
    table.row("GC pauses > 5 ms (wall) / longest in CPU time",
              f"{sum(d > 0.005 for _, d in pauses)} / {1e3 * max(m.gc.cpu, default=0):.1f} ms",
              "none > 5 ms", m.gc.longest_ms <= 5.0)
    a = m.analysis
    table.row("scenes received complete by each reader",
              f"{a.scenes_in_window - max(a.scenes_missed, default=0):,} / "
              f"{a.scenes_in_window:,} in window "
              f"({', '.join(f'{len(r):,}' for r in a.complete)} in all; {a.scenes:,} emitted)",
              "all", not any(a.scenes_missed) and a.frames_without_scene == 0)
    dropped = sum(m.stats[a].dropped for a in clients.addresses[:-1] if a in m.stats)
    table.row("messages dropped, reading clients", f"{dropped:,}", "0", dropped == 0)
    stalled = m.stats.get(clients.stalled)
    table.row("messages dropped, stalled client (its own)",
              f"{stalled.dropped:,} (sent {stalled.sent:,})" if stalled else "?", "> 0",
              (stalled is not None and stalled.dropped > 0) if stalled_topics == "all" else None)


def resource_rows(table: Table, m: Measured, bridge: Bridge) -> None:
    """Memory (``ru_maxrss`` of this process: bridge, senders and the prepared traffic, taken
    before the drive is read back), the drive written, and whether the bridge caught up."""
    before, peak, end = m.rss
    table.row("peak RSS (ru_maxrss)", f"{peak:.0f} MB (before bridge {before:.0f} MB, "
              f"at end {end:.0f} MB)")
    drive_mb = sum(p.stat().st_size for p in m.files) / 1e6
    table.row("drive written", f"{drive_mb:.0f} MB in {len(m.files)} file(s), "
              f"{drive_mb / m.cpu.wall:.1f} MB/s")
    if not m.drained:
        sent = sum(s.sent for s in m.senders)
        table.row("bridge caught up within 60 s", f"{bridge.live.pipeline.frames:,} of "
                  f"{sent:,} frames, server inbox {len(bridge.server._inbox):,}", "all", False)


def print_cpu_by_thread(cpu: CpuUse) -> None:
    print()
    print("CPU by thread over the window (% of one core, /proc/self/task/*/stat):")
    for name, seconds in sorted(cpu.by_thread.items(), key=lambda kv: -kv[1]):
        if seconds > 0:
            print(f"  {name:<32} {cpu.pct(seconds):5.1f} %")
    print(f"  (process total {cpu.pct(cpu.process):.1f} %; bridge = process - senders "
          f"{cpu.pct(cpu.senders):.1f} % - harness {cpu.pct(cpu.harness):.1f}"
          " %; clients run in another process)")
    print(f"machine: {os.cpu_count()} CPUs; during the window this process used "
          f"{cpu.pct(cpu.process):.0f} % of one CPU, the clients' process "
          f"{cpu.pct(cpu.clients):.0f} %, other processes "
          f"{cpu.pct(cpu.others):.0f} % (those alive at both ends); load average "
          f"{os.getloadavg()[0]:.2f}")


def report(args: argparse.Namespace, duration: float, refs: References, m: Measured,
           bridge: Bridge, clients: Clients) -> None:
    """The table, the CPU by thread, what the bridge said, the profile, the targets missed."""
    table = Table()
    sender_rows(table, m, args.rate)
    cpu_rows(table, m.cpu, refs)
    latency_rows(table, m, duration)
    health_rows(table, m, args.stalled_topics, clients)
    resource_rows(table, m, bridge)
    table.print(f"window {m.cpu.wall:.1f} s (senders started → every frame processed, the scenes "
                f"passed on); latency over {m.analysis.frame_latency.count:,} frame deliveries "
                f"(frames x {len(m.analysis.complete)} readers, {WARMUP_S:g} s warm-up and "
                f"{TAIL_S:g} s tail left out)")
    print_cpu_by_thread(m.cpu)
    if bridge.said:
        print("bridge said: " + "; ".join(bridge.said))
    print(f"(drive read back in {m.analyse_s:.1f} s)")
    if args.cprofile and "profile" in bridge.outcome:
        import pstats

        profiled = pstats.Stats(bridge.outcome["profile"])
        print_profile_summary(profiled)
        print("\ncProfile of the pipeline thread (thread CPU time; the profiler inflates it; "
              "top 25 by own time):")
        profiled.sort_stats("tottime").print_stats(25)
    for missed in table.missed:
        print(f"TARGET MISSED: {missed}")


def run(args: argparse.Namespace) -> None:
    """The benchmark: set up, drive, measure, report."""
    duration = 10.0 if args.quick else args.duration
    print(f"tankviz live benchmark: {len(BUSES)} virtual buses x {args.rate:,.0f} frames/s for "
          f"{duration:g} s, scene at {SCENE_RATE:g} Hz, 4 WebSocket clients (1 stalled)")
    messages = prepared_traffic(args.traffic_s)
    refs = measure_references(args)
    # The prepared traffic is the harness's, not the bridge's: keep it out of the collector's
    # view, so that the bridge's full collections cost what they would cost without it.
    gc.freeze()
    with tempfile.TemporaryDirectory(prefix="tankviz-bench-live-") as tmp:
        bridge = start_bridge(Path(args.drives) if args.drives else Path(tmp), args.cprofile)
        clients = start_clients(bridge.server, Path(tmp), args.stalled_topics)
        channels = {bus: spec.channel or "" for bus, spec in zip(BUSES, bridge.specs, strict=True)}
        car = start_car(channels, messages,
                        args.rate, duration, args.batch_ms / 1000,
                        threading.Barrier(len(BUSES) + 1), threading.Event())
        if args.switch_interval:
            sys.setswitchinterval(args.switch_interval / 1000)
        measured = measure(bridge, clients, car)
        report(args, duration, refs, measured, bridge, clients)


# --- the pipeline alone: the references and --stages ---------------------------------------

def _everyone_wants() -> Sink:
    """A stand-in server for --stages: a sink whose every channel has a subscriber; messages
    are counted."""
    from bridge.sinks.base import Sink

    class EveryoneWants(Sink):
        def __init__(self) -> None:
            self.channels: dict[str, int] = {}
            self.published = 0

        def on_raw(self, blocks: Any, /) -> None:
            for block in blocks:
                self.channels.setdefault(block.bus, len(self.channels))
                self.published += 1

        def on_decoded(self, t_ns: int, decoded: Any, /) -> None:
            self.channels.setdefault(decoded.codec.topic, len(self.channels))
            self.published += 1

        def on_messages(self, messages: Any, /) -> None:
            for m in messages:
                self.channels.setdefault(m.topic, len(self.channels))
            self.published += len(messages)

    return EveryoneWants()


def pipeline_frames(messages: dict[str, list[can.Message]], count: int,
                    frames_per_s: float = 12_000) -> list[Frame]:
    """``count`` frames of the traffic as the pipeline gets them: the buses in turn, at
    ``frames_per_s`` (all buses) of log time."""
    from bridge.frame import Frame

    frames = []
    t = 1_767_268_800_000_000_000
    step = round(NS / frames_per_s)
    for i in range(count):
        bus = BUSES[i % len(BUSES)]
        m = messages[bus][(i // len(BUSES)) % len(messages[bus])]
        t += step
        frames.append(Frame(t, bus, m.arbitration_id, bytes(m.data), m.is_extended_id,
                            m.is_fd, False, False, m.bitrate_switch, False, m.dlc))
    return frames


def pipeline_cost(frames: list[Frame], *, record: bool = True, health: bool = True,
                  profile: bool = True, serve: bool = True, paced: bool = False) -> float:
    """µs per frame of the pipeline alone in this thread (thread CPU time): at once, or
    ``paced``: in real time, read as the live loop reads (:class:`bridge.io.buses.ReadSchedule`:
    the frames stamped by then, three times per scene period, sleeping between)."""
    import io

    from bridge.io.buses import ReadSchedule
    from bridge.pipeline.drive import load_stages, new_health_monitor
    from bridge.pipeline.pipeline import Pipeline
    from bridge.sinks.mcap import Recorder

    decoder, loaded = load_stages([], "ecocar")
    # The stages one by one (--stages), so by hand here: the apps use bridge.pipeline.drive.
    sinks: list[Any] = [_everyone_wants()] if serve else []
    if record:
        sinks.append(Recorder(io.BytesIO()))
    pipeline = Pipeline(decoder, profile=loaded if profile else None, scene_rate=SCENE_RATE,
                        sinks=sinks,
                        health=new_health_monitor(decoder, loaded) if health else None)
    pipeline.advertise(BUSES)
    start = time.thread_time()
    if not paced:
        for frame in frames:
            pipeline.process(frame)
    else:
        schedule = ReadSchedule(round(NS / SCENE_RATE))
        offset = frames[0].timestamp_ns - time.time_ns()  # log time - wall time
        schedule.saw(frames[0].timestamp_ns, frames[0].timestamp_ns - offset)
        i = 0
        while i < len(frames):
            schedule.wait()
            now = time.time_ns()
            while i < len(frames) and frames[i].timestamp_ns <= now + offset:  # arrived
                pipeline.process(frames[i])
                i += 1
            pipeline.advance(schedule.log_time(now) or 0)
    pipeline.finish()
    return (time.thread_time() - start) / len(frames) * 1e6


def bare_receive_pct(messages: dict[str, list[can.Message]], rate: float, seconds: float,
                     batch_s: float) -> float:
    """The fixed reference of issue #15: bare python-can receive of the same traffic on the same
    virtual buses, as % of one core: one thread per bus calling ``bus.recv`` in a loop, while
    the benchmark's own senders send at ``rate`` for ``seconds``; the receivers' thread CPU
    time over the wall time."""
    pid = os.getpid()
    channels = {bus: f"bench-bare-{pid}-{bus}" for bus in BUSES}
    go, done = threading.Event(), threading.Event()
    opened = threading.Barrier(2 * len(BUSES) + 1)
    cpu: list[float] = []
    receivers = [threading.Thread(target=_receive, args=(channel, opened, go, done, cpu),
                                  daemon=True) for channel in channels.values()]
    for thread in receivers:
        thread.start()
    car = start_car(channels, messages, rate, seconds, batch_s, opened, go)
    car.drive()
    car.join()
    wall = time.monotonic() - car.start_at[0]
    time.sleep(0.05)  # the last frames are received
    done.set()
    for thread in receivers:
        thread.join(timeout=5)
    return 100 * sum(cpu) / wall


def _receive(channel: str, opened: threading.Barrier, go: threading.Event,
             done: threading.Event, cpu: list[float]) -> None:
    """Receive on ``channel`` from ``go`` until ``done``; the thread's CPU time goes to ``cpu``."""
    bus = can.Bus(interface="virtual", channel=channel)
    opened.wait()
    go.wait()
    start = time.thread_time()
    recv = bus.recv
    while not done.is_set():
        recv(0.1)  # a frame, or None after 0.1 s without one
    cpu.append(time.thread_time() - start)
    bus.shutdown()


def references(args: argparse.Namespace) -> None:
    """``--reference FRAMES``: print the pipeline's µs per frame at once and paced, and bare
    receive's % of one core (:func:`measure_references` reads them)."""
    messages = traffic(args.traffic_s)
    frames = pipeline_frames(messages, args.reference, len(BUSES) * args.rate)
    gc.freeze()
    best = best_of({
        "pipeline": lambda: pipeline_cost(frames),
        "paced": lambda: pipeline_cost(frames, paced=True),
        "bare": lambda: bare_receive_pct(messages, args.rate, 5.0, args.batch_ms / 1e3),
    }, 3)
    print(best["pipeline"], best["paced"], best["bare"])


def stage_costs(frames_count: int) -> None:
    """The pipeline alone in this thread, no other thread: µs per frame as stages are added."""
    frames = pipeline_frames(traffic(60.0), frames_count)
    gc.freeze()
    print(f"pipeline alone, one thread, {frames_count:,} frames of the benchmark's traffic:")
    for label, record, health, profile, serve in (
            ("decode", False, False, False, False),
            ("+ record", True, False, False, False),
            ("+ health", True, True, False, False),
            ("+ profile, scene at 50 Hz", True, True, True, False),
            ("+ server (every channel subscribed)", True, True, True, True)):
        cost = pipeline_cost(frames, record=record, health=health, profile=profile, serve=serve)
        print(f"  {label:40s} {cost:6.2f} µs/frame  ({cost * 12_000 / 1e4:5.1f} % of one core "
              "at 12,000 frames/s)")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split(":")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of traffic (60)")
    parser.add_argument("--quick", action="store_true", help="10 s of traffic")
    parser.add_argument("--rate", type=float, default=4000.0, help="frames/s per bus (4000)")
    parser.add_argument("--batch-ms", type=float, default=1.0,
                        help="senders send what is due every this many ms (1)")
    parser.add_argument("--traffic-s", type=float, default=60.0,
                        help="seconds of simulated drive the senders cycle through (60)")
    parser.add_argument("--drives", help="record here instead of a temporary folder (kept)")
    parser.add_argument("--cprofile", action="store_true",
                        help="profile the pipeline thread with cProfile and print the top")
    parser.add_argument("--stalled-topics", choices=("all", "scene"), default="all",
                        help="what the stalled client subscribes to: every channel (the "
                        "default) or only /scene/* (to see what the raw topics cost)")
    parser.add_argument("--switch-interval", type=float, default=0.0, metavar="MS",
                        help="experiment: sys.setswitchinterval for this process (Python's "
                        "default is 5 ms)")
    parser.add_argument("--client", nargs=2, metavar=("URL", "OUT"), help=argparse.SUPPRESS)
    parser.add_argument("--readers", type=int, default=3, help=argparse.SUPPRESS)
    parser.add_argument("--stages", type=int, metavar="FRAMES", default=0,
                        help="instead: the pipeline alone in one thread, µs per frame as the "
                        "stages are added (e.g. --stages 120000)")
    parser.add_argument("--reference", type=int, metavar="FRAMES", default=0,
                        help=argparse.SUPPRESS)  # (the reference, in its own process)
    args = parser.parse_args(argv)
    if args.reference:
        references(args)
        return 0
    if args.stages:
        stage_costs(args.stages)
        return 0
    if args.client:
        asyncio.run(run_clients(args.client[0], args.client[1], args.readers,
                                args.stalled_topics))
        return 0
    run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
