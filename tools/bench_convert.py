#!/usr/bin/env python3
"""Benchmark ``tankviz convert`` against fixed references in the same run (a report, not a test).

Every figure is a ratio against reference code run in the same run, interleaved with tankviz
(``--runs`` rounds, the best counts), on elapsed time or, with ``--clock cpu``, CPU time (of the
contender's process and its children). The contenders, on ``bridge/sim``'s ecocar drive on three
buses (:func:`benchlib.ecocar_log`) as BLF and as ASC, and on a candump of a production car's
bus made from a public DBC (:func:`real_frames`): python-can's bare reader, the naive converter
(:func:`naive_convert`, raw + decoded and with :func:`naive_scene`) and ``tankviz convert`` in a
subprocess; also start-up, archive sizes and memory on a longer drive. It prints the ratios of
issue #15's table, then ``TARGET MISSED`` lines, then the details; progress goes to stderr;
``--json FILE`` is for ``tools/bench_report.py``. The exit status is 0 regardless: a report.

    python tools/bench_convert.py --quick      # 200k / 400k simulated, 50k real frames
    python tools/bench_convert.py              # 1.44M (about 650 s) / 2.88M, 135k real frames
    python tools/bench_convert.py --frames 5000 --frames2 10000 --real-frames 5000 --runs 1
"""

from __future__ import annotations

import argparse
import compileall
import heapq
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import can
import cantools
from cantools.database.can.database import Database
from cantools.database.can.message import Message as DbcMessage

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import ECOCAR_DBC, MB, add_workdir, ecocar_log, interleaved, log_copy

#: Absolute start of the real-format log (python-can float seconds).
T0 = 1_700_000_000.0


def _frame_ns(length: int, fd: bool) -> int:
    """Time one frame occupies its bus: 500 kbit/s, FD data phase at 2 Mbit/s, with stuffing."""
    if fd:
        return int((29 / 500e3 + (length * 8 + 60) * 1.1 / 2e6) * 1e9)
    return int((47 + 8 * length) * 1.2 / 500e3 * 1e9)

# --------------------------------------------------------------------------------------------
# A public real-format log: candump of a production car's bus, from a public DBC


#: The public DBCs beside the project (opendbc, MIT), as the tests find them.
SHARED_DBC_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "dbc"
#: A production GM car's object bus: counters and checksums (it has no GenMsgCycleTime).
REAL_DBC = "gm_global_a_object.dbc"
REAL_GENERATOR_VERSION = 1
#: Ids on the bus that the DBC does not define (gateways, diagnostics), 100 ms each.
REAL_UNKNOWN_IDS = (0x1F1, 0x3C9, 0x4D1)


def _is_counter(name: str) -> bool:
    lower = name.lower()
    return "rolling" in lower or lower.endswith("counter") or (
        lower.endswith("count") and ("roll" in lower or "alive" in lower))


def _is_checksum(name: str) -> bool:
    lower = name.lower()
    return "checksum" in lower or "crc" in lower


