"""``tankviz live`` measured the way a car runs it: the car's frames from another process.

The car is another process (``tools/car_sender.py``: the simulated ecocar drive at ``--rate``
frames/s over three udp_multicast groups, ``radar``, ``camera`` and ``chassis``, each frame
stamped with the wall clock when sent); ``tankviz live --profile ecocar`` runs as a command of
its own, recording into a temporary folder, and one viewer (another process: bench_live's
``--client`` with one reading client, and one stalled client subscribed to the scene) watches.

Per run it prints: the CPU of each process of the bridge (``/proc/<pid>/stat``, utime + stime,
over the sending window, % of one core, and µs per frame sent: what a loaded machine, which
slows the car and stretches the window, disturbs less), the rate the car achieved, frame →
scene latency p50/p99 at the reading viewer (a frame stamped t is in the scene of the first
tick after t; the receipt of that tick's last ``/scene/*`` message minus t; the first 0.5 s are
left out), and the frames recorded in the drive's MCAP against those sent. Goal (issue #36
item 6): at 12k frames/s no process above 35 % of one core, p99 < 50 ms, every frame recorded.
Each rate runs live once per ``--readers`` (``process``: the buses read in a process of their
own, live's default; ``here``: in the pipeline's, ``TANKVIZ_LIVE_READER=here``), then the fixed
reference on the same traffic: python-can alone receiving the three groups, a thread per bus
blocking in ``recv`` (:func:`bare_receive`), as a program that only takes the frames in would.
Its CPU per frame measures the machine; live's ratio to it compares runs on other days or
computers.

    python tools/bench_live_car.py [--rates 12000,6000] [--seconds 20] [--readers process,here]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

TOOLS = Path(__file__).resolve().parent
ROOT = TOOLS.parent
PERIOD_NS = 20_000_000  # the scene period at 50 Hz
WARMUP_NS = 500_000_000
CPU_GOAL = 35.0
P99_GOAL_MS = 50.0


def family(pid: int) -> list[int]:
    """The process and its children (and theirs)."""
    out = [pid]
    for p in out:
        for task in Path(f"/proc/{p}/task").glob("*"):
            with contextlib.suppress(OSError):
                out += [int(c) for c in (task / "children").read_text().split()]
    return out


def groups_for(run: int) -> dict[str, str]:
    base = (os.getpid() + 17 * run) % 250
    return {bus: f"239.91.{base}.{i + 1}" for i, bus in enumerate(("radar", "camera",
                                                                    "chassis"))}


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def bare_receive(groups: list[str]) -> None:
    """The reference (a process of its own): python-can receives each group in a thread,
    ``recv`` blocking, until standard input says stop; prints the frames received. Each socket
    gets its own group only, as live's (else Linux gives each every group joined)."""
    import threading

    import can

    from bridge.io.buses import own_group_only

    buses = [can.Bus(interface="udp_multicast", channel=g, receive_own_messages=False)
             for g in groups]
    for bus in buses:
        own_group_only(bus)
    stop = threading.Event()
    counts = [0] * len(buses)

    def receive(i: int, bus: can.BusABC) -> None:
        while not stop.is_set():
            if bus.recv(0.2) is not None:
                counts[i] += 1

    threads = [threading.Thread(target=receive, args=(i, b)) for i, b in enumerate(buses)]
    for thread in threads:
        thread.start()
    print("READY", flush=True)
    sys.stdin.readline()
    stop.set()
    for thread in threads:
        thread.join()
    for bus in buses:
        bus.shutdown()
    print(sum(counts), flush=True)


