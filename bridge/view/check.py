"""A layout's format, and every topic, frame and message path it names, checked against what
the bridge produces.

:func:`check_format` says what keeps data from being a layout Foxglove Studio imports;
:func:`check_layout` resolves every topic, frame, message path and variable a layout names against
what the bridge produces for a profile, and checks each panel reads what it can show.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

from google.protobuf.descriptor import FieldDescriptor

from bridge.errors import MessagePathError
from bridge.topics import LOG_TOPIC, MARKS_TOPIC
from bridge.view.paths import NUMERIC_TYPES, resolve_path, split_topic
from bridge.view.produced import Produced

#: The keys of Foxglove Studio's layout import/export format.
LAYOUT_KEYS = ("configById", "layout", "globalVariables", "userNodes", "playbackConfig")

#: Panel types the bundled layouts use, as Foxglove names them in panel ids, and how to say them.
PANEL_NAMES = {
    "3D": "3D",
    "Plot": "plot",
    "RawMessages": "Raw Messages",
    "SourceInfo": "Data Source Info",
    "Table": "Table",
    "Indicator": "Indicator",
    "Gauge": "Gauge",
    "StateTransitions": "State Transitions",
    "RosOut": "Log",
    "Tab": "Tab",
    "ImageViewPanel": "Image",
    "GlobalVariableSliderPanel": "Variable Slider",
    "Publish": "Publish",
}

#: Message types the 3D panel draws (topics it can show).
DRAWABLE = frozenset({"foxglove.SceneUpdate", "foxglove.FrameTransforms"})

#: Message types the Image panel shows as its image, and draws over it (Foxglove Studio 1.48:
#: of ``foxglove.ImageAnnotations`` it draws circles and points, not texts).
IMAGE_SCHEMAS = frozenset({"foxglove.CompressedImage", "foxglove.RawImage"})
ANNOTATION_SCHEMAS = frozenset({"foxglove.ImageAnnotations"})

#: A layout variable in a message path: ``{id==$unknown_id}``, ``[$word]``.
_VARIABLE = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")

#: Foxglove user scripts publish on topics under this prefix.
USER_SCRIPT_PREFIX = "/studio_script/"


def panel_type(panel_id: str) -> str:
    """``3D`` for ``3D!tankviz``: Foxglove's panel ids are ``<PanelType>!<name>``."""
    return panel_id.split("!", 1)[0]


def _tree_ids(node: Any, where: str, problems: list[str]) -> Iterator[str]:
    if isinstance(node, str):
        yield node
    elif isinstance(node, dict):
        if node.get("direction") not in ("row", "column"):
            problems.append(f"{where}.direction: expected 'row' or 'column'")
        split = node.get("splitPercentage", 50)
        if not isinstance(split, int | float) or not 0 < split < 100:
            problems.append(f"{where}.splitPercentage: expected a number between 0 and 100")
        for side in ("first", "second"):
            if side not in node:
                problems.append(f"{where}.{side}: missing")
            else:
                yield from _tree_ids(node[side], f"{where}.{side}", problems)
    else:
        problems.append(f"{where}: expected a panel id or a split")


def check_format(data: Any) -> list[str]:
    """What keeps ``data`` from being a layout Foxglove imports (empty when nothing)."""
    if not isinstance(data, dict):
        return ["expected a JSON object"]
    problems = []
    missing = [k for k in LAYOUT_KEYS if k not in data]
    extra = [k for k in data if k not in LAYOUT_KEYS]
    if missing:
        problems.append(f"missing keys: {', '.join(missing)}")
    if extra:
        problems.append(f"unknown keys: {', '.join(extra)}")
    for key in ("configById", "globalVariables", "userNodes", "playbackConfig"):
        if key in data and not isinstance(data[key], dict):
            problems.append(f"{key}: expected an object")
    if problems:
        return problems
    configs = data["configById"]
    for panel_id, config in configs.items():
        if "!" not in panel_id or not panel_id.split("!", 1)[1]:
            problems.append(f"configById.{panel_id}: a panel id is '<PanelType>!<name>'")
        if panel_type(panel_id) not in PANEL_NAMES:
            problems.append(f"configById.{panel_id}: unknown panel type "
                            f"{panel_type(panel_id)!r}; known: {', '.join(PANEL_NAMES)}")
        if not isinstance(config, dict):
            problems.append(f"configById.{panel_id}: expected an object")
    ids = list(_tree_ids(data["layout"], "layout", problems))
    for panel_id, config in configs.items():  # panels inside Tab panels
        if panel_type(panel_id) == "Tab" and isinstance(config, dict):
            for i, tab in enumerate(config.get("tabs", [])):
                if isinstance(tab, dict) and tab.get("layout") is not None:
                    ids += _tree_ids(tab["layout"], f"configById.{panel_id}.tabs[{i}].layout",
                                     problems)
    for panel_id in ids:
        if panel_id not in configs:
            problems.append(f"layout: panel {panel_id!r} has no entry in configById")
    if len(ids) != len(set(ids)):
        problems.append("layout: a panel id appears twice")
    for panel_id in configs:
        if panel_id not in ids:
            problems.append(f"configById.{panel_id}: not placed in the layout")
    speed = data["playbackConfig"].get("speed", 1)
    if not isinstance(speed, int | float) or speed <= 0:
        problems.append("playbackConfig.speed: expected a positive number")
    return problems


