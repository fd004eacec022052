#!/usr/bin/env python3
"""Benchmark ``tankviz live`` under a heavy three-bus load (a report, not a test).

Three python-can ``virtual`` buses (``radar``, ``camera``, ``chassis``) each carry 4,000 frames/s
for ``--duration`` seconds (default 60, ``--quick``: 10) into the live bridge
(:class:`bridge.pipeline.live_engine.Live` + :class:`bridge.sinks.server.ViewerServer`, the
bundled ecocar profile, scene at 50 Hz, drives recorded into a temporary folder), while four
``foxglove.websocket.v1`` clients watch: three subscribe to every ``/scene/*`` topic and read
everything, one subscribes to every channel (raw frames and decoded signals included) and then never
reads (``transport.pause_reading()``). It prints one table (metric, value, target, ok?), a
``TARGET MISSED: ...`` line for each missed target, and exits 0 regardless: this is a report.

Processes. python-can's ``virtual`` interface only connects buses inside one process, so the
bridge and the three sender threads (the "car") share this process; the WebSocket clients run in
a separate process (this script with ``--client``), so their CPU is not counted. The CPU that
other processes used during the run is printed too (``/proc/<pid>/stat``): other processes on a
small machine distort every figure here, latency most.

Traffic. The payloads are the simulated ecocar drive (:func:`bridge.sim.ecocar.simulate`, every
payload encoded with the bundled DBC), split by sensor: ``radar`` carries RadarObj*/RadarHeader/
RadarStatus, ``camera`` CamObstacle*/CamLane*, ``chassis`` everything else (fusion tracks, lead
vehicle, ego motion, steering, driver inputs, position, diagnostics). Each sender cycles through
its list at 4,000 frames/s - faster than the car's own cycle times, so the scene moves quickly,
but every frame decodes and feeds perception like real traffic. Frames are paced in real time in
small batches (``--batch-ms``, default 1 ms: 4 frames per bus): a sender sleeps to its schedule
and sends what is due; the achieved rate and the worst lateness per bus are printed. The virtual
bus stamps each frame with the wall clock at ``send``, so a frame's timestamp is when the car
sent it. The prepared messages are hidden from the garbage collector (``gc.freeze()``) so they do
not slow the bridge's full collections. Every collection's pause is timed (``gc.callbacks``): in
wall time (what the pipeline and the server wait) and in the collecting thread's CPU time (what
the collector itself costs, whatever else the machine runs); the target is no pause > 5 ms.

Frames recorded vs sent. The senders stop first; once the pipeline has processed every frame and
the server has passed on everything queued for the reading clients (at most 60 s), the clients
and then the bridge (``live.stop()``) stop. The ``/can/<bus>/frames`` message counts in the
drive's MCAP summary must equal each sender's count.

CPU. ``bridge CPU = Δ process CPU (getrusage(RUSAGE_SELF), user+system, all threads) - Σ sender
CPU (time.thread_time() measured inside each sender thread around its send loop) - Δ CPU of this
script's main thread (the harness: it sleeps and samples backlogs every 50 ms)``, over the window
from just before the senders start until everything is processed and passed on (above), divided
by that wall time: % of one core. The clients' process is not included. A cross-check sums
``/proc/self/task/<tid>/stat`` (utime+stime) of the bridge's own threads (pipeline, bus openers,
server) over the same window; the per-thread breakdown is printed. The fixed reference of issue
#15, measured in the same run just before the bridge starts (in a process of its own): bare
python-can receive of the same traffic on the same virtual buses (one thread per bus calling
``recv`` in a loop while the same senders send, the best of three 5 s passes), as % of one
core; the ratio bridge / bare receive says what tankviz costs beyond taking the frames in. The
target, < 20 % of one core, is a third of what the bridge took when issue #15 was filed (57 %).
Two more references, tankviz's own code: the same pipeline alone in one thread, without buses,
threads or clients (the best of three passes over 24,000 frames of the same traffic at the
same rate), as % of one core; and the same pipeline paced as live reads
(in real time, the frames stamped by then taken three times per scene period by live's own
ReadSchedule, sleeping between: the best of three passes). How fast this machine is varies
from hour to hour (the same code has measured 34 % and 45 %); the ratio bridge / reference tells
what live adds to the work itself on the machine as it was, and bridge / paced what it adds
beyond doing that work in 150 short bursts a second (reading the buses, the server thread, the
senders' GIL), which this machine charges more for than for the same work done at once. The
senders share the GIL with the bridge: their CPU is subtracted, their contention for the GIL is
not (a real CAN adapter costs the bridge no GIL), so CPU and latency here are somewhat
pessimistic.

Latency. "From a frame's timestamp to a client receiving the scene that contains it." The scene
tick at log time T (the WebSocket message timestamp; ticks are multiples of 20 ms at 50 Hz) is
emitted by the pipeline when it processes the first frame stamped >= T (or at its read of the
buses just after T, if none came), and contains exactly the frames processed before it: the
harness notes how many that is at every tick, and takes the drive's frames, read back from
their blocks, in that order (a frame stamped before T but read after scene T went out lands in
the next scene, and is counted so). A reading client has received scene T
when it has as many ``/scene/*`` messages stamped T as the drive recorded: the arrival of the last
one (wall clock, in the client process; the same clock as the frame stamps). Then per frame and
reading client::

    latency = receive time of the containing scene - frame timestamp

pooled over all frames and the three reading clients (10 µs bins). A frame sent just after a tick
waits for the next one, so latency spans 0 ... one scene period (20 ms) + the delivery delay; the
target is p99 < scene period + 5 ms = 25 ms. Also printed: the scene delivery delay
(receive - T: the latency of the newest frame a scene can contain), the latency of each scene's
oldest frame, and where the delivery delay goes: the wall times at which the pipeline starts
computing tick T, has computed it, and has serialised, recorded and handed it to the server
(two methods of the running pipeline are wrapped to note them; 50 calls/s), then the server and
the network to the client. The first 0.5 s (warm-up) and the last 0.1 s of sending (the last
scene is emitted by the idle timer once the buses go quiet) are left out of the latency figures.
While the car drives, the harness samples every 50 ms how far the pipeline is behind (wall clock
minus the newest frame processed) and the backlog of the server inbox.

RSS. ``ru_maxrss`` of this process (bridge + senders + the prepared traffic), taken before the
drive is read back; the RSS before the bridge started is printed for comparison.

Options for looking closer: ``--stages N`` runs N frames of the same traffic through the
pipeline alone in one thread (no buses, no clients, no other thread) and prints the cost per
frame as decoding, recording, health, perception and serving are added; ``--cprofile``
profiles the pipeline thread (thread CPU time) and prints the share of each stage;
``--stalled-topics scene`` lets the stalled client subscribe to the scene only (what do the raw
and decoded topics cost?); ``--switch-interval`` sets ``sys.setswitchinterval`` (GIL hand-over)
for this process.

    python tools/bench_live.py --quick      # 10 s
    python tools/bench_live.py              # 60 s
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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MS = 1_000_000
NS = 1_000_000_000
BUSES = ("radar", "camera", "chassis")
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
    """``readers`` clients read every /scene/* topic, one stalls; results go to ``out_path``."""
    import websockets

    loop = asyncio.get_running_loop()
    proto = [websockets.Subprotocol(SUBPROTOCOL)]

    async def connect(**options: Any) -> tuple[Any, dict[str, int]]:
        ws = await websockets.connect(url, subprotocols=proto, max_size=None, compression=None,
                                      **options)
        channels: dict[str, int] = {}
        while "/scene/radar" not in channels:
            message = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(message, str):
                data = json.loads(message)
                if data.get("op") == "advertise":
                    channels.update({c["topic"]: c["id"] for c in data["channels"]})
        return ws, channels

    def address(ws: Any) -> str:
        host, port = ws.local_address[:2]
        return f"{host}:{port}"

    clients: list[dict[str, Any]] = []
    tasks = []
    for _ in range(readers):
        ws, channels = await connect()
        scene = sorted(t for t in channels if t.startswith("/scene/"))
        subscriptions = {i: topic for i, topic in enumerate(scene, start=1)}
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": channels[t]} for i, t in subscriptions.items()]}))
        got: dict[str, list[list[int]]] = {t: [] for t in scene}
        client = {"role": "reader", "address": address(ws), "scenes": got, "messages": 0}
        clients.append(client)

        async def read(ws: Any = ws, subscriptions: dict[int, str] = subscriptions,
                       got: dict[str, list[list[int]]] = got,
                       client: dict[str, Any] = client) -> None:
            clock = time.time_ns
            unpack = _HEADER.unpack_from
            while True:
                data = await ws.recv()
                now = clock()
                if isinstance(data, bytes) and data[0] == 1:
                    _, sub, t_ns = unpack(data)
                    got[subscriptions[sub]].append([t_ns, now])
                    client["messages"] += 1

        tasks.append(loop.create_task(read()))
    # No keepalive pings from the stalled one (a browser sends none): the server's pong to a
    # client it cannot write to fails with an AssertionError in websockets' legacy protocol.
    # (The server's own keepalive ping, 20 s in, fails the same way and logs a traceback; the
    # connection stays registered and is fed until the end, so it still counts as stalled.)
    stalled, channels = await connect(ping_interval=None)
    if stalled_topics == "scene":
        channels = {t: c for t, c in channels.items() if t.startswith("/scene/")}
    await stalled.send(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": c} for i, c in enumerate(channels.values(), start=1)]}))
    stalled.transport.pause_reading()
    clients.append({"role": "stalled", "address": address(stalled),
                    "subscribed": len(channels)})
    print("READY " + json.dumps([c["address"] for c in clients]), flush=True)

    await loop.run_in_executor(None, sys.stdin.readline)  # the bridge says stop
    for task in tasks:
        task.cancel()
    stalled.transport.abort()
    Path(out_path).write_text(json.dumps({"clients": clients}))
    print("DONE", flush=True)
    os._exit(0)  # the readers' sockets need no goodbye


# --- the car: three senders -----------------------------------------------------------------

def traffic(duration_s: float) -> dict[str, list[Any]]:
    """The simulated ecocar drive's frames as python-can messages, split by sensor bus."""
    import can

    from bridge.sim.ecocar import simulate
    from bridge.sim.frames import load_ecocar

    db = load_ecocar()
    names = {m.frame_id: m.name for m in db.messages}
    out: dict[str, list[Any]] = {bus: [] for bus in BUSES}
    for frame in simulate(duration_s=duration_s):
        name = names.get(frame.arbitration_id, "")
        bus = ("radar" if name.startswith("Radar") else
               "camera" if name.startswith("Cam") else "chassis")
        out[bus].append(can.Message(
            arbitration_id=frame.arbitration_id, data=frame.data,
            is_extended_id=frame.is_extended, is_fd=frame.is_fd,
            bitrate_switch=frame.bitrate_switch, dlc=frame.dlc))
    return out


@dataclass
class Sender:
    bus: str
    channel: str
    messages: list[Any]
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
        import can

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


def percentile(values: Sequence[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, int(q * len(ordered) + 0.5) - 1))]


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


def analyse(files: Sequence[Path], received: list[dict[int, tuple[int, int]]],
            window: tuple[int, int], frames_before: dict[int, int]) -> DriveAnalysis:
    """Which scene contains which frame, and the latencies at the readers.

    ``received``: per reading client, tick -> (when the last of its /scene/* messages stamped
    with that tick arrived, how many arrived). A tick counts as received when the client got as
    many /scene/* messages stamped with it as the drive recorded. ``frames_before``: tick -> how
    many frames the pipeline had processed when it began the tick (:func:`time_scene_stages`):
    the tick's scene contains them. The drive's frames, read back from their blocks
    (:class:`bridge.io.drives.ArchiveSource`), are taken in that order.
    """
    from mcap.reader import make_reader

    from bridge.io.drives import ArchiveSource

    result = DriveAnalysis(summary_frame_counts(files), 0, Histogram(),
                           scenes_missed=[0] * len(received))
    lo, hi = window
    stamps = array("q", (f.timestamp_ns for path in files for f in ArchiveSource(path)))
    scenes: list[tuple[int, array[int]]] = []  # tick, the frames it contains (in the window)
    done = 0
    for tick, before in sorted(frames_before.items()):
        scenes.append((tick, array("q", (t for t in stamps[done:before] if lo <= t < hi))))
        done = max(done, before)
    recorded: dict[int, int] = {}  # tick -> /scene/* messages recorded with that time
    for path in files:
        with path.open("rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            topics = [c.topic for c in summary.channels.values()
                      if c.topic.startswith("/scene/")] if summary is not None else []
            for _, _, message in reader.iter_messages(topics=topics):
                recorded[message.log_time] = recorded.get(message.log_time, 0) + 1
    result.scenes = len(scenes)
    complete = result.complete = [
        {t: at for t, (at, n) in got.items() if n >= recorded.get(t, 0)} for got in received]
    hist = result.frame_latency
    for tick, frames in scenes:
        in_window = lo <= tick < hi
        result.scenes_in_window += in_window
        if not frames and not in_window:
            continue
        result.frames_in_window += len(frames)
        oldest = min(frames) if frames else None
        for r, got in enumerate(complete):
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
                hist.add(at - t)
    return result


def scene_receipts(client: dict[str, Any]) -> dict[int, tuple[int, int]]:
    """Tick -> (when the last of its /scene/* messages arrived, how many arrived)."""
    last: dict[int, int] = {}
    parts: dict[int, int] = {}
    for rows in client["scenes"].values():
        for t_ns, at in rows:
            parts[t_ns] = parts.get(t_ns, 0) + 1
            last[t_ns] = max(last.get(t_ns, 0), at)
    return {t: (at, parts[t]) for t, at in last.items()}


def time_scene_stages(pipeline: Any) -> dict[int, list[int]]:
    """Wall times of each scene tick inside the bridge: tick -> [the pipeline starts computing
    it, computed, serialised + recorded + handed to the server, and the frames processed before
    it (the frames its scene contains)]. Wraps two methods of this
    pipeline's instances (50 calls a second; the bridge's code is unchanged): the perception's
    ``tick`` (one scene tick) and the pipeline's ``emit``."""
    stages: dict[int, list[int]] = {}
    perception = pipeline.perception
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
    pipeline.emit = timed_emit
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


def print_profile_summary(stats: Any) -> None:
    """Inclusive CPU time of the pipeline's stages, as a share of the thread's CPU time."""
    entries = stats.stats  # (file, line, function) -> (calls, ncalls, tottime, cumtime, callers)
    total = sum(e[2] for e in entries.values()) or 1.0
    print(f"\npipeline thread under cProfile: {total:.1f} s CPU; inclusive share per stage "
          "(scene emit includes its publish):")
    for label, module, function in PROFILE_PARTS:
        # the outermost of same-named functions (Decoder.decode calls MessageCodec.decode)
        found = [e for (file, _, name), e in entries.items()
                 if file.endswith(module) and name == function]
        cum, calls = max(((e[3], e[1]) for e in found), default=(0.0, 0))
        print(f"  {100 * cum / total:5.1f} %  {label}  ({calls:,} calls)")


# --- the run ----------------------------------------------------------------------------------

def run(args: argparse.Namespace) -> None:
    import can  # noqa: F401  (imported before the CPU window)

    from bridge.io.buses import BusSpec
    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.live_engine import Live
    from bridge.sinks.server import ViewerServer
    from tests.waiting import wait_for

    duration = 10.0 if args.quick else args.duration
    period_ms = 1000 / SCENE_RATE
    print(f"tankviz live benchmark: {len(BUSES)} virtual buses x {args.rate:,.0f} frames/s for "
          f"{duration:g} s, scene at {SCENE_RATE:g} Hz, 4 WebSocket clients (1 stalled)")
    t = time.perf_counter()
    messages = traffic(args.traffic_s)
    print("traffic: " + ", ".join(f"{b} cycles {len(m):,} simulated frames"
                                  for b, m in messages.items())
          + f" (prepared in {time.perf_counter() - t:.1f} s)")

    # The reference, measured now on this machine as it is: the same work without live (in a
    # process of its own, so that its memory is not this one's).
    reference_us, paced_us, bare_pct = map(float, subprocess.run(
        [sys.executable, __file__, "--reference", str(REFERENCE_FRAMES), "--traffic-s",
         str(args.traffic_s), "--rate", str(args.rate), "--batch-ms", str(args.batch_ms)],
        check=True, capture_output=True, text=True).stdout.split())
    reference_pct = reference_us * len(BUSES) * args.rate / 1e4
    paced_pct = paced_us * len(BUSES) * args.rate / 1e4
    # The prepared traffic is the harness's, not the bridge's: keep it out of the collector's
    # view, so that the bridge's full collections cost what they would cost without it.
    gc.freeze()
    ecocar = load_stages([], "ecocar")
    tmp = tempfile.TemporaryDirectory(prefix="tankviz-bench-live-")
    drives = Path(args.drives) if args.drives else Path(tmp.name)
    said: list[str] = []
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    server = ViewerServer(port=0)
    server.start()
    pid = os.getpid()
    specs = [BusSpec(bus, "virtual", f"bench-live-{pid}-{bus}") for bus in BUSES]
    live = Live(specs, ecocar, scene_rate=SCENE_RATE, drives=drives,
                server=server, say=said.append)
    live.start()
    outcome: dict[str, Any] = {}
    stages = time_scene_stages(live.pipeline)

    def pipeline() -> None:
        if args.cprofile:
            import cProfile

            profiler = cProfile.Profile(time.thread_time)  # CPU, not GIL waits
            outcome["profile"] = profiler
            profiler.enable()
        try:
            outcome["report"] = live.run()
        finally:
            if args.cprofile:
                profiler.disable()

    runner = threading.Thread(target=pipeline, name="tankviz-pipeline")
    runner.start()

    results = Path(tmp.name) / "clients.json"
    clients = subprocess.Popen(
        [sys.executable, os.path.abspath(__file__), "--client", server.url, str(results),
         "--stalled-topics", args.stalled_topics],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert clients.stdout is not None and clients.stdin is not None
    line = clients.stdout.readline()
    if not line.startswith("READY "):
        raise SystemExit(f"the clients did not start: {line!r}, exit {clients.wait()}")
    addresses = json.loads(line[len("READY "):])
    wait_for(lambda: len(server._wanted) > 0, timeout=5)  # subscriptions have landed
    time.sleep(0.5)

    opened = threading.Barrier(len(BUSES) + 1)
    go = threading.Event()
    start_at: list[float] = [0.0]
    senders = [Sender(bus, spec.channel or "", messages[bus], args.rate, duration,
                      args.batch_ms / 1000) for bus, spec in zip(BUSES, specs, strict=True)]
    for sender in senders:
        sender.start(go, start_at, opened)
    opened.wait()

    if args.switch_interval:
        sys.setswitchinterval(args.switch_interval / 1000)
    gc_pauses: list[tuple[int, float]] = []
    gc_cpu: list[float] = []  # the same pauses in the collecting thread's CPU time
    gc_started = [0.0, 0.0]

    def gc_watch(phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            gc_started[:] = time.perf_counter(), time.thread_time()
        else:
            gc_pauses.append((info["generation"], time.perf_counter() - gc_started[0]))
            gc_cpu.append(time.thread_time() - gc_started[1])

    gc.callbacks.append(gc_watch)
    threads_before = thread_cpu()
    exclude = {os.getpid(), clients.pid}
    others_before, clients_before = other_processes_cpu(exclude), child_cpu(clients.pid)
    cpu_before, main_before = process_cpu(), time.thread_time()
    wall_before = time.monotonic()
    send_start_ns = time.time_ns()
    start_at[0] = time.monotonic()
    go.set()
    # While the car drives, the harness samples how far behind the pipeline and the server are.
    lag_ms: list[float] = []
    inbox: list[int] = []
    while any(s.thread is not None and s.thread.is_alive() for s in senders):
        time.sleep(0.05)
        last = live.pipeline.last_ns
        if last is not None:
            lag_ms.append((time.time_ns() - last) / MS)
        inbox.append(len(server._inbox))
    for sender in senders:
        assert sender.thread is not None
        sender.thread.join()
    send_end_ns = time.time_ns()
    sent_total = sum(s.sent for s in senders)
    stalled_address = addresses[-1]

    def delivered() -> bool:
        """Every frame processed, and the server has passed on all the readers' messages."""
        return (live.pipeline.frames >= sent_total and not server._inbox
                and all(not c.queue for c in list(server._clients.values())
                        if c.stats.address != stalled_address))

    drained = wait_for(delivered, timeout=60, step=0.002)
    wall_after = time.monotonic()
    cpu_after, main_after = process_cpu(), time.thread_time()
    threads_after = thread_cpu()
    others_after, clients_after = other_processes_cpu(exclude), child_cpu(clients.pid)
    gc.callbacks.remove(gc_watch)
    names = {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}
    time.sleep(0.2)  # the idle timer's last scene reaches the clients
    stats = {s.address: s for s in server.client_stats()}

    clients.stdin.write("stop\n")
    clients.stdin.flush()
    clients.wait(30)
    live.stop()
    runner.join(60)
    server.stop()
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rss_end = rss_now_mb()

    # --- CPU ---
    wall = wall_after - wall_before
    sender_cpu = sum(s.cpu_s for s in senders)
    process_delta = cpu_after - cpu_before
    bridge_cpu = process_delta - sender_cpu - (main_after - main_before)
    bridge_pct = 100 * bridge_cpu / wall
    names.update({s.thread.native_id: s.thread.name for s in senders
                  if s.thread is not None and s.thread.native_id is not None})
    names[threading.main_thread().native_id or 0] = "harness (main thread)"
    by_thread: dict[str, float] = {}
    for tid, after in threads_after.items():
        name = names.get(tid, f"thread {tid}")
        by_thread[name] = by_thread.get(name, 0.0) + after - threads_before.get(tid, 0.0)
    bridge_threads = sum(v for k, v in by_thread.items() if k.startswith("tankviz-"))

    # --- frames, scenes, latency ---
    data = json.loads(results.read_text())
    readers = [c for c in data["clients"] if c["role"] == "reader"]
    receipts = [scene_receipts(c) for c in readers]
    window = (send_start_ns + round(WARMUP_S * NS), send_end_ns - round(TAIL_S * NS))
    report = outcome.get("report")
    files = list(report.files) if report is not None else sorted(drives.glob("*.mcap"))
    t = time.perf_counter()
    analysis = analyse(files, receipts, window,
                       {tick: noted[3] for tick, noted in stages.items()})
    analyse_s = time.perf_counter() - t
    drive_mb = sum(p.stat().st_size for p in files) / 1e6

    # --- the table ---
    rows: list[tuple[str, str, str, str]] = []
    missed: list[str] = []

    def row(metric: str, value: str, target: str = "", ok: bool | None = None,
            miss: str = "") -> None:
        rows.append((metric, value, target, "" if ok is None else ("ok" if ok else "MISSED")))
        if ok is False:
            missed.append(miss or f"{metric}: {value} (target {target})")

    for s in senders:
        achieved = s.sent / s.elapsed_s if s.elapsed_s else float("nan")
        row(f"send rate {s.bus}", f"{achieved:,.0f} frames/s (max late {s.late_max_s * 1e3:.1f} "
            f"ms)", f"{args.rate:,.0f} frames/s", abs(achieved - args.rate) <= 0.01 * args.rate)
    for s in senders:
        recorded = analysis.frames_by_bus.get(s.bus, 0)
        row(f"frames recorded / sent {s.bus}", f"{recorded:,} / {s.sent:,}", "equal",
            recorded == s.sent)
    recorded_total = sum(analysis.frames_by_bus.values())
    row("frames recorded / sent, total", f"{recorded_total:,} / {sent_total:,}", "equal",
        recorded_total == sent_total)
    row("bridge CPU (process - senders - harness)", f"{bridge_pct:.1f} % of one core",
        f"< {CPU_TARGET:g} %", bridge_pct < CPU_TARGET)
    row("  cross-check: bridge threads (/proc)", f"{100 * bridge_threads / wall:.1f} %")
    row("  reference: bare python-can receive, same run", f"{bare_pct:.1f} %; bridge / bare "
        f"receive = {bridge_pct / bare_pct:.2f}")
    row("  reference: the pipeline alone, same run", f"{reference_pct:.1f} % ({reference_us:.1f} "
        f"µs/frame); bridge / reference = {bridge_pct / reference_pct:.2f}")
    row("  reference paced as live reads, same run", f"{paced_pct:.1f} % ({paced_us:.1f} "
        f"µs/frame); bridge / paced = {bridge_pct / paced_pct:.2f}")
    row("  senders (subtracted)", f"{100 * sender_cpu / wall:.1f} %")
    target_ms = period_ms + LATENCY_MARGIN_MS
    hist = analysis.frame_latency
    row("latency frame → scene at client p50", f"{hist.quantile_ms(0.5):.1f} ms")
    row("latency frame → scene at client p99", f"{hist.quantile_ms(0.99):.1f} ms",
        f"< {target_ms:g} ms ({period_ms:g} + {LATENCY_MARGIN_MS:g})",
        hist.quantile_ms(0.99) < target_ms)
    row("latency frame → scene at client max", f"{hist.max_ns / MS:.1f} ms")
    row("  scene delivery (receive - tick) p50 / p99 / max",
        f"{percentile(analysis.delivery_ms, 0.5):.1f} / "
        f"{percentile(analysis.delivery_ms, 0.99):.1f} / "
        f"{max(analysis.delivery_ms, default=float('nan')):.1f} ms")
    segment_s = 10 if duration > 10 else 2
    segments: dict[int, list[float]] = {}
    for tick, ms in zip(analysis.delivery_at, analysis.delivery_ms, strict=True):
        segments.setdefault((tick - send_start_ns) // (segment_s * NS), []).append(ms)
    row(f"  scene delivery p99 per {segment_s} s of the run",
        " ".join(f"{percentile(v, 0.99):.0f}" for _, v in sorted(segments.items())) + " ms")
    row("  oldest frame of a scene p50 / p99 / max",
        f"{percentile(analysis.oldest_ms, 0.5):.1f} / "
        f"{percentile(analysis.oldest_ms, 0.99):.1f} / "
        f"{max(analysis.oldest_ms, default=float('nan')):.1f} ms")
    lo, hi = window
    parts: list[list[float]] = [[], [], [], []]
    for received_at in analysis.complete:
        for tick, (start, computed, emitted, _) in stages.items():
            at = received_at.get(tick)
            if at is None or not emitted or not lo <= tick < hi:
                continue
            for i, ms in enumerate((start - tick, computed - start, emitted - computed,
                                    at - emitted)):
                parts[i].append(ms / MS)
    row("    where: tick → the pipeline starts the scene",
        f"{percentile(parts[0], 0.5):.1f} / {percentile(parts[0], 0.99):.1f} / "
        f"{max(parts[0], default=float('nan')):.1f} ms")
    row("    where: the scene is computed (perception tick)",
        f"{percentile(parts[1], 0.5):.1f} / {percentile(parts[1], 0.99):.1f} / "
        f"{max(parts[1], default=float('nan')):.1f} ms")
    row("    where: serialised, recorded, handed to the server",
        f"{percentile(parts[2], 0.5):.1f} / {percentile(parts[2], 0.99):.1f} / "
        f"{max(parts[2], default=float('nan')):.1f} ms")
    row("    where: server thread → client has the whole scene",
        f"{percentile(parts[3], 0.5):.1f} / {percentile(parts[3], 0.99):.1f} / "
        f"{max(parts[3], default=float('nan')):.1f} ms")
    row("pipeline lag (now - newest frame processed) p50 / p99 / max",
        f"{percentile(lag_ms, 0.5):.1f} / {percentile(lag_ms, 0.99):.1f} / "
        f"{max(lag_ms, default=float('nan')):.1f} ms")
    row("backlog max: server inbox", f"{max(inbox, default=0):,} messages")
    full = [d for g, d in gc_pauses if g == 2]
    row("garbage collections: all / full (gen 2), longest pause",
        f"{len(gc_pauses):,} / {len(full)}, {1e3 * max((d for _, d in gc_pauses), default=0):.1f}"
        " ms")
    longest_gc = 1e3 * max((d for _, d in gc_pauses), default=0)
    row("GC pauses > 5 ms (wall) / longest in CPU time",
        f"{sum(d > 0.005 for _, d in gc_pauses)} / {1e3 * max(gc_cpu, default=0):.1f} ms",
        "none > 5 ms", longest_gc <= 5.0)
    got = [len(r) for r in analysis.complete]
    row("scenes received complete by each reader",
        f"{analysis.scenes_in_window - max(analysis.scenes_missed, default=0):,} / "
        f"{analysis.scenes_in_window:,} in window "
        f"({', '.join(f'{n:,}' for n in got)} in all; {analysis.scenes:,} emitted)",
        "all", not any(analysis.scenes_missed) and analysis.frames_without_scene == 0)
    reader_addresses = addresses[:-1]
    dropped_readers = sum(stats[a].dropped for a in reader_addresses if a in stats)
    row("messages dropped, reading clients", f"{dropped_readers:,}", "0", dropped_readers == 0)
    stalled = stats.get(stalled_address)
    row("messages dropped, stalled client (its own)",
        f"{stalled.dropped:,} (sent {stalled.sent:,})" if stalled else "?", "> 0",
        (stalled is not None and stalled.dropped > 0) if args.stalled_topics == "all" else None)
    row("peak RSS (ru_maxrss)", f"{peak_rss:.0f} MB (before bridge {rss_before:.0f} MB, "
        f"at end {rss_end:.0f} MB)")
    row("drive written", f"{drive_mb:.0f} MB in {len(files)} file(s), "
        f"{drive_mb / wall:.1f} MB/s")
    if not drained:
        row("bridge caught up within 60 s", f"{live.pipeline.frames:,} of {sent_total:,} frames"
            f", server inbox {len(server._inbox):,}", "all", False)

    width = [max(len(r[i]) for r in [*rows, ("metric", "value", "target", "ok?")])
             for i in range(4)]
    print()
    print(f"window {wall:.1f} s (senders started → every frame processed, the scenes passed on); "
          f"latency over {hist.count:,} frame deliveries (frames x {len(readers)} readers, "
          f"{WARMUP_S:g} s warm-up and {TAIL_S:g} s tail left out)")
    header = ("metric", "value", "target", "ok?")
    line = "  ".join(f"{h:<{w}}" for h, w in zip(header, width, strict=True))
    print(line)
    print("-" * len(line))
    for r in rows:
        print("  ".join(f"{c:<{w}}" for c, w in zip(r, width, strict=True)).rstrip())
    print()
    print("CPU by thread over the window (% of one core, /proc/self/task/*/stat):")
    for name, seconds in sorted(by_thread.items(), key=lambda kv: -kv[1]):
        if seconds > 0:
            print(f"  {name:<32} {100 * seconds / wall:5.1f} %")
    print(f"  (process total {100 * process_delta / wall:.1f} %; bridge = process - senders "
          f"{100 * sender_cpu / wall:.1f} % - harness {100 * (main_after - main_before) / wall:.1f}"
          " %; clients run in another process)")
    others = sum(cpu - others_before[pid] for pid, cpu in others_after.items()
                 if pid in others_before)
    print(f"machine: {os.cpu_count()} CPUs; during the window this process used "
          f"{100 * process_delta / wall:.0f} % of one CPU, the clients' process "
          f"{100 * (clients_after - clients_before) / wall:.0f} %, other processes "
          f"{100 * others / wall:.0f} % (those alive at both ends); load average "
          f"{os.getloadavg()[0]:.2f}")
    if said:
        print("bridge said: " + "; ".join(said))
    print(f"(drive read back in {analyse_s:.1f} s)")
    if args.cprofile and "profile" in outcome:
        import pstats

        profiled = pstats.Stats(outcome["profile"])
        print_profile_summary(profiled)
        print("\ncProfile of the pipeline thread (thread CPU time; the profiler inflates it; "
              "top 25 by own time):")
        profiled.sort_stats("tottime").print_stats(25)
    for m in missed:
        print(f"TARGET MISSED: {m}")
    tmp.cleanup()


