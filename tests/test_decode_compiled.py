"""The precompiled decoder gives exactly what cantools gives: the same signals in the same order,
each value equal and of the same type, on every message of the bundled and public DBCs."""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

import cantools
import pytest
from cantools.database.can.database import Database
from conftest import ECOCAR_DBC, SHARED_DBC

from bridge.decode.compiled import compile_decoder

PAYLOADS_PER_MESSAGE = 40


def databases() -> list[Path]:
    return [ECOCAR_DBC, *sorted(SHARED_DBC.glob("*.dbc"))] if SHARED_DBC.is_dir() \
        else [ECOCAR_DBC]


def same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Equal keys in equal order, and equal values of equal types (NaN equals NaN)."""
    return list(a) == list(b) and all(
        type(a[k]) is type(b[k]) and (a[k] == b[k] or (isinstance(a[k], float)
                                                      and math.isnan(a[k]) and math.isnan(b[k])))
        for k in a)


def cantools_decode(message: Any, data: bytes) -> dict[str, Any] | Exception:
    try:
        return dict(message.decode(data, decode_choices=False, allow_truncated=True))
    except Exception as exc:
        return exc


@pytest.mark.parametrize("path", databases(), ids=lambda p: p.name)
def test_every_message_decodes_as_cantools_decodes_it(path: Path) -> None:
    db = cantools.database.load_file(path, strict=False)
    assert isinstance(db, Database)
    rng = random.Random(path.name)
    compiled = 0
    for message in db.messages:
        decode = compile_decoder(message)
        if decode is None:
            # (or, like PCS_HUD of a real Toyota's DBC, its signals overlap: nothing decodes)
            assert (message.is_multiplexed() or message.is_container or isinstance(
                cantools_decode(message, bytes(message.length)), Exception)), message.name
            continue
        compiled += 1
        n = message.length
        payloads = [bytes(n), b"\xff" * n, *(rng.randbytes(n) for _ in range(PAYLOADS_PER_MESSAGE))]
        payloads += [rng.randbytes(n // 2), rng.randbytes(n + 3)]  # cantools' own way
        for data in payloads:
            expected = cantools_decode(message, data)
            if isinstance(expected, Exception):
                with pytest.raises(type(expected)):
                    decode(data)
                continue
            got = decode(data)
            assert same(got, expected), f"{path.name}: {message.name} {data.hex()}"
    assert compiled > 0


def test_a_multiplexed_message_is_left_to_cantools() -> None:
    db = cantools.database.load_file(ECOCAR_DBC)
    multiplexed = [m for m in db.messages if m.is_multiplexed()]
    assert multiplexed and all(compile_decoder(m) is None for m in multiplexed)


def test_integer_scaling_stays_integer_and_floats_stay_floats() -> None:
    db = cantools.database.load_string("""VERSION ""
BO_ 256 Mixed: 8 Vector__XXX
 SG_ Count : 0|8@1+ (2,-10) [-10|500] "" Vector__XXX
 SG_ Speed : 8|16@1- (0.01,0) [-327|327] "m/s" Vector__XXX
 SG_ Raw : 31|8@0+ (1,0) [0|255] "" Vector__XXX
 SG_ Level : 32|32@1- (1,0) [0|0] "" Vector__XXX
SIG_VALTYPE_ 256 Level : 1;
""")
    message = db.get_message_by_name("Mixed")
    decode = compile_decoder(message)
    assert decode is not None
    data = bytes([7, 0x38, 0xFF, 0x80]) + (float("inf").hex() and b"\x00\x00\x80\x7f")

    got = decode(data)

    assert got == {"Count": 4, "Speed": -2.0, "Raw": 0x80, "Level": float("inf")}
    assert [type(v) for v in got.values()] == [int, float, int, float]
    assert same(got, dict(message.decode(data, decode_choices=False)))