def _paths_of(panel_id: str, config: Mapping[str, Any]) -> Iterator[tuple[str, str, bool]]:
    """(where, message path, must be plottable) for every path a panel reads."""
    kind = panel_type(panel_id)
    for key in ("topicPath", "diffTopicPath", "path", "topicToRender"):
        value = config.get(key)
        if isinstance(value, str) and value:
            if key == "diffTopicPath" and not config.get("diffEnabled"):
                continue
            yield f"{panel_id}.{key}", value, kind == "Gauge"
    for i, item in enumerate(config.get("paths", []) or []):
        value = item.get("value") if isinstance(item, dict) else None
        if isinstance(value, str):
            yield f"{panel_id}.paths[{i}]", value, kind == "Plot"
    x_path = config.get("xAxisPath")
    if isinstance(x_path, dict) and isinstance(x_path.get("value"), str) and x_path["value"]:
        yield f"{panel_id}.xAxisPath", x_path["value"], True


def _check_3d(panel_id: str, config: Mapping[str, Any], where: Produced) -> Iterator[str]:
    frames = sorted(where.frames)
    follow = config.get("followTf")
    if follow is not None and follow not in where.frames:
        yield f"{panel_id}.followTf: no frame {follow!r}; frames: {', '.join(frames)}"
    for key in config.get("transforms", {}):
        frame = key.removeprefix("frame:")
        if not key.startswith("frame:") or frame not in where.frames:
            yield f"{panel_id}.transforms.{key}: no frame {frame!r}; frames: {', '.join(frames)}"
    for topic in config.get("topics", {}):
        descriptor = where.topics.get(topic)
        if descriptor is None:
            yield f"{panel_id}.topics.{topic}: no such topic"
        elif descriptor.full_name not in DRAWABLE:
            yield (f"{panel_id}.topics.{topic}: {descriptor.full_name} is not drawn by the 3D "
                   "panel")
    for name, layer in config.get("layers", {}).items():
        frame = layer.get("frameId") if isinstance(layer, dict) else None
        if frame is not None and frame not in where.frames:
            yield (f"{panel_id}.layers.{name}.frameId: no frame {frame!r}; "
                   f"frames: {', '.join(frames)}")


#: What the Indicator panel's rules compare with (Foxglove Studio 1.48).
INDICATOR_OPERATORS = ("=", "<", "<=", ">", ">=")
INDICATOR_STYLES = ("bulb", "background")
#: Message types the Log panel shows.
LOG_SCHEMAS = frozenset({"foxglove.Log"})
_COLOR = re.compile(r"#(?:[0-9a-fA-F]{3}|[0-9a-fA-F]{6}|[0-9a-fA-F]{8})")


def _rule_value_problem(leaf: Any, raw: str, operator: str) -> str | None:
    """Why an Indicator rule's value can never match the values of ``leaf`` (None if it can).

    Foxglove parses the value as JSON for numbers and booleans and compares with ``===``."""
    if leaf.type == FieldDescriptor.TYPE_STRING:
        return None
    try:
        value = json.loads(raw)
    except ValueError:
        value = None
    if leaf.type == FieldDescriptor.TYPE_BOOL:
        if not isinstance(value, bool):
            return f"{raw!r} is not true or false"
        return None if operator == "=" else f"a boolean is compared with '=', not {operator!r}"
    if leaf.type in NUMERIC_TYPES:
        number = isinstance(value, int | float) and not isinstance(value, bool)
        return None if number else f"{raw!r} is not a number"
    return "the path is not a number, a string or a boolean"


