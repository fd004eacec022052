"""Layouts made for a profile (`tankviz layouts --profile P --export DIR`, bridge.view.generate):
for ecocar (the bundled layouts are its output), for every profile in tests/profiles with the
public DBCs it names, and for a small two-bus car written here: everything a generated layout
names is produced for that profile (bridge.view.check), it shows the profile's object groups,
frames, buses, ego signals and one Indicator per alarm its health monitor checks, and nothing
the profile cannot produce."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import pytest
from conftest import SHARED_DBC, SHARED_DBC_ORIGIN

from bridge.apps.layouts import load_layout
from bridge.cli import main
from bridge.decode.outcome import Undecoded
from bridge.frame import Frame
from bridge.health.monitor import HealthMonitor
from bridge.pipeline.drive import load_stages
from bridge.resources import layouts_dir
from bridge.scene.camera import view_range
from bridge.topics import EGO_TOPIC, LEAD_TOPIC, frames_topic, objects_topic
from bridge.view.check import check_layout, panel_type
from bridge.view.generate import (
    LAYOUT_NAMES,
    database_buses,
    generate_layouts,
    layout_text,
)
from bridge.view.produced import produced

PROFILES = Path(__file__).parent / "profiles"
REGENERATE = "tankviz layouts --profile ecocar --export layouts --force"


def panels(data: dict[str, Any], kind: str) -> dict[str, dict[str, Any]]:
    return {k: v for k, v in data["configById"].items() if panel_type(k) == kind}


def plotted(data: dict[str, Any]) -> set[str]:
    return {p["value"] for plot in panels(data, "Plot").values() for p in plot["paths"]}


def indicated(data: dict[str, Any]) -> list[str]:
    return [k.split("!", 1)[1] for k in panels(data, "Indicator")]


def monitored_alarms(decoder: Any, profile: Any, buses: list[str]) -> list[str]:
    """Every alarm a health monitor of the profile checks once each bus has carried a frame."""
    monitor = HealthMonitor(profile, decoder)
    for bus in buses:
        monitor.on_frame(Frame(0, bus, 0x7FF, bytes(8)), Undecoded.UNKNOWN_ID)
    return monitor.alarm_ids()


def profile_dbcs(path: Path) -> list[str]:
    """The `--dbc [BUS=]PATH` options a test profile's header names (`tankviz convert ...
    --dbc ../shared/data/dbc/X.dbc`), read from ../shared/data/dbc."""
    options = re.findall(r"--dbc\s+(?:(\w+)=)?\S*?([^\s/=]+\.(?:dbc|kcd|sym|arxml))",
                         path.read_text(encoding="utf-8"))
    assert options, f"{path}: its header names no --dbc ../shared/data/dbc/FILE"
    return [f"{bus}={SHARED_DBC / name}" if bus else str(SHARED_DBC / name)
            for bus, name in options]


CARS = ["ecocar", *sorted(p.name for p in PROFILES.glob("*.toml"))]


def stages_of(car: str) -> tuple[Any, Any]:
    if car == "ecocar":
        return load_stages([], "ecocar")
    if not SHARED_DBC.is_dir():
        pytest.skip(f"public DBCs not found at {SHARED_DBC}: {SHARED_DBC_ORIGIN}")
    return load_stages(profile_dbcs(PROFILES / car), PROFILES / car)


def test_the_bundled_layouts_are_what_the_generator_writes_for_ecocar() -> None:
    decoder, profile = load_stages([], "ecocar")
    made = generate_layouts(profile, decoder)
    assert list(made) == list(LAYOUT_NAMES)
    for name, data in made.items():
        path = layouts_dir() / f"{name}.json"
        assert path.read_text(encoding="utf-8") == layout_text(data), (
            f"{path} is not what the generator writes for ecocar: regenerate it with "
            f"`{REGENERATE}`")


@pytest.mark.parametrize("car", CARS)
def test_generated_layouts_name_only_what_the_profile_produces(car: str) -> None:
    decoder, profile = stages_of(car)
    buses = database_buses(decoder)
    made = produced(decoder, profile, buses)
    layouts = generate_layouts(profile, decoder)
    for name, data in layouts.items():
        assert check_layout(data, made) == [], f"{car}: {name}"
    # The 3D views: every scene topic and every frame of this profile, nothing else; each view
    # its own labels.
    chase, view = panels(layouts["tank-viz"], "3D").values()
    assert set(chase["topics"]) - set(view["topics"]) == {"/scene/labels/chase"}
    assert set(view["topics"]) - set(chase["topics"]) == {"/scene/labels/range"}
    assert chase["transforms"] == view["transforms"]
    # The range view frames the profile's reach: from behind the vehicle to its farthest sensor.
    reach = view_range(profile)
    state = view["cameraState"]
    eye_x = state["targetOffset"][0] - state["distance"] * math.sin(math.radians(state["phi"]))
    eye_z = state["distance"] * math.cos(math.radians(state["phi"]))
    top = math.radians(90 - state["phi"] - state["fovy"] / 2)  # the top edge, below horizon
    bottom = math.radians(90 - state["phi"] + state["fovy"] / 2)
    assert eye_x + eye_z / math.tan(top) >= reach, f"{car}: {reach} m not in view"
    assert eye_x + eye_z / math.tan(bottom) < 0, f"{car}: the ego vehicle not in view"
    (grid,) = view["layers"].values()
    assert grid["position"][0] + grid["size"] / 2 >= reach
    scene = {t for t, d in made.topics.items() if d.full_name == "foxglove.SceneUpdate"}
    assert set(view["topics"]) == scene - {"/scene/labels/chase"}
    assert {f"/scene/{g}" for g in profile.groups} <= scene
    assert set(view["transforms"]) == {f"frame:{f}" for f in made.frames}
    assert {f"frame:{s}" for s in profile.sensors} <= set(view["transforms"])
    # Engineer: one Indicator per alarm the health monitor checks for this profile.
    engineer = layouts["engineer"]
    alarms = monitored_alarms(decoder, profile, buses)
    assert indicated(engineer) == alarms
    for sensor in profile.sensors:
        assert f"{sensor}.silent" in alarms, "one silent alarm per sensor"
    camera_lines = profile.lanes is not None and bool(profile.lanes.lines)
    assert ("lanes.lost" in alarms) == camera_lines
    assert {f"{objects_topic(g)}.count" for g in profile.groups} <= plotted(engineer)
    ego = {f"{EGO_TOPIC}.{f}" for f in ("speed", "yaw_rate", "steering_wheel_angle")
           if getattr(profile.ego, f) is not None}
    assert {p for p in plotted(engineer) if p.startswith(f"{EGO_TOPIC}.")} == ego
    # speed (m/s) never shares an axis with the angles (rad/s, rad): flat lines beside it
    for plot in panels(engineer, "Plot").values():
        paths = {p["value"] for p in plot["paths"]}
        assert not (f"{EGO_TOPIC}.speed" in paths and len(paths & ego) > 1), plot
    assert (f"{LEAD_TOPIC}.object.x" in plotted(engineer)) == (profile.lead is not None)
    # The lead's relative speed only where the lead's objects have a velocity (GM's polar
    # radar tracks have none: the plot would never show a value).
    lead = profile.lead
    lead_groups = ([] if lead is None else [lead.group] if lead.group is not None
                   else [g for g in profile.groups.values() if g.is_tracks])
    assert (f"{LEAD_TOPIC}.object.vx" in plotted(engineer)) == any(
        g is not None and g.vx is not None for g in lead_groups)
    # can-debug: per bus its raw frames, health figures and bus alarms.
    debug = layouts["can-debug"]
    raw = {p["topicPath"] for p in panels(debug, "RawMessages").values()}
    assert {path for path in raw if "{" not in path} == {frames_topic(b) for b in buses}
    one_id = raw - {frames_topic(b) for b in buses}  # one id's frames, by a filter
    assert one_id and all(re.fullmatch(r"/can/\w+/frames\.frames\[:\]\{id==\d+\}", path)
                          for path in one_id), one_id
    assert sorted(indicated(debug)) == sorted(
        f"bus.{b}.{kind}" for b in buses for kind in ("silent", "babbling"))
    signals = {p for p in plotted(debug) if p.startswith("/can/")}
    assert signals, f"{car}: no decoded signal plotted"


TWO_BUS_DBC_RADAR = """VERSION ""
NS_ :
BS_:
BU_: RADAR
BO_ 1280 Trk_0: 8 RADAR
 SG_ TrkDist : 0|16@1+ (0.01,0) [0|655.35] "m" Vector__XXX
 SG_ TrkLat : 16|16@1- (0.01,0) [-327.68|327.67] "m" Vector__XXX
 SG_ TrkOk : 32|1@1+ (1,0) [0|1] "" Vector__XXX
BO_ 1281 Trk_1: 8 RADAR
 SG_ TrkDist : 0|16@1+ (0.01,0) [0|655.35] "m" Vector__XXX
 SG_ TrkLat : 16|16@1- (0.01,0) [-327.68|327.67] "m" Vector__XXX
 SG_ TrkOk : 32|1@1+ (1,0) [0|1] "" Vector__XXX
"""

TWO_BUS_DBC_CHASSIS = """VERSION ""
NS_ :
BS_:
BU_: ECU
BO_ 300 Chassis: 8 ECU
 SG_ WheelSpd : 0|16@1+ (0.01,0) [0|655.35] "km/h" Vector__XXX
 SG_ SteerWhl : 16|16@1- (0.1,0) [-3276.8|3276.7] "deg" Vector__XXX
"""

TWO_BUS_PROFILE = """
[profile]
name = "two_bus"

[sensors.front]
kind = "radar"
mount = { x = 3.9 }

[objects.slots]
sensor = "front"
role = "tracks"
messages = ["Trk_{i}"]
index = [0, 1]
x = "TrkDist"
y = "TrkLat"
valid = "TrkOk == 1"

[lanes]

[ego]
speed = { signal = "Chassis.WheelSpd", scale = 0.2777778 }
steering_wheel_angle = { signal = "Chassis.SteerWhl", scale = 0.01745329 }
"""


@pytest.fixture
def two_bus(tmp_path: Path) -> tuple[Path, list[str]]:
    """A car with a radar of track slots on bus `front_radar`, speed and steering (no yaw rate)
    on bus `chassis`, no camera (steering lanes only), no lead."""
    (tmp_path / "radar.dbc").write_text(TWO_BUS_DBC_RADAR, encoding="utf-8")
    (tmp_path / "chassis.dbc").write_text(TWO_BUS_DBC_CHASSIS, encoding="utf-8")
    (tmp_path / "two_bus.toml").write_text(TWO_BUS_PROFILE, encoding="utf-8")
    return tmp_path / "two_bus.toml", [f"front_radar={tmp_path / 'radar.dbc'}",
                                       f"chassis={tmp_path / 'chassis.dbc'}"]


def test_a_two_bus_car_without_camera_or_lead(two_bus: tuple[Path, list[str]]) -> None:
    path, dbcs = two_bus
    decoder, profile = load_stages(dbcs, path)
    assert database_buses(decoder) == ["front_radar", "chassis"]
    layouts = generate_layouts(profile, decoder)
    made = produced(decoder, profile, ["front_radar", "chassis"])
    for data in layouts.values():
        assert check_layout(data, made) == []
    view = layouts["tank-viz"]["configById"]["3D!tankviz-range"]
    assert set(view["topics"]) == {"/scene/ego", "/scene/lanes", "/scene/slots",
                                   "/scene/health", "/scene/labels/range", "/scene/marks"}
    assert set(view["transforms"]) == {"frame:vehicle", "frame:front"}
    engineer = layouts["engineer"]
    assert indicated(engineer) == ["front.silent", "front.rate", "ego.silent", "ego.rate",
                                   "bus.front_radar.silent", "bus.front_radar.babbling",
                                   "bus.chassis.silent", "bus.chassis.babbling"]
    assert plotted(engineer) == {
        "/ego.speed", "/ego.steering_wheel_angle", "/perception/slots.count",
        '/health.families[:]{name=="slots"}.actual_hz',
        '/health.families[:]{name=="slots"}.expected_hz'}
    assert "RawMessages!lead" not in engineer["configById"], "no lead: no lead panel"
    assert engineer["configById"]["Plot!counts"]["foxglovePanelTitle"] == "Valid tracks"
    debug = layouts["can-debug"]
    raw = {p["topicPath"]: p["foxglovePanelTitle"] for p in panels(debug, "RawMessages").values()}
    assert {path for path in raw if "{" not in path} == {
        "/can/front_radar/frames", "/can/chassis/frames"}
    assert {path: title for path, title in raw.items() if "{" in path} == {
        "/can/chassis/frames.frames[:]{id==300}":
            "Raw frames of Chassis (id 300 = 0x12C; another id: edit the path)",
        "/can/front_radar/frames.frames[:]{id==1280}":
            "Raw frames of Trk_0 (id 1280 = 0x500; another id: edit the path)"}
    signals = {p["value"]: p["label"] for plot in panels(debug, "Plot").values()
               for p in plot["paths"] if p["value"].startswith("/can/")}
    assert signals == {
        "/can/chassis/Chassis.WheelSpd": "chassis: Chassis.WheelSpd (km/h)",
        "/can/chassis/Chassis.SteerWhl": "chassis: Chassis.SteerWhl (deg)",
        "/can/front_radar/Trk_0.TrkDist": "front_radar: Trk_0.TrkDist (m)",
        "/can/front_radar/Trk_0.TrkLat": "front_radar: Trk_0.TrkLat (m)"}
    bus_plots = [k for k in panels(debug, "Plot") if k.startswith("Plot!bus-")]
    assert len(bus_plots) == 6
    # Databases for every bus (no BUS=) are on can0, the bus of a log without channels.
    decoder, profile = load_stages([dbc.split("=", 1)[1] for dbc in dbcs], path)
    assert database_buses(decoder) == ["can0"]
    assert indicated(generate_layouts(profile, decoder)["can-debug"]) == [
        "bus.can0.silent", "bus.can0.babbling"]


def test_the_command_exports_the_layouts_of_a_profile(
        capsys: pytest.CaptureFixture[str], two_bus: tuple[Path, list[str]],
        tmp_path: Path) -> None:
    path, dbcs = two_bus
    out = tmp_path / "layouts"
    argv = ["layouts", "--profile", str(path), *(a for d in dbcs for a in ("--dbc", d)),
            "--export", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    for name in LAYOUT_NAMES:
        assert f"wrote {out / name}.json" in printed
        assert load_layout(out / f"{name}.json")["configById"]
    assert "Indicator!front.silent" in load_layout(out / "engineer.json")["configById"]
    # Nothing is overwritten without --force; one line names the files.
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "--force" in err[0]
    assert main([*argv, "--force", "engineer"]) == 0
    assert capsys.readouterr().out.startswith(f"wrote {out / 'engineer.json'}\n")
    # Without --export: what would be written, per layout.
    assert main(["layouts", "--profile", str(path), *(a for d in dbcs
                                                       for a in ("--dbc", d))]) == 0
    listing = capsys.readouterr().out
    assert re.search(r"^engineer\s+3D, 4 plots, Log, Publish, 8 Indicator panels$", listing, re.M)
    # A profile that does not exist is one line.
    assert main(["layouts", "--profile", str(tmp_path / "nope.toml"), "--export",
                 str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.toml" in err[0]
