"""The bundled Foxglove layouts: their format, and that every topic, frame and message path they
name is produced by the bundled profile (resolved against bridge.topics, Perception.topics() and
the protobuf descriptors, not against a copy of the list). They are what `tankviz layouts
--profile ecocar` makes (tests/test_layouts_generate.py checks that, and layouts made for other
profiles)."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bridge.apps.layouts import (
    bundled_layouts,
    export_layouts,
    format_listing,
    load_layout,
    select_layouts,
)
from bridge.decode.outcome import Undecoded
from bridge.errors import BridgeError, FileError, UsageError
from bridge.frame import Frame
from bridge.health.monitor import HealthMonitor
from bridge.pb.can_frame_pb2 import CanFrameBlock
from bridge.pb.perception_pb2 import EgoState, LeadVehicle, PerceivedObjects
from bridge.pipeline.drive import load_stages
from bridge.pipeline.perception import Perception
from bridge.resources import layouts_dir
from bridge.topics import (
    EGO_TOPIC,
    HEALTH_TOPIC,
    LEAD_TOPIC,
    LOG_TOPIC,
    VEHICLE_FRAME,
    frames_topic,
    message_topic,
    objects_topic,
    scene_topic,
)
from bridge.view.check import (
    LAYOUT_KEYS,
    check_format,
    check_layout,
    panel_type,
    referenced_topics,
)
from bridge.view.paths import resolve_path
from bridge.view.produced import Produced, produced

LAYOUTS = layouts_dir()
NAMES = ("tank-viz", "engineer", "can-debug", "bring-up")
PNG = b"\x89PNG\r\n\x1a\n"
#: The bus of `tankviz demo` and `tankviz simulate`.
BUS = "can0"
OK_GREEN, ALARM_RED = "#1e8e3e", "#d93025"


@pytest.fixture(scope="module")
def stages() -> tuple[Any, Any]:
    return load_stages([], "ecocar")


@pytest.fixture(scope="module")
def made(stages: tuple[Any, Any]) -> Produced:
    decoder, profile = stages
    return produced(decoder, profile, [BUS])


@pytest.fixture(scope="module")
def alarm_ids(stages: tuple[Any, Any]) -> list[str]:
    """Every alarm the health monitor checks for the bundled profile once the demo's bus has
    carried a frame (bus alarms appear with their bus)."""
    decoder, profile = stages
    monitor = HealthMonitor(profile, decoder)
    monitor.on_frame(Frame(0, BUS, 0x100, bytes(8)), Undecoded.UNKNOWN_ID)
    return monitor.alarm_ids()


def alarm_path(alarm: str) -> str:
    return f'{HEALTH_TOPIC}.alarms[:]{{id=="{alarm}"}}.active'


def check_indicators(data: dict[str, Any]) -> dict[str, str]:
    """The alarm of each Indicator panel, after checking that it is a green OK while the alarm
    is inactive and red with the alarm id while it is active."""
    out = {}
    for panel_id, config in panels(data, "Indicator").items():
        alarm = panel_id.split("!", 1)[1]
        assert config["path"] == alarm_path(alarm), panel_id
        assert config["foxglovePanelTitle"] == alarm
        assert config["style"] == "background"
        rules = {r["rawValue"]: r for r in config["rules"]}
        assert set(rules) == {"true", "false"} and len(config["rules"]) == 2
        assert all(r["operator"] == "=" for r in rules.values())
        assert (rules["true"]["label"], rules["true"]["color"]) == (alarm, ALARM_RED)
        assert (rules["false"]["label"], rules["false"]["color"]) == ("OK", OK_GREEN)
        assert config["fallbackLabel"] == "no data"
        assert config["fallbackColor"] not in (OK_GREEN, ALARM_RED), "no data is neither"
        out[panel_id] = alarm
    return out


def layout(name: str) -> dict[str, Any]:
    return load_layout(LAYOUTS / f"{name}.json")


def panels(data: dict[str, Any], kind: str) -> dict[str, dict[str, Any]]:
    return {k: v for k, v in data["configById"].items() if panel_type(k) == kind}


def test_the_bundled_layouts_with_their_previews() -> None:
    found = {b.name: b for b in bundled_layouts()}
    assert set(found) == set(NAMES)
    for b in found.values():
        assert b.path == LAYOUTS / f"{b.name}.json"
        assert b.preview == LAYOUTS / f"{b.name}.png", f"{b.name}: no preview picture"
        data = b.preview.read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, f"{b.preview}: not a screenshot"
    assert found["tank-viz"].summary == "2 3D panels, Publish"
    assert (found["engineer"].summary
            == "3D, 5 plots, Raw Messages, Log, Publish, 14 Indicator panels")
    assert (found["can-debug"].summary
            == "9 plots, 2 Indicator panels, 2 Raw Messages panels, Data Source Info")
    assert (found["bring-up"].summary
            == "Table, Image, 2 plots, Variable Slider, Raw Messages")


@pytest.mark.parametrize("name", NAMES)
def test_foxglove_layout_format(name: str) -> None:
    data = json.loads((LAYOUTS / f"{name}.json").read_text(encoding="utf-8"))
    assert list(data) == list(LAYOUT_KEYS) or set(data) == set(LAYOUT_KEYS)
    assert check_format(data) == []
    assert data["userNodes"] == {}
    # the bring-up layout's variables: the unknown id its plots follow, their words' first byte
    assert data["globalVariables"] == ({"unknown_id": "", "word": 0} if name == "bring-up"
                                       else {})
    assert data["playbackConfig"]["speed"] == 1
    for config in data["configById"].values():
        assert config.get("foxglovePanelTitle"), "every panel is titled"


@pytest.mark.parametrize("name", NAMES)
def test_everything_a_layout_names_is_produced(name: str, made: Produced) -> None:
    assert check_layout(layout(name), made) == []


def test_tank_viz_is_the_seed_view(stages: tuple[Any, Any], made: Produced) -> None:
    _, profile = stages
    chase, whole = layout("tank-viz")["configById"]["3D!tankviz"], layout("tank-viz")[
        "configById"]["3D!tankviz-range"]
    # The range view shows the same scene as the chase view, from farther, over a longer grid,
    # with the labels laid out for it.
    kept = ("cameraState", "layers", "foxglovePanelTitle", "topics")
    assert {k: v for k, v in whole.items() if k not in kept} == {
        k: v for k, v in chase.items() if k not in kept}
    assert set(whole["topics"]) ^ set(chase["topics"]) == {"/scene/labels/chase",
                                                          "/scene/labels/range"}
    assert whole["cameraState"]["distance"] > chase["cameraState"]["distance"]
    panel = chase
    assert panel["followTf"] == VEHICLE_FRAME and panel["followMode"] == "follow-pose"
    camera = panel["cameraState"]
    assert camera["perspective"] is True
    assert camera["thetaOffset"] == 90, "looking along +x (ahead)"
    assert 0 < camera["targetOffset"][0] < 50 and camera["targetOffset"][1:] == [0, 0]
    assert 30 <= camera["phi"] <= 75, "behind and above the vehicle"
    # Every scene topic the bridge produces is explicitly visible (the 3D panel hides
    # SceneUpdate topics unless told), and nothing else is listed.
    scene = {t for t, d in made.topics.items() if d.full_name == "foxglove.SceneUpdate"}
    assert {t for t, cls in Perception(profile).topics() if cls is SceneUpdate} <= scene
    assert all(t.startswith(scene_topic("")) for t in scene)
    assert scene >= {scene_topic(c) for c in ("ego", "lanes", "radar", "camera", "tracks",
                                              "lead", "mio")}
    assert set(panel["topics"]) == scene - {"/scene/labels/range"}
    assert all(panel["topics"][t]["visible"] is True for t in panel["topics"])
    # Every frame transform is visible.
    assert {f"frame:{f}" for f in made.frames} == set(panel["transforms"])
    assert all(t["visible"] is True for t in panel["transforms"].values())
    # The grid: 10 m cells, shifted 70 m ahead, in the vehicle frame.
    (grid,) = [g for g in panel["layers"].values() if g["layerId"] == "foxglove.Grid"]
    assert grid["visible"] is True and grid["frameId"] == VEHICLE_FRAME
    assert grid["size"] / grid["divisions"] == 10
    assert grid["position"] == [70, 0, 0]


def test_engineer_layout(made: Produced, alarm_ids: list[str]) -> None:
    data = layout("engineer")
    (view,) = panels(data, "3D").values()
    tank = layout("tank-viz")["configById"]["3D!tankviz"]
    assert view == tank, "the engineer's 3D view is the Tank Viz chase view"
    plotted = {p["value"] for plot in panels(data, "Plot").values() for p in plot["paths"]}
    assert {f"{LEAD_TOPIC}.object.x", f"{LEAD_TOPIC}.object.vx", f"{EGO_TOPIC}.speed",
            f"{EGO_TOPIC}.steering_wheel_angle"} <= plotted
    assert {f"{objects_topic(g)}.count" for g in ("radar", "camera", "tracks")} <= plotted
    assert f"{EGO_TOPIC}.yaw_rate" in plotted, "ecocar maps its yaw rate: it is plotted"
    lead = resolve_path(f"{LEAD_TOPIC}.object.x", made)
    assert lead.schema == LeadVehicle.DESCRIPTOR.full_name and lead.plottable
    assert resolve_path(f"{EGO_TOPIC}.speed", made).schema == EgoState.DESCRIPTOR.full_name
    assert (resolve_path(f"{objects_topic('radar')}.count", made).schema
            == PerceivedObjects.DESCRIPTOR.full_name)
    (raw,) = panels(data, "RawMessages").values()
    assert raw["topicPath"] == LEAD_TOPIC
    # Health: one Indicator per alarm the monitor checks, the family rates, the alarm log.
    shown = check_indicators(data)
    assert sorted(shown.values()) == sorted(alarm_ids)
    assert len(alarm_ids) == 14 and "radar.silent" in alarm_ids
    rates = [p["value"] for p in data["configById"]["Plot!rates"]["paths"]]
    assert rates == [f'{HEALTH_TOPIC}.families[:]{{name=="{family}"}}.{rate}'
                     for family in ("radar", "camera", "tracks")
                     for rate in ("actual_hz", "expected_hz")]
    for path in rates:
        resolved = resolve_path(path, made)
        assert resolved.plottable and not resolved.several
    (log,) = panels(data, "RosOut").values()
    assert log["topicToRender"] == LOG_TOPIC
    assert made.topics[LOG_TOPIC].full_name == "foxglove.Log"


def test_can_debug_layout(made: Produced) -> None:
    data = layout("can-debug")
    raw, one_id = panels(data, "RawMessages").values()
    assert raw["topicPath"] == frames_topic(BUS)
    # one id's frames, found in the blocks with a filter (the ego's first message: EgoMotion)
    assert one_id["topicPath"] == f"{frames_topic(BUS)}.frames[:]{{id==256}}"
    assert "EgoMotion" in one_id["foxglovePanelTitle"]
    resolved = resolve_path(one_id["topicPath"], made)
    assert resolved.schema == CanFrameBlock.DESCRIPTOR.full_name
    assert panels(data, "SourceInfo"), "topics with message counts and rates"
    plots = panels(data, "Plot")
    signals = [p["value"] for plot_id, plot in plots.items() for p in plot["paths"]
               if not plot_id.startswith("Plot!bus-")]
    assert len(signals) >= 8
    for path in signals:
        resolved = resolve_path(path, made)
        assert resolved.topic.startswith(f"/can/{BUS}/") and resolved.plottable
        assert resolved.schema.startswith("tankviz.dbc.ecocar.")
    assert f"{message_topic(BUS, 'EgoMotion')}.VehicleSpeed" in signals
    # The signals the profile reads: ego, the first object of each group, lanes, lead.
    assert {f"{message_topic(BUS, 'RadarObj0_A')}.LongDist",
            f"{message_topic(BUS, 'CamLaneLeft')}.C0_Offset",
            f"{message_topic(BUS, 'LeadVehicle')}.PosX"} <= set(signals)
    # The bus's health from /health: frames/s, load, error frames, unknown ids, decode errors.
    bus = [p["value"] for plot_id, plot in plots.items() for p in plot["paths"]
           if plot_id.startswith("Plot!bus-")]
    assert bus == [f'{HEALTH_TOPIC}.buses[:]{{bus=="{BUS}"}}.{figure}'
                   for figure in ("frames_per_s", "load", "error_frames", "unknown_ids",
                                  "decode_errors")]
    for path in bus:
        resolved = resolve_path(path, made)
        assert resolved.plottable and not resolved.several
    assert sorted(check_indicators(data).values()) == [f"bus.{BUS}.babbling", f"bus.{BUS}.silent"]
    assert referenced_topics(data, made) >= {frames_topic(BUS), HEALTH_TOPIC}


def test_the_health_sample_is_what_the_monitor_reports(made: Produced,
                                                       alarm_ids: list[str]) -> None:
    """The checker knows /health's buses, families and alarms from the pipeline's own health
    monitor: the same alarms as a monitor of the bundled profile on the demo's bus."""
    health = made.samples[HEALTH_TOPIC]
    assert [a.id for a in health.alarms] == alarm_ids
    assert [b.bus for b in health.buses] == [BUS]
    assert {f.name for f in health.families} >= {"radar", "camera", "tracks"}
    assert [b.pair for b in health.biases] == ["radar-camera"]