def car_process(rate: float, seconds: float, groups: dict[str, str],
                env: dict[str, str]) -> subprocess.Popen[str]:
    """The car, ready to send at ``go``."""
    car = subprocess.Popen(
        [sys.executable, str(TOOLS / "car_sender.py"), "--rate", str(rate), "--seconds",
         str(seconds), *[a for bus, g in groups.items() for a in ("--group", f"{bus}={g}")]],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
    assert car.stdout is not None
    car.stdout.readline()  # READY
    return car


def drive_car(car: subprocess.Popen[str], pids: Callable[[], list[int]]
              ) -> tuple[dict[str, Any], float, dict[int, float]]:
    """The car sends its drive: its figures, the wall seconds from its start to a second after
    its end (for the last scene and frames), and the CPU seconds each of ``pids()`` (asked
    before and after: a process may start meanwhile) used in them."""
    from bench_live import child_cpu

    assert car.stdout is not None and car.stdin is not None
    before = {pid: child_cpu(pid) for pid in pids()}
    began = time.monotonic()
    car.stdin.write("go\n")
    car.stdin.flush()
    sender = json.loads(car.stdout.readline())
    time.sleep(1.0)
    wall = time.monotonic() - began
    used = {pid: child_cpu(pid) - before.get(pid, 0.0) for pid in pids()}
    car.wait()
    return sender, wall, used


def run_reference(rate: float, seconds: float, run: int) -> dict[str, Any]:
    """The reference (:func:`bare_receive`) with the car at ``rate``."""
    groups = groups_for(run)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    receiver = subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve()), "--bare-receive", *groups.values()],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
    assert receiver.stdout is not None and receiver.stdin is not None
    receiver.stdout.readline()  # READY
    car = car_process(rate, seconds, groups, env)
    sender, wall, used = drive_car(car, lambda: [receiver.pid])
    receiver.stdin.write("stop\n")
    receiver.stdin.flush()
    received = int(receiver.communicate(timeout=60)[0].split()[-1])
    frames = sum(sender["sent"].values())
    return {"pct": 100 * used[receiver.pid] / wall,
            "us_per_frame": 1e6 * used[receiver.pid] / frames,
            "received": received, "sent": frames}