def real_frames(db: Database, seed: int, channel: str = "can0") -> Iterator[can.Message]:
    """An endless candump-like stream of ``db``'s messages on one bus, as a production car sends.

    Each message comes at its ``GenMsgCycleTime`` where the DBC has one, else at a cycle drawn
    once from 10..1000 ms (±0.2 ms jitter); multiplexed messages are left out. About a quarter of
    the signals of a message change now and then (a small random walk of the raw value), the rest
    hold a value for the whole drive; a rolling counter/count signal rolls on every frame, and a
    checksum/CRC signal is the byte sum of the rest of the payload: so most payloads repeat except
    for their counter and checksum, as on a real bus.
    """
    rng = random.Random(seed)
    ms = 1_000_000
    plans: list[tuple[int, DbcMessage | int, dict[str, int], list[str], list[str], str | None]] = []
    for m in sorted(db.messages, key=lambda m: m.frame_id):
        if m.is_multiplexed():
            continue
        period = int(m.cycle_time or rng.choice((10, 20, 25, 50, 50, 100, 100, 100, 200, 1000)))
        values: dict[str, int] = {}
        moving: list[str] = []
        counters: list[str] = []
        checksum = None
        for s in m.signals:
            top = 2 ** min(s.length, 12) - 1
            values[s.name] = 0 if s.is_float else rng.randint(0, top) if not s.is_signed else \
                rng.randint(-(top // 2), top // 2)
            if _is_checksum(s.name):
                checksum = s.name
            elif _is_counter(s.name):
                counters.append(s.name)
            elif not s.is_float and s.length > 1 and rng.random() < 0.25:
                moving.append(s.name)
        plans.append((period * ms, m, values, moving, counters, checksum))
    for ident in REAL_UNKNOWN_IDS:
        plans.append((100 * ms, ident, {}, [], [], None))
    pending = [(rng.randrange(p[0]), i) for i, p in enumerate(plans)]
    heapq.heapify(pending)
    limits = {(dm.name, s.name): s for _, dm, *_ in plans if not isinstance(dm, int)
              for s in dm.signals}
    free = 0
    alive = 0
    while True:
        t, i = heapq.heappop(pending)
        period, what, values, moving, counters, checksum = plans[i]
        heapq.heappush(pending, (t + period + rng.randint(-200, 200) * 1000, i))
        frame_id: int
        if isinstance(what, int):
            alive = (alive + 1) & 0xFF
            data = bytes([alive, 0x10, 0, 0, 0, 0, 0, 0])
            frame_id = what
        else:
            for name in moving:
                if rng.random() < 0.3:
                    s = limits[(what.name, name)]
                    lo, hi = (-(2 ** (s.length - 1)), 2 ** (s.length - 1) - 1) if s.is_signed \
                        else (0, 2**s.length - 1)
                    values[name] = max(lo, min(hi, values[name] + rng.randint(-3, 3)))
            for name in counters:
                values[name] = (values[name] + 1) % 2 ** limits[(what.name, name)].length
            if checksum is not None:
                values[checksum] = 0
            data = bytes(what.encode(values, scaling=False, padding=False, strict=False))
            if checksum is not None:
                values[checksum] = sum(data) % 2 ** limits[(what.name, checksum)].length
                data = bytes(what.encode(values, scaling=False, padding=False, strict=False))
            frame_id = what.frame_id
        tx = max(t, free)
        tx -= tx % 1000
        free = tx + _frame_ns(len(data), False)
        yield can.Message(timestamp=T0 + tx / 1e9, arbitration_id=frame_id, data=data,
                          channel=channel, is_extended_id=frame_id > 0x7FF, dlc=len(data))


def real_log(workdir: Path, frames: int, seed: int,
             dbc: Path | None = None) -> tuple[Path, Path, dict[str, Any]]:
    """The cached candump (.log) of ``frames`` frames from a public DBC: (log, DBC, statistics).

    Raises :class:`FileNotFoundError` naming the folder when the public DBCs are absent."""
    dbc = dbc or SHARED_DBC_DIR / REAL_DBC
    if not dbc.is_file():
        raise FileNotFoundError(f"{dbc}: not found (the public DBCs come from ../shared/data/dbc, "
                                "opendbc, MIT)")
    stem = f"real-{dbc.stem}-{frames}f-seed{seed}-g{REAL_GENERATOR_VERSION}"
    path, meta_path = workdir / f"{stem}.log", workdir / f"{stem}.json"
    if path.is_file() and meta_path.is_file():
        meta: dict[str, Any] = json.loads(meta_path.read_text())
        return path, dbc, meta
    db = cantools.database.load_file(str(dbc), strict=False)
    assert isinstance(db, Database)
    partial = workdir / f".{stem}.log.partial"
    known = {m.frame_id for m in db.messages}
    in_dbc = same_as_last = 0
    last: dict[int, bytes] = {}
    last_t = 0.0
    with can.CanutilsLogWriter(str(partial)) as writer:
        for n, msg in enumerate(real_frames(db, seed)):
            if n >= frames:
                break
            writer.on_message_received(msg)
            data = bytes(msg.data)
            in_dbc += msg.arbitration_id in known
            same_as_last += last.get(msg.arbitration_id) == data
            last[msg.arbitration_id] = data
            last_t = msg.timestamp
    os.replace(partial, path)
    meta = {"frames": frames, "seed": seed, "dbc": dbc.name, "ids": len(last),
            "seconds_of_driving": last_t - T0, "share_of_frames_in_dbc": in_dbc / frames,
            "repeat_previous_payload_of_id": same_as_last / frames,
            "bytes": path.stat().st_size}
    meta_path.write_text(json.dumps(meta, indent=1))
    return path, dbc, meta


# --------------------------------------------------------------------------------------------
# The references: bare reading and the naive converter (with or without the scene)


#: What the ratios compare (``--clock``): "wall", the elapsed time a user waits; or "cpu", user +
#: system CPU time of the contender (its process and children, or this process for the
#: in-process references), which a loaded shared machine disturbs far less than elapsed time.
CLOCK = "wall"


@dataclass
class Run:
    frames: int
    wall: float
    rss_mb: float | None = None
    errors: int = 0
    unknown: int = 0
    cpu: float = 0.0

    @property
    def seconds(self) -> float:
        """The time on :data:`CLOCK`."""
        return self.cpu if CLOCK == "cpu" else self.wall

    @property
    def rate(self) -> float:
        return self.frames / self.seconds if self.seconds else 0.0


def bare_read(path: Path) -> Run:
    """(a) python-can's reader alone."""
    started, cpu = time.perf_counter(), time.process_time()
    n = 0
    for _ in can.LogReader(str(path)):
        n += 1
    return Run(n, time.perf_counter() - started, cpu=time.process_time() - cpu)


#: Scene updates per second of log time, as ``tankviz convert`` makes them by default.
SCENE_RATE = 20.0
#: The ecocar categories the naive converter draws (tankviz's topics ``/scene/<category>``).
NAIVE_SCENE_CATEGORIES = ("ego", "lanes", "radar", "camera", "tracks", "lead")


def naive_scene(latest: dict[str, dict[str, Any]], t_ns: int) -> list[tuple[str, Any]]:
    """The ecocar's scene drawn the straightforward way: one ``foxglove.SceneUpdate`` per category.

    ``latest`` holds the newest decoded signals of each DBC message. Ego: a box; lanes: each
    valid camera lane (``Source == 1 and Quality > 0``) as a 100-point line of its cubic, 100 m
    ahead (the camera counts y to the right); radar objects (``Valid == 1 and ProbExist > 70``),
    camera obstacles (``Valid == 1``), fusion tracks (``Status != 0``) and the lead vehicle
    (``Valid == 1``) as boxes with a text label. Fixed reference code: it never changes with
    tankviz."""
    from foxglove_schemas_protobuf.Color_pb2 import Color
    from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
    from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
    from foxglove_schemas_protobuf.Point3_pb2 import Point3
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
    from google.protobuf.timestamp_pb2 import Timestamp

    stamp = Timestamp(seconds=t_ns // 1_000_000_000, nanos=t_ns % 1_000_000_000)

    def entity(ident: str) -> Any:
        return SceneEntity(timestamp=stamp, frame_id="vehicle", id=ident, frame_locked=True)

    def box(x: float, y: float, length: float, width: float, height: float,
            rgba: tuple[float, float, float, float]) -> Any:
        return CubePrimitive(pose=Pose(position=Vector3(x=x, y=y, z=height / 2)),
                             size=Vector3(x=max(length, 0.3), y=max(width, 0.3), z=height),
                             color=Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]))

    def label(x: float, y: float, text: str) -> Any:
        return TextPrimitive(pose=Pose(position=Vector3(x=x, y=y, z=2.0)), billboard=True,
                             font_size=12, scale_invariant=True,
                             color=Color(r=1, g=1, b=1, a=1), text=text)

    def get(name: str) -> dict[str, Any]:
        return latest.get(name, {})

    out: list[tuple[str, Any]] = []
    ego = entity("ego")
    ego.cubes.append(box(0.0, 0.0, 2.5, 1.5, 1.0, (0.2, 0.5, 1.0, 0.8)))
    out.append(("ego", SceneUpdate(entities=[ego])))

    lanes = SceneUpdate()
    for name in ("CamLaneLeft", "CamLaneRight", "CamLaneNextLeft", "CamLaneNextRight"):
        s = get(name)
        if not (s.get("Source") == 1 and s.get("Quality", 0) > 0):
            continue
        c0, c1 = s["C0_Offset"], s["C1_Heading"]
        c2, c3 = s["C2_Curvature"], s["C3_CurvatureDerivative"]
        line = LinePrimitive(type=LinePrimitive.LINE_STRIP, thickness=0.15,
                             color=Color(r=1, g=1, b=1, a=0.9))
        for k in range(100):
            x = k * 100.0 / 99
            line.points.append(Point3(x=x, y=-(c0 + c1 * x + c2 * x * x + c3 * x * x * x),
                                      z=0.0))
        e = entity(f"lane-{name}")
        e.lines.append(line)
        lanes.entities.append(e)
    out.append(("lanes", lanes))

    radar = SceneUpdate()
    for i in range(32):
        a, b = get(f"RadarObj{i}_A"), get(f"RadarObj{i}_B")
        if not (a.get("Valid") == 1 and a.get("ProbExist", 0) > 70):
            continue
        x, y = a["LongDist"], a["LatDist"]
        e = entity(f"radar-{i}")
        e.cubes.append(box(x, y, b.get("Length", 0.5), b.get("Width", 0.5), 1.5,
                           (1.0, 0.3, 0.3, 0.6)))
        e.texts.append(label(x, y, f"radar {i} {a['LongSpeed']:+.1f} m/s"))
        radar.entities.append(e)
    out.append(("radar", radar))

    camera = SceneUpdate()
    for i in range(10):
        a, b = get(f"CamObstacle{i}_A"), get(f"CamObstacle{i}_B")
        if a.get("Valid") != 1:
            continue
        x, y = a["PosX"], -a["PosY"]
        e = entity(f"camera-{a['ObstacleID']}")
        e.cubes.append(box(x, y, b.get("Length", 1.0), b.get("Width", 1.0), 1.5,
                           (0.3, 1.0, 0.3, 0.6)))
        e.texts.append(label(x, y, f"camera {a['ObstacleID']}"))
        camera.entities.append(e)
    out.append(("camera", camera))

    tracks = SceneUpdate()
    for i in range(20):
        s = get(f"FusionTrack{i}")
        if s.get("Status", 0) == 0:
            continue
        x, y = s["PosX"], s["PosY"]
        e = entity(f"track-{s['TrackID']}")
        e.cubes.append(box(x, y, 4.5, 1.8, 1.5, (1.0, 0.8, 0.2, 0.6)))
        e.texts.append(label(x, y, f"track {s['TrackID']} {s['RelVelX']:+.1f} m/s"))
        tracks.entities.append(e)
    out.append(("tracks", tracks))

    lead = SceneUpdate()
    s = get("LeadVehicle")
    if s.get("Valid") == 1:
        x, y = s["PosX"], s["PosY"]
        e = entity("lead")
        e.cubes.append(box(x, y, 4.5, 1.8, 1.6, (1.0, 0.0, 1.0, 0.7)))
        e.texts.append(label(x, y, f"lead {x:.1f} m, gap {s['TimeGap']:.1f} s"))
        lead.entities.append(e)
    out.append(("lead", lead))
    return out


def _bus_name(channel: Any) -> str:
    """tankviz's bus name of a python-can channel (docs/commands.md: ``can<N>`` for numbered
    channels)."""
    if isinstance(channel, int):
        return f"can{channel}"
    return str(channel).strip() or "can"


def naive_convert(path: Path, output: Path, dbc: Path = ECOCAR_DBC, *,
                  scene: bool = False) -> Run:
    """(b) The straightforward converter: LogReader → cantools → mcap_protobuf Writer (zstd).

    With ``scene``, also :func:`naive_scene` at :data:`SCENE_RATE` of log time (the ecocar's
    categories), from the newest decoded values of each message."""
    from google.protobuf import descriptor_pool
    from mcap_protobuf.writer import Writer

    from bridge.decode.proto_schema import MessageSchema
    from bridge.pb.can_frame_pb2 import CanFrame

    started, cpu = time.perf_counter(), time.process_time()
    db = cantools.database.load_file(str(dbc), strict=False)
    assert isinstance(db, Database)
    pool = descriptor_pool.DescriptorPool()
    schemas = {m.frame_id: (m.name, MessageSchema(m, dbc.stem, pool)) for m in db.messages}
    # Every field the recorder writes: the schema (schemas/can_frame.proto) is the contract.
    with_time = "timestamp_ns" in CanFrame.DESCRIPTOR.fields_by_name
    frames = errors = unknown = 0
    latest: dict[str, dict[str, Any]] = {}
    period = round(1e9 / SCENE_RATE)
    next_tick: int | None = None
    with output.open("wb") as stream, Writer(stream) as writer:
        for msg in can.LogReader(str(path)):
            frames += 1
            bus = _bus_name(msg.channel)
            t = round(msg.timestamp * 1_000_000) * 1000
            if scene:
                if next_tick is None:
                    next_tick = t - t % period
                while t >= next_tick:
                    for category, update in naive_scene(latest, next_tick):
                        writer.write_message(f"/scene/{category}", update, log_time=next_tick,
                                             publish_time=next_tick)
                    next_tick += period
            data = bytes(msg.data)
            raw = CanFrame(
                bus=bus, id=msg.arbitration_id, extended=msg.is_extended_id, fd=msg.is_fd,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
                error=msg.is_error_frame, remote=msg.is_remote_frame, dlc=msg.dlc, data=data)
            if with_time:
                raw.timestamp_ns = t
            writer.write_message(f"/can/{bus}/frames", raw, log_time=t, publish_time=t)
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            entry = schemas.get(msg.arbitration_id)
            if entry is None:
                unknown += 1
                continue
            name, schema = entry
            try:
                signals = cast(dict[str, Any], db.decode_message(
                    msg.arbitration_id, data, decode_choices=False))
            except Exception:
                errors += 1
                continue
            if scene:
                latest[name] = signals
            if schema.renamed:
                signals = {schema.renamed.get(k, k): v for k, v in signals.items()}
            writer.write_message(f"/can/{bus}/{name}", schema.message_class(**signals),
                                 log_time=t, publish_time=t)
    return Run(frames, time.perf_counter() - started, errors=errors, unknown=unknown,
               cpu=time.process_time() - cpu)


# --------------------------------------------------------------------------------------------
# tankviz


def tankviz_command(path: Path, output: Path, *, dbc: Path | None = ECOCAR_DBC,
                    profile: str | None = None) -> list[str]:
    """``tankviz convert`` of ``path``: raw only (no ``dbc``/``profile``), decoded, or the scene."""
    command = [sys.executable, "-m", "bridge", "convert", str(path), "-o", str(output),
               "--quiet", "--force"]
    if dbc is not None:
        command += ["--dbc", str(dbc)]
    if profile is not None:
        command += ["--profile", profile]
    return command


def timed_process(command: list[str], frames: int = 0) -> Run:
    """Run ``command``: wall time from outside (start-up included), that process's peak RSS."""
    with tempfile.TemporaryFile() as said:
        started = time.perf_counter()
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=said)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - started
        code = os.waitstatus_to_exitcode(status)
        if code != 0:
            said.seek(0)
            raise SystemExit(f"failed with status {code}: {' '.join(command)}\n"
                             + said.read().decode(errors="replace"))
    return Run(frames, seconds, rss_mb=usage.ru_maxrss / 1024,  # ru_maxrss: KiB on Linux
               cpu=usage.ru_utime + usage.ru_stime)


