"""Fields found as DBC text: ``BO_`` and ``SG_`` lines to paste, or a whole file that
``--dbc`` loads.

A field becomes a signal of a message named for its id (``ID_2C4``, ``ID_18FEF100`` with the
extended bit set in its ``BO_`` number), its fitted scale and offset rounded to six significant
digits, its range the one its raw values can take.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from bridge.bringup.search import Candidate, Field
from bridge.frame import EXTENDED_KEY, key_id

#: The DBC's marker of a 29-bit id in a ``BO_`` number.
DBC_EXTENDED = 0x80000000
_HEADER = 'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_:\n\n'
_UNSAFE = re.compile(r"[^A-Za-z0-9_]")


def message_name(key: int) -> str:
    digits = 8 if key & EXTENDED_KEY else 3
    return f"ID_{key_id(key):0{digits}X}"


def signal_name(reference: str, rank: int) -> str:
    """``SPEED_LIKE_1``: named for what it follows, numbered by rank."""
    base = _UNSAFE.sub("_", reference.rsplit(".", 1)[-1]).strip("_").upper() or "SIGNAL"
    if base[0].isdigit():
        base = f"S_{base}"
    return f"{base}_LIKE_{rank}"


def _number(value: float) -> str:
    text = f"{value:.6g}"
    return "0" if text in ("-0", "0") else text


def message_line(f: Field, length_bytes: int) -> str:
    number = key_id(f.key) | DBC_EXTENDED if f.key & EXTENDED_KEY else f.key
    return f"BO_ {number} {message_name(f.key)}: {length_bytes} Vector__XXX"


def signal_line(c: Candidate, name: str, unit: str) -> str:
    f = c.field
    order = "0" if f.big_endian else "1"
    sign = "-" if f.signed else "+"
    scale, offset = float(_number(c.scale)), float(_number(c.offset))
    low_raw, high_raw = ((-(1 << (f.length - 1)), (1 << (f.length - 1)) - 1) if f.signed
                         else (0, (1 << f.length) - 1))
    ends = sorted((low_raw * scale + offset, high_raw * scale + offset))
    unit_text = unit.replace('"', "'")
    return (f" SG_ {name} : {f.start_bit}|{f.length}@{order}{sign} ({_number(scale)},"
            f"{_number(offset)}) [{_number(ends[0])}|{_number(ends[1])}] \"{unit_text}\" "
            "Vector__XXX")


def candidate_lines(c: Candidate, rank: int, reference: str, unit: str,
                    length_bytes: int) -> list[str]:
    """The two lines of one candidate, to paste into a DBC."""
    return [message_line(c.field, length_bytes),
            signal_line(c, signal_name(reference, rank), unit)]


def dbc_file(candidates: Sequence[Candidate], reference: str, unit: str,
             lengths: dict[tuple[str, int], int]) -> str:
    """A DBC of one bus, the best candidate's: every candidate of it that overlaps none before
    it on its id, best first (``lengths``: each id's payload length, bytes)."""
    messages: dict[int, list[str]] = {}
    used: dict[int, set[int]] = {}
    bus = candidates[0].field.bus if candidates else None
    for rank, c in enumerate(candidates, 1):
        key = c.field.key
        if c.field.bus != bus:
            continue
        bits = set(c.field.bits())
        if used.get(key, set()) & bits:
            continue
        used.setdefault(key, set()).update(bits)
        if key not in messages:
            messages[key] = [message_line(c.field, lengths[(c.field.bus, key)])]
        messages[key].append(signal_line(c, signal_name(reference, rank), unit))
    body = "\n\n".join("\n".join(lines) for lines in messages.values())
    return _HEADER + body + "\n"