def _check_indicator(panel_id: str, config: Mapping[str, Any], leaf: Any) -> Iterator[str]:
    """The Indicator panel's settings: a path, a style, colours, and rules whose values the
    path's field can have (``leaf``: its descriptor, None when the path did not resolve)."""
    if not config.get("path"):
        yield f"{panel_id}.path: missing: the Indicator shows nothing"
    if config.get("style", "bulb") not in INDICATOR_STYLES:
        yield f"{panel_id}.style: {config.get('style')!r}; one of {', '.join(INDICATOR_STYLES)}"
    color = config.get("fallbackColor")
    if color is not None and not (isinstance(color, str) and _COLOR.fullmatch(color)):
        yield f"{panel_id}.fallbackColor: {color!r} is not a colour (#rrggbb)"
    rules = config.get("rules")
    if not isinstance(rules, list) or not rules:
        yield f"{panel_id}.rules: expected a list of rules"
        return
    for i, rule in enumerate(rules):
        where = f"{panel_id}.rules[{i}]"
        if not isinstance(rule, dict):
            yield f"{where}: expected an object"
            continue
        operator, raw = rule.get("operator"), rule.get("rawValue")
        if operator not in INDICATOR_OPERATORS:
            yield f"{where}.operator: {operator!r}; one of {', '.join(INDICATOR_OPERATORS)}"
        if not isinstance(rule.get("color"), str) or not _COLOR.fullmatch(rule["color"]):
            yield f"{where}.color: {rule.get('color')!r} is not a colour (#rrggbb)"
        if not isinstance(rule.get("label"), str):
            yield f"{where}.label: expected a text"
        if not isinstance(raw, str):
            yield f"{where}.rawValue: expected a text"
        elif leaf is not None and operator in INDICATOR_OPERATORS:
            problem = _rule_value_problem(leaf, raw, operator)
            if problem:
                yield f"{where}.rawValue: never matches {leaf.full_name}: {problem}"


def _check_log(panel_id: str, config: Mapping[str, Any], where: Produced) -> Iterator[str]:
    """The Log panel shows a foxglove.Log topic (by default the first one there is)."""
    topic = config.get("topicToRender")
    if topic is None:
        if not any(d.full_name in LOG_SCHEMAS for d in where.topics.values()):
            yield f"{panel_id}: no {', '.join(sorted(LOG_SCHEMAS))} topic to show"
        return
    descriptor = where.topics.get(topic) if isinstance(topic, str) else None
    if descriptor is not None and descriptor.full_name not in LOG_SCHEMAS:
        yield (f"{panel_id}.topicToRender: {topic} is {descriptor.full_name}; the Log panel "
               f"shows {', '.join(sorted(LOG_SCHEMAS))} (such as {LOG_TOPIC})")


def _check_image(panel_id: str, config: Mapping[str, Any], where: Produced) -> Iterator[str]:
    """The Image panel's image topic and the annotation topics it draws over it."""
    topic = config.get("cameraTopic")
    if not topic:
        yield f"{panel_id}.cameraTopic: missing: the Image panel shows nothing"
    else:
        yield from _schema_of(f"{panel_id}.cameraTopic", topic, where, IMAGE_SCHEMAS,
                              f"an image ({', '.join(sorted(IMAGE_SCHEMAS))})")
    markers = config.get("enabledMarkerTopics", [])
    if not isinstance(markers, list):
        yield f"{panel_id}.enabledMarkerTopics: expected a list of topics"
        return
    for marker in markers:
        yield from _schema_of(f"{panel_id}.enabledMarkerTopics", marker, where,
                              ANNOTATION_SCHEMAS, ", ".join(sorted(ANNOTATION_SCHEMAS)))


def _schema_of(key: str, topic: str, where: Produced, schemas: Iterable[str],
               expected: str) -> Iterator[str]:
    """What is wrong with ``topic`` as one of ``schemas``: none, or not produced, or another
    schema."""
    descriptor = where.topics.get(topic)
    if descriptor is None:
        yield f"{key}: no such topic {topic}"
    elif descriptor.full_name not in schemas:
        yield f"{key}: {topic} is {descriptor.full_name}, not {expected}"


def _check_slider(panel_id: str, config: Mapping[str, Any],
                  variables: Mapping[str, Any]) -> Iterator[str]:
    """The Variable Slider panel: the layout variable it sets, and a range."""
    name = config.get("globalVariableName")
    if not isinstance(name, str) or not name:
        yield f"{panel_id}.globalVariableName: missing: the slider sets no variable"
    elif name not in variables:
        yield (f"{panel_id}.globalVariableName: {name!r} is not one of the layout's "
               f"globalVariables ({', '.join(variables) or 'none'})")
    props = config.get("sliderProps", {})
    low, high = props.get("min", 0), props.get("max", 10)
    if not (isinstance(low, int | float) and isinstance(high, int | float) and low < high):
        yield f"{panel_id}.sliderProps: expected min < max, not {low!r} and {high!r}"