def tankviz_convert(path: Path, output: Path, frames: int, *, dbc: Path | None = ECOCAR_DBC,
                    profile: str | None = None) -> Run:
    """(c) ``tankviz convert`` in its own process: wall time and that process's peak RSS."""
    return timed_process(tankviz_command(path, output, dbc=dbc, profile=profile), frames)


def startup_seconds() -> float:
    """Interpreter start-up plus importing what ``convert`` imports, part of (c)'s time."""
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import bridge.cli, bridge.apps.convert"], check=True)
    return time.perf_counter() - started


def topic_counts(path: Path) -> dict[str, int]:
    """Messages per topic, but frames on the raw-frame topics (tankviz writes them in blocks;
    a tankviz from before blocks, measured by ``bench_report.py --before``, one a message)."""
    from mcap.reader import make_reader

    from bridge.topics import frames_topic

    try:
        from bridge.io.drives import raw_frame_counts
        blocks = True
    except ImportError:  # before blocks: a message per frame
        blocks = False
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, f"{path}: no summary"
        counts = {summary.channels[cid].topic: n
                  for cid, n in summary.statistics.channel_message_counts.items()}
        if blocks:
            counts.update({frames_topic(bus): n for bus, n in raw_frame_counts(reader).items()})
    return counts


def index_bytes(path: Path) -> int:
    """Bytes of an MCAP's MessageIndex records (the chunk indexes' ``message_index_length``):
    16 bytes per message (log time, offset), never compressed. ``@mcap/core``'s indexed reader
    (Foxglove's) refuses a chunk of messages without them, so they are the archive's floor."""
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None, f"{path}: no summary"
    return sum(c.message_index_length for c in summary.chunk_indexes)


