"""Bundled Foxglove layouts (``layouts/*.json``): list them, copy them out, check them.

A layout is Foxglove Studio's import/export JSON: ``configById`` (panel id → panel settings,
the id is ``<PanelType>!<name>``), ``layout`` (the mosaic tree of panel ids), ``globalVariables``,
``userNodes`` and ``playbackConfig``. Each bundled layout has a preview picture beside it
(``tank-viz.png`` for ``tank-viz.json``), taken by the end-to-end browser test.

:func:`check_layout` resolves every topic, frame and message path a layout names against what
the bridge produces for a profile (:func:`produced`: every topic the live pipeline advertises,
with the schema it advertises it with, and the frames of :mod:`bridge.topics` and the
profile's sensors), walking the protobuf descriptors field by field, so that a plot of
``/perception/lead.object.x`` is known to read a number of ``tankviz.LeadVehicle``.
"""

from __future__ import annotations

import json
import re
import shutil
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridge.errors import BridgeError
from bridge.resources import layouts_dir
from bridge.topics import VEHICLE_FRAME

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
}

#: Message types the 3D panel draws (topics it can show).
DRAWABLE = frozenset({"foxglove.SceneUpdate", "foxglove.FrameTransforms"})

#: Protobuf field types a plot can draw: numbers, booleans and enums.
_NUMERIC_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 8, 13, 14, 15, 16, 17, 18})  # all but
# string (9), group (10), message (11) and bytes (12)
_MESSAGE_TYPE = 11

#: Foxglove user scripts publish on topics under this prefix.
USER_SCRIPT_PREFIX = "/studio_script/"


