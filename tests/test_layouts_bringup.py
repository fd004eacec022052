"""The bring-up layout (`tankviz layouts --dbc ... [--bus NAME] [--plot BUS/ID] --export DIR`,
bridge.view.bringup): made from databases alone (a car in bring-up has no profile) and beside the
layouts made for a profile, for a car that is not ecocar (opendbc's Toyota DBCs in ../shared);
its panels and message paths, checked against what the bridge produces (the bring-up topics),
what the layout checks say of a wrong one, and the line live and replay print when a bus carries
ids no database knows (bridge.apps.hints.BringupHint)."""

from __future__ import annotations

import json
import shlex
import threading
import time
from pathlib import Path
from typing import Any

import can
import pytest
from conftest import SHARED_DBC, SHARED_DBC_ORIGIN, timeout_scale
from waiting import wait_for

from bridge.apps.hints import BringupHint, bringup_command
from bridge.apps.layouts import load_layout
from bridge.cli import main
from bridge.pipeline.drive import load_stages
from bridge.resources import data_dir, layouts_dir
from bridge.topics import BITS_LABELS_TOPIC, BITS_TOPIC, ids_topic, unknown_topic
from bridge.view.bringup import bringup_layout
from bridge.view.check import check_layout, panel_type
from bridge.view.panels import layout_text
from bridge.view.paths import resolve_path
from bridge.view.produced import produced

PROFILES = Path(__file__).parent / "profiles"
TOYOTA_PT = "toyota_2017_pt.dbc"
#: The panels of a bring-up layout of one bus (can0).
PANELS = {"Table!ids-can0", "ImageViewPanel!bits", "Plot!unknown-bytes", "Plot!unknown-words",
          "GlobalVariableSliderPanel!word", "RawMessages!unknown"}


pytestmark = pytest.mark.usefixtures("restore_stop_signals")


@pytest.fixture
def toyota() -> Path:
    if not (SHARED_DBC / TOYOTA_PT).is_file():
        pytest.skip(f"public DBCs not found at {SHARED_DBC}: {SHARED_DBC_ORIGIN}")
    return SHARED_DBC / TOYOTA_PT


def configs(data: dict[str, Any], kind: str) -> dict[str, dict[str, Any]]:
    return {k: v for k, v in data["configById"].items() if panel_type(k) == kind}