def compare_outputs(naive: Path, ours: Path) -> list[str]:
    """Topics the naive converter wrote whose message counts (frames, on the raw-frame topics)
    differ in tankviz's MCAP (tankviz's
    extra topics - perception, health, /tf, /ego - are not compared; a scene category may
    differ by one tick at the end of the log)."""
    a, b = topic_counts(naive), topic_counts(ours)
    problems = []
    for topic in sorted(a):
        slack = 1 if topic.startswith("/scene/") else 0
        if abs(a[topic] - b.get(topic, 0)) > slack:
            problems.append(f"{topic}: naive {a[topic]}, tankviz {b.get(topic, 0)}")
    return problems



# --------------------------------------------------------------------------------------------
# The measurements


def _warm(path: Path) -> None:
    """Read the file once so every contender starts from the page cache."""
    with path.open("rb") as f:
        while f.read(1 << 22):
            pass


@dataclass
class Contender:
    """One way to read or convert a log, run ``runs`` times interleaved with the others."""

    key: str
    label: str
    go: Callable[[], Run]
    runs: list[Run] = field(default_factory=list)
    log: str = ""  # which log, for the progress lines

    @property
    def best(self) -> Run:
        return min(self.runs, key=lambda r: r.seconds)

    def best_rate(self, clock: str) -> float:
        """Frames per second of the best run on ``clock`` ("cpu" or "wall")."""
        return max(r.frames / (r.cpu if clock == "cpu" else r.wall) for r in self.runs)