def _check_publish(panel_id: str, config: Mapping[str, Any], where: Produced) -> Iterator[str]:
    """The Publish panel sends to /marks, the one topic a viewer may publish to, a JSON object
    whose fields /marks has."""
    topic = config.get("topicName")
    if topic != MARKS_TOPIC:
        yield f"{panel_id}.topicName: {topic!r}: a viewer may publish to {MARKS_TOPIC} only"
        return
    try:
        value = json.loads(config.get("value", ""))
    except ValueError as exc:
        yield f"{panel_id}.value: not JSON ({exc}): the panel's button stays disabled"
        return
    descriptor = where.topics.get(MARKS_TOPIC)
    if descriptor is None:
        yield f"{panel_id}.topicName: {MARKS_TOPIC} is not produced"
    elif not isinstance(value, dict) or not set(value) <= set(descriptor.fields_by_name):
        yield (f"{panel_id}.value: expected an object of {descriptor.full_name}'s fields "
               f"({', '.join(descriptor.fields_by_name)})")


def check_layout(layout: Mapping[str, Any], where: Produced) -> list[str]:
    """Everything a layout names that the bridge does not produce (empty when all resolve)."""
    problems = check_format(layout)
    if problems:
        return problems
    scripts = layout["userNodes"]
    for panel_id, config in layout["configById"].items():
        kind = panel_type(panel_id)
        if kind == "3D":
            problems += _check_3d(panel_id, config, where)
        if kind == "RosOut":
            problems += _check_log(panel_id, config, where)
        if kind == "ImageViewPanel":
            problems += _check_image(panel_id, config, where)
        if kind == "GlobalVariableSliderPanel":
            problems += _check_slider(panel_id, config, layout["globalVariables"])
        if kind == "Publish":
            problems += _check_publish(panel_id, config, where)
        leaf = None
        for place, path, numeric in _paths_of(panel_id, config):
            if scripts and path.startswith(USER_SCRIPT_PREFIX):
                continue  # published by the layout's own user script
            undefined = [name for name in _VARIABLE.findall(path)
                         if name not in layout["globalVariables"]]
            if undefined:
                problems.append(f"{place}: {path}: ${', $'.join(undefined)} is not one of "
                                "the layout's globalVariables")
            try:
                resolved = resolve_path(path, where, lists=kind == "Table")
            except MessagePathError as exc:
                problems.append(f"{place}: {exc}")
                continue
            if numeric and not resolved.plottable:
                whole = (resolved.leaf is None
                         or resolved.leaf.type == FieldDescriptor.TYPE_MESSAGE)
                what = "a message" if whole else "not a number"
                problems.append(f"{place}: {path} is {what}: nothing to plot")
            elif kind in ("Indicator", "Gauge") and place == f"{panel_id}.path":
                leaf = resolved.leaf
                if leaf is None or leaf.type in (FieldDescriptor.TYPE_MESSAGE,
                                                 FieldDescriptor.TYPE_BYTES):
                    is_bytes = leaf is not None and leaf.type == FieldDescriptor.TYPE_BYTES
                    what = "bytes" if is_bytes else "a message"
                    problems.append(f"{place}: {path} is {what}: nothing to show")
                    leaf = None
                elif resolved.several:
                    problems.append(f"{place}: {path} can give several values; the "
                                    f"{PANEL_NAMES[kind]} panel shows one: pick it with [n] "
                                    "or a filter")
        if kind == "Indicator":
            problems += _check_indicator(panel_id, config, leaf)
    return problems


def referenced_topics(layout: Mapping[str, Any], where: Produced) -> set[str]:
    """Every produced topic a layout reads (3D topics and the topics of its message paths)."""
    out: set[str] = set()
    for panel_id, config in layout["configById"].items():
        if panel_type(panel_id) == "3D":
            out.update(config.get("topics", {}))
        if panel_type(panel_id) == "ImageViewPanel":
            out.update(t for t in [config.get("cameraTopic"),
                                   *config.get("enabledMarkerTopics", [])]
                       if t in where.topics)
        for _, path, _ in _paths_of(panel_id, config):
            topic, _ = split_topic(path, where.topics)
            if topic:
                out.add(topic)
    return out
