"""End to end in a real browser: the real Foxglove Studio web app (the prebuilt bundle of the npm
package @foxglove/studio-base, mounted by tests/browser/host) in headless Chromium renders what
tankviz serves live (`tankviz demo`, `tankviz replay`) and what it records (`tankviz simulate`,
opened as a remote file), with the bundled layouts applied through the app's own "Import
layout" button (or preloaded into its layout storage); the checks read the screenshots' pixels
(ego box, lanes, detections, tracks, lead box, a detection showing inside the track at its
place), the text labels (OCR with tesseract), the
panels' text (plot legends, Raw Messages, Log) and the Indicator panels of the sensor health
alarms (their label, and their colour read from the pixels).

Needs node + npm (the packages in tests/browser/package-lock.json are installed with `npm ci` when
missing), Debian's chromium and tesseract-ocr. Without them the tests skip with the reason,
except under CI (CI=true), where they fail: CI installs them.

TANKVIZ_UPDATE_PREVIEWS=1 also writes the screenshots as the layouts' preview pictures
(layouts/<name>.png). TANKVIZ_E2E_OUT=DIR keeps every screenshot and the driver's result there.

Time: every wait is for a condition (the app started, the layout imported, its panels shown,
everything expected on screen; a tankviz command serving), so a fast machine spends no time
waiting; each has a generous budget (WAIT_S), scaled by TANKVIZ_TEST_TIMEOUT_SCALE on a very slow
or loaded machine. The driver says what it is waiting for, and what is still missing, as it goes;
a run with no sign of life for a whole budget is stopped and reported with what it was doing.
The live sources (`tankviz demo`, `tankviz replay`) are started for each live shot when the
browser is ready for it, so their timelines (the demo's first fault, the replay's dropout) run
from the shot's start, however long the shots before it took.
"""

from __future__ import annotations

import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, NoReturn

import pytest
from conftest import summary_counts, timeout_scale

from bridge.sim.scenario import DEFAULT_START_NS, TIMELINE