def run_interleaved(contenders: list[Contender], runs: int, loads: list[float]) -> None:
    """:func:`benchlib.interleaved`: every contender once per round, ``runs`` rounds; the load
    average after each run goes to ``loads``."""
    by_name = {f"{c.log} {c.key}": c for c in contenders}

    def done(name: str, k: int, run: Run) -> None:
        loads.append(os.getloadavg()[0])
        c = by_name[name]
        print(f"  round {k + 1} of {runs}: {c.label} ({c.log}) {run.seconds:.2f} s",
              file=sys.stderr, flush=True)

    results = interleaved({name: c.go for name, c in by_name.items()}, runs, done=done)
    for name, c in by_name.items():
        c.runs = results[name]


def _best_of(runs: int, command: list[str]) -> float:
    """The best time on :data:`CLOCK` of ``runs`` runs of ``command``."""
    return min(timed_process(command).seconds for _ in range(runs))


@dataclass
class Row:
    """One line of issue #15's table: the measure, the figure now, the goal, met or not."""

    measure: str
    now: str
    goal: str
    ok: bool | None = None
    value: float | None = None


def _ratio_row(rows: list[Row], measure: str, value: float, goal: float, *,
               at_most: bool = False, unit: str = "x", aside: str = "") -> None:
    ok = value <= goal if at_most else value >= goal
    rows.append(Row(measure, f"{value:.2f}{unit}{aside}",
                    f"{'≤' if at_most else '≥'} {goal:g}{unit}", ok, value))


def _speed_row(rows: list[Row], measure: str, ours: Contender, reference: Contender,
               goal: float) -> None:
    """tankviz's speed over the reference's on :data:`CLOCK`, the other clock's aside."""
    other = "cpu" if CLOCK == "wall" else "wall"
    aside = ours.best_rate(other) / reference.best_rate(other)
    _ratio_row(rows, measure, ours.best_rate(CLOCK) / reference.best_rate(CLOCK), goal,
               aside=f" ({aside:.2f}x {other})")


@dataclass
class Bench:
    """One run's settings and what it has measured so far."""

    args: argparse.Namespace
    out: Path
    loads: list[float] = field(default_factory=list)
    details: list[str] = field(default_factory=list)

    def say(self, line: str) -> None:
        """A detail: printed after the table (and to stderr now, as progress)."""
        self.details.append(line)
        if line:
            print(line, file=sys.stderr, flush=True)


@dataclass
class Simulated:
    """The simulated drive's logs and its contenders, by (format, key)."""

    blf: Path
    meta: dict[str, Any]
    contenders: dict[tuple[str, str], Contender]


def compile_bridge() -> None:
    """tankviz as pip installs it: its bytecode compiled (a source tree under
    ``PYTHONDONTWRITEBYTECODE`` would compile it again in every run, about 0.2 s)."""
    import bridge

    compileall.compile_dir(str(Path(bridge.__file__).parent), quiet=1)


def simulated_contenders(log: Path, fmt: str, frames: int, out: Path) -> list[Contender]:
    """The five contenders on one log of the simulated drive."""
    return [Contender(key, label, go, log=fmt) for key, label, go in (
        ("bare", "bare can.LogReader iteration", lambda: bare_read(log)),
        ("naive", "naive raw + decoded", lambda: naive_convert(log, out / f"naive-{fmt}.mcap")),
        ("naive_scene", "naive with scene", lambda: naive_convert(
            log, out / f"naive-scene-{fmt}.mcap", scene=True)),
        ("tankviz", "tankviz raw + decoded", lambda: tankviz_convert(
            log, out / f"tankviz-{fmt}.mcap", frames)),
        ("tankviz_scene", "tankviz with scene", lambda: tankviz_convert(
            log, out / f"tankviz-scene-{fmt}.mcap", frames, profile="ecocar")),
    )]


