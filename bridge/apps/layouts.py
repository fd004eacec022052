"""Bundled Foxglove layouts (``layouts/*.json``): list them, copy them out, check them.

A layout is Foxglove Studio's import/export JSON: ``configById`` (panel id → panel settings,
the id is ``<PanelType>!<name>``), ``layout`` (the mosaic tree of panel ids), ``globalVariables``,
``userNodes`` and ``playbackConfig``. Each bundled layout has a preview picture beside it
(``tank-viz.png`` for ``tank-viz.json``), taken by the end-to-end browser test.

:func:`check_layout` resolves every topic, frame and message path a layout names against what
the bridge produces for a profile (:func:`produced`: every topic the live pipeline advertises,
with the schema it advertises it with, and the frames of :mod:`bridge.topics` and the
profile's sensors), walking the protobuf descriptors field by field, so that a plot of
``/perception/lead.object.x`` is known to read a number of ``tankviz.LeadVehicle``. Filters on
``/health`` (``/health.alarms[:]{id=="radar.silent"}.active``) are also checked against the
``/health`` the pipeline's own health monitor reports, so an alarm id, bus or message family
the bridge does not have is an error; Indicator panels must read one value and have rules that
can match it, Log panels must show a ``foxglove.Log`` topic.
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
from bridge.topics import HEALTH_TOPIC, LOG_TOPIC, VEHICLE_FRAME

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
    #: a message of each topic whose repeated elements are known in advance, to check message
    #: path filters on their :data:`SAMPLE_KEYS` against: ``/health`` with every bus, message
    #: family, sensor pair and alarm
    samples: dict[str, Any] = field(default_factory=dict)


#: The fields that say which element of a sample's repeated field an element is (a filter on
#: one of them must match an element of the sample); every other field is state that changes.
SAMPLE_KEYS: dict[str, frozenset[str]] = {
    "tankviz.BusHealth": frozenset({"bus"}),
    "tankviz.FamilyHealth": frozenset({"name", "sensor"}),
    "tankviz.SensorBias": frozenset({"pair", "sensor_a", "sensor_b"}),
    "tankviz.Alarm": frozenset({"id", "kind", "subject"}),
}


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

    The live pipeline's own announcement (:meth:`~bridge.pipeline.pipeline.Pipeline.advertise`) is
    recorded, and each topic's descriptor is built from the FileDescriptorSet it is advertised
    with: the scene, perception and health topics, /log, and per bus the raw frames and every
    message its databases define. Frames: the vehicle frame and the profile's sensors. Sample:
    the pipeline's own health monitor's ``/health`` (:func:`health_sample`).
    """
    from bridge.pipeline.pipeline import Pipeline, new_health_monitor

    buses = list(buses)
    announcements = _Announcements()
    health = new_health_monitor(decoder, profile)
    pipeline = Pipeline(decoder, profile=profile, server=announcements,  # type: ignore[arg-type]
                        health=health)
    pipeline.advertise(buses)
    out = Produced(frames={VEHICLE_FRAME})
    if profile is not None:
        out.frames.update(profile.sensors)
    for topic, (schema_name, schema) in announcements.schemas.items():
        out.topics[topic] = descriptor_of(schema_name, schema)
    out.samples[HEALTH_TOPIC] = health_sample(health, buses)
    return out


def health_sample(monitor: Any, buses: Iterable[str]) -> Any:
    """The ``/health`` message a new :class:`~bridge.health.monitor.HealthMonitor` publishes
    once each of ``buses`` has carried a frame: every bus, message family, sensor pair and alarm
    it reports (bus alarms appear with their bus). ``monitor`` is used up."""
    from bridge.frame import Frame

    for bus in buses:
        monitor.on_frame(Frame(0, bus, 0, b"", is_remote=True), None)
    for output in monitor.tick(0):
        if output.topic == HEALTH_TOPIC:
            return output.message
    raise BridgeError("the health monitor published no /health")  # pragma: no cover


def bundled_produced(profile: str = "ecocar", buses: Iterable[str] = ("can0",)) -> Produced:
    """What the bundled profile produces (the simulated car and ``tankviz demo`` use bus can0)."""
    from bridge.apps.convert import build_stages

    decoder, loaded = build_stages([], profile)
    return produced(decoder, loaded, buses)


# --- message paths ---------------------------------------------------------------------------