class LayoutError(BridgeError):
    """A layout file that cannot be read or is not in Foxglove's layout format."""

    def __init__(self, path: Path | str, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{path}: {reason}")


@dataclass(frozen=True)
class BundledLayout:
    """One layout shipped with tankviz."""

    name: str
    path: Path
    #: the preview picture beside it, if there is one
    preview: Path | None
    #: what it shows, e.g. "3D, 3 plots, Raw Messages"
    summary: str


def bundled_layouts(directory: Path | None = None) -> list[BundledLayout]:
    """The layouts in ``layouts/`` (or ``directory``), by name."""
    folder = directory if directory is not None else layouts_dir()
    out = []
    for path in sorted(folder.glob("*.json")):
        preview = path.with_suffix(".png")
        out.append(BundledLayout(path.stem, path, preview if preview.is_file() else None,
                                 summarize(load_layout(path))))
    return out


def select_layouts(names: Iterable[str] = (), directory: Path | None = None
                   ) -> list[BundledLayout]:
    """The bundled layouts called ``names`` in that order (all of them when none is named)."""
    layouts = {layout.name: layout for layout in bundled_layouts(directory)}
    wanted = list(names) or list(layouts)
    unknown = [n for n in wanted if n not in layouts]
    if unknown:
        raise BridgeError(f"no bundled layout {', '.join(repr(n) for n in unknown)}; "
                          f"bundled: {', '.join(layouts)}")
    return [layouts[n] for n in wanted]


def format_listing(layouts: Iterable[BundledLayout]) -> str:
    """One line per layout: name, panels, file (what ``tankviz layouts`` prints)."""
    rows = [(layout.name, layout.summary, str(layout.path)) for layout in layouts]
    if not rows:
        return ""
    widths = [max(len(row[i]) for row in rows) for i in range(2)]
    return "\n".join(f"{name:<{widths[0]}}  {summary:<{widths[1]}}  {path}"
                     for name, summary, path in rows)


def summarize(layout: Mapping[str, Any]) -> str:
    """The panels of a layout in words: ``3D, 3 plots, Raw Messages``."""
    counts = Counter(panel_type(panel_id) for panel_id in layout["configById"])
    words = []
    for kind, n in counts.items():
        name = PANEL_NAMES.get(kind, kind)
        words.append(name if n == 1 else f"{n} {name}{'s' if name.islower() else ' panels'}")
    return ", ".join(words)


def export_layouts(directory: Path, *, names: Iterable[str] | None = None,
                   force: bool = False, source: Path | None = None) -> list[Path]:
    """Copy bundled layouts (all, or those ``names``) into ``directory`` (created if needed).

    An existing file is not overwritten unless ``force``; nothing is copied then.
    """
    chosen = select_layouts(names or (), source)
    targets = [(layout.path, directory / layout.path.name) for layout in chosen]
    if not force:
        existing = [str(target) for _, target in targets if target.exists()]
        if existing:
            raise BridgeError(f"{', '.join(existing)}: exists (--force overwrites)")
    if directory.exists() and not directory.is_dir():
        raise BridgeError(f"{directory}: not a folder")
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for path, target in targets:
            shutil.copyfile(path, target)
    except OSError as exc:
        raise BridgeError(f"{directory}: cannot write: {exc.strerror or exc}") from None
    return [target for _, target in targets]


def load_layout(path: Path) -> dict[str, Any]:
    """Read a layout file and check its shape (keys, panel ids, the mosaic tree)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise LayoutError(path, "no such file") from None
    except json.JSONDecodeError as exc:
        raise LayoutError(path, f"not JSON: line {exc.lineno}: {exc.msg}") from None
    problems = check_format(data)
    if problems:
        raise LayoutError(path, "; ".join(problems))
    return dict(data)


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


# --- what the bridge produces ----------------------------------------------------------------


@dataclass
class Produced:
    """Topics (name → protobuf message descriptor) and frame ids the bridge publishes."""

    topics: dict[str, Any] = field(default_factory=dict)
    frames: set[str] = field(default_factory=set)


class _Announcements:
    """Stands in for the live server: keeps what the pipeline advertises (topic → schema)."""

    def __init__(self) -> None:
        self.schemas: dict[str, tuple[str, bytes]] = {}

    def channel_for_schema(self, topic: str, schema_name: str, schema: bytes, *,
                           encoding: str = "protobuf", schema_encoding: str = "protobuf") -> int:
        self.schemas.setdefault(topic, (schema_name, schema))
        return len(self.schemas)

    def wanted(self, channel_id: int) -> bool:
        return False


def descriptor_of(schema_name: str, file_descriptor_set: bytes) -> Any:
    """The message descriptor ``schema_name`` of a serialized FileDescriptorSet."""
    from google.protobuf import descriptor_pb2, descriptor_pool

    files = descriptor_pb2.FileDescriptorSet.FromString(file_descriptor_set).file
    pool = descriptor_pool.DescriptorPool()
    pending = list(files)
    while pending:  # add each file after its dependencies
        ready = [f for f in pending
                 if all(d in {g.name for g in files if g not in pending} for d in f.dependency)]
        if not ready:
            raise BridgeError(f"{schema_name}: the schema's files depend on missing files")
        for f in ready:
            pool.Add(f)
            pending.remove(f)
    return pool.FindMessageTypeByName(schema_name)


def produced(decoder: Any, profile: Any, buses: Iterable[str] = ("can0",)) -> Produced:
    """What the bridge advertises live (and records) with this decoder and profile on ``buses``.

    The live pipeline's own announcement (:meth:`~bridge.pipeline.Pipeline.advertise`) is
    recorded, and each topic's descriptor is built from the FileDescriptorSet it is advertised
    with: the scene, perception and health topics, /log, and per bus the raw frames and every
    message its databases define. Frames: the vehicle frame and the profile's sensors.
    """
    from bridge.pipeline import Pipeline, new_health_monitor

    announcements = _Announcements()
    pipeline = Pipeline(decoder, profile=profile, server=announcements,  # type: ignore[arg-type]
                        health=new_health_monitor(decoder, profile))
    pipeline.advertise(list(buses))
    out = Produced(frames={VEHICLE_FRAME})
    if profile is not None:
        out.frames.update(profile.sensors)
    for topic, (schema_name, schema) in announcements.schemas.items():
        out.topics[topic] = descriptor_of(schema_name, schema)
    return out


def bundled_produced(profile: str = "ecocar", buses: Iterable[str] = ("can0",)) -> Produced:
    """What the bundled profile produces (the simulated car and ``tankviz demo`` use bus can0)."""
    from bridge.convert import build_stages

    decoder, loaded = build_stages([], profile)
    return produced(decoder, loaded, buses)


# --- message paths ---------------------------------------------------------------------------

_SEGMENT = re.compile(r"""
    (?P<name>[A-Za-z_][A-Za-z0-9_]*)          # a field
    (?P<suffix>(?:\[[^\]]*\]|\{[^}]*\})*)      # indexes, slices and filters
    """, re.VERBOSE)
_FILTER = re.compile(r"\{\s*([A-Za-z_][A-Za-z0-9_.]*)\s*(==|!=|<=|>=|<|>)\s*([^}]+)\}")


@dataclass(frozen=True)
class Resolved:
    """A message path resolved against a topic's type."""

    topic: str
    schema: str
    #: the field descriptor at the end, or None for the whole message
    leaf: Any

    @property
    def plottable(self) -> bool:
        return self.leaf is not None and self.leaf.type in _NUMERIC_TYPES