def measure_simulated(bench: Bench) -> Simulated:
    """The simulated drive, BLF and ASC: five contenders each, interleaved, best of --runs;
    the naive and tankviz outputs must hold as many messages on every naive topic."""
    blf, meta = ecocar_log(bench.args.workdir, bench.args.frames, bench.args.seed)
    asc = log_copy(blf, ".asc")
    bench.say(f"simulated drive {blf.name}: {meta['frames']:,} frames, "
              f"{meta['seconds_of_driving']:.0f} s of driving, BLF {blf.stat().st_size / MB:.1f} "
              f"MB, ASC {asc.stat().st_size / MB:.1f} MB; per bus {meta['frames_per_bus']}; "
              f"payload = previous one of its id {meta['repeat_previous_payload_of_id']:.1%}, one "
              f"of the last 16 {meta['repeat_one_of_last_16_payloads_of_id']:.1%}")
    contenders: dict[tuple[str, str], Contender] = {}
    for fmt, log in (("BLF", blf), ("ASC", asc)):
        _warm(log)
        for c in simulated_contenders(log, fmt, meta["frames"], bench.out):
            contenders[fmt, c.key] = c
    run_interleaved(list(contenders.values()), bench.args.runs, bench.loads)
    for fmt in ("BLF", "ASC"):
        for naive, ours in (("naive", "tankviz"), ("naive-scene", "tankviz-scene")):
            check_outputs(bench, f"{naive}-{fmt}", f"{ours}-{fmt}", f"{naive} and {ours} ({fmt})")
    return Simulated(blf, meta, contenders)


def check_outputs(bench: Bench, naive: str, ours: str, what: str) -> None:
    """Say whether the outputs ``naive`` and ``ours`` hold as many messages per naive topic."""
    problems = compare_outputs(bench.out / f"{naive}.mcap", bench.out / f"{ours}.mcap")
    if problems:
        bench.say(f"WARNING: {what} wrote different message counts: " + "; ".join(problems[:10]))
    elif naive.endswith(("BLF", "ASC")):
        bench.say(f"{what} wrote the same messages per topic of the naive converter")


def measure_sizes(bench: Bench, sim: Simulated) -> tuple[dict[str, int], dict[str, int]]:
    """Each archive's bytes (raw only: one more run) and of its message indexes, by kind."""
    out = bench.out
    raw_only = tankviz_convert(sim.blf, out / "tankviz-raw-BLF.mcap", sim.meta["frames"],
                               dbc=None)
    sizes = {"raw only": (out / "tankviz-raw-BLF.mcap").stat().st_size,
             "raw + decoded": (out / "tankviz-BLF.mcap").stat().st_size,
             "with scene": (out / "tankviz-scene-BLF.mcap").stat().st_size,
             "naive raw + decoded": (out / "naive-BLF.mcap").stat().st_size,
             "naive with scene": (out / "naive-scene-BLF.mcap").stat().st_size}
    indexes = {k: index_bytes(out / f"tankviz{tag}-BLF.mcap") for k, tag in
               (("raw only", "-raw"), ("raw + decoded", ""), ("with scene", "-scene"))}
    bench.say(f"tankviz raw only (one run, BLF): {raw_only.seconds:.2f} s {CLOCK}")
    return sizes, indexes


def measure_real(bench: Bench) -> dict[str, Any] | None:
    """The public real-format log, raw + decoded: bare, naive and tankviz, interleaved (None
    without the public DBCs)."""
    args, out = bench.args, bench.out
    try:
        rlog, rdbc, rmeta = real_log(args.workdir, args.real_frames, args.seed, args.real_dbc)
    except FileNotFoundError as e:
        bench.say(f"real-format log skipped: {e}")
        return None
    _warm(rlog)
    bench.say(f"real-format log {rlog.name} (candump, {rmeta['dbc']}): {rmeta['frames']:,} "
              f"frames, {rmeta['ids']} ids, {rmeta['share_of_frames_in_dbc']:.1%} of frames in "
              f"the DBC, {rmeta['seconds_of_driving']:.0f} s, payload = previous one of its id "
              f"{rmeta['repeat_previous_payload_of_id']:.1%}")
    rc = [Contender("bare", "bare can.LogReader iteration", lambda: bare_read(rlog)),
          Contender("naive", "naive raw + decoded", lambda: naive_convert(
              rlog, out / "naive-real.mcap", rdbc)),
          Contender("tankviz", "tankviz raw + decoded", lambda: tankviz_convert(
              rlog, out / "tankviz-real.mcap", rmeta["frames"], dbc=rdbc))]
    for c in rc:
        c.log = "candump"
    run_interleaved(rc, args.runs, bench.loads)
    check_outputs(bench, "naive-real", "tankviz-real", "naive and tankviz (real log)")
    return {c.key: c for c in rc} | {"meta": rmeta}


