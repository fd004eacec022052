"""Foxglove message paths resolved against what the bridge produces.

:func:`resolve_path` walks a path such as ``/perception/lead.object.x`` through its topic's
protobuf descriptor and says its topic, schema and last field, whether a plot can draw it and
whether it gives several values; a path that cannot be read or names what is not there is a
:class:`~bridge.errors.BridgeError`.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from google.protobuf.descriptor import FieldDescriptor

from bridge.errors import MessagePathError
from bridge.view.produced import SAMPLE_KEYS, Produced

#: Protobuf field types a plot can draw: numbers, booleans and enums (all but string, group,
#: message and bytes).
NUMERIC_TYPES: frozenset[int] = frozenset({
    FieldDescriptor.TYPE_DOUBLE, FieldDescriptor.TYPE_FLOAT,
    FieldDescriptor.TYPE_INT64, FieldDescriptor.TYPE_UINT64,
    FieldDescriptor.TYPE_INT32, FieldDescriptor.TYPE_FIXED64,
    FieldDescriptor.TYPE_FIXED32, FieldDescriptor.TYPE_BOOL,
    FieldDescriptor.TYPE_UINT32, FieldDescriptor.TYPE_ENUM,
    FieldDescriptor.TYPE_SFIXED32, FieldDescriptor.TYPE_SFIXED64,
    FieldDescriptor.TYPE_SINT32, FieldDescriptor.TYPE_SINT64,
})

#: A field name and its indexes, slices and filters (quoted filter values may hold ``.``, ``]``
#: and ``}``).
_SUFFIX_TOKEN = r"""\[[^\]]*\]|\{(?:[^}"']|"[^"]*"|'[^']*')*\}"""
_SEGMENT = re.compile(rf"""
    (?P<name>[A-Za-z_][A-Za-z0-9_]*)          # a field
    (?P<suffix>(?:{_SUFFIX_TOKEN})*)           # indexes, slices and filters
    """, re.VERBOSE)
_TOKEN = re.compile(_SUFFIX_TOKEN)
#: Filters on a topic's message itself, right after the topic name.
_HEAD_FILTERS = re.compile(r"""(?:\{(?:[^}"']|"[^"]*"|'[^']*')*\})+""")
_FILTER = re.compile(r"\{\s*([A-Za-z_][A-Za-z0-9_.]*)\s*(==|!=|<=|>=|<|>)\s*(.+?)\s*\}",
                     re.DOTALL)
_INDEX = re.compile(r"\s*(-?\d+)?\s*(?::\s*(-?\d+)?\s*)?")
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
        return self.leaf is not None and self.leaf.type in NUMERIC_TYPES


def _is_repeated(descriptor: Any) -> bool:
    repeated = getattr(descriptor, "is_repeated", None)
    if isinstance(repeated, bool):
        return repeated
    return bool(descriptor.label == descriptor.LABEL_REPEATED)


def split_topic(path: str, topics: Mapping[str, Any]) -> tuple[str, str]:
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
        raise MessagePathError(path, "unbalanced brackets or quotes")
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
        raise MessagePathError(path, f"cannot read the filter value {text!r} (a quoted "
                               "string, a number, true or false)") from None


def _field_of(message: Any, dotted: str) -> Any:
    """The field descriptor ``a.b`` of a message descriptor (None if there is none)."""
    leaf = None
    for name in dotted.split("."):
        if message is None:
            return None
        leaf = message.fields_by_name.get(name)
        if leaf is None or _is_repeated(leaf):
            return None
        message = leaf.message_type if leaf.type == FieldDescriptor.TYPE_MESSAGE else None
    return leaf


def _value_of(element: Any, dotted: str) -> Any:
    for name in dotted.split("."):
        element = getattr(element, name)
    return element


def _filter_type_error(leaf: Any, value: Any) -> str | None:
    """Why a filter value can never equal the field (None if it can)."""
    if value is _UNKNOWN:
        return None
    if leaf.type == FieldDescriptor.TYPE_STRING:
        return None if isinstance(value, str) else "a string field: quote the value"
    if leaf.type == FieldDescriptor.TYPE_BOOL:
        return None if isinstance(value, bool) else "a boolean field: true or false"
    if leaf.type in NUMERIC_TYPES:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        return None if ok else "a number field: compare it with a number"
    return "not a number, a string or a boolean"


def resolve_path(path: str, where: Produced, *, lists: bool = False) -> Resolved:
    """Resolve a Foxglove message path (``/topic.field.sub``, ``[0]``, ``[:]``, ``{id==3}``,
    ``{id=="radar.silent"}``, a filter on the topic's message itself ``/topic{id==3}.field``, a
    trailing ``.@derivative`` and the like) against the produced topics' descriptors.
    ``lists``: the path may end at a repeated field, not indexed (the Table panel shows the
    whole list, a row per element); the path can then give several values.

    On a topic with a sample message (:attr:`Produced.samples`, e.g. ``/health``), the path is
    also followed through the sample: an index past the end or a filter that matches no
    element (an alarm id, bus or family the bridge does not report) is an error.
    """
    topic, rest = split_topic(path, where.topics)
    if not topic:
        raise MessagePathError(path, "no such topic")
    descriptor = where.topics[topic]
    schema = descriptor.full_name
    rest = re.sub(r"\.@[A-Za-z]+$", "", rest)  # modifiers (@derivative, @abs, …)
    sample = where.samples.get(topic)
    #: the sample's values at the path walked so far (None: no sample, or not known)
    values: list[Any] | None = [sample] if sample is not None else None
    # filters on the topic's message itself: /can/can0/unknown{id=="0x2C4"}.bytes[0]
    head = _HEAD_FILTERS.match(rest)
    for token in _TOKEN.findall(head[0] if head else ""):
        values = _filtered(token, descriptor, values, path, topic)
    rest = rest[head.end() if head else 0:]
    if not rest:
        return Resolved(topic, schema, None)
    if not rest.startswith("."):
        raise MessagePathError(path, f"expected '.field' after {topic}")
    message, leaf = descriptor, None
    walked = topic
    several = False
    parts = _segments(rest[1:], path)
    for n, part in enumerate(parts, 1):
        match = _SEGMENT.fullmatch(part)
        if match is None:
            raise MessagePathError(path, f"cannot read {part!r}")
        if message is None:
            raise MessagePathError(path, f"{walked} is not a message, it has no field "
                                        f"{match['name']!r}")
        name = match["name"]
        leaf = message.fields_by_name.get(name)
        if leaf is None:
            fields = ", ".join(message.fields_by_name)
            raise MessagePathError(path, f"{message.full_name} has no field {name!r}; "
                                        f"fields: {fields}")
        walked += f".{name}"
        suffix = match["suffix"]
        repeated = _is_repeated(leaf)
        whole = repeated and lists and not suffix and n == len(parts)  # a whole list
        if repeated and "[" not in suffix and not whole:
            raise MessagePathError(path, f"{walked} is repeated: index it ([0], [:])")
        if not repeated and "[" in suffix:
            raise MessagePathError(path, f"{walked} is not repeated: it cannot be indexed")
        message = leaf.message_type if leaf.type == FieldDescriptor.TYPE_MESSAGE else None
        if values is not None:
            values = [getattr(v, name) for v in values]
        tokens = _TOKEN.findall(suffix)
        if sum(t.startswith("[") for t in tokens) > 1:
            raise MessagePathError(path, f"{walked} is indexed twice")
        sliced = False
        for token in tokens:
            if token.startswith("["):
                values, sliced = _index(token, values, path, walked)
                continue
            values = _filtered(token, message, values, path, walked)
            sliced = False  # narrowed down
        if whole:
            values = [e for v in values for e in v] if values is not None else None
            sliced = True
        several = several or sliced
    if values is not None:
        several = len(values) > 1
    return Resolved(topic, schema, leaf, several)


def _filtered(token: str, message: Any, values: list[Any] | None, path: str,
              walked: str) -> list[Any] | None:
    """Apply the filter ``token`` (``{id==3}``) to the elements of ``walked`` (each a
    ``message``; ``values``: the sample's, None when not known in advance)."""
    filtered = _FILTER.fullmatch(token)
    if filtered is None:
        raise MessagePathError(path, f"cannot read the filter {token}")
    field_name, operator, raw = filtered[1], filtered[2], filtered[3]
    field_leaf = _field_of(message, field_name) if message is not None else None
    if message is None or field_leaf is None:
        raise MessagePathError(path, f"the filter on {walked} names no field {field_name!r}")
    value = _literal(raw, path)
    problem = _filter_type_error(field_leaf, value)
    if problem:
        raise MessagePathError(path, f"the filter on {walked}: {field_name} is {problem}")
    keys = SAMPLE_KEYS.get(message.full_name, frozenset())
    if values is None or value is _UNKNOWN or field_name not in keys:
        return None  # which elements match is not known in advance
    kept = [v for v in values if _COMPARE[operator](_value_of(v, field_name), value)]
    if not kept:
        there = sorted({str(_value_of(v, field_name)) for v in values})
        raise MessagePathError(path, f"no {walked} has {field_name} {operator} {raw}; "
                               f"{field_name}: {', '.join(there) if there else 'none at all'}")
    return kept


def _index(token: str, values: list[Any] | None, path: str,
           walked: str) -> tuple[list[Any] | None, bool]:
    """Apply ``[n]`` or ``[a:b]`` to the sample's repeated values (each a list)."""
    inner = token[1:-1]
    if "$" in inner:  # a layout variable
        return None, ":" in inner
    match = _INDEX.fullmatch(inner)
    if match is None or (match[1] is None and ":" not in inner):
        raise MessagePathError(path, f"cannot read the index {token} (n, a:b or :)")
    if ":" not in inner:
        n = int(match[1])
        if values is None:
            return None, False
        picked = [v[n] for v in values if -len(v) <= n < len(v)]
        if not picked:
            raise MessagePathError(path, f"{walked} has no element {n}")
        return picked, False
    if values is None:
        return None, True
    a = int(match[1]) if match[1] is not None else None
    b = int(match[2]) if match[2] is not None else None
    return [e for v in values for e in list(v)[a:b]], True