def test_filters_in_message_paths(made: Produced, stages: tuple[Any, Any]) -> None:
    silent = resolve_path(alarm_path("radar.silent"), made)
    assert silent.leaf.full_name == "tankviz.Alarm.active" and silent.plottable
    assert not silent.several, "ids are unique: one value"
    assert resolve_path(f"{HEALTH_TOPIC}.alarms[:].active", made).several
    assert not resolve_path(f"{HEALTH_TOPIC}.alarms[0].active", made).several
    assert resolve_path(f"{HEALTH_TOPIC}.alarms[1:3].active", made).several
    # Quoted values may hold dots, brackets and braces; single quotes work too.
    assert not resolve_path(f"{HEALTH_TOPIC}.alarms[:]{{id=='lanes.lost'}}.active",
                            made).several
    # State fields (not known in advance) and layout variables are not checked by value.
    assert resolve_path(f"{HEALTH_TOPIC}.alarms[:]{{active==true}}.id", made).leaf.type == 9
    assert resolve_path(f"{HEALTH_TOPIC}.alarms[:]{{id==$alarm}}.active", made).plottable
    assert resolve_path(f"{objects_topic('radar')}.objects[:]{{id==3}}.x", made).plottable
    for path, message in [
        (alarm_path("radar.silnet"), 'no /health.alarms has id == "radar.silnet"; id: '),
        (alarm_path(f"bus.{BUS}x.silent"), f'has id == "bus.{BUS}x.silent"'),
        (f"{HEALTH_TOPIC}.alarms[99].active", "/health.alarms has no element 99"),
        (f'{HEALTH_TOPIC}.alarms[:]{{id=="radar.silent"}}.activ',
         "tankviz.Alarm has no field 'activ'"),
        (f'{HEALTH_TOPIC}.alarms[:]{{ids=="radar.silent"}}.active',
         "the filter on /health.alarms names no field 'ids'"),
        (f"{HEALTH_TOPIC}.alarms[:]{{id==3}}.active", "id is a string field: quote the value"),
        (f'{HEALTH_TOPIC}.alarms[:]{{active=="yes"}}.id', "active is a boolean field"),
        (f'{HEALTH_TOPIC}.buses[:]{{frames_per_s=="x"}}.load', "a number field"),
        (f'{HEALTH_TOPIC}.families[:]{{name=="lidar"}}.actual_hz',
         'no /health.families has name == "lidar"; name: camera, ego, lanes, lead, radar, '
         "tracks"),
        (f'{HEALTH_TOPIC}.alarms[:]{{id=="radar.silent".active', "unbalanced"),
        (f"{HEALTH_TOPIC}.alarms[:][0].active", "indexed twice"),
    ]:
        with pytest.raises(BridgeError, match=re.escape(message)):
            resolve_path(path, made)
    # Another bus has its own alarms.
    decoder, profile = stages
    two = produced(decoder, profile, [BUS, "can1"])
    assert not resolve_path(alarm_path("bus.can1.babbling"), two).several
    with pytest.raises(BridgeError, match=re.escape('has id == "bus.can1.babbling"')):
        resolve_path(alarm_path("bus.can1.babbling"), made)