pytestmark = [pytest.mark.browser, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
BROWSER = ROOT / "tests" / "browser"
LAYOUTS = ROOT / "layouts"
#: Long enough for the radar dropout (5 % of the drive: 2.5 s) to raise radar.silent (1 s after
#: the radar is found silent) and to show it on a /health message (1 Hz) while it lasts.
DRIVE_S = 50.0
#: `tankviz demo`'s scenario length: its first fault (the lane dropout, at 40 %: lanes.lost after
#: 49 s) comes well after the live shots, which need a demo without any alarm, while the lead
#: brakes (12-42 s) and the traffic is close.
DEMO_SCENARIO_S = 120.0
CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome")
#: Colours of the Tank Viz view that must be on screen live (pixels.mjs verdict keys).
LIVE_VIEW = ["ego", "greenLanes", "radar", "camera", "tracks", "lead"]
#: What must be read in the Tank Viz labels: the lead's title and the seed's track label format
#: "TrackID: n / x: … / y: …". OCR may misread a letter or add a stray mark beside a colon
#: ("TrackID;: 33", "TrackIB: 35"), read the colon after a lone x as an i ("xi 25.19": a CI run
#: read every x so), and a label that another one overlaps is not readable at all: the driver
#: reads screenshot after screenshot until every pattern was matched once.
LABEL_PATTERNS = [r"Lead\s*Vehicle", r"TrackI[D0OB][:;.,]{0,2}\s*\d+", r"x[:;i]\s*-?\d+[.,]\d\d"]
#: The highway car (`tankviz simulate --car highway`, profile highway: a 16-slot radar with twins,
#: no lane camera) 15 s into its drive: objects from 10 to 190 m, twins on most of them.
HIGHWAY_S = 15.0
#: The windows a user's screen may have: a laptop's and a large one (width, height px).
WINDOWS = [(1280, 800), (1920, 1080)]
#: The time budgets' factor (TANKVIZ_TEST_TIMEOUT_SCALE, default 1).
SCALE = timeout_scale()
#: The budget of each wait for a condition, in the driver (the app started, the layout imported,
#: the panels shown, everything expected on screen) and here (a tankviz command serving). On an
#: idle machine the longest of them takes about 25 s.
WAIT_S = 120.0 * SCALE
#: How often the driver logs what it is still waiting for.
REPORT_S = 15.0


def unavailable(reason: str) -> NoReturn:
    """Skip, except under CI, which installs everything the test needs: fail there."""
    if os.environ.get("CI"):
        pytest.fail(f"browser test prerequisites missing under CI: {reason}")
    pytest.skip(reason)


def chromium() -> str | None:
    wanted = os.environ.get("TANKVIZ_CHROMIUM")
    if wanted:
        return wanted if Path(wanted).exists() else None
    return next((c for c in CHROMIUM_CANDIDATES if Path(c).exists()), None)


def ensure_node_modules() -> None:
    """`npm ci` in tests/browser when the packages are missing (exact versions, lock file)."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        unavailable("node and npm are not installed (Node >= 20 with npm)")
    marker = BROWSER / "node_modules" / "@foxglove" / "studio-base" / "assets" / "index.js"
    needed = ["playwright-core", "react", "react-dom", "@foxglove/ws-protocol", "@mcap/core"]
    if marker.exists() and all((BROWSER / "node_modules" / n).exists() for n in needed):
        return
    run = subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=BROWSER,
                         capture_output=True, text=True, timeout=900 * SCALE, check=False)
    if run.returncode != 0 or not marker.exists():
        unavailable(f"npm ci in {BROWSER} failed: {(run.stderr or run.stdout)[-800:]}")


def browser_session(tmp_path_factory: pytest.TempPathFactory, name: str) -> tuple[str, Path]:
    """What a browser session needs: Chromium's path and the node packages (else skipped, or
    failed under CI), and the folder for its files: ``TANKVIZ_E2E_OUT/name`` if set (to look at
    the screenshots), else a temporary one."""
    browser = chromium()
    if browser is None:
        unavailable("chromium is not installed (apt-get install chromium)")
    ensure_node_modules()
    kept = os.environ.get("TANKVIZ_E2E_OUT")
    out = Path(kept) / name if kept else tmp_path_factory.mktemp(f"e2e-{name}")
    out.mkdir(parents=True, exist_ok=True)
    return browser, out


@dataclass
class Tankviz:
    """A tankviz command serving Foxglove: its process, WebSocket URL and output (read all along,
    so that a chatty command never blocks on a full pipe)."""

    args: tuple[str, ...]
    process: subprocess.Popen[str]
    url: str = ""
    started: float = field(default_factory=time.monotonic)
    output: list[str] = field(default_factory=list)


def start_tankviz(*args: str) -> Tankviz:
    """Run a tankviz command that serves Foxglove; returns once it printed its WebSocket URL."""
    process = subprocess.Popen([sys.executable, "-m", "bridge", *args], cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    served = Tankviz(args, process)
    found: queue.SimpleQueue[str | None] = queue.SimpleQueue()

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            served.output.append(line)
            if not served.url and (match := re.search(r"ws://[^\s:]+:(\d+)", line)):
                served.url = f"ws://127.0.0.1:{match[1]}"
                found.put(served.url)
        found.put(None)

    threading.Thread(target=read, daemon=True).start()
    try:
        url, waited_out = found.get(timeout=WAIT_S), False
    except queue.Empty:
        url, waited_out = None, True
    if url is None:
        stop(served)
        state = (f"printed no ws:// URL within {WAIT_S:g} s" if waited_out
                 else f"exited with status {process.returncode} before printing a ws:// URL")
        raise AssertionError(f"tankviz {' '.join(args)} {state}:\n{''.join(served.output)}")
    served.started = time.monotonic()
    return served


def stop(served: Tankviz) -> None:
    served.process.terminate()
    try:
        served.process.wait(timeout=20 * SCALE)
    except subprocess.TimeoutExpired:
        served.process.kill()
        served.process.wait()


def drive_time(seconds: float) -> str:
    """The RFC 3339 time `seconds` into the simulated drive (Foxglove's `time` URL parameter)."""
    start = datetime.fromtimestamp(DEFAULT_START_NS // 1_000_000_000, tz=timezone.utc)
    return (start + timedelta(seconds=seconds)).strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def active_alarms_at(drive: Path, seconds: float) -> set[str]:
    """The alarms active on the drive's last /health message at or before `seconds` into it
    (what Foxglove shows there)."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    until = DEFAULT_START_NS + round(seconds * 1e9)
    latest: Any = None
    with drive.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, _, message, health in reader.iter_decoded_messages(topics=["/health"]):
            if message.log_time <= until:
                latest = health
    assert latest is not None, f"{drive}: no /health before {seconds} s"
    return {alarm.id for alarm in latest.alarms if alarm.active}


def track_with_its_detections_at(drive: Path, window_s: tuple[float, float],
                                 near: tuple[float, float] = (8.0, 40.0)) -> float:
    """Seconds into the drive of its first scene in `window_s` where a labelled track (not the
    lead: that one is inside the see-through lead box) has a radar and a camera detection at its
    very place (within 10 cm), `near` metres ahead: read from the drive's /scene topics (the
    chase view's labels, the last of a tick's)."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    latest: dict[str, dict[str, tuple[float, float]]] = {}
    labels = "/scene/labels/chase"
    with drive.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, update in reader.iter_decoded_messages(
                topics=["/scene/radar", "/scene/camera", "/scene/tracks", labels],
                log_time_order=True):
            latest[channel.topic] = {e.id: (e.spheres[0].pose.position.x,
                                            e.spheres[0].pose.position.y)
                                     for e in update.entities if e.spheres}
            seconds = (message.log_time - DEFAULT_START_NS) / 1e9
            if channel.topic != labels or not window_s[0] <= seconds <= window_s[1]:
                continue
            labelled = {e.id for e in update.entities}
            tracks = latest.get("/scene/tracks", {})
            for tx, ty in [place for i, place in tracks.items() if i in labelled]:
                if near[0] <= tx <= near[1] and all(
                        any(abs(tx - x) < 0.1 and abs(ty - y) < 0.1
                            for x, y in latest.get(t, {}).values())
                        for t in ("/scene/radar", "/scene/camera")):
                    return seconds
    raise AssertionError(f"{drive}: no labelled track with a radar and a camera detection at "
                         f"its place, {near[0]}-{near[1]} m ahead, in {window_s} s")


def scene_at(drive: Path, seconds: float) -> dict[str, Any]:
    """The latest SceneUpdate of each /scene topic at or before `seconds` into the drive
    (what Foxglove shows there)."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    until = DEFAULT_START_NS + round(seconds * 1e9)
    latest: dict[str, Any] = {}
    with drive.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, update in reader.iter_decoded_messages(
                log_time_order=True, ending_before=until + 1):
            if channel.topic.startswith("/scene/"):
                latest[channel.topic] = update
    return latest


def label_pattern(text: str) -> str:
    """What OCR must read of a label: the words and ids of its first line (not the distance of a
    compact label, "· 22 m"), whole.
    Tesseract may read one letter of a word as another ('TreckID', 'Vohicle'), a letter or a
    stray mark beside a colon or slash differently ('TrackI0;', 'TrackIDB', '2 /8') and a small 0
    as @, O, 6 or 8; the numbers must be read."""
    words = []
    first = re.sub(r" · \d+ m$", "", text.split("\n")[0])
    for word in re.findall(r"[A-Za-z]+|\d+(?:/\d+)*", first):
        if word.startswith("TrackID"):  # a grid line behind a far label reads as a mark
            words.append(rf"(?:Tra\S{{0,4}}|{one_letter_off('Track')})I[D0OB]{{1,2}}[:;.,]{{0,2}}")
        elif word[0].isdigit():
            words.append(r"\s*/\s*".join(word.split("/")).replace("0", "[0O@Q68]") + "(?![0-9])")
        else:
            words.append(one_letter_off(word))
    return r"[^A-Za-z0-9]{0,4}".join(words)


def one_letter_off(word: str) -> str:
    """A pattern of ``word``, or of it with any one of its letters read as another."""
    return "(?:" + "|".join(re.escape(word[:i]) + r"\S" + re.escape(word[i + 1:])
                            for i in range(len(word))) + ")"


def places_on_screen(reading: dict[str, Any], gap: int = 3) -> int:
    """How many separate places of red (tracks) the screenshot shows: red blobs joined with
    the blue blobs they touch (a detection ball splits its track's disc in two), each group
    one place."""
    blobs = [("red", b) for b in reading["redBlobs"]] + [("blue", b) for b in
                                                        reading["blueBlobs"]]
    parent = list(range(len(blobs)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i, (_, a) in enumerate(blobs):
        for j in range(i + 1, len(blobs)):
            b = blobs[j][1]
            if (a["x0"] - gap <= b["x1"] and b["x0"] - gap <= a["x1"]
                    and a["y0"] - gap <= b["y1"] and b["y0"] - gap <= a["y1"]):
                parent[root(j)] = root(i)
    return len({root(i) for i, (kind, _) in enumerate(blobs) if kind == "red"})


def indicators(layout: str, active: set[str], folder: Path = LAYOUTS
               ) -> dict[str, dict[str, str]]:
    """What each Indicator panel of a layout (in `folder`) must show: its rule for true (the
    alarm is active) or false (label and colour), read from the layout itself."""
    data = json.loads((folder / layout).read_text(encoding="utf-8"))
    out = {}
    for panel_id, config in data["configById"].items():
        if panel_id.startswith("Indicator!"):
            alarm = re.fullmatch(r'/health\.alarms\[:\]\{id=="([^"]+)"\}\.active',
                                 config["path"])
            assert alarm, f"{layout}: {panel_id}: {config['path']}"
            wanted = "true" if alarm[1] in active else "false"
            (rule,) = [r for r in config["rules"] if r["rawValue"] == wanted]
            out[panel_id] = {"label": rule["label"], "color": rule["color"]}
    return out


@dataclass
class DriverRun:
    """What a run of the browser driver did, shot by shot, however far it got."""

    shots: dict[str, dict[str, Any]] = field(default_factory=dict)  # by name, as each ended
    ended: dict[str, float] = field(default_factory=dict)  # when each shot's result came
    served: dict[str, Tankviz] = field(default_factory=dict)  # each live shot's own source
    result: dict[str, Any] | None = None  # the driver's last line: every shot
    problem: str | None = None  # why the run did not finish, if it did not
    log: list[str] = field(default_factory=list)  # the driver's progress (its stderr)


def run_driver(plan: Path, sources: dict[str, list[str]], shots: int) -> DriverRun:
    """Run the browser driver (e2e.mjs) on a plan: start the live source each live shot asks for
    when it asks (and stop it when the shot's result comes), and stop the driver if it shows no
    sign of life for longer than any of its waits may take (it logs every step, and what it is
    waiting for every REPORT_S)."""
    process = subprocess.Popen(["node", str(BROWSER / "e2e.mjs"), str(plan)], cwd=BROWSER,
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    assert process.stdin is not None and process.stdout is not None
    assert process.stderr is not None
    lines: queue.SimpleQueue[tuple[str, str | None]] = queue.SimpleQueue()

    def pump(name: str, stream: Any) -> None:
        for line in stream:
            lines.put((name, line.rstrip("\n")))
        lines.put((name, None))

    for name, stream in (("out", process.stdout), ("err", process.stderr)):
        threading.Thread(target=pump, args=(name, stream), daemon=True).start()
    run = DriverRun()
    silent_s = WAIT_S + 60 * SCALE  # a wait, plus a screenshot or an OCR read after it
    overall_s = (2 + 4 * shots) * WAIT_S  # a safety net only: every wait has its budget
    began = alive = time.monotonic()
    streams = {"out", "err"}
    try:
        while streams:
            try:
                name, line = lines.get(timeout=1.0)
            except queue.Empty:
                name, line = "", None
            now = time.monotonic()
            if name:
                alive = now
                if line is None:
                    streams.discard(name)
                elif name == "err":
                    run.log.append(line)
                elif line.startswith("{"):
                    message = json.loads(line)
                    if "start" in message:  # a live shot is ready for its source
                        shot = message["shot"]
                        try:
                            run.served[shot] = start_tankviz(*sources[message["start"]])
                            reply = {"ws": run.served[shot].url}
                        except AssertionError as error:
                            reply = {"error": str(error)[-2000:]}
                        run.log.append(f"[test] {shot}: {message['start']} -> {reply}")
                        try:
                            process.stdin.write(json.dumps(reply) + "\n")
                            process.stdin.flush()
                        except OSError:
                            pass  # the driver is gone: its end is reported below
                        alive = time.monotonic()
                    elif "shot" in message:
                        shot = message["shot"]["name"]
                        run.shots[shot], run.ended[shot] = message["shot"], now
                        if shot in run.served:
                            stop(run.served[shot])
                    else:
                        run.result = message
                else:
                    run.log.append(f"[stdout] {line}")
            if now - alive > silent_s:
                run.problem = f"the driver showed no sign of life for {silent_s:g} s"
                break
            if now - began > overall_s:
                run.problem = f"the driver was still running after {overall_s:g} s"
                break
        if run.problem is None:
            status = process.wait(timeout=60 * SCALE)
            if status != 0 or run.result is None:
                run.problem = f"the driver exited with status {status} and no result"
    finally:
        for served in run.served.values():
            if served.process.poll() is None:
                stop(served)
        if process.poll() is None:
            process.terminate()  # playwright closes chromium on SIGTERM
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
    if run.problem:
        waiting = [line for line in run.log if "still waiting" in line][-3:]
        run.problem += (f" (TANKVIZ_TEST_TIMEOUT_SCALE={SCALE:g}); shots ended: "
                        f"{sorted(run.shots) or 'none'}; what it last waited for: "
                        f"{waiting or 'nothing'}; its last lines:\n" + "\n".join(run.log[-30:]))
    return run


@pytest.fixture(scope="module")
def e2e(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """One browser session for every shot (about three minutes on an idle machine)."""
    browser, out = browser_session(tmp_path_factory, "")
    drive = out / "drive.mcap"
    subprocess.run([sys.executable, "-m", "bridge", "simulate", "-o", str(drive), "--duration",
                    str(DRIVE_S), "--force"], cwd=ROOT, check=True, capture_output=True)
    begin, end = TIMELINE.lane_dropout.window_s(DRIVE_S)
    dropout = drive_time((begin + end) / 2)
    # Late in the radar dropout: radar.silent is raised and on the latest /health message.
    radar_begin, radar_end = TIMELINE.radar_dropout.window_s(DRIVE_S)
    radar_out_s = radar_end - 0.2
    radar_alarms = active_alarms_at(drive, radar_out_s)
    assert radar_alarms == {"radar.silent"}, (
        f"the drive's /health at {radar_out_s} s (radar dropout {radar_begin}-{radar_end} s): "
        f"active {sorted(radar_alarms)}")
    radar_out = drive_time(radar_out_s)
    # A track and the radar and camera detections it was fused from at one place, in the healthy
    # part of the drive (before its first fault).
    together = drive_time(track_with_its_detections_at(drive, (5.0, begin)))
    # A car unlike ecocar at highway range, with the layouts made for its profile.
    highway = out / "highway.mcap"
    highway_layouts = out / "highway-layouts"
    # (imported under its file name, so that it is never taken for ecocar's tank-viz)
    highway_layout = out / "tank-viz-highway.json"
    for args in (["simulate", "--car", "highway", "-o", str(highway), "--duration", "20",
                  "--force"],
                 ["layouts", "--profile", "highway", "--export", str(highway_layouts),
                  "--force"]):
        subprocess.run([sys.executable, "-m", "bridge", *args], cwd=ROOT, check=True,
                       capture_output=True)
    shutil.copyfile(highway_layouts / "tank-viz.json", highway_layout)
    shutil.copyfile(highway_layouts / "engineer.json", out / "engineer-highway.json")
    highway_scene = scene_at(highway, HIGHWAY_S)
    highway_labels = [t.text for e in highway_scene["/scene/labels/range"].entities
                      for t in e.texts]
    # The highway car in each 3D panel of its layouts, in a laptop's and a large window.
    windows = [
        {"name": f"window-{width}-{panel}", "viewport": {"width": width, "height": height},
         "source": {"mcap": highway.name, "time": drive_time(HIGHWAY_S)}, "via": "import",
         "layout": str(out / layout), "scene": {"panel": panel, "expect": ["ego", "tracks"]},
         "ocr": [label_pattern(t.text) for e in highway_scene[f"/scene/labels/{view}"].entities
                 for t in e.texts],
         "screenshot": str(out / f"window-{width}-{panel.replace('!', '-')}.png")}
        for width, height in WINDOWS
        for layout, panel, view in (("tank-viz-highway.json", "3D!tankviz", "chase"),
                                    ("tank-viz-highway.json", "3D!tankviz-range", "range"),
                                    ("engineer-highway.json", "3D!engineer", "chase"))]
    # The live sources, each started for its shot when the browser is ready for it.
    sources = {
        "demo": ["demo", "--port", "0", "--no-record", "--scenario", f"{DEMO_SCENARIO_S:g}"],
        # The drive served live by `tankviz replay` from just inside the camera dropout, slowly
        # (0.05x: the dropout lasts over a minute and a half), so the browser is there before
        # it ends.
        "replay": ["replay", str(drive), "--port", "0", "--start", f"{begin + 0.2:.1f}",
                   "--speed", "0.05"],
    }
    plan = {
        "chromium": browser,
        "dataDir": str(out),
        "timeoutMs": round(WAIT_S * 1000),
        "reportMs": round(REPORT_S * 1000),
        "viewport": {"width": 1600, "height": 1000},
        "shots": [
            {"name": "tank-viz", "source": {"serve": "demo"}, "via": "import",
             "layout": str(LAYOUTS / "tank-viz.json"),
             "scene": {"panel": "3D!tankviz", "expect": LIVE_VIEW},
             "ocr": LABEL_PATTERNS, "screenshot": str(out / "tank-viz.png")},
            # No fault in the demo before 40 % of its scenario: every alarm a green OK.
            {"name": "engineer-live", "source": {"serve": "demo"}, "via": "preload",
             "layout": str(LAYOUTS / "engineer.json"),
             "scene": {"panel": "3D!engineer", "expect": ["ego", "greenLanes", "lead"]},
             "plots": True, "plotExtent": 0.3,
             "indicators": indicators("engineer.json", set()),
             "screenshot": str(out / "engineer-live.png")},
            {"name": "replay", "source": {"serve": "replay"}, "via": "preload",
             "layout": str(LAYOUTS / "tank-viz.json"),
             "scene": {"panel": "3D!tankviz", "expect": ["ego", "magentaLanes", "lead"],
                       "absent": ["greenLanes"]},
             "screenshot": str(out / "replay.png")},
            {"name": "dropout", "source": {"mcap": drive.name, "time": dropout},
             "via": "preload", "layout": str(LAYOUTS / "tank-viz.json"),
             "scene": {"panel": "3D!tankviz", "expect": ["ego", "magentaLanes", "tracks", "lead"],
                       "absent": ["greenLanes"]},
             "screenshot": str(out / "dropout.png")},
            # The recorded drive in its radar dropout: radar.silent red, no blue radar spheres.
            # Preloaded: its Log panel subscribes before the file opens at the dropout, so it
            # gets the seek's last /log message (imported after the seek, it got it only when
            # its subscription happened to beat the seek: 2 of 5 runs showed an empty Log).
            {"name": "engineer", "source": {"mcap": drive.name, "time": radar_out},
             "via": "preload", "layout": str(LAYOUTS / "engineer.json"),
             "scene": {"panel": "3D!engineer", "expect": ["ego", "greenLanes", "tracks", "lead"],
                       "absent": ["radar"]},
             "plots": True, "plotExtent": 0.8,
             "indicators": indicators("engineer.json", radar_alarms),
             "panelText": {"RawMessages!lead": ["tankviz.LeadVehicle @", "mio_ok", "present"],
                           "RosOut!alarms": ["ALARM radar.silent", "no frame for"]},
             "screenshot": str(out / "engineer.png")},
            {"name": "can-debug", "source": {"mcap": drive.name, "time": radar_out},
             "via": "import", "layout": str(LAYOUTS / "can-debug.json"),
             "plots": True, "plotExtent": 0.8,
             "indicators": indicators("can-debug.json", radar_alarms),
             "panelText": {"RawMessages!frames-can0": ["tankviz.CanFrameBlock @", "frames",
                                                       "offset_ns", "data"],
                           # one id's frames, found in the blocks by a message-path filter
                           "RawMessages!frames-can0-id": ["id", "256", "offset_ns"],
                           "SourceInfo!topics": ["/can/can0/frames", "tankviz.CanFrameBlock",
                                                 "/health", "tankviz.Health"]},
             "screenshot": str(out / "can-debug.png")},
            # A track and its detections at one place: both drawn, each in its own colour.
            {"name": "together", "source": {"mcap": drive.name, "time": together},
             "via": "preload", "layout": str(LAYOUTS / "tank-viz.json"),
             "scene": {"panel": "3D!tankviz", "expect": ["ego", "tracks"],
                       "inside": {"red": ["blue", "white"]}},
             "screenshot": str(out / "together.png")},
            # The highway car 15 s into its drive, in the range view of the layouts made for its
            # profile: every track, detection and label readable from 10 to 190 m.
            {"name": "highway", "source": {"mcap": highway.name, "time": drive_time(HIGHWAY_S)},
             "via": "import", "layout": str(highway_layout),
             "scene": {"panel": "3D!tankviz-range",
                       "expect": ["ego", "tracks", "radar", "lead"],
                       "inside": {"red": ["blue"]}},
             "ocr": [label_pattern(text) for text in highway_labels],
             "screenshot": str(out / "highway.png")},
            *windows,
            # The engineer in the car clicks the Mark button (a laptop's window): the mark is
            # in the log panel and, for a few seconds, in the scene.
            {"name": "mark", "source": {"serve": "demo"}, "via": "preload",
             "layout": str(LAYOUTS / "engineer.json"), "viewport": {"width": 1280, "height": 800},
             "clicks": [{"panel": "Publish!mark", "button": "Mark"}],
             "scene": {"panel": "3D!engineer", "expect": ["ego"]},
             "panelText": {"RosOut!alarms": ["MARK 1: mark (viewer"]},
             # (a small 1 is read as l, L, I or | by Tesseract: "MARK L" in 1 of 3 runs)
             "ocr": [r"MARK\s*[1lLI|]"], "screenshot": str(out / "mark.png")},
        ],
    }
    (out / "plan.json").write_text(json.dumps(plan, indent=2), encoding="utf-8")
    started = time.monotonic()
    run = run_driver(out / "plan.json", sources, len(plan["shots"]))
    wall = time.monotonic() - started
    (out / "driver.log").write_text("\n".join(run.log) + "\n", encoding="utf-8")
    shots = run.shots
    # How far into its own live source (started for it) each live shot ended, at most.
    for name, served in run.served.items():
        if name in shots:
            shots[name]["servedSeconds"] = round(run.ended[name] - served.started, 1)
    result = run.result or {"ok": False, "problem": run.problem, "shots": list(shots.values())}
    (out / "result.json").write_text(json.dumps(result, indent=2), encoding="utf-8")
    if os.environ.get("TANKVIZ_UPDATE_PREVIEWS"):
        for name in ("tank-viz", "engineer", "can-debug", "highway"):
            if shots.get(name, {}).get("ok"):
                shutil.copyfile(out / f"{name}.png", LAYOUTS / f"{name}.png")
    yield {"shots": shots, "planned": [shot["name"] for shot in plan["shots"]],
           "problem": run.problem, "out": out, "wall": wall, "result": result,
           "highway": highway_scene}


def shot_named(e2e: dict[str, Any], name: str) -> dict[str, Any]:
    """A shot's result; fails with what the driver was doing if the run ended before it."""
    shot: dict[str, Any] | None = e2e["shots"].get(name)
    if shot is None:
        pytest.fail(f"the browser driver did not get to the shot {name!r}: {e2e['problem']}")
    return shot


def explain(shot: dict[str, Any]) -> str:
    return json.dumps({k: shot.get(k) for k in ("failures", "verdict", "steps", "errors",
                                                   "plots")}, indent=1)[:4000]


def test_live_demo_in_foxglove_with_tank_viz(e2e: dict[str, Any]) -> None:
    """Live over the WebSocket, the layout imported from the Layouts menu: the Tank Viz look."""
    shot = shot_named(e2e, "tank-viz")
    assert shot["ok"], explain(shot)
    assert all(shot["verdict"][k] for k in LIVE_VIEW), explain(shot)
    reading = shot["reading"]
    # The ego box sits at the bottom centre, the lane lines run up the screen on both sides.
    assert 0.4 < reading["ego"]["rel"]["x"] < 0.6 and reading["ego"]["rel"]["y"] > 0.65
    lanes = reading["lanes"]["brightGreen"]
    ego_x = reading["ego"]["cx"]
    assert any(b["cx"] < ego_x for b in lanes) and any(b["cx"] > ego_x for b in lanes)
    # The lead box is ahead of the ego (above it on screen).
    assert reading["lead"][0]["cy"] < reading["ego"]["cy"]


def test_tank_viz_text_labels_are_readable(e2e: dict[str, Any]) -> None:
    ocr = shot_named(e2e, "tank-viz").get("ocr")
    if not ocr or not ocr.get("available"):
        unavailable("tesseract is not installed (apt-get install tesseract-ocr)")
    assert ocr["found"] == LABEL_PATTERNS, ocr["text"]
    for pattern in LABEL_PATTERNS:
        assert re.search(pattern, ocr["text"]), (pattern, ocr["text"])


def test_replay_in_the_lane_dropout_shows_magenta_lanes(e2e: dict[str, Any]) -> None:
    """`tankviz replay` (server time, messages as recorded) in the camera lane dropout."""
    shot = shot_named(e2e, "replay")
    assert shot["ok"], explain(shot)
    assert shot["verdict"]["magentaLanes"] and not shot["verdict"]["greenLanes"]
    assert shot["reading"]["egoBottomCentre"]


def test_lane_dropout_shows_magenta_lanes(e2e: dict[str, Any]) -> None:
    """A recorded drive opened as a remote file (HTTP ranges) at a time in the camera dropout."""
    shot = shot_named(e2e, "dropout")
    assert shot["ok"], explain(shot)
    assert shot["verdict"]["magentaLanes"] and not shot["verdict"]["greenLanes"]
    assert len(shot["reading"]["lanes"]["magenta"]) >= 2


ENGINEER_PLOTS = {"Plot!lead", "Plot!ego", "Plot!ego-angles", "Plot!counts", "Plot!rates"}


def test_engineer_layout_plots_and_raw_messages(e2e: dict[str, Any]) -> None:
    shot = shot_named(e2e, "engineer")
    assert shot["ok"], explain(shot)
    assert set(shot["plots"]) == ENGINEER_PLOTS
    for plot in shot["plots"].values():
        assert plot["missingValues"] == [] and plot["extent"] >= 0.8


def test_engineer_indicators_live_without_alarms(e2e: dict[str, Any]) -> None:
    """`tankviz demo` live, before its first fault: every alarm's Indicator is a green OK, and
    the health plot (family rates from /health) has values."""
    shot = shot_named(e2e, "engineer-live")
    first_fault_s = TIMELINE.lane_dropout.start * DEMO_SCENARIO_S
    assert shot["ok"], (f"ended at most {shot.get('servedSeconds')} s into its demo (its first "
                        f"fault: {first_fault_s:g} s)\n{explain(shot)}")
    shown = shot["indicators"]
    assert len(shown) == 14, sorted(shown)
    assert {i["label"] for i in shown.values()} == {"OK"}
    assert all(i["share"] >= 0.5 for i in shown.values())
    assert set(shot["plots"]) == ENGINEER_PLOTS
    assert shot["plots"]["Plot!rates"]["missingValues"] == []


def test_engineer_indicators_in_the_radar_dropout(e2e: dict[str, Any]) -> None:
    """The recorded drive opened in its radar dropout: radar.silent is red and says so, every
    other alarm is a green OK, the Log panel has the alarm and the rate plot the gap."""
    shot = shot_named(e2e, "engineer")
    assert shot["ok"], explain(shot)
    shown = shot["indicators"]
    assert len(shown) == 14
    red = {k for k, v in shown.items() if v["label"] != "OK"}
    assert red == {"Indicator!radar.silent"}
    assert shown["Indicator!radar.silent"]["label"] == "radar.silent"
    assert not shot["verdict"]["radar"], "no radar detections while the radar is silent"
    rates = shot["plots"]["Plot!rates"]
    assert rates["missingValues"] == [] and rates["extent"] >= 0.8


def test_can_debug_layout(e2e: dict[str, Any]) -> None:
    shot = shot_named(e2e, "can-debug")
    assert shot["ok"], explain(shot)
    assert len(shot["plots"]) == 9  # 6 of the signals ecocar reads, 3 of the bus's health
    for plot in shot["plots"].values():
        assert plot["missingValues"] == [] and plot["extent"] >= 0.8
    assert set(shot["indicators"]) == {"Indicator!bus.can0.silent", "Indicator!bus.can0.babbling"}
    assert {i["label"] for i in shot["indicators"].values()} == {"OK"}


def test_a_track_does_not_hide_the_detections_at_its_place(e2e: dict[str, Any]) -> None:
    """The recorded drive where a track and the radar and camera detections it was fused from
    are at one place: the blue and the white detection show inside the track's red region."""
    shot = shot_named(e2e, "together")
    assert shot["ok"], explain(shot)
    inside = shot["reading"]["inside"]
    for colour in ("blue", "white"):
        (track, detection) = inside[colour][0]
        assert track["x0"] <= detection["cx"] <= track["x1"], inside
        assert track["y0"] <= detection["cy"] <= track["y1"], inside
        assert detection["area"] < track["area"], inside


def test_a_car_at_highway_range_every_track_and_label_is_seen(e2e: dict[str, Any]) -> None:
    """The highway car (16 radar slots, twins, objects from 10 to 190 m) with the layouts made
    for its profile: one red place per track place the scene draws, blue detections inside
    them, and every label drawn read whole."""
    shot = shot_named(e2e, "highway")
    assert shot["ok"], explain(shot)
    tracks = e2e["highway"]["/scene/tracks"].entities
    distances = sorted(e.spheres[0].pose.position.x for e in tracks)
    assert distances[0] < 25 and distances[-1] > 150, distances  # near and far in one view
    assert places_on_screen(shot["reading"]) == len(tracks), (
        len(tracks), shot["reading"]["redBlobs"])
    assert shot["reading"]["inside"]["blue"], "no detection shows inside its track"
    ocr = shot.get("ocr")
    if not ocr or not ocr.get("available"):
        unavailable("tesseract is not installed (apt-get install tesseract-ocr)")
    missing = [p for p in ocr["wanted"] if p not in ocr["found"]]
    assert not missing, (missing, ocr["text"])


@pytest.mark.parametrize("width", [w for w, _ in WINDOWS])
@pytest.mark.parametrize("panel, view", [("3D!tankviz", "chase"), ("3D!tankviz-range", "range"),
                                         ("3D!engineer", "chase")])
def test_labels_stay_whole_and_apart_on_a_laptop_and_a_large_window(
        e2e: dict[str, Any], width: int, panel: str, view: str) -> None:
    """Each 3D panel of the highway car's layouts, in a 1280 x 800 and a 1920 x 1080 window, is
    as large as its view's labels were laid out for (so none leaves it and none covers another:
    tests/test_labels.py), and every label of that view is read whole there."""
    from bridge.scene.camera import chase_camera, view_cameras

    shot = shot_named(e2e, f"window-{width}-{panel}")
    assert shot["ok"], explain(shot)
    region = shot["reading"]["region"]
    camera = chase_camera() if view == "chase" else view_cameras(
        highway_profile())["range"]
    assert camera.holds(region["height"], region["width"]), (region, camera)
    ocr = shot.get("ocr")
    if not ocr or not ocr.get("available"):
        unavailable("tesseract is not installed (apt-get install tesseract-ocr)")
    missing = [p for p in ocr["wanted"] if p not in ocr["found"]]
    assert not missing, (missing, ocr["text"])


def test_a_click_on_the_mark_button_marks_the_moment(e2e: dict[str, Any]) -> None:
    """In Foxglove Studio, the engineer layout's Mark button (a Publish panel) publishes a mark to
    the live demo: it comes back at once, in the log panel and as a text in the 3D view."""
    shot = shot_named(e2e, "mark")
    assert shot["ok"], explain(shot)
    assert "clicked Publish!mark" in shot["steps"]
    ocr = shot.get("ocr")
    if not ocr or not ocr.get("available"):
        unavailable("tesseract is not installed (apt-get install tesseract-ocr)")
    assert ocr["found"] == ocr["wanted"], ocr["text"]


def highway_profile() -> Any:
    from bridge.pipeline.drive import load_stages

    return load_stages([], "highway").profile


def test_no_errors_in_the_app(e2e: dict[str, Any]) -> None:
    for name in e2e["planned"]:
        shot = shot_named(e2e, name)
        errors = [e for e in shot["errors"] if "WebGL" not in e]
        assert errors == [], f"{shot['name']}: {errors}"


# --- layouts made for another car's profile (tankviz layouts --profile) ---------------------------

#: A car that is not ecocar: GM's object bus (tests/profiles/gm_object.toml, opendbc's
#: gm_global_a_object.dbc): radar tracks in polar coordinates, camera objects, camera lanes given
#: as distances, the lead chosen among the tracks.
GM_PROFILE = ROOT / "tests" / "profiles" / "gm_object.toml"
GM_DBC = "gm_global_a_object.dbc"
#: Seconds of the GM drive, and where it is opened (families' rates are learned in 3 s).
GM_DRIVE_S, GM_AT_S = 10.0, 8.0


def gm_drive_log(path: Path) -> Path:
    """A BLF log of the GM car at 20 Hz: a track 30 m straight ahead (the lead, x 33.6 m), a
    track 25 m away 8 degrees to the left (y +3.5 m), a camera object 40 m away 5 degrees to the
    right, and the camera's lane lines 1.7 m left and 1.9 m right."""
    import can
    import cantools
    from conftest import SHARED_DBC, message

    db = cantools.database.load_file(SHARED_DBC / GM_DBC)
    t0 = DEFAULT_START_NS / 1e9
    with can.Logger(path) as logger:
        for i in range(round(GM_DRIVE_S * 20)):
            t = t0 + i * 0.05
            for m in [
                message(db, "LRRObject01", t, TrkRange=30.0, TrkAzimuth=0.0, TrkObjectID=7),
                message(db, "LRRObject02", t + 0.001, TrkRange=25.0, TrkAzimuth=8.0,
                        TrkObjectID=12),
                message(db, "F_Vision_Obj_Track_1", t + 0.002, FwdVsnRngTrk1Rev=40.0,
                        FwdVsnAzmthTrk1Rev=-5.0),
                message(db, "F_Vision_Environment", t + 0.003, LnSenseDistToLLnEdge=1.7,
                        LnSnsDistToRLnEdge=1.9, LaneSnsLLnPosValid=0, LnSnsRLnPosValid=0),
                message(db, "F_Vision_Environment_5", t + 0.004, LnMrkg3LnSnsLnDst=5.4,
                        LnMrkg3LnQltyConfLvl=80),
                message(db, "F_Vision_Environment_6", t + 0.005, LnMrkg4LnSnsLnDst=-5.6,
                        LnMrkg4LnQltyConfLvl=80),
            ]:
                logger.on_message_received(m)
    return path


@pytest.fixture(scope="module")
def e2e_gm(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The GM car's drive, converted with its profile, opened in the browser with the layouts
    `tankviz layouts --profile` made for it, each through the app's Import layout (preload
    serves the repository's layouts/ only); its own browser session: two shots."""
    from conftest import SHARED_DBC, SHARED_DBC_ORIGIN

    if not (SHARED_DBC / GM_DBC).is_file():
        pytest.skip(f"public DBCs not found at {SHARED_DBC}: {SHARED_DBC_ORIGIN}")
    browser, out = browser_session(tmp_path_factory, "gm")
    log = gm_drive_log(out / "gm.blf")
    drive = out / "gm.mcap"
    dbc = str(SHARED_DBC / GM_DBC)
    for args in (["convert", str(log), "-o", str(drive), "--dbc", dbc, "--profile",
                  str(GM_PROFILE), "--force", "--quiet"],
                 ["layouts", "--profile", str(GM_PROFILE), "--dbc", dbc, "--export",
                  str(out / "layouts"), "--force"]):
        subprocess.run([sys.executable, "-m", "bridge", *args], cwd=ROOT, check=True,
                       capture_output=True)
    layouts = out / "layouts"
    active = active_alarms_at(drive, GM_AT_S)
    at = drive_time(GM_AT_S)
    plan = {
        "chromium": browser, "dataDir": str(out), "timeoutMs": round(WAIT_S * 1000),
        "reportMs": round(REPORT_S * 1000), "viewport": {"width": 1600, "height": 1000},
        "shots": [
            {"name": "gm-tank-viz", "source": {"mcap": drive.name, "time": at},
             "via": "import", "layout": str(layouts / "tank-viz.json"),
             "scene": {"panel": "3D!tankviz",
                       "expect": ["ego", "greenLanes", "tracks", "camera", "lead"],
                       "absent": ["magentaLanes", "radar"]},
             "screenshot": str(out / "gm-tank-viz.png")},
            {"name": "gm-engineer", "source": {"mcap": drive.name, "time": at},
             "via": "import", "layout": str(layouts / "engineer.json"),
             "scene": {"panel": "3D!engineer", "expect": ["ego", "greenLanes", "tracks"]},
             "plots": True, "plotExtent": 0.5,
             "indicators": indicators("engineer.json", active, layouts),
             "screenshot": str(out / "gm-engineer.png")},
        ],
    }
    (out / "plan.json").write_text(json.dumps(plan, indent=2), encoding="utf-8")
    run = run_driver(out / "plan.json", {}, len(plan["shots"]))
    (out / "driver.log").write_text("\n".join(run.log) + "\n", encoding="utf-8")
    engineer = json.loads((layouts / "engineer.json").read_text(encoding="utf-8"))
    return {"shots": run.shots, "problem": run.problem, "out": out, "active": active,
            "engineer": engineer}


def test_layouts_made_for_a_gm_car_show_its_tracks_lanes_and_alarms(
        e2e_gm: dict[str, Any]) -> None:
    """Another car than ecocar: its drive in the layouts `tankviz layouts --profile` made for it.
    Its tracks (red), camera objects (white), green camera lanes and the lead box are drawn where
    the log put them, and the engineer layout shows one Indicator per alarm of this profile
    (none of ecocar's), each a green OK on this healthy drive."""
    assert e2e_gm["active"] == set(), "a healthy drive: no alarm at the shot's time"
    shot = shot_named(e2e_gm, "gm-tank-viz")
    assert shot["ok"], explain(shot)
    reading = shot["reading"]
    ego_x, ego_y = reading["ego"]["cx"], reading["ego"]["cy"]
    # The track 8 degrees to the left is left of the ego, the lead (straight ahead) above it,
    # the camera object to the right; a lane line on each side.
    assert any(t["cx"] < ego_x - 20 and t["cy"] < ego_y for t in reading["tracks"]), reading
    assert any(c["cx"] > ego_x + 20 and c["cy"] < ego_y for c in reading["camera"]), reading
    assert reading["lead"][0]["cy"] < ego_y and abs(reading["lead"][0]["cx"] - ego_x) < 60
    lanes = reading["lanes"]["brightGreen"]
    assert any(b["cx"] < ego_x for b in lanes) and any(b["cx"] > ego_x for b in lanes)
    engineer = shot_named(e2e_gm, "gm-engineer")
    assert engineer["ok"], explain(engineer)
    shown = engineer["indicators"]
    alarms = [k for k in e2e_gm["engineer"]["configById"] if k.startswith("Indicator!")]
    assert set(shown) == set(alarms) and len(alarms) == 9
    assert {"Indicator!lrr.silent", "Indicator!vision.silent", "Indicator!camera.silent",
            "Indicator!lanes.lost", "Indicator!bus.can0.silent"} <= set(shown)
    assert "Indicator!radar.silent" not in shown, "no ecocar alarm"
    assert {i["label"] for i in shown.values()} == {"OK"}
    for name in ("gm-tank-viz", "gm-engineer"):
        errors = [e for e in shot_named(e2e_gm, name)["errors"] if "WebGL" not in e]
        assert errors == [], f"{name}: {errors}"


# --- bring-up: a car's unknown ids (tankviz layouts --dbc ...: bring-up.json) ------------------

#: The highway car's databases by bundled name, as a car in bring-up has them: no profile.
HIGHWAY_DBCS = ["can0=highway_car", "can1=highway_radar"]
#: The unknown id the bring-up layout plots (brake switch, speedometer, yaw rate; bytes 0-7).
BRINGUP_ID = "0x2C4"
#: What OCR must read of that id: a 0 is often read as O or @.
BRINGUP_ID_OCR = r"[0O@Q689G]x2C4"
#: The two windows the bring-up layout is looked at in: a laptop's and a large one.
BRINGUP_VIEWPORTS = {"1280": {"width": 1280, "height": 800},
                     "1920": {"width": 1920, "height": 1080}}
#: The shot kept as the layout's preview (layouts/bring-up.png).
BRINGUP_PREVIEW = "bring-up-1920"


@pytest.fixture(scope="module")
def e2e_bringup(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The simulated highway car (ids no database defines on can0 and can1) served by `tankviz
    replay` of its log with its databases and no profile, looked at through the bring-up layout
    `tankviz layouts --dbc ... --plot can0/0x2C4` writes, imported through the app's Import
    layout, at 1280 x 800 and at 1920 x 1080; its own browser session, a replay per shot."""
    browser, out = browser_session(tmp_path_factory, "bring-up")
    log = out / "highway.blf"
    layouts = out / "layouts"
    dbcs = [word for dbc in HIGHWAY_DBCS for word in ("--dbc", dbc)]
    for args in (["simulate", "--car", "highway", "-o", str(log), "--duration", "60",
                  "--force"],
                 ["layouts", *dbcs, "--plot", f"can0/{BRINGUP_ID}", "--export", str(layouts),
                  "--force"]):
        subprocess.run([sys.executable, "-m", "bridge", *args], cwd=ROOT, check=True,
                       capture_output=True)
    layout = layouts / "bring-up.json"
    # At real speed from 2 s in (the ids tables and the map come once a second of log time),
    # looping: the viewer keeps its server however long OCR takes.
    sources = {"replay": ["replay", str(log), *dbcs, "--port", "0", "--start", "2", "--loop"]}
    plan = {
        "chromium": browser, "dataDir": str(out), "timeoutMs": round(WAIT_S * 1000),
        "reportMs": round(REPORT_S * 1000), "viewport": BRINGUP_VIEWPORTS["1280"],
        "shots": [
            {"name": f"bring-up-{size}", "source": {"serve": "replay"}, "viewport": viewport,
             "via": "import", "layout": str(layout),
             # every line of the bytes and the words plots has a value and is drawn
             "plots": True, "plotExtent": 0.5,
             "panelText": {"Table!ids-can0": [BRINGUP_ID, "unknown", "KINEMATICS"],
                           "Table!ids-can1": ["TRACK_A_0"],
                           "RawMessages!unknown": ["tankviz.CanPayload @", "bytes", "be16",
                                                   "le16"]},
             "image": {"panel": "ImageViewPanel!bits", "minBright": 200},
             "ocrPanels": {"Table!ids-can0": [BRINGUP_ID_OCR, "unknown"],
                           "ImageViewPanel!bits": [r"[Cc][Aa][NnHh][0O@QG]\s*[0O@QG]x2C4"]},
             "ocrAttempts": 2,
             "screenshot": str(out / f"bring-up-{size}.png")}
            for size, viewport in BRINGUP_VIEWPORTS.items()],
    }
    (out / "plan.json").write_text(json.dumps(plan, indent=2), encoding="utf-8")
    run = run_driver(out / "plan.json", sources, len(plan["shots"]))
    (out / "driver.log").write_text("\n".join(run.log) + "\n", encoding="utf-8")
    if os.environ.get("TANKVIZ_UPDATE_PREVIEWS") and run.shots.get(BRINGUP_PREVIEW, {}).get("ok"):
        shutil.copyfile(out / f"{BRINGUP_PREVIEW}.png", LAYOUTS / "bring-up.png")
    return {"shots": run.shots, "problem": run.problem, "out": out,
            "said": {name: "".join(served.output) for name, served in run.served.items()},
            "layout": json.loads(layout.read_text(encoding="utf-8"))}


@pytest.mark.parametrize("size", list(BRINGUP_VIEWPORTS))
def test_bring_up_layout_on_a_replay_of_a_car_without_profile(
        e2e_bringup: dict[str, Any], size: str) -> None:
    """The ids tables (read in the DOM and by OCR), the bit map drawn (bright cells), the plots
    of the unknown id 0x2C4 chosen by the layout's variable (a value and a line for each of its
    bytes and words) and its latest frame, at a laptop's window and a large one; and the replay
    said which layout shows them."""
    name = f"bring-up-{size}"
    shot = shot_named(e2e_bringup, name)
    assert shot["ok"], explain(shot)
    assert e2e_bringup["layout"]["globalVariables"]["unknown_id"] == BRINGUP_ID
    assert set(shot["plots"]) == {"Plot!unknown-bytes", "Plot!unknown-words"}
    for plot in shot["plots"].values():
        assert plot["missingValues"] == [] and plot["extent"] >= 0.5, shot["plots"]
    assert shot["image"]["bright"] >= 200, shot["image"]
    ocr = shot["ocrPanels"]["Table!ids-can0"]
    if not ocr.get("available"):
        unavailable("tesseract is not installed (apt-get install tesseract-ocr)")
    assert ocr["found"] == ocr["wanted"], ocr["text"]
    said = e2e_bringup["said"][name].splitlines()
    assert any(line.startswith(f"bring-up: can0 carries ids no database knows (first "
                               f"{BRINGUP_ID}): import ") for line in said), said
    errors = [e for e in shot["errors"] if "WebGL" not in e]
    assert errors == [], errors


def test_bring_up_map_rows_are_labelled(e2e_bringup: dict[str, Any]) -> None:
    """The map's rows name their bus and id, in the image's own pixels (Foxglove Studio 1.48's
    Image panel draws no text annotation): OCR reads "CAN0 0x2C4" in the Image panel."""
    shot = shot_named(e2e_bringup, "bring-up-1920")
    ocr = shot["ocrPanels"]["ImageViewPanel!bits"]
    if not ocr.get("available"):
        unavailable("tesseract is not installed (apt-get install tesseract-ocr)")
    assert ocr["found"] == ocr["wanted"], ocr["text"]


# --- conformance with Foxglove's client libraries (tools/conformance.mjs) -------------------------


def conformance(*args: str, timeout: float = 120 * SCALE) -> dict[str, Any]:
    if shutil.which("node") is None:
        unavailable("node is not installed")
    ensure_node_modules()
    run = subprocess.run(["node", str(ROOT / "tools" / "conformance.mjs"), *args], cwd=ROOT,
                         capture_output=True, text=True, timeout=timeout, check=False)
    lines = [line for line in run.stdout.splitlines() if line.startswith("{")]
    assert lines, f"conformance.mjs {' '.join(args)} printed nothing:\n{run.stderr[-3000:]}"
    findings: dict[str, Any] = json.loads(lines[-1])
    assert run.returncode == (0 if findings["ok"] else 1), run.stderr[-3000:]
    return findings


def test_live_demo_with_foxglove_ws_protocol_client(tmp_path: Path) -> None:
    """@foxglove/ws-protocol's FoxgloveClient subscribes to every channel of `tankviz demo`,
    parses every schema (base64 FileDescriptorSet) and decodes every message with protobufjs.
    It also advertises /marks and publishes three marks (#34), as Studio's Publish panel does:
    they are in the recorded drive at the drive's time when they came, in `inspect` and the
    catalogue, and `replay --start mark:2` starts before the second."""
    from mcap.reader import make_reader

    from bridge.pb.marks_pb2 import Mark
    from bridge.view.produced import bundled_produced

    drives = tmp_path / "drives"
    demo = start_tankviz("demo", "--port", "0", "--drives", str(drives))
    try:
        found = conformance("live", demo.url, "--seconds", "30", "--marks", "3")
    finally:
        stop(demo)
    assert found["ok"], json.dumps({k: v for k, v in found.items() if k != "channels"})[:3000]
    assert found["serverInfo"]["name"] == "tankviz"
    assert "clientPublish" in found["serverInfo"]["capabilities"]
    channels = found["channels"]
    # Every topic the bundled profile produces is advertised, and nothing else.
    assert set(channels) == set(bundled_produced().topics)
    for topic, channel in channels.items():
        assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
        # /log only carries alarms, /can/<bus>/unknown only ids no database knows (the
        # demo's ecocar sends none)
        if topic != "/log" and not re.fullmatch(r"/can/[^/]+/unknown", topic):
            assert channel["messages"] > 0, f"{topic}: no message within 30 s"
            assert not channel.get("decodeErrors"), topic
    assert channels["/scene/lanes"]["schemaName"] == "foxglove.SceneUpdate"
    assert channels["/can/can0/frames"]["schemaName"] == "tankviz.CanFrameBlock"

    # The marks: in the drive at the drive's time when each came (after the scene the client
    # had seen when it published, where the scene after its /log line is), numbered in order.
    (drive,) = drives.glob("*.mcap")
    with drive.open("rb") as f:
        recorded = [(m.log_time, Mark.FromString(m.data)) for _, _, m
                    in make_reader(f).iter_messages(topics=["/marks"])]
    sent = found["marks"]
    assert [(m.number, m.text, m.category, m.source, m.by) for _, m in recorded] == [
        (n, f"conformance {n}", "ws-protocol", "viewer", sent[0]["by"]) for n in (1, 2, 3)]
    for (t, mark), published in zip(recorded, sent, strict=True):
        assert t == mark.timestamp.seconds * 1_000_000_000 + mark.timestamp.nanos
        assert t == int(published["loggedNs"]) >= int(published["sceneBeforeNs"])
        assert abs(t - int(published["sceneAfterNs"])) <= 100_000_000, published
    inspected = subprocess.run([sys.executable, "-m", "bridge", "inspect", str(drive)],
                               cwd=ROOT, capture_output=True, text=True, timeout=WAIT_S)
    assert inspected.returncode == 0, inspected.stderr
    assert "marks (3; seconds from the drive's start):" in inspected.stdout
    assert f"MARK 2: conformance 2 [ws-protocol] (viewer {sent[0]['by']})" in inspected.stdout
    replayed = subprocess.run([sys.executable, "-m", "bridge", "replay", str(drive), "--port",
                               "0", "--speed", "100", "--start", "mark:2"], cwd=ROOT,
                              capture_output=True, text=True, timeout=WAIT_S)
    assert replayed.returncode == 0, replayed.stderr
    assert "before MARK 2: conformance 2 [ws-protocol]" in replayed.stdout, replayed.stdout
    # in the catalogue, whose answer opens each with replay --start mark:N
    pytest.importorskip("duckdb")
    catalog = tmp_path / "catalog.duckdb"
    for command in (["catalog", str(drive), "-o", str(catalog)],
                    ["catalog", "query", str(catalog), "--mark", "CONFORMANCE"]):
        done = subprocess.run([sys.executable, "-m", "bridge", *command], cwd=ROOT,
                              capture_output=True, text=True, timeout=WAIT_S)
        assert done.returncode == 0, done.stderr
    assert "(3 rows)" in done.stdout, done.stdout
    assert f"tankviz replay {drive} --start mark:2" in done.stdout, done.stdout


def test_recorded_drives_with_mcap_core(tmp_path: Path) -> None:
    """@mcap/core reads what tankviz records (simulate, and the live recorder of demo): summary,
    statistics, chunk and message indexes agree with every record in the file, every message
    decodes with its schema, and the counts agree with the Python mcap library."""
    simulated = tmp_path / "simulated.mcap"
    subprocess.run([sys.executable, "-m", "bridge", "simulate", "-o", str(simulated),
                    "--duration", "10"], cwd=ROOT, check=True, capture_output=True)
    drives = tmp_path / "drives"
    subprocess.run([sys.executable, "-m", "bridge", "demo", "--no-server", "--for", "4",
                    "--drives", str(drives)], cwd=ROOT, check=True, capture_output=True,
                   timeout=120 * SCALE)
    recorded = sorted(drives.glob("*.mcap"))
    assert recorded, f"tankviz demo recorded nothing into {drives}"
    for path in [simulated, *recorded]:
        found = conformance("mcap", str(path))
        assert found["ok"], found["problems"]
        assert found["chunks"] > 0 and found["compression"] == ["zstd"]
        assert found["decodeErrors"] == 0
        assert "tankviz" in found["metadata"] and "ecocar.dbc" in found["attachments"]
        assert found["topics"] == summary_counts(path)
        assert found["messagesRead"] == int(found["messageCount"]) > 0