#: A field name and its indexes, slices and filters (quoted filter values may hold ``.``, ``]``
#: and ``}``).
_SUFFIX_TOKEN = r"""\[[^\]]*\]|\{(?:[^}"']|"[^"]*"|'[^']*')*\}"""
_SEGMENT = re.compile(rf"""
    (?P<name>[A-Za-z_][A-Za-z0-9_]*)          # a field
    (?P<suffix>(?:{_SUFFIX_TOKEN})*)           # indexes, slices and filters
    """, re.VERBOSE)
_TOKEN = re.compile(_SUFFIX_TOKEN)
_FILTER = re.compile(r"\{\s*([A-Za-z_][A-Za-z0-9_.]*)\s*(==|!=|<=|>=|<|>)\s*(.+?)\s*\}",
                     re.DOTALL)
_INDEX = re.compile(r"\s*(-?\d+)?\s*(?::\s*(-?\d+)?\s*)?")
_STRING_TYPE = 9
_BYTES_TYPE = 12
_BOOL_TYPE = 8
_UNKNOWN = object()  # a filter value that is a layout variable ($name): not known in advance
_COMPARE = {"==": lambda a, b: a == b, "!=": lambda a, b: a != b,
            "<": lambda a, b: a < b, "<=": lambda a, b: a <= b,
            ">": lambda a, b: a > b, ">=": lambda a, b: a >= b}


@dataclass(frozen=True)
class Resolved:
    """A message path resolved against a topic's type."""

    topic: str
    schema: str
    #: the field descriptor at the end, or None for the whole message
    leaf: Any
    #: whether the path can give more than one value (a slice that nothing narrows down, or,
    #: where the topic's elements are known in advance, a filter that matches several)
    several: bool = False

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


def _segments(rest: str, path: str) -> list[str]:
    """``a[:]{id=="x.y"}.b`` → ``['a[:]{id=="x.y"}', 'b']``: dots inside brackets, filters
    and quotes do not separate fields."""
    parts: list[str] = []
    current: list[str] = []
    depth = 0
    quote = ""
    for ch in rest:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'" and depth:
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "." and depth == 0:
            parts.append("".join(current))
            current = []
            continue
        current.append(ch)
    if quote or depth:
        raise BridgeError(f"{path}: unbalanced brackets or quotes")
    parts.append("".join(current))
    return parts


def _literal(text: str, path: str) -> Any:
    """The value of a filter: a quoted string, true/false, a number or a $variable."""
    if text.startswith("$"):
        return _UNKNOWN
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        return text[1:-1]
    if text in ("true", "false"):
        return text == "true"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        raise BridgeError(f"{path}: cannot read the filter value {text!r} (a quoted string, "
                          "a number, true or false)") from None


def _field_of(message: Any, dotted: str) -> Any:
    """The field descriptor ``a.b`` of a message descriptor (None if there is none)."""
    leaf = None
    for name in dotted.split("."):
        if message is None:
            return None
        leaf = message.fields_by_name.get(name)
        if leaf is None or _is_repeated(leaf):
            return None
        message = leaf.message_type if leaf.type == _MESSAGE_TYPE else None
    return leaf


def _value_of(element: Any, dotted: str) -> Any:
    for name in dotted.split("."):
        element = getattr(element, name)
    return element


def _filter_type_error(leaf: Any, value: Any) -> str | None:
    """Why a filter value can never equal the field (None if it can)."""
    if value is _UNKNOWN:
        return None
    if leaf.type == _STRING_TYPE:
        return None if isinstance(value, str) else "a string field: quote the value"
    if leaf.type == _BOOL_TYPE:
        return None if isinstance(value, bool) else "a boolean field: true or false"
    if leaf.type in _NUMERIC_TYPES:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        return None if ok else "a number field: compare it with a number"
    return "not a number, a string or a boolean"


