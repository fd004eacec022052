"""The bundled Foxglove layouts: their format, and that every topic, frame and message path they
name is produced by the bundled profile (resolved against bridge.topics, Perception.topics() and
the protobuf descriptors, not against a copy of the list)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from bridge.convert import build_stages
from bridge.errors import BridgeError
from bridge.layouts import (
    LAYOUT_KEYS,
    Produced,
    bundled_layouts,
    check_format,
    check_layout,
    export_layouts,
    format_listing,
    load_layout,
    panel_type,
    produced,
    referenced_topics,
    resolve_path,
    select_layouts,
)
from bridge.pb.perception_pb2 import EgoState, LeadVehicle, PerceivedObjects
from bridge.perception import Perception
from bridge.resources import layouts_dir
from bridge.topics import (
    EGO_TOPIC,
    LEAD_TOPIC,
    VEHICLE_FRAME,
    frames_topic,
    message_topic,
    objects_topic,
    scene_topic,
)

LAYOUTS = layouts_dir()
NAMES = ("tank-viz", "engineer", "can-debug")
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def stages() -> tuple[Any, Any]:
    return build_stages([], "ecocar")


@pytest.fixture(scope="module")
def made(stages: tuple[Any, Any]) -> Produced:
    decoder, profile = stages
    return produced(decoder, profile, ["can0"])  # the bus of tankviz demo and simulate


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
    assert found["tank-viz"].summary == "3D"
    assert found["engineer"].summary == "3D, 3 plots, Raw Messages"


@pytest.mark.parametrize("name", NAMES)
def test_foxglove_layout_format(name: str) -> None:
    data = json.loads((LAYOUTS / f"{name}.json").read_text(encoding="utf-8"))
    assert list(data) == list(LAYOUT_KEYS) or set(data) == set(LAYOUT_KEYS)
    assert check_format(data) == []
    assert data["userNodes"] == {} and data["globalVariables"] == {}
    assert data["playbackConfig"]["speed"] == 1
    for config in data["configById"].values():
        assert config.get("foxglovePanelTitle"), "every panel is titled"


@pytest.mark.parametrize("name", NAMES)
def test_everything_a_layout_names_is_produced(name: str, made: Produced) -> None:
    assert check_layout(layout(name), made) == []


def test_tank_viz_is_the_seed_view(stages: tuple[Any, Any], made: Produced) -> None:
    _, profile = stages
    (panel,) = panels(layout("tank-viz"), "3D").values()
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
    assert set(panel["topics"]) == scene
    assert all(panel["topics"][t]["visible"] is True for t in scene)
    # Every frame transform is visible.
    assert {f"frame:{f}" for f in made.frames} == set(panel["transforms"])
    assert all(t["visible"] is True for t in panel["transforms"].values())
    # The grid: 10 m cells, shifted 70 m ahead, in the vehicle frame.
    (grid,) = [g for g in panel["layers"].values() if g["layerId"] == "foxglove.Grid"]
    assert grid["visible"] is True and grid["frameId"] == VEHICLE_FRAME
    assert grid["size"] / grid["divisions"] == 10
    assert grid["position"] == [70, 0, 0]


def test_engineer_layout(made: Produced) -> None:
    data = layout("engineer")
    (view,) = panels(data, "3D").values()
    (tank,) = panels(layout("tank-viz"), "3D").values()
    assert view == tank, "the engineer's 3D view is the Tank Viz view"
    plotted = {p["value"] for plot in panels(data, "Plot").values() for p in plot["paths"]}
    assert {f"{LEAD_TOPIC}.object.x", f"{LEAD_TOPIC}.object.vx", f"{EGO_TOPIC}.speed",
            f"{EGO_TOPIC}.steering_wheel_angle"} <= plotted
    assert {f"{objects_topic(g)}.count" for g in ("radar", "camera", "tracks")} <= plotted
    lead = resolve_path(f"{LEAD_TOPIC}.object.x", made)
    assert lead.schema == LeadVehicle.DESCRIPTOR.full_name and lead.plottable
    assert resolve_path(f"{EGO_TOPIC}.speed", made).schema == EgoState.DESCRIPTOR.full_name
    assert (resolve_path(f"{objects_topic('radar')}.count", made).schema
            == PerceivedObjects.DESCRIPTOR.full_name)
    (raw,) = panels(data, "RawMessages").values()
    assert raw["topicPath"] == LEAD_TOPIC


def test_can_debug_layout(made: Produced) -> None:
    data = layout("can-debug")
    (raw,) = panels(data, "RawMessages").values()
    assert raw["topicPath"] == frames_topic("can0")
    assert panels(data, "SourceInfo"), "topics with message counts and rates"
    plotted = [p["value"] for plot in panels(data, "Plot").values() for p in plot["paths"]]
    assert len(plotted) >= 8
    for path in plotted:
        resolved = resolve_path(path, made)
        assert resolved.topic.startswith("/can/can0/") and resolved.plottable
        assert resolved.schema.startswith("tankviz.dbc.ecocar.")
    assert f"{message_topic('can0', 'EgoMotion')}.VehicleSpeed" in plotted
    assert referenced_topics(data, made) >= {frames_topic("can0")}


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
    with pytest.raises(BridgeError, match=r"bad.json: not JSON: line 1"):
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
    with pytest.raises(BridgeError, match=r"no bundled layout 'nope'; bundled: can-debug"):
        export_layouts(out, names=["nope"])
    blocker = tmp_path / "file"
    blocker.write_text("", encoding="utf-8")
    with pytest.raises(BridgeError, match="not a folder"):
        export_layouts(blocker)


def test_listing() -> None:
    lines = format_listing(select_layouts()).splitlines()
    assert [line.split()[0] for line in lines] == sorted(NAMES)
    assert len({line.index(str(LAYOUTS)) for line in lines}) == 1, "aligned columns"
    assert [b.name for b in select_layouts(["tank-viz", "engineer"])] == ["tank-viz", "engineer"]
    with pytest.raises(BridgeError, match="no bundled layout 'x'"):
        select_layouts(["x"])