def _everyone_wants() -> Any:
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


def pipeline_frames(messages: dict[str, list[Any]], count: int,
                    frames_per_s: float = 12_000) -> list[Any]:
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


def pipeline_cost(frames: list[Any], *, record: bool = True, health: bool = True,
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
    sinks = [_everyone_wants()] if serve else []
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


def bare_receive_pct(messages: dict[str, list[Any]], rate: float, seconds: float,
                     batch_s: float) -> float:
    """The fixed reference of issue #15: bare python-can receive of the same traffic on the same
    virtual buses, as % of one core: one thread per bus calling ``bus.recv`` in a loop, while
    the benchmark's own senders send at ``rate`` for ``seconds``; the receivers' thread CPU
    time over the wall time."""
    import can

    pid = os.getpid()
    go, start_at = threading.Event(), [0.0]
    opened = threading.Barrier(2 * len(BUSES) + 1)
    done = threading.Event()
    cpu: list[float] = []

    def receive(bus_name: str) -> None:
        bus = can.Bus(interface="virtual", channel=f"bench-bare-{pid}-{bus_name}")
        opened.wait()
        go.wait()
        start = time.thread_time()
        recv = bus.recv
        while not done.is_set():
            recv(0.1)  # a frame, or None after 0.1 s without one
        cpu.append(time.thread_time() - start)
        bus.shutdown()

    receivers = [threading.Thread(target=receive, args=(b,), daemon=True) for b in BUSES]
    senders = [Sender(b, f"bench-bare-{pid}-{b}", messages[b], rate, seconds, batch_s)
               for b in BUSES]
    for thread in receivers:
        thread.start()
    for sender in senders:
        sender.start(go, start_at, opened)
    opened.wait()
    start_at[0] = time.monotonic()
    go.set()
    for sender in senders:
        assert sender.thread is not None
        sender.thread.join()
    wall = time.monotonic() - start_at[0]
    time.sleep(0.05)  # the last frames are received
    done.set()
    for thread in receivers:
        thread.join(timeout=5)
    return 100 * sum(cpu) / wall


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
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
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
    parser.add_argument("--car", action="store_true",
                        help="instead: tankviz live as a command with the car in another "
                        "process (udp_multicast), split and not (tools/bench_live_car.py)")
    parser.add_argument("--car-rates", default="12000,6000", help="--car: frames/s, all buses")
    parser.add_argument("--car-seconds", type=float, default=20.0, help="--car: per run")
    parser.add_argument("--car-readers", default="process,here",
                        help="--car: where the buses are read (process: their own; here)")
    args = parser.parse_args(argv)
    if args.car:
        from bench_live_car import main as car_main

        return car_main([float(r) for r in args.car_rates.split(",")], args.car_seconds,
                        args.car_readers.split(","))
    if args.reference:
        messages = traffic(args.traffic_s)
        frames = pipeline_frames(messages, args.reference, len(BUSES) * args.rate)
        gc.freeze()
        print(min(pipeline_cost(frames) for _ in range(3)),
              min(pipeline_cost(frames, paced=True) for _ in range(3)),
              min(bare_receive_pct(messages, args.rate, 5.0, args.batch_ms / 1e3)
                  for _ in range(3)))
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