def _is_repeated(descriptor: Any) -> bool:
    repeated = getattr(descriptor, "is_repeated", None)
    if isinstance(repeated, bool):
        return repeated
    return bool(descriptor.label == descriptor.LABEL_REPEATED)


def _split_topic(path: str, topics: Mapping[str, Any]) -> tuple[str, str]:
    """The longest topic the path starts with, and the rest (``.field…``)."""
    best = ""
    for topic in topics:
        matches = path == topic or (path.startswith(topic) and path[len(topic)] in ".[{")
        if matches and len(topic) > len(best):
            best = topic
    return best, path[len(best):]


def resolve_path(path: str, where: Produced) -> Resolved:
    """Resolve a Foxglove message path (``/topic.field.sub``, ``[0]``, ``[:]``, ``{id==3}``,
    a trailing ``.@derivative`` and the like) against the produced topics' descriptors."""
    topic, rest = _split_topic(path, where.topics)
    if not topic:
        raise BridgeError(f"{path}: no such topic")
    descriptor = where.topics[topic]
    schema = descriptor.full_name
    rest = re.sub(r"\.@[A-Za-z]+$", "", rest)  # modifiers (@derivative, @abs, …)
    if not rest:
        return Resolved(topic, schema, None)
    if not rest.startswith("."):
        raise BridgeError(f"{path}: expected '.field' after {topic}")
    message, leaf = descriptor, None
    walked = topic
    for part in rest[1:].split("."):
        match = _SEGMENT.fullmatch(part)
        if match is None:
            raise BridgeError(f"{path}: cannot read {part!r}")
        if message is None:
            raise BridgeError(f"{path}: {walked} is not a message, it has no field "
                              f"{match['name']!r}")
        name = match["name"]
        leaf = message.fields_by_name.get(name)
        if leaf is None:
            fields = ", ".join(message.fields_by_name)
            raise BridgeError(f"{path}: {message.full_name} has no field {name!r}; "
                              f"fields: {fields}")
        walked += f".{name}"
        suffix = match["suffix"]
        if _is_repeated(leaf) and "[" not in suffix:
            raise BridgeError(f"{path}: {walked} is repeated: index it ([0], [:])")
        if not _is_repeated(leaf) and "[" in suffix:
            raise BridgeError(f"{path}: {walked} is not repeated: it cannot be indexed")
        message = leaf.message_type if leaf.type == _MESSAGE_TYPE else None
        for filter_match in _FILTER.finditer(suffix):
            field_name = filter_match[1].split(".")[0]
            if message is None or field_name not in message.fields_by_name:
                raise BridgeError(f"{path}: the filter on {walked} names no field "
                                  f"{field_name!r}")
    return Resolved(topic, schema, leaf)


# --- checking a layout -----------------------------------------------------------------------


def _paths_of(panel_id: str, config: Mapping[str, Any]) -> Iterator[tuple[str, str, bool]]:
    """(where, message path, must be plottable) for every path a panel reads."""
    kind = panel_type(panel_id)
    for key in ("topicPath", "diffTopicPath", "path", "topicToRender"):
        value = config.get(key)
        if isinstance(value, str) and value:
            if key == "diffTopicPath" and not config.get("diffEnabled"):
                continue
            yield f"{panel_id}.{key}", value, kind in ("Indicator", "Gauge")
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


def check_layout(layout: Mapping[str, Any], where: Produced) -> list[str]:
    """Everything a layout names that the bridge does not produce (empty when all resolve)."""
    problems = check_format(layout)
    if problems:
        return problems
    scripts = layout["userNodes"]
    for panel_id, config in layout["configById"].items():
        if panel_type(panel_id) == "3D":
            problems += _check_3d(panel_id, config, where)
        for place, path, numeric in _paths_of(panel_id, config):
            if scripts and path.startswith(USER_SCRIPT_PREFIX):
                continue  # published by the layout's own user script
            try:
                resolved = resolve_path(path, where)
            except BridgeError as exc:
                problems.append(f"{place}: {exc}")
                continue
            if numeric and not resolved.plottable:
                whole = resolved.leaf is None or resolved.leaf.type == _MESSAGE_TYPE
                kind = "a message" if whole else "not a number"
                problems.append(f"{place}: {path} is {kind}: nothing to plot")
    return problems


def referenced_topics(layout: Mapping[str, Any], where: Produced) -> set[str]:
    """Every produced topic a layout reads (3D topics and the topics of its message paths)."""
    out: set[str] = set()
    for panel_id, config in layout["configById"].items():
        if panel_type(panel_id) == "3D":
            out.update(config.get("topics", {}))
        for _, path, _ in _paths_of(panel_id, config):
            topic, _ = _split_topic(path, where.topics)
            if topic:
                out.add(topic)
    return out