def run_once(rate: float, seconds: float, run: int, reader: str) -> dict[str, Any]:
    """One run of live with the car at ``rate``, its buses read ``reader``."""
    from bench_live import scene_receipts, summary_frame_counts

    from bridge.io.drives import ArchiveSource

    groups = groups_for(run)
    with tempfile.TemporaryDirectory(prefix="tankviz-car-") as tmp:
        drives = Path(tmp) / "drives"
        env = {**os.environ, "PYTHONPATH": str(ROOT), "TANKVIZ_LIVE_READER": reader}
        live = subprocess.Popen(
            [sys.executable, "-m", "bridge", "live", "--profile", "ecocar", "--port", "0",
             "--min-free", "0", "--drives", str(drives),
             *[a for bus, g in groups.items() for a in ("--bus", f"{bus}=udp_multicast:{g}")]],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp)
        assert live.stdout is not None
        url, seen = "", []
        for line in live.stdout:
            seen.append(line)
            if "open connection" in line:
                url = line.split("open connection ")[1].split()[0]
            if line.startswith("Ctrl+C stops"):
                break
        if not url:
            raise SystemExit("live did not start:\n" + "".join(seen))
        out_path = Path(tmp) / "clients.json"
        clients = subprocess.Popen(
            [sys.executable, str(TOOLS / "bench_live.py"), "--client", url, str(out_path),
             "--readers", "1", "--stalled-topics", "scene"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        assert clients.stdout is not None and clients.stdin is not None
        clients.stdout.readline()  # READY
        car = car_process(rate, seconds, groups, env)
        sender, wall, used = drive_car(car, lambda: family(live.pid))
        clients.stdin.write("stop\n")
        clients.stdin.flush()
        clients.wait(60)
        live.send_signal(signal.SIGTERM)
        rest = live.communicate(timeout=120)[0]
        files = sorted(drives.glob("*.mcap"))
        recorded = summary_frame_counts(files)
        receipts = scene_receipts(json.loads(out_path.read_text())["clients"][0])
        latencies: list[float] = []
        unseen = 0
        first: int | None = None
        for path in files:
            for frame in ArchiveSource(path):
                t = frame.timestamp_ns
                first = t if first is None else first
                if t - first < WARMUP_NS:
                    continue
                got = receipts.get((t // PERIOD_NS + 1) * PERIOD_NS)
                if got is None:
                    unseen += 1
                else:
                    latencies.append((got[0] - t) / 1e6)
    names = {pid: ("live" if pid == live.pid else "reader") for pid in used if used[pid] > 0.05}
    cpu = {f"{names[pid]} {pid}": 100 * used[pid] / wall for pid in names}
    frames = sum(sender["sent"].values())
    per_frame = {f"{names[pid]} {pid}": 1e6 * used[pid] / frames for pid in names}
    return {"rate": rate, "reader": reader, "cpu": cpu, "sent": sender["sent"],
            "us_per_frame": per_frame, "achieved": frames / sender["seconds"],
            "recorded": recorded, "p50_ms": percentile(latencies, 0.5),
            "p99_ms": percentile(latencies, 0.99), "unseen": unseen,
            "sender_late_ms": 1e3 * sender["late_max_s"], "exit": live.returncode,
            "tail": rest.strip().splitlines()[-3:]}


def report(result: dict[str, Any], reference: dict[str, Any]) -> list[str]:
    cpu = result["cpu"]
    top = max(cpu.values())
    sent, recorded = sum(result["sent"].values()), sum(result["recorded"].values())
    misses = []
    if result["rate"] >= 12_000:
        misses += [f"a process at {top:.0f} % > {CPU_GOAL:g} %"] if top > CPU_GOAL else []
        misses += [f"p99 {result['p99_ms']:.0f} ms"] if result["p99_ms"] >= P99_GOAL_MS else []
    misses += [f"{sent - recorded} frames not recorded"] if recorded != sent else []
    return [
        f"{result['rate']:>6.0f} frames/s  read {result['reader']:<7}  "
        + "  ".join(f"{name} {pct:4.1f}% ({result['us_per_frame'][name]:.1f} µs/frame)"
                    for name, pct in sorted(cpu.items()))
        + f"  sent {result['achieved']:.0f}/s"
        + f"  p50 {result['p50_ms']:.1f} ms  p99 {result['p99_ms']:.1f} ms  "
        f"recorded {recorded}/{sent}  (car late ≤ {result['sender_late_ms']:.0f} ms, "
        f"exit {result['exit']})  " + ("GOAL MISSED: " + "; ".join(misses) if misses else "ok"),
        f"{'':>16}busiest process / reference {top / reference['pct']:.2f}x, all of live "
        f"{sum(cpu.values()) / reference['pct']:.2f}x"]


def reference_line(rate: float, reference: dict[str, Any]) -> str:
    return (f"{rate:>6.0f} frames/s  reference: python-can alone receives the same traffic  "
            f"{reference['pct']:4.1f}% ({reference['us_per_frame']:.1f} µs/frame)  "
            f"received {reference['received']}/{reference['sent']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rates", default="12000,6000", help="frames/s of the car, all buses")
    parser.add_argument("--seconds", type=float, default=20.0, help="the car's drive, per run")
    parser.add_argument("--readers", default="process",
                        help="where live reads its buses, per run: process, here or both")
    parser.add_argument("--bare-receive", nargs="+", metavar="GROUP", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.bare_receive:
        bare_receive(args.bare_receive)
        return 0
    sys.path.insert(0, str(TOOLS))
    sys.path.insert(0, str(ROOT))
    print(f"tankviz live, car in another process (udp_multicast), {args.seconds:g} s per run; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    run = 0
    for rate in (float(r) for r in args.rates.split(",")):
        results = []
        for reader in args.readers.split(","):
            run += 1
            results.append(run_once(rate, args.seconds, run, reader))
        run += 1
        reference = run_reference(rate, args.seconds, run)
        print(reference_line(rate, reference), flush=True)
        for result in results:
            for line in report(result, reference):
                print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