def test_the_check_names_wrong_alarms_and_panels(made: Produced) -> None:
    """A misspelt alarm id, one the monitor does not check (another bus), a misspelt field, a
    path with several values, rules that never match and a Log panel on the wrong topic."""
    broken = layout("engineer")
    configs = broken["configById"]
    configs["Indicator!radar.silent"]["path"] = alarm_path("radar.silnet")
    configs["Indicator!radar.rate"]["path"] = alarm_path("bus.can1.silent")
    configs["Indicator!radar.blind"]["path"] = alarm_path("radar.blind").replace(
        ".active", ".activ")
    configs["Indicator!camera.silent"]["path"] = f"{HEALTH_TOPIC}.alarms[:].active"
    configs["Indicator!camera.rate"]["path"] = f"{HEALTH_TOPIC}.alarms[:]{{id==\"camera.rate\"}}"
    rules = configs["Indicator!lanes.lost"]["rules"]
    rules[0]["rawValue"] = "yes"
    rules[1]["operator"] = "=="
    rules[1]["color"] = "green"
    configs["Indicator!ego.rate"]["style"] = "lamp"
    del configs["Indicator!ego.silent"]["path"]
    configs["RosOut!alarms"]["topicToRender"] = HEALTH_TOPIC
    configs["Plot!rates"]["paths"][0]["value"] = (
        f'{HEALTH_TOPIC}.families[:]{{name=="raddar"}}.actual_hz')
    problems = check_layout(broken, made)
    text = "\n".join(problems)
    assert 'Indicator!radar.silent.path: /health.alarms[:]{id=="radar.silnet"}.active: no ' in text
    assert 'no /health.alarms has id == "bus.can1.silent"' in text
    assert "tankviz.Alarm has no field 'activ'" in text
    assert ("Indicator!camera.silent.path: /health.alarms[:].active can give several values; "
            "the Indicator panel shows one") in text
    assert "Indicator!camera.rate.path: " in text and "is a message: nothing to show" in text
    assert ("Indicator!lanes.lost.rules[0].rawValue: never matches tankviz.Alarm.active: "
            "'yes' is not true or false") in text
    assert "Indicator!lanes.lost.rules[1].operator: '=='; one of =, <, <=, >, >=" in text
    assert "Indicator!lanes.lost.rules[1].color: 'green' is not a colour" in text
    assert "Indicator!ego.rate.style: 'lamp'; one of bulb, background" in text
    assert "Indicator!ego.silent.path: missing" in text
    assert ("RosOut!alarms.topicToRender: /health is tankviz.Health; the Log panel shows "
            "foxglove.Log") in text
    assert 'no /health.families has name == "raddar"' in text
    assert len(problems) == 12, text
    # Every bundled Indicator rule is checked against the field it reads.
    fine = layout("engineer")
    fine["configById"]["Indicator!radar.silent"]["rules"][0]["rawValue"] = "1"
    assert check_layout(fine, made) == [
        "Indicator!radar.silent.rules[0].rawValue: never matches tankviz.Alarm.active: '1' is "
        "not true or false"]


