"""Foxglove panel settings and the mosaic of a layout, as the generated layouts write them
(:mod:`bridge.view.generate`, :mod:`bridge.view.bringup`): a layout of panels (:func:`layout_of`),
plots and their lines (:func:`plot`, :func:`series`), Raw Messages panels, panels side by side or
one above the other (:func:`stack`, :func:`weighted`, :func:`split`), and a layout as a file is
written (:func:`layout_text`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any


def layout_text(layout: dict[str, Any]) -> str:
    """A layout as the bundled files are written: JSON, indented by 2, a final newline."""
    return json.dumps(layout, indent=2, ensure_ascii=False) + "\n"


def layout_of(configs: dict[str, Any], tree: Any,
              variables: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A layout: panel settings by panel id, the mosaic ``tree`` of panel ids, and its global
    variables (names and first values)."""
    return {"configById": configs, "globalVariables": dict(variables or {}), "userNodes": {},
            "playbackConfig": {"speed": 1}, "layout": tree}


def series(value: str, label: str, color: str | None = None) -> dict[str, Any]:
    """A plot's line: a message path, its label in the legend, its colour if given."""
    out: dict[str, Any] = {"value": value, "enabled": True, "timestampMethod": "receiveTime",
                           "label": label}
    if color is not None:
        out["color"] = color
    return out


def plot(title: str, paths: list[dict[str, Any]], *, legend: str = "floating",
         sidebar: int = 240) -> dict[str, Any]:
    return {"foxglovePanelTitle": title, "paths": paths, "showXAxisLabels": True,
            "showYAxisLabels": True, "showLegend": True, "legendDisplay": legend,
            "showPlotValuesInLegend": True, "isSynced": True, "xAxisVal": "timestamp",
            "sidebarDimension": sidebar}


def raw_messages(title: str, topic: str) -> dict[str, Any]:
    return {"foxglovePanelTitle": title, "topicPath": topic, "diffEnabled": False,
            "diffMethod": "custom", "diffTopicPath": "", "showFullMessageForDiff": False,
            "expansion": "all"}


def stack(ids: Sequence[Any], direction: str) -> Any:
    """Panels (or trees) side by side (``row``) or one above the other (``column``), each the
    same share; None for none."""
    if not ids:
        return None
    if len(ids) == 1:
        return ids[0]
    return {"direction": direction, "first": ids[0], "second": stack(ids[1:], direction),
            "splitPercentage": round(100 / len(ids), 1)}


def weighted(ids: Sequence[Any], weights: Sequence[float], direction: str) -> Any:
    """Like :func:`stack`, each panel its weight's share."""
    if len(ids) <= 1:
        return ids[0] if ids else None
    share = round(100 * weights[0] / sum(weights), 1)
    return {"direction": direction, "first": ids[0],
            "second": weighted(ids[1:], weights[1:], direction), "splitPercentage": share}


def split(first: Any, second: Any, direction: str, percentage: float) -> Any:
    """``first`` and ``second`` split at ``percentage``, or whichever of them there is."""
    if first is None or second is None:
        return second if first is None else first
    return {"direction": direction, "first": first, "second": second,
            "splitPercentage": percentage}


