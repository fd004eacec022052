"""The bring-up layout: a new car's ids, which of them no database knows, and their bits
(what ``tankviz layouts --dbc ... --export DIR`` writes as ``bring-up.json``).

A Table of each bus's ids, the bit-change map and one unknown id followed (plots of its bytes and
16-bit words), the id the layout variable ``unknown_id`` (:data:`ID_VARIABLE`) and the words'
first byte the variable ``word`` (:data:`WORD_VARIABLE`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from bridge.topics import BITS_TOPIC, ids_topic, unknown_topic
from bridge.view.panels import layout_of, plot, raw_messages, series, split, stack, weighted

#: The layout's name (``bring-up.json``).
BRINGUP_NAME = "bring-up"
#: The layout variable holding the unknown id the plots follow (the id as the table writes it).
ID_VARIABLE = "unknown_id"
#: The layout variable holding the byte the 16-bit words start at (0 to 6).
WORD_VARIABLE = "word"
#: The bytes of a classic CAN payload, plotted one line each.
PAYLOAD_BYTES = 8
#: Line colours of the eight bytes (distinct on a dark background), then of the two words.
BYTE_COLOURS = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1",
                "#ff9da7")
WORD_COLOURS = ("#4e79a7", "#f28e2b")
#: Shares of the window: the tables and the map above the plots; the tables beside the map
#: (on a laptop, 1280 x 800, the tables show id, message, frames, period and jitter, the rest
#: a scroll away; the map, about 1000 pixels wide for a car, is drawn at three quarters).
TOP_SHARE, TABLES_SHARE = 58.0, 45.0


def id_filter(bus: str) -> str:
    """The message path of the followed unknown id's frames on ``bus``."""
    return f"{unknown_topic(bus)}{{id==${ID_VARIABLE}}}"


def ids_table(bus: str) -> dict[str, Any]:
    return {"foxglovePanelTitle": f"Ids of {bus} ({ids_topic(bus)})",
            "topicPath": f"{ids_topic(bus)}.rows"}


def bit_map() -> dict[str, Any]:
    """The Image panel of the bit-change map: cells drawn sharp (no smoothing), the whole map
    in view; its labels are in the image (the same texts as annotations would be drawn twice)."""
    return {"foxglovePanelTitle": "Bit-change map: a row per bus and id, a column per bit",
            "cameraTopic": BITS_TOPIC, "enabledMarkerTopics": [],
            "synchronize": False, "smooth": False, "mode": "fit", "pan": {"x": 0, "y": 0},
            "rotation": 0, "zoom": 1, "transformMarkers": False}


def word_slider() -> dict[str, Any]:
    return {"foxglovePanelTitle": f"${WORD_VARIABLE}: the words' first byte",
            "sliderProps": {"min": 0, "max": PAYLOAD_BYTES - 2, "step": 1},
            "globalVariableName": WORD_VARIABLE}


def bringup_layout(buses: Sequence[str], plot_id: tuple[str, str] | None = None
                   ) -> dict[str, Any]:
    """The bring-up layout for ``buses``: a table of ids per bus, the bit-change map, and the
    plots of one unknown id (``plot_id``: its bus and id as the table writes it, ``0x2C4``;
    default: the first bus, no id)."""
    buses = list(dict.fromkeys(buses))
    if not buses:
        raise ValueError("the bring-up layout needs a bus")
    bus, ident = plot_id if plot_id is not None else (buses[0], "")
    if bus not in buses:
        buses.append(bus)
    configs: dict[str, Any] = {f"Table!ids-{b}": ids_table(b) for b in buses}
    configs["ImageViewPanel!bits"] = bit_map()
    where = id_filter(bus)
    configs["Plot!unknown-bytes"] = plot(
        f"Bytes of ${ID_VARIABLE} on {bus} (set {ID_VARIABLE} in the Variables sidebar, e.g. "
        f'"0x2C4")',
        [series(f"{where}.bytes[{i}]", f"byte {i}", BYTE_COLOURS[i])
         for i in range(PAYLOAD_BYTES)], legend="left", sidebar=150)
    configs["Plot!unknown-words"] = plot(
        f"16-bit words of ${ID_VARIABLE} from byte ${WORD_VARIABLE}",
        [series(f"{where}.be16[${WORD_VARIABLE}]", "be16", WORD_COLOURS[0]),
         series(f"{where}.le16[${WORD_VARIABLE}]", "le16", WORD_COLOURS[1])],
        legend="left", sidebar=130)
    configs["GlobalVariableSliderPanel!word"] = word_slider()
    configs["RawMessages!unknown"] = raw_messages(f"Latest frame of ${ID_VARIABLE} on {bus}",
                                                  where)
    tables = stack([f"Table!ids-{b}" for b in buses], "column")
    words = weighted(["GlobalVariableSliderPanel!word", "Plot!unknown-words"], [1, 3],
                     "column")
    plots = weighted(["Plot!unknown-bytes", words, "RawMessages!unknown"], [4, 3, 2], "row")
    top = split(tables, "ImageViewPanel!bits", "row", TABLES_SHARE)
    return layout_of(configs, split(top, plots, "column", TOP_SHARE),
                     {ID_VARIABLE: ident, WORD_VARIABLE: 0})