def test_the_check_names_what_is_wrong(made: Produced) -> None:
    data = layout("engineer")
    broken = copy.deepcopy(data)
    plot = broken["configById"]["Plot!lead"]
    plot["paths"][0]["value"] = f"{LEAD_TOPIC}.object.distanc"
    plot["paths"][1]["value"] = f"{LEAD_TOPIC}.object"  # a message: nothing to plot
    plot["paths"].append({"value": "/perception/radar.objects.x", "enabled": True})
    plot["paths"].append({"value": "/perception/lidar.count", "enabled": True})
    view = broken["configById"]["3D!engineer"]
    view["topics"]["/scene/lidar"] = {"visible": True}
    view["topics"][EGO_TOPIC] = {"visible": True}
    view["transforms"]["frame:base_link"] = {"visible": True}
    view["followTf"] = "map"
    problems = check_layout(broken, made)
    text = "\n".join(problems)
    assert "tankviz.PerceivedObject has no field 'distanc'" in text
    assert "/perception/lead.object is a message: nothing to plot" in text
    assert "/perception/radar.objects is repeated" in text
    assert "/perception/lidar.count: no such topic" in text
    assert "topics./scene/lidar: no such topic" in text
    assert "tankviz.EgoState is not drawn by the 3D panel" in text
    assert "no frame 'base_link'" in text and "followTf: no frame 'map'" in text
    assert len(problems) == 8