def measure_startup(bench: Bench) -> dict[str, float]:
    """Best of --runs: the interpreter, importing convert, ``tankviz --help`` and a 1 s log
    converted with the scene, by name; ``import share``: importing's share of that convert."""
    runs = bench.args.runs
    one_s, _ = ecocar_log(bench.args.workdir, ONE_SECOND_FRAMES, bench.args.seed)
    times = {
        "interpreter": _best_of(runs, [sys.executable, "-c", "pass"]),
        "imports": _best_of(runs, [sys.executable, "-c", "import bridge.cli, bridge.apps.convert"]),
        "help": _best_of(runs, [sys.executable, "-m", "bridge", "--help"]),
        "short": _best_of(runs, tankviz_command(one_s, bench.out / "one-second.mcap",
                                                profile="ecocar")),
    }
    times["import share"] = max(0.0, times["imports"] - times["interpreter"]) / times["short"]
    return times


def measure_memory(bench: Bench) -> tuple[Path, dict[str, Any], Run]:
    """The longer drive with the scene, one run: its log, statistics and run."""
    long_blf, long_meta = ecocar_log(bench.args.workdir, bench.args.frames2, bench.args.seed)
    _warm(long_blf)
    return long_blf, long_meta, tankviz_convert(
        long_blf, bench.out / "tankviz-scene-long.mcap", long_meta["frames"], profile="ecocar")


def table(args: argparse.Namespace, sim: Simulated, real: dict[str, Any] | None,
          sizes: dict[str, int], startup: dict[str, float], long_meta: dict[str, Any],
          long_run: Run) -> list[Row]:
    """The rows of issue #15's table."""
    rows: list[Row] = []
    contender = sim.contenders
    for fmt in ("BLF", "ASC"):
        _speed_row(rows, f"convert with the scene, tankviz / naive ({fmt}, simulated)",
                   contender[fmt, "tankviz_scene"], contender[fmt, "naive_scene"], 3.0)
    for fmt in ("BLF", "ASC"):
        _speed_row(rows, f"convert raw + decoded, tankviz / naive ({fmt}, simulated)",
                   contender[fmt, "tankviz"], contender[fmt, "naive"], 3.0)
    if real is not None:
        _speed_row(rows, "convert raw + decoded, tankviz / naive (candump, real-format log)",
                   real["tankviz"], real["naive"], 3.0)
    else:
        rows.append(Row("convert raw + decoded, tankviz / naive (candump, real-format log)",
                        "skipped (no ../shared/data/dbc)", "≥ 3x"))
    for fmt in ("BLF", "ASC"):
        _speed_row(rows, f"convert raw + decoded, tankviz / bare LogReader ({fmt})",
                   contender[fmt, "tankviz"], contender[fmt, "bare"], 0.5)
    # issue #26's goals (raw frames archived in blocks); raw + decoded keeps #15's
    blf_bytes = sim.blf.stat().st_size
    for label, goal in (("raw only", 1.0), ("raw + decoded", 3.0), ("with scene", 4.0)):
        _ratio_row(rows, f"archive size / BLF size, {label}", sizes[label] / blf_bytes, goal,
                   at_most=True)
    _ratio_row(rows, "share of a 1 s log's convert (with scene) spent importing",
               startup["import share"], 0.1, at_most=True, unit="")
    short_rss = max(r.rss_mb or 0.0 for r in contender["BLF", "tankviz_scene"].runs)
    long_rss = long_run.rss_mb or 0.0
    growth = long_rss - short_rss
    rows.append(Row(f"peak RSS, with scene: {args.frames:,} → {args.frames2:,} frames",
                    f"{short_rss:.0f} → {long_rss:.0f} MB ({growth:+.0f} MB)",
                    "flat (≤ +5 %)", growth <= max(2.0, 0.05 * short_rss), growth))
    per_hour = long_run.seconds / long_meta["seconds_of_driving"] * 3600
    rows.append(Row(f"1 hour of the 3-bus drive with the scene, one convert ({CLOCK} time, "
                    "extrapolated)",
                    f"{per_hour / 60:.1f} min", "≤ 2 min", per_hour <= 120, per_hour))
    return rows


def say_runs(bench: Bench, sim: Simulated, real: dict[str, Any] | None) -> None:
    """The details of every contender's best run."""
    bench.say("")
    bench.say(f"{'best of ' + str(bench.args.runs) + ', interleaved (' + CLOCK + ')':<44}"
              f"{'frames':>11}{'CPU s':>9}{'wall s':>9}{'frames/s':>11}{'peak RSS':>10}")
    groups: list[tuple[str, list[Contender]]] = [
        (f"simulated {fmt}", [sim.contenders[fmt, k] for k in
                              ("bare", "naive", "naive_scene", "tankviz", "tankviz_scene")])
        for fmt in ("BLF", "ASC")]
    if real is not None:
        groups.append(("real-format candump", [real["bare"], real["naive"], real["tankviz"]]))
    for title, cs in groups:
        bench.say(title)
        for c in cs:
            r = c.best
            rss = f"{r.rss_mb:,.0f} MB" if r.rss_mb is not None else ""
            bench.say(f"  {c.label:<42}{r.frames:>11,}{r.cpu:>9.2f}{r.wall:>9.2f}"
                      f"{r.rate:>11,.0f}{rss:>10}")


