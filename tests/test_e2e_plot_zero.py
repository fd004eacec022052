"""In the real Foxglove app (#36 decision 2): a signal that is 0 for a stretch, whose zeros the
decoded topic no longer writes (implicit presence), is plotted as 0 there, not as a gap, and the
Plot legend shows its value 0 in the stretch. Runs the browser driver of tests/test_e2e_browser.py
on a drive converted here; TANKVIZ_E2E_OUT=DIR keeps its screenshot."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from test_e2e_browser import (
    REPORT_S,
    ROOT,
    WAIT_S,
    browser_session,
    drive_time,
    explain,
    run_driver,
)

from bridge.resources import data_dir
from bridge.sim.scenario import DEFAULT_START_NS

pytestmark = [pytest.mark.browser, pytest.mark.slow]

#: VehicleSpeed is 10 m/s but from ZERO_FROM_S to ZERO_TO_S, where it is 0
ZERO_FROM_S, ZERO_TO_S, DRIVE_S = 3.0, 7.0, 10.0
TOPIC = "/can/can0/EgoMotion"


def zero_drive(folder: Path) -> Path:
    """EgoMotion at 50 Hz, every other signal 0 throughout, converted with the ecocar DBC."""
    db = cantools.database.load_file(data_dir() / "ecocar.dbc")
    message = db.get_message_by_name("EgoMotion")
    log = folder / "zero.blf"
    with can.BLFWriter(str(log)) as writer:
        for i in range(round(DRIVE_S * 50)):
            t = i * 0.02
            speed = 0.0 if ZERO_FROM_S <= t < ZERO_TO_S else 10.0
            data = message.encode({"VehicleSpeed": speed, "YawRate": 0.0, "LongAccel": 0.0,
                                   "LatAccel": 0.0, "Counter": 0, "Checksum": 0}, strict=False)
            writer.on_message_received(can.Message(
                timestamp=DEFAULT_START_NS / 1e9 + t, arbitration_id=message.frame_id,
                is_extended_id=False, data=data, channel=0))
    drive = folder / "zero.mcap"
    subprocess.run([sys.executable, "-m", "bridge", "convert", str(log), "-o", str(drive),
                    "--dbc", "ecocar", "--force", "--quiet"], cwd=ROOT, check=True,
                   capture_output=True)
    return drive


def test_a_signal_that_is_0_for_a_stretch_is_plotted_as_0(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    browser, out = browser_session(tmp_path_factory, "zero")
    drive = zero_drive(out)
    from mcap.reader import make_reader

    with drive.open("rb") as stream:
        sizes = [len(m.data) for _, _, m in make_reader(stream).iter_messages(topics=[TOPIC])]
    assert 0 in sizes  # every signal 0: nothing written, the message is empty
    plot = {"foxglovePanelTitle": "VehicleSpeed, 0 from 3 s to 7 s",
            "paths": [{"value": f"{TOPIC}.VehicleSpeed", "enabled": True,
                       "timestampMethod": "receiveTime", "label": "VehicleSpeed"}],
            "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True,
            "legendDisplay": "floating", "showPlotValuesInLegend": True, "isSynced": True,
            "xAxisVal": "timestamp", "sidebarDimension": 240}
    layout = out / "zero-layout.json"
    layout.write_text(json.dumps({"configById": {"Plot!zero": plot}, "globalVariables": {},
                                  "userNodes": {}, "playbackConfig": {"speed": 1},
                                  "layout": "Plot!zero"}), encoding="utf-8")
    middle = (ZERO_FROM_S + ZERO_TO_S) / 2
    plan = {"chromium": browser, "dataDir": str(out), "timeoutMs": round(WAIT_S * 1000),
            "reportMs": round(REPORT_S * 1000), "viewport": {"width": 1280, "height": 800},
            "shots": [{"name": "zero", "source": {"mcap": drive.name, "time": drive_time(middle)},
                       "via": "import", "layout": str(layout), "plots": True,
                       "plotExtent": 0.9, "panelText": {"Plot!zero": ["VehicleSp"]},
                       "screenshot": str(out / "zero.png")}]}
    (out / "plan.json").write_text(json.dumps(plan, indent=2), encoding="utf-8")
    run = run_driver(out / "plan.json", {}, 1)
    shot = run.shots.get("zero")
    assert shot is not None, run.problem
    assert shot["ok"], explain(shot)
    # the legend shows a value at the playhead, in the stretch of zeros (a gap shows none), and
    # the line runs across the whole plot
    assert shot["plots"]["Plot!zero"]["missingValues"] == [], explain(shot)
    assert shot["plots"]["Plot!zero"]["extent"] >= 0.9, explain(shot)
