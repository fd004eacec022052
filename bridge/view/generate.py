"""Foxglove layouts made for a profile: profile + databases -> the tank-viz, engineer,
can-debug and bring-up layouts (what ``tankviz layouts --profile P --export DIR`` writes).

They are built from what the bridge produces for the profile on its buses, never from a list of
ecocar's names, so every panel reads a topic that exists and nothing the profile lacks is shown;
the bundled ``layouts/*.json`` are ecocar's, written so.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

from bridge.decode.decoder import Decoder
from bridge.health.alarms import AlarmKind, alarm_id
from bridge.pb.marks_pb2 import Mark
from bridge.profile.model import Field, ObjectGroup, Profile
from bridge.scene.camera import VIEWS, camera_for, chase_camera, view_range
from bridge.scene.entities import label_category
from bridge.topics import (
    EGO_TOPIC,
    HEALTH_TOPIC,
    LEAD_TOPIC,
    LOG_TOPIC,
    MARKS_TOPIC,
    VEHICLE_FRAME,
    frames_topic,
    message_topic,
    objects_topic,
    scene_topic,
)
from bridge.view.bringup import BRINGUP_NAME, bringup_layout
from bridge.view.panels import layout_of as _layout
from bridge.view.panels import layout_text, plot, raw_messages, split, stack, weighted
from bridge.view.panels import series as _path
from bridge.view.produced import Produced, produced

__all__ = ["LAYOUT_NAMES", "database_buses", "generate_layouts", "layout_text", "plot",
           "raw_messages", "split", "stack", "weighted"]

#: The layouts :func:`generate_layouts` makes, in this order.
LAYOUT_NAMES = ("tank-viz", "engineer", "can-debug", BRINGUP_NAME)
#: The bus of databases given for every bus (a log without channels, ``tankviz demo``).
DEFAULT_BUS = "can0"
#: Indicator colours: an active alarm, a cleared one, no /health yet.
ALARM_RED, OK_GREEN, NO_DATA_GREY = "#d93025", "#1e8e3e", "#9e9e9e"
#: The Mark button's colour (the scene's orange of attention, as the MIO check's ring).
MARK_COLOUR = "#e8710a"
#: Colours of the rate plot: a dark (actual) and a light (expected) shade per family.
RATE_COLOURS = (("#1f77b4", "#9ecae1"), ("#e6550d", "#fdae6b"), ("#31a354", "#a1d99b"),
                ("#756bb1", "#bcbddc"), ("#636363", "#bdbdbd"), ("#d6616b", "#e7969c"))
#: Indicator panels per row in the engineer layout.
INDICATORS_PER_ROW = 5
#: Ego fields of ``/ego`` (tankviz.EgoState) and how the plot labels them.
EGO_FIELDS = (("speed", "ego speed (m/s)"), ("yaw_rate", "yaw rate (rad/s)"),
              ("steering_wheel_angle", "steering wheel angle (rad)"))


def database_buses(decoder: Decoder) -> list[str]:
    """The buses the decoder's databases are given for, in the order given; ``can0`` when
    every database is for every bus."""
    named: list[str] = []
    for database in decoder.files:
        for bus in decoder.buses_for(database):
            if bus != "*" and bus not in named:
                named.append(bus)
    return named or [DEFAULT_BUS]


def generate_layouts(profile: Profile, decoder: Decoder,
                     buses: Sequence[str] | None = None, *,
                     plot_id: tuple[str, str] | None = None) -> dict[str, dict[str, Any]]:
    """The tank-viz, engineer, can-debug and bring-up layouts for ``profile`` with the
    databases of ``decoder`` on ``buses`` (default :func:`database_buses`); ``plot_id``: the
    bus and unknown id the bring-up layout follows at first
    (:func:`bridge.view.bringup.bringup_layout`)."""
    buses = list(buses) if buses else database_buses(decoder)
    made = produced(decoder, profile, buses)
    return {
        "tank-viz": tank_viz(made, profile),
        "engineer": engineer(made, profile),
        "can-debug": can_debug(made, profile, decoder, buses),
        BRINGUP_NAME: bringup_layout(buses, plot_id),
    }


# --- panels --------------------------------------------------------------------------------------


#: The Tank Viz view's camera: close behind and above the vehicle, about 60 m of road in view.
CHASE_CAMERA = chase_camera().foxglove_state()
#: Share of the tank-viz layout's width the chase view takes (the range view the rest).
CHASE_SHARE = 55.0


def view_3d(made: Produced, profile: Profile, *, whole_range: bool = False) -> dict[str, Any]:
    """A Tank Viz 3D panel: every scene topic produced, every frame (vehicle, then the
    profile's sensors), following the vehicle from behind and above, on a dark background with
    a grid of 10 m cells.

    The chase view (default) has the Tank Viz view's close camera and grid (160 m, 70 m ahead). The
    range view (``whole_range``) frames the road from just behind the vehicle to the profile's
    largest sensor range (:func:`bridge.scene.camera.camera_for`, the camera the scene keeps
    its marks visible for), on a grid from 10 m behind to beyond it. Each view shows the labels
    laid out for it, not the other's."""
    view = "range" if whole_range else "chase"
    others = {scene_topic(label_category(v)) for v in VIEWS if v != view}
    scene = [t for t, d in made.topics.items()
             if d.full_name == "foxglove.SceneUpdate" and t not in others]
    frames = [VEHICLE_FRAME, *(s for s in profile.sensors if s != VEHICLE_FRAME)]
    if whole_range:
        reach = view_range(profile)
        grid = 10 * math.ceil((reach + 20) / 10)  # 10 m behind the origin to beyond the range
        title, camera = f"Tank Viz: the sensors' range, {reach:g} m", camera_for(
            reach).foxglove_state()
        where, label = [grid / 2 - 10, 0, 0], f"Grid: 10 m cells, {grid - 10:g} m ahead"
    else:
        grid, title, camera = 160, "Tank Viz", CHASE_CAMERA
        where, label = [70, 0, 0], "Grid: 10 m cells, 70 m ahead"
    return {
        "foxglovePanelTitle": title,
        "cameraState": camera,
        "followMode": "follow-pose",
        "followTf": VEHICLE_FRAME,
        "scene": {"backgroundColor": "#303030", "labelScaleFactor": 1,
                  "transforms": {"showLabel": False, "axisScale": 1, "lineWidth": 1,
                                 "editable": False, "enablePreloading": True}},
        "transforms": {f"frame:{f}": {"visible": True} for f in frames},
        "topics": {t: {"visible": True} for t in scene},
        "layers": {"tankviz-grid": {
            "visible": True, "frameLocked": True, "label": label,
            "instanceId": "tankviz-grid", "layerId": "foxglove.Grid",
            "frameId": VEHICLE_FRAME, "size": grid, "divisions": grid // 10, "lineWidth": 1,
            "color": "#a0a0a4a0", "position": where, "rotation": [0, 0, 0], "order": 1}},
        "publish": {"type": "point", "poseTopic": "/move_base_simple/goal",
                    "pointTopic": "/clicked_point", "poseEstimateTopic": "/initialpose",
                    "poseEstimateXDeviation": 0.5, "poseEstimateYDeviation": 0.5,
                    "poseEstimateThetaDeviation": 0.26179939},
        "imageMode": {},
    }


def tank_viz(made: Produced, profile: Profile) -> dict[str, Any]:
    """The tank-viz layout: the chase view (near objects readable) beside the range view
    (everything up to the sensors' reach in view); under the chase view, the Mark button (the
    chase view's labels are laid out for a smaller panel: the engineer layout's)."""
    return _layout({"3D!tankviz": view_3d(made, profile),
                    "3D!tankviz-range": view_3d(made, profile, whole_range=True),
                    "Publish!mark": mark_panel()},
                   split(split("3D!tankviz", "Publish!mark", "column", MARK_BUTTON_SHARE),
                         "3D!tankviz-range", "row", CHASE_SHARE))


#: The share of the chase view's column the tank-viz layout's Mark button leaves it: room for
#: the button in a 1280 x 800 window.
MARK_BUTTON_SHARE = 85.0


def mark_panel() -> dict[str, Any]:
    """A Publish panel that marks the moment: a click sends its template to /marks as it is
    ("mark"). Its button alone fits a laptop's window; the panel's Editing mode (its settings)
    shows the JSON, to type a word into before sending."""
    return {"foxglovePanelTitle": f"Mark the moment ({MARKS_TOPIC})", "topicName": MARKS_TOPIC,
            "datatype": Mark.DESCRIPTOR.full_name, "buttonText": "Mark",
            "buttonTooltip": "mark this moment of the drive: tankviz inspect, catalog and "
            "replay --start mark:N find it", "buttonColor": MARK_COLOUR,
            "advancedView": False,
            "value": json.dumps({"text": "mark", "category": ""}, indent=2)}


def alarm_path(alarm: str) -> str:
    """The message path of an alarm's state in ``/health``."""
    return f'{HEALTH_TOPIC}.alarms[:]{{id=="{alarm}"}}.active'


def indicator(alarm: str) -> dict[str, Any]:
    """An alarm's Indicator: a green OK while inactive, red with the alarm id while active,
    grey "no data" before the first /health."""
    return {"foxglovePanelTitle": alarm, "path": alarm_path(alarm), "style": "background",
            "fallbackColor": NO_DATA_GREY, "fallbackLabel": "no data",
            "rules": [{"operator": "=", "rawValue": "true", "color": ALARM_RED, "label": alarm},
                      {"operator": "=", "rawValue": "false", "color": OK_GREEN,
                       "label": "OK"}]}


# --- engineer ------------------------------------------------------------------------------------


def _group_label(group: ObjectGroup) -> str:
    role = "tracks" if group.is_tracks else "detections"
    return group.name if group.name == role else f"{group.name} {role}"


def lead_has_velocity(profile: Profile) -> bool:
    """Whether the lead's objects carry a relative velocity: its own message maps ``vx``, or
    (``source = "tracks"``) a group of tracks does."""
    lead = profile.lead
    if lead is None:
        return False
    groups = ([lead.group] if lead.group is not None
              else [g for g in profile.groups.values() if g.is_tracks])
    return any(g.vx is not None for g in groups)


def engineer(made: Produced, profile: Profile) -> dict[str, Any]:
    """The engineer layout: the 3D view, plots, the lead, the alarm log and every alarm."""
    health = made.samples[HEALTH_TOPIC]
    configs: dict[str, Any] = {"3D!engineer": view_3d(made, profile)}
    plots: list[str] = []
    if profile.lead is not None:
        lead = [_path(f"{LEAD_TOPIC}.object.x", "lead distance x (m)")]
        if lead_has_velocity(profile):
            lead.append(_path(f"{LEAD_TOPIC}.object.vx", "lead relative speed (m/s)"))
        configs["Plot!lead"] = plot("Lead vehicle", lead)
        plots.append("Plot!lead")
    # speed (m/s) and the angles (rad/s, rad) differ a hundredfold: each on its own axis
    for panel, title, fields in (("Plot!ego", "Ego speed", EGO_FIELDS[:1]),
                                 ("Plot!ego-angles", "Ego yaw rate and steering",
                                  EGO_FIELDS[1:])):
        ego = [_path(f"{EGO_TOPIC}.{name}", label) for name, label in fields
               if getattr(profile.ego, name) is not None]
        if ego:
            configs[panel] = plot(title, ego)
            plots.append(panel)
    groups = list(profile.groups.values())
    if groups:
        kinds = {g.is_tracks for g in groups}
        title = ("Valid detections and tracks" if len(kinds) == 2
                 else "Valid tracks" if True in kinds else "Valid detections")
        configs["Plot!counts"] = plot(title, [_path(f"{objects_topic(g.name)}.count",
                                                    _group_label(g)) for g in groups])
        plots.append("Plot!counts")
    right: list[str] = []
    families = [f.name for f in health.families if f.name in profile.groups]
    if families:
        paths = []
        for i, family in enumerate(families):
            dark, light = RATE_COLOURS[i % len(RATE_COLOURS)]
            where = f'{HEALTH_TOPIC}.families[:]{{name=="{family}"}}'
            paths += [_path(f"{where}.actual_hz", family, dark),
                      _path(f"{where}.expected_hz", f"{family} expected", light)]
        configs["Plot!rates"] = plot("Message rates: actual vs expected (frames/s, /health)",
                                     paths)
        right.append("Plot!rates")
    if profile.lead is not None:
        configs["RawMessages!lead"] = raw_messages("Lead vehicle and MIO check", LEAD_TOPIC)
        right.append("RawMessages!lead")
    configs["RosOut!alarms"] = {"foxglovePanelTitle": "Alarms and marks (/log)",
                                "topicToRender": LOG_TOPIC, "minLogLevel": 1,
                                "searchTerms": []}
    right.append("RosOut!alarms")
    configs["Publish!mark"] = mark_panel()
    right.append("Publish!mark")
    alarms = [a.id for a in health.alarms]
    for alarm in alarms:
        configs[f"Indicator!{alarm}"] = indicator(alarm)
    rows = [stack([f"Indicator!{a}" for a in alarms[i:i + INDICATORS_PER_ROW]], "row")
            for i in range(0, len(alarms), INDICATORS_PER_ROW)]
    top = split("3D!engineer", split(stack(plots, "column"), stack(right, "column"), "row",
                                     51.6), "row", 36.0)
    return _layout(configs, split(top, stack(rows, "column"), "column", 73.0))


# --- can-debug -----------------------------------------------------------------------------------


def _first(group: ObjectGroup) -> int | None:
    indices = [m.index for m in group.members.values() if m.index is not None]
    return min(indices) if indices else None


def signal_families(profile: Profile) -> list[tuple[str, list[tuple[str, str]]]]:
    """The DBC signals (message, signal) the profile reads, by what they are: the ego signals,
    the position (and velocity) of the first object of each group, the lane lines' offsets, the
    lead's own message. A field computed from several signals gives each of them."""

    def signals(fields: Iterable[Field | None], index: int | None = None) -> list[tuple[str, str]]:
        found = [pair for f in fields if f is not None for pair in f.at(index).signals]
        return list(dict.fromkeys(found))

    out = [("ego", signals(getattr(profile.ego, name) for name, _ in EGO_FIELDS))]
    for group in profile.groups.values():
        out.append((group.name, signals([group.x, group.y, group.range, group.azimuth,
                                         group.vx], _first(group))))
    if profile.lanes is not None:
        out.append(("lanes", signals(line.c0 for line in profile.lanes.lines.values())))
    if profile.lead is not None and profile.lead.group is not None:
        lead = profile.lead.group
        out.append(("lead", signals([lead.x, lead.range, lead.vx], _first(lead))))
    return [(name, pairs) for name, pairs in out if pairs]


def raw_frames_of(bus: str, frame_id: int) -> str:
    """The message path of one id's frames in a bus's blocks of raw frames (ids are decimal)."""
    return f"{frames_topic(bus)}.frames[:]{{id=={frame_id}}}"


def _one_id(decoder: Decoder, bus: str, messages: Iterable[str]) -> tuple[str, int] | None:
    """The first of ``messages`` the databases of ``bus`` define, and its id."""
    ids = {codec.message.name: codec.message.frame_id for codec in decoder.codecs_for(bus)}
    return next(((m, ids[m]) for m in messages if m in ids), None)


def _units(decoder: Decoder, bus: str) -> dict[tuple[str, str], str]:
    """(message, signal) -> unit of every signal the databases of ``bus`` define."""
    return {(codec.message.name, signal.name): signal.unit or ""
            for codec in decoder.codecs_for(bus) for signal in codec.message.signals}


#: Heights of a bus's health column: its two Indicators, then frames/s, load and errors.
BUS_HEALTH_WEIGHTS = (1.0, 1.0, 2.67, 2.67, 2.67)


def _bus_health(bus: str) -> tuple[dict[str, Any], Any]:
    where = f'{HEALTH_TOPIC}.buses[:]{{bus=="{bus}"}}'
    silent, babbling = alarm_id(AlarmKind.BUS_SILENT, bus), alarm_id(AlarmKind.BABBLING, bus)
    configs = {
        f"Indicator!{silent}": indicator(silent),
        f"Indicator!{babbling}": indicator(babbling),
        f"Plot!bus-{bus}-rate": plot(f"Bus {bus}: frames/s (/health)", [
            _path(f"{where}.frames_per_s", f"{bus} frames/s")], legend="top", sidebar=34),
        f"Plot!bus-{bus}-load": plot(f"Bus {bus}: load (share of the bitrate)", [
            _path(f"{where}.load", f"{bus} load (0-1)")], legend="top", sidebar=34),
        f"Plot!bus-{bus}-errors": plot(f"Bus {bus}: errors in the last second", [
            _path(f"{where}.error_frames", "error frames"),
            _path(f"{where}.unknown_ids", "frames with an unknown id"),
            _path(f"{where}.decode_errors", "frames that do not decode")],
            legend="top", sidebar=86),
        f"RawMessages!frames-{bus}": raw_messages(f"Raw frames {frames_topic(bus)}",
                                                  frames_topic(bus)),
    }
    health = weighted([f"Indicator!{silent}", f"Indicator!{babbling}",
                       f"Plot!bus-{bus}-rate", f"Plot!bus-{bus}-load",
                       f"Plot!bus-{bus}-errors"], BUS_HEALTH_WEIGHTS, "column")
    return configs, health


def can_debug(made: Produced, profile: Profile, decoder: Decoder,
              buses: Iterable[str]) -> dict[str, Any]:
    """The can-debug layout: decoded signals, each bus's health and raw frames (its latest block,
    and the frames of one id the profile reads: the filter a user edits to follow another), the
    topics."""
    buses = list(buses)
    configs: dict[str, Any] = {}
    signal_plots = []
    units = {bus: _units(decoder, bus) for bus in buses}
    for name, pairs in signal_families(profile):
        paths = []
        for message, signal in pairs:
            for bus in buses:
                unit = units[bus].get((message, signal))
                if unit is None or message_topic(bus, message) not in made.topics:
                    continue
                label = f"{message}.{signal}" + (f" ({unit})" if unit else "")
                paths.append(_path(f"{message_topic(bus, message)}.{signal}",
                                   f"{bus}: {label}" if len(buses) > 1 else label))
        if paths:
            messages = list(dict.fromkeys(message for message, _ in pairs))
            configs[f"Plot!signals-{name}"] = plot(f"{name} ({', '.join(messages)})", paths)
            signal_plots.append(f"Plot!signals-{name}")
    columns = []
    for bus in buses:
        bus_configs, column = _bus_health(bus)
        configs.update(bus_configs)
        columns.append(column)
    configs["SourceInfo!topics"] = {"foxglovePanelTitle": "Topics, message counts and rates"}
    raw_panels = []
    for bus in buses:
        raw_panels.append(f"RawMessages!frames-{bus}")
        one = _one_id(decoder, bus, [m for _, pairs in signal_families(profile) for m, _ in pairs])
        if one is not None:
            message, frame_id = one
            path = raw_frames_of(bus, frame_id)
            configs[f"RawMessages!frames-{bus}-id"] = raw_messages(
                f"Raw frames of {message} (id {frame_id} = 0x{frame_id:X}; another id: edit "
                f"the path)", path)
            raw_panels.append(f"RawMessages!frames-{bus}-id")
    raw = stack(raw_panels, "column")
    rest = split(stack(columns, "row"), split(raw, "SourceInfo!topics", "column", 55.0), "row",
                 50.0)
    return _layout(configs, split(stack(signal_plots, "column"), rest, "row", 36.0))