def test_the_bring_up_layout_of_databases_alone(
        toyota: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--dbc PATH` (for every bus: can0) without a profile writes bring-up.json alone: a table
    of can0's ids, the bit map (its labels in its pixels), the plots of the id in the variable
    unknown_id (empty: none chosen yet) and its latest frame; every path is what the bridge
    produces."""
    out = tmp_path / "layouts"
    assert main(["layouts", "--dbc", str(toyota), "--export", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed == [f"wrote {out / 'bring-up.json'}",
                       "made for bus can0; import in Foxglove: Layouts menu > Import layout"]
    assert sorted(p.name for p in out.iterdir()) == ["bring-up.json"]
    data = load_layout(out / "bring-up.json")
    assert set(data["configById"]) == PANELS
    assert data["globalVariables"] == {"unknown_id": "", "word": 0}
    assert data["configById"]["Table!ids-can0"]["topicPath"] == "/can/can0/ids.rows"
    image = data["configById"]["ImageViewPanel!bits"]
    # the map's labels are in its pixels: the annotations (the same texts) stay off
    assert (image["cameraTopic"], image["enabledMarkerTopics"]) == (BITS_TOPIC, [])
    assert [p["value"] for p in data["configById"]["Plot!unknown-bytes"]["paths"]] == [
        f"/can/can0/unknown{{id==$unknown_id}}.bytes[{i}]" for i in range(8)]
    assert [p["value"] for p in data["configById"]["Plot!unknown-words"]["paths"]] == [
        "/can/can0/unknown{id==$unknown_id}.be16[$word]",
        "/can/can0/unknown{id==$unknown_id}.le16[$word]"]
    assert (data["configById"]["RawMessages!unknown"]["topicPath"]
            == "/can/can0/unknown{id==$unknown_id}")
    assert data["configById"]["GlobalVariableSliderPanel!word"]["globalVariableName"] == "word"
    decoder, _ = load_stages([str(toyota)], None)
    assert check_layout(data, produced(decoder, None, ["can0"])) == []
    # Without --export: what it would write; a layout made for a profile is not made here.
    assert main(["layouts", "--dbc", str(toyota)]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "bring-up  Table, Image, 2 plots, Variable Slider, Raw Messages",
        "made for bus can0; --export DIR writes it"]
    assert main(["layouts", "--dbc", str(toyota), "tank-viz"]) == 1
    assert ("'tank-viz': no such layout; made without a profile: bring-up (--profile makes "
            "the others)") in capsys.readouterr().err


def test_buses_and_the_plotted_id(toyota: Path, tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """`--bus` names the layout's buses (a table each), `--plot BUS/ID` the unknown id its plots
    follow at first (hex or decimal, written as the bring-up topics write it; its bus is added);
    a 29-bit id keeps its eight digits."""
    out = tmp_path / "layouts"
    assert main(["layouts", "--dbc", f"can0={toyota}", "--bus", "can0", "--bus", "chassis",
                 "--plot", "radar/708", "--export", str(out)]) == 0
    assert "made for buses can0, chassis;" in capsys.readouterr().out
    data = load_layout(out / "bring-up.json")
    assert list(configs(data, "Table")) == ["Table!ids-can0", "Table!ids-chassis",
                                            "Table!ids-radar"]
    assert data["globalVariables"]["unknown_id"] == "0x2C4"
    assert all(p["value"].startswith("/can/radar/unknown{id==$unknown_id}.")
               for plot in configs(data, "Plot").values() for p in plot["paths"])
    decoder, _ = load_stages([f"can0={toyota}"], None)
    assert check_layout(data, produced(decoder, None, ["can0", "chassis", "radar"])) == []
    # No databases at all: the plotted id's bus.
    assert main(["layouts", "--plot", "can1/0x18FEF100", "--export", str(out), "--force"]) == 0
    data = load_layout(out / "bring-up.json")
    assert list(configs(data, "Table")) == ["Table!ids-can1"]
    assert data["globalVariables"]["unknown_id"] == "0x18FEF100"
    capsys.readouterr()
    assert main(["layouts", "--plot", "can0", "--export", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--plot can0: expected BUS/ID" in err[0]


def test_the_bring_up_layout_beside_those_of_a_profile(
        toyota: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """With --profile, bring-up.json is written beside the profile's layouts, for the buses of
    the profile's databases (the RAV4: can0 and can1)."""
    out = tmp_path / "layouts"
    profile = PROFILES / "rav4.toml"
    assert main(["layouts", "--profile", str(profile), "--plot", "can1/0x2E0", "--export",
                 str(out)]) == 0
    assert f"wrote {out / 'bring-up.json'}" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [
        "bring-up.json", "can-debug.json", "engineer.json", "tank-viz.json"]
    data = load_layout(out / "bring-up.json")
    assert list(configs(data, "Table")) == ["Table!ids-can0", "Table!ids-can1"]
    assert data["globalVariables"]["unknown_id"] == "0x2E0"
    assert (data["configById"]["RawMessages!unknown"]["topicPath"]
            == "/can/can1/unknown{id==$unknown_id}")
    decoder, loaded = load_stages([], profile)
    assert check_layout(data, produced(decoder, loaded, ["can0", "can1"])) == []
    # It depends on the buses only: the same as made without the profile.
    assert data == bringup_layout(["can0", "can1"], ("can1", "0x2E0"))


def test_the_bundled_bring_up_layout_is_for_can0() -> None:
    data = load_layout(layouts_dir() / "bring-up.json")
    assert data == bringup_layout(["can0"])
    decoder, profile = load_stages([], "ecocar")
    assert check_layout(data, produced(decoder, profile, ["can0"])) == []


def test_the_checks_name_what_is_wrong_in_a_bring_up_layout(toyota: Path) -> None:
    decoder, _ = load_stages([str(toyota)], None)
    made = produced(decoder, None, ["can0"])
    assert {ids_topic("can0"), unknown_topic("can0"), BITS_TOPIC, BITS_LABELS_TOPIC} <= set(
        made.topics)
    # Message paths with a filter on the topic's message itself, and layout variables.
    byte = resolve_path('/can/can0/unknown{id=="0x2C4"}.bytes[3]', made)
    assert byte.plottable and byte.schema == "tankviz.CanPayload"
    assert resolve_path("/can/can0/unknown{id==$unknown_id}.be16[$word]", made).plottable
    assert resolve_path("/can/can0/ids.rows", made, lists=True).several
    data = bringup_layout(["can0"])
    panels = data["configById"]
    panels["Plot!unknown-bytes"]["paths"][0]["value"] = "/can/can0/unknown{id==$nope}.bytes[0]"
    panels["Plot!unknown-bytes"]["paths"][1]["value"] = "/can/can0/unknown{id==708}.bytes[1]"
    panels["Plot!unknown-bytes"]["paths"][2]["value"] = "/can/can0/unknown.bytes"
    panels["ImageViewPanel!bits"]["cameraTopic"] = ids_topic("can0")
    panels["ImageViewPanel!bits"]["enabledMarkerTopics"] = [BITS_TOPIC, "/can/nope"]
    panels["GlobalVariableSliderPanel!word"]["globalVariableName"] = "byte"
    panels["Table!ids-can0"]["topicPath"] = "/can/can0/ids.roes"
    problems = check_layout(data, made)
    expected = [
        "Table!ids-can0.topicPath: /can/can0/ids.roes: tankviz.CanIds has no field 'roes'",
        "ImageViewPanel!bits.cameraTopic: /can/can0/ids is tankviz.CanIds, not an image",
        "ImageViewPanel!bits.enabledMarkerTopics: /can/bits is foxglove.CompressedImage, not "
        "foxglove.ImageAnnotations",
        "ImageViewPanel!bits.enabledMarkerTopics: no such topic /can/nope",
        "Plot!unknown-bytes.paths[0]: /can/can0/unknown{id==$nope}.bytes[0]: $nope is not one "
        "of the layout's globalVariables",
        "Plot!unknown-bytes.paths[1]: /can/can0/unknown{id==708}.bytes[1]: the filter on "
        "/can/can0/unknown: id is a string field: quote the value",
        "Plot!unknown-bytes.paths[2]: /can/can0/unknown.bytes: /can/can0/unknown.bytes is "
        "repeated: index it",
        "GlobalVariableSliderPanel!word.globalVariableName: 'byte' is not one of the layout's "
        "globalVariables",
    ]
    for text in expected:
        assert any(p.startswith(text) for p in problems), (text, problems)
    assert len(problems) == len(expected), problems


# --- the line live and replay say ----------------------------------------------------------------


def test_the_bring_up_line_names_the_layout_or_the_command_that_writes_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)

    def make(buses: Any) -> str:
        return layout_text(bringup_layout(buses))

    folder = tmp_path / "drives" / "layouts"
    hint = BringupHint(folder, ["can0", "can1"], make)
    hint.tell("can0", 0x2C4)
    hint.tell("can0", 0x3B7)  # said once a bus
    command = bringup_command(["can0", "can1"], ("can0", "0x2C4"), folder)
    assert command == shlex.join(["tankviz", "layouts", "--bus", "can0", "--bus", "can1",
                                  "--plot", "can0/0x2C4", "--export", str(folder)])
    assert capsys.readouterr().out.splitlines() == [
        f"bring-up: can0 carries ids no database knows (first 0x2C4): import "
        f"{folder / 'bring-up.json'} (Layouts menu) once {command} writes it"]
    # The printed command writes it, its plots on that id.
    assert main(shlex.split(command)[1:]) == 0
    capsys.readouterr()
    assert load_layout(folder / "bring-up.json")["globalVariables"]["unknown_id"] == "0x2C4"
    # There: named, and the variable to set (whatever id it holds, it is the layout made now).
    hint.tell("can1", 0x18FEF100 | 1 << 31)
    assert capsys.readouterr().out.splitlines() == [
        f"bring-up: can1 carries ids no database knows (first 0x18FEF100): import "
        f'{folder / "bring-up.json"} (Layouts menu), then set its variable unknown_id to '
        f'"0x18FEF100" (Variables)']
    # A file of that name that is another layout: the command that replaces it.
    other = BringupHint(folder, ["can0"], make)
    other.tell("can0", 0x2C4)
    assert capsys.readouterr().out.endswith(
        f"{bringup_command(['can0'], ('can0', '0x2C4'), folder)} --force replaces it\n")
    # The bundled one, for the bundled profile on can0 alone.
    bundled = BringupHint(folder, ["can0"], make, bundled=layouts_dir() / "bring-up.json")
    bundled.tell("can0", 0x7A1)
    assert f"import {layouts_dir() / 'bring-up.json'} (Layouts menu), then set" in (
        capsys.readouterr().out)


def highway_log(path: Path, seconds: float = 3.0) -> Path:
    assert main(["simulate", "--car", "highway", "-o", str(path), "--duration", str(seconds),
                 "--force"]) == 0
    return path


@pytest.mark.slow
def test_replay_of_a_log_says_which_ids_no_database_knows(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The highway car's log with its databases and no profile: one line per bus with ids no
    database knows (its first one), and the command it names writes the layout for its buses,
    plotting that id."""
    monkeypatch.chdir(tmp_path)
    log = highway_log(tmp_path / "highway.blf")
    capsys.readouterr()
    assert main(["replay", str(log), "--dbc", "can0=highway_car", "--dbc", "can1=highway_radar",
                 "--port", "0", "--speed", "20"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines()
             if line.startswith("bring-up: ")]
    folder = Path("bring-up-layouts")
    command = bringup_command(["can0", "can1"], ("can0", "0x2C4"), folder)
    assert lines == [
        f"bring-up: can0 carries ids no database knows (first 0x2C4): import "
        f"{folder / 'bring-up.json'} (Layouts menu) once {command} writes it",
        f"bring-up: can1 carries ids no database knows (first 0x2E0): import "
        f"{folder / 'bring-up.json'} (Layouts menu) once "
        f"{bringup_command(['can0', 'can1'], ('can1', '0x2E0'), folder)} writes it"]
    assert main(shlex.split(command)[1:]) == 0
    data = json.loads((folder / "bring-up.json").read_text(encoding="utf-8"))
    assert data == bringup_layout(["can0", "can1"], ("can0", "0x2C4"))
    # Every database knows every id of the ecocar's sample: nothing said.
    capsys.readouterr()
    assert main(["replay", str(data_dir() / "ecocar_sample.blf"),
                 "--profile", "ecocar", "--port", "0", "--speed", "50"]) == 0
    assert "bring-up:" not in capsys.readouterr().out


@pytest.mark.slow
def test_live_recording_without_a_profile_writes_the_bring_up_layout_and_names_it(
        toyota: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`tankviz live --dbc ...` recording: DRIVES/layouts/bring-up.json is written at start
    (for live's buses) and named, with the id to set, when the first unknown id comes."""
    channel = f"bring-up-{time.monotonic_ns()}"
    drives = tmp_path / "drives"
    layout = drives / "layouts" / "bring-up.json"

    def send() -> None:  # once live reads the bus (it wrote the layouts after opening it)
        wait_for(layout.exists, 20 * timeout_scale())
        with can.Bus(interface="virtual", channel=channel) as bus:
            for _ in range(5):
                bus.send(can.Message(arbitration_id=0x7A1, data=bytes(8), is_extended_id=False))
                time.sleep(0.05)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()
    assert main(["live", "--bus", f"can0=virtual:{channel}", "--dbc", str(toyota), "--port",
                 "0", "--for", "2.5", "--drives", str(drives)]) == 0
    sender.join(5)
    assert load_layout(layout) == bringup_layout(["can0"])
    lines = [line for line in capsys.readouterr().out.splitlines()
             if line.startswith("bring-up: ")]
    assert lines == [f"bring-up: can0 carries ids no database knows (first 0x7A1): import "
                     f'{layout} (Layouts menu), then set its variable unknown_id to "0x7A1" '
                     "(Variables)"]