def test_the_format_check() -> None:
    data = layout("tank-viz")
    assert check_format([]) == ["expected a JSON object"]
    missing = {k: v for k, v in data.items() if k != "userNodes"}
    assert check_format(missing) == ["missing keys: userNodes"]
    orphan = copy.deepcopy(data)
    orphan["layout"] = {"direction": "row", "first": "3D!tankviz", "second": "Plot!gone"}
    assert "layout: panel 'Plot!gone' has no entry in configById" in check_format(orphan)
    unplaced = copy.deepcopy(data)
    unplaced["configById"]["Plot!x"] = {}
    assert check_format(unplaced) == ["configById.Plot!x: not placed in the layout"]
    unknown = copy.deepcopy(data)
    unknown["configById"] = {"Nope!x": {}}
    unknown["layout"] = "Nope!x"
    assert "unknown panel type 'Nope'" in check_format(unknown)[0]


def test_load_layout_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{", encoding="utf-8")
    with pytest.raises(FileError, match=r"bad.json: not JSON: line 1"):
        load_layout(bad)
    with pytest.raises(BridgeError, match="no such file"):
        load_layout(tmp_path / "none.json")
    bad.write_text("{}", encoding="utf-8")
    with pytest.raises(BridgeError, match="missing keys: configById, layout"):
        load_layout(bad)


def test_export(tmp_path: Path) -> None:
    out = tmp_path / "exported"
    written = export_layouts(out)
    assert sorted(p.name for p in written) == sorted(f"{n}.json" for n in NAMES)
    for path in written:
        assert path.read_bytes() == (LAYOUTS / path.name).read_bytes()
    with pytest.raises(BridgeError, match="exists"):
        export_layouts(out)
    assert export_layouts(out, names=["tank-viz"], force=True) == [out / "tank-viz.json"]
    with pytest.raises(UsageError, match=r"^'nope': no such bundled layout; bundled: bring-up"):
        export_layouts(out, names=["nope"])
    blocker = tmp_path / "file"
    blocker.write_text("", encoding="utf-8")
    with pytest.raises(FileError, match="file: not a folder"):
        export_layouts(blocker)


def test_listing() -> None:
    lines = format_listing(select_layouts()).splitlines()
    assert [line.split()[0] for line in lines] == sorted(NAMES)
    assert len({line.index(str(LAYOUTS)) for line in lines}) == 1, "aligned columns"
    assert [b.name for b in select_layouts(["tank-viz", "engineer"])] == ["tank-viz", "engineer"]
    with pytest.raises(UsageError, match=r"^'x': no such bundled layout"):
        select_layouts(["x"])


@pytest.mark.parametrize("name, views", [("tank-viz", ["3D!tankviz", "3D!tankviz-range"]),
                                         ("engineer", ["3D!engineer"])])
def test_a_click_on_the_mark_button_marks_and_every_3d_view_shows_marks(
        name: str, views: list[str], made: Produced) -> None:
    """The Publish panel sends its template to /marks as it is, a JSON object of
    tankviz.Mark's fields; the 3D views show /scene/marks (the mark's text for a few seconds)."""
    data = layout(name)
    mark = data["configById"]["Publish!mark"]
    assert mark["topicName"] == "/marks" and mark["datatype"] == "tankviz.Mark"
    assert json.loads(mark["value"]) == {"text": "mark", "category": ""}
    assert mark["buttonText"] == "Mark" and mark["advancedView"] is False
    for view in views:
        assert data["configById"][view]["topics"]["/scene/marks"] == {"visible": True}


@pytest.mark.parametrize("edit, problem", [
    ({"topicName": "/cmd_vel"}, "Publish!mark.topicName: '/cmd_vel': a viewer may publish to "
                                "/marks only"),
    ({"value": "{text: mark}"}, "Publish!mark.value: not JSON"),
    ({"value": '{"words": "x"}'}, "Publish!mark.value: expected an object of tankviz.Mark's "
                                  "fields"),
])
def test_a_publish_panel_that_cannot_mark_is_named(edit: dict[str, str], problem: str,
                                                   made: Produced) -> None:
    data = copy.deepcopy(layout("engineer"))
    data["configById"]["Publish!mark"].update(edit)
    (found,) = check_layout(data, made)
    assert found.startswith(problem), found