def resolve_path(path: str, where: Produced) -> Resolved:
    """Resolve a Foxglove message path (``/topic.field.sub``, ``[0]``, ``[:]``, ``{id==3}``,
    ``{id=="radar.silent"}``, a trailing ``.@derivative`` and the like) against the produced
    topics' descriptors.

    On a topic with a sample message (:attr:`Produced.samples`, e.g. ``/health``), the path is
    also followed through the sample: an index past the end or a filter that matches no
    element (an alarm id, bus or family the bridge does not report) is an error.
    """
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
    sample = where.samples.get(topic)
    #: the sample's values at the path walked so far (None: no sample, or not known)
    values: list[Any] | None = [sample] if sample is not None else None
    several = False
    for part in _segments(rest[1:], path):
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
        repeated = _is_repeated(leaf)
        if repeated and "[" not in suffix:
            raise BridgeError(f"{path}: {walked} is repeated: index it ([0], [:])")
        if not repeated and "[" in suffix:
            raise BridgeError(f"{path}: {walked} is not repeated: it cannot be indexed")
        message = leaf.message_type if leaf.type == _MESSAGE_TYPE else None
        if values is not None:
            values = [getattr(v, name) for v in values]
        tokens = _TOKEN.findall(suffix)
        if sum(t.startswith("[") for t in tokens) > 1:
            raise BridgeError(f"{path}: {walked} is indexed twice")
        sliced = False
        for token in tokens:
            if token.startswith("["):
                values, sliced = _index(token, values, path, walked)
                continue
            filtered = _FILTER.fullmatch(token)
            if filtered is None:
                raise BridgeError(f"{path}: cannot read the filter {token}")
            field_name, operator, raw = filtered[1], filtered[2], filtered[3]
            field_leaf = _field_of(message, field_name) if message is not None else None
            if message is None or field_leaf is None:
                raise BridgeError(f"{path}: the filter on {walked} names no field "
                                  f"{field_name!r}")
            value = _literal(raw, path)
            problem = _filter_type_error(field_leaf, value)
            if problem:
                raise BridgeError(f"{path}: the filter on {walked}: {field_name} is {problem}")
            sliced = False  # narrowed down
            keys = SAMPLE_KEYS.get(message.full_name, frozenset())
            if values is None or value is _UNKNOWN or field_name not in keys:
                values = None  # which elements match is not known in advance
                continue
            kept = [v for v in values if _COMPARE[operator](_value_of(v, field_name), value)]
            if not kept:
                there = sorted({str(_value_of(v, field_name)) for v in values})
                raise BridgeError(
                    f"{path}: no {walked} has {field_name} {operator} {raw}; "
                    f"{field_name}: {', '.join(there) if there else 'none at all'}")
            values = kept
        several = several or sliced
    if values is not None:
        several = len(values) > 1
    return Resolved(topic, schema, leaf, several)


def _index(token: str, values: list[Any] | None, path: str,
           walked: str) -> tuple[list[Any] | None, bool]:
    """Apply ``[n]`` or ``[a:b]`` to the sample's repeated values (each a list)."""
    inner = token[1:-1]
    if "$" in inner:  # a layout variable
        return None, ":" in inner
    match = _INDEX.fullmatch(inner)
    if match is None or (match[1] is None and ":" not in inner):
        raise BridgeError(f"{path}: cannot read the index {token} (n, a:b or :)")
    if ":" not in inner:
        n = int(match[1])
        if values is None:
            return None, False
        picked = [v[n] for v in values if -len(v) <= n < len(v)]
        if not picked:
            raise BridgeError(f"{path}: {walked} has no element {n}")
        return picked, False
    if values is None:
        return None, True
    a = int(match[1]) if match[1] is not None else None
    b = int(match[2]) if match[2] is not None else None
    return [e for v in values for e in list(v)[a:b]], True


# --- checking a layout -----------------------------------------------------------------------


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
    if leaf.type == _STRING_TYPE:
        return None
    try:
        value = json.loads(raw)
    except ValueError:
        value = None
    if leaf.type == _BOOL_TYPE:
        if not isinstance(value, bool):
            return f"{raw!r} is not true or false"
        return None if operator == "=" else f"a boolean is compared with '=', not {operator!r}"
    if leaf.type in _NUMERIC_TYPES:
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
        leaf = None
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
                what = "a message" if whole else "not a number"
                problems.append(f"{place}: {path} is {what}: nothing to plot")
            elif kind in ("Indicator", "Gauge") and place == f"{panel_id}.path":
                leaf = resolved.leaf
                if leaf is None or leaf.type in (_MESSAGE_TYPE, _BYTES_TYPE):
                    what = "bytes" if leaf is not None and leaf.type == _BYTES_TYPE else "a message"
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
        for _, path, _ in _paths_of(panel_id, config):
            topic, _ = _split_topic(path, where.topics)
            if topic:
                out.add(topic)
    return out
