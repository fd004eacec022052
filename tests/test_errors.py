"""The error classes build their one-line messages from fields, and a caller's ``except`` tells
apart the kinds it handles differently (bridge/errors.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bridge.apps.layouts import load_layout
from bridge.apps.sources import parse_id
from bridge.errors import (
    BridgeError,
    DatabaseError,
    FileError,
    InputError,
    MessagePathError,
    ServerError,
    UsageError,
    ViewerInputError,
)
from bridge.profile.model import ProfileError
from bridge.sinks.server.viewer_input import TooManyMarks, client_message


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text
    return text


def test_file_errors_name_the_file_and_the_place() -> None:
    assert one_line(FileError(Path("out/d.mcap"), "exists already")) == "out/d.mcap: exists already"
    bad = InputError("d.blf", "a damaged object", where="object 3")
    assert one_line(bad) == "d.blf:object 3: a damaged object"
    assert (bad.path, bad.where, bad.reason) == ("d.blf", "object 3", "a damaged object")
    assert one_line(DatabaseError("car.dbc", "no such file")) == "car.dbc: no such file"
    profile = ProfileError("car.toml", "sensors.radar.x", "expected a number")
    assert one_line(profile) == "car.toml: sensors.radar.x: expected a number"
    assert (profile.key, profile.reason) == ("sensors.radar.x", "expected a number")
    assert one_line(ProfileError("car.toml", "", "not TOML")) == "car.toml: not TOML"
    # a name that is not UTF-8 is shown as \xNN
    assert str(FileError("bad\udce9.blf", "no such file")) == "bad\\xe9.blf: no such file"


def test_usage_errors_name_the_option_or_setting_and_the_value() -> None:
    assert one_line(UsageError("--speed", "must be above 0", value="0")) == (
        "--speed 0: must be above 0")
    assert one_line(UsageError("TANKVIZ_PORT", "expected a port", value="'abc'")) == (
        "TANKVIZ_PORT='abc': expected a port")
    assert one_line(UsageError("replay", "one MCAP at a time")) == "replay: one MCAP at a time"
    error = UsageError(Path("in/*.blf"), "matches no file")
    assert (error.argument, error.value, error.reason) == ("in/*.blf", None, "matches no file")
    with pytest.raises(UsageError, match=r"^--plot can0: expected BUS/ID, e\.g\. can0/0x1A0$"):
        parse_id("can0", "--plot")


def test_server_and_viewer_errors() -> None:
    assert one_line(ServerError("127.0.0.1", 8765, "address in use")) == (
        "cannot serve on 127.0.0.1:8765: address in use")
    assert one_line(ViewerInputError("not JSON")) == "not JSON"
    with pytest.raises(ViewerInputError) as refused:
        client_message(json.dumps({"op": "unsubscribe", "subscriptionIds": "x"}))
    assert refused.value.op == "unsubscribe"
    assert str(refused.value) == 'unsubscribe: "subscriptionIds" must be a list of integers'
    assert issubclass(TooManyMarks, ViewerInputError)


def test_a_layout_file_is_a_file_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{", encoding="utf-8")
    with pytest.raises(FileError, match=r"bad\.json: not JSON: line 1") as raised:
        load_layout(bad)
    assert not isinstance(raised.value, InputError)


def test_callers_tell_the_kinds_apart() -> None:
    """What each ``except`` of the bridge catches is its own class: an input another command
    goes on without, a database named anew, a message path reported as a layout's problem."""
    kinds = [InputError("a", "r"), DatabaseError("a", "r"), FileError("a", "r"),
             UsageError("--x", "r"), MessagePathError("/t.x", "r"), ServerError("h", 1, "r"),
             ViewerInputError("r")]
    for caught in (InputError, DatabaseError, MessagePathError, ViewerInputError):
        assert [type(k) for k in kinds if isinstance(k, caught)] == [caught]
    assert all(isinstance(k, BridgeError) for k in kinds)  # the CLI reports every one
    assert all(isinstance(k, FileError) for k in kinds[:3])
    assert issubclass(ProfileError, FileError)