def say_rest(bench: Bench, sim: Simulated, sizes: dict[str, int], indexes: dict[str, int],
             startup: dict[str, float], long_blf: Path, long_meta: dict[str, Any],
             long_run: Run) -> None:
    """The details of sizes, start-up, the longer drive and the load average."""
    blf_bytes = sim.blf.stat().st_size
    bench.say(f"archive sizes (simulated drive, {sim.meta['seconds_of_driving']:.0f} s; BLF "
              f"{blf_bytes / MB:.2f} MB): " + ", ".join(
                  f"{k} {v / MB:.2f} MB ({v / blf_bytes:.2f}x)" for k, v in sizes.items()))
    bench.say("  of which message indexes (16 bytes per message, uncompressed; Foxglove's reader "
              "needs them): " + ", ".join(f"{k} {v / MB:.2f} MB ({v / blf_bytes:.2f}x the BLF)"
                                         for k, v in indexes.items()))
    interpreter, short = startup["interpreter"], startup["short"]
    bench.say(f"start-up, best of {bench.args.runs}, {CLOCK} time: python -c pass "
              f"{interpreter:.2f} s; import bridge.cli + convert {startup['imports']:.2f} s; "
              f"tankviz --help {startup['help']:.2f} s; 1 s log ({ONE_SECOND_FRAMES:,} frames) "
              f"converted with the scene {short:.2f} s, of which importing "
              f"{startup['import share']:.0%} and the interpreter {interpreter / short:.0%}")
    bench.say(f"longer drive {long_blf.name}: {long_meta['frames']:,} frames, "
              f"{long_meta['seconds_of_driving']:.0f} s of driving, with scene "
              f"{long_run.seconds:.2f} s {CLOCK} (peak RSS {long_run.rss_mb or 0.0:.0f} MB)")
    cores = os.cpu_count() or 1
    loads = bench.loads
    bench.say(f"1-min load average during the runs: {min(loads):.2f}..{max(loads):.2f} ({cores} "
              "cores; this benchmark adds about 1)")
    if max(loads) > cores:
        bench.say("NOTE: other processes competed for the CPU during the run: the figures are "
                  "noisy (the ratios less so: every reference ran interleaved with tankviz)")


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every measurement of one run; returns the table rows and the details (for --json)."""
    bench = Bench(args, args.workdir / "out")
    bench.out.mkdir(exist_ok=True)
    compile_bridge()
    sim = measure_simulated(bench)
    sizes, indexes = measure_sizes(bench, sim)
    real = measure_real(bench)
    startup = measure_startup(bench)
    long_blf, long_meta, long_run = measure_memory(bench)
    rows = table(args, sim, real, sizes, startup, long_meta, long_run)
    say_runs(bench, sim, real)
    say_rest(bench, sim, sizes, indexes, startup, long_blf, long_meta, long_run)
    return {"rows": [vars(r) for r in rows], "details": bench.details, "clock": CLOCK,
            "load": [min(bench.loads), max(bench.loads)], "runs": args.runs,
            "frames": [args.frames, args.frames2, args.real_frames]}


#: About one second of the simulated drive (about 2,300 frames/s on its three buses).
ONE_SECOND_FRAMES = 2_300


def print_table(rows: list[dict[str, Any]]) -> None:
    """The ratios of issue #15's table, measure | now | goal | ok."""
    width = max(len(r["measure"]) for r in rows)
    now_w = max(len(r["now"]) for r in rows)
    print(f"{'measure (same run, ratios)':<{width}}  {'now':<{now_w}}  goal")
    for r in rows:
        ok = "" if r["ok"] is None else "  ok" if r["ok"] else "  MISSED"
        print(f"{r['measure']:<{width}}  {r['now']:<{now_w}}  {r['goal']}{ok}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--frames", type=int, default=1_440_000,
                        help="frames of the simulated drive (1,440,000: about 600 s)")
    parser.add_argument("--frames2", type=int, default=2_880_000,
                        help="frames of the longer drive, for memory (2,880,000)")
    parser.add_argument("--real-frames", type=int, default=135_000,
                        help="frames of the real-format candump log (135,000)")
    parser.add_argument("--real-dbc", type=Path, metavar="DBC",
                        help=f"the public DBC of the real-format log ({REAL_DBC} in "
                        "../shared/data/dbc)")
    parser.add_argument("--runs", type=int, default=3, help="interleaved rounds, best of (3)")
    parser.add_argument("--quick", action="store_true",
                        help="200k / 400k simulated and 50k real frames, to iterate")
    parser.add_argument("--seed", type=int, default=1)
    add_workdir(parser, "where logs are cached and outputs written")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="wall",
                        help="compare elapsed time (default: what a user waits) or CPU time "
                        "(steadier on a shared machine; counts the second core's work)")
    parser.add_argument("--json", type=Path, metavar="FILE",
                        help="also write the table and the details as JSON (for bench_report)")
    args = parser.parse_args(argv)
    global CLOCK
    CLOCK = args.clock
    if args.quick:
        args.frames, args.frames2, args.real_frames = 200_000, 400_000, 50_000
    args.workdir.mkdir(parents=True, exist_ok=True)
    print(f"tankviz convert benchmark: {args.frames:,} / {args.frames2:,} simulated frames, "
          f"{args.real_frames:,} real-format frames, best of {args.runs} interleaved runs, "
          f"{CLOCK} time (progress on stderr; the table first, then the details)", flush=True)
    result = measure(args)
    print()
    print_table(result["rows"])
    missed = [r for r in result["rows"] if r["ok"] is False]
    for r in missed:
        print(f"TARGET MISSED: {r['measure']}: {r['now']} (goal {r['goal']})")
    print("\n".join(result["details"]))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
