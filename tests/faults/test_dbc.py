"""Database problems that silence a message are said, not found out later (issue #13, item 9):
overlapping signals or a signal beyond its message (cantools cannot decode such a message) are
warned about when the database is loaded; a ``--dbc BUS=`` for a bus that no input has is warned
about at the end of the summary; both are in the drive's metadata. CAN FD frames longer than their
DBC message decode what the message defines, and the statistics note the bytes beyond it.
"""

from __future__ import annotations

import json
from pathlib import Path

import can
import cantools
import pytest
from conftest import T0, WriteLog, message

from bridge.apps.inspect import format_summary, summarize_file
from bridge.cli import main
from bridge.decode.database import load_database

DOOR_DBC = """VERSION ""
BS_:
BU_: Door
BO_ 1056 DoorState: 8 Door
 SG_ Open : 0|8@1+ (1,0) [0|255] "" Door
 SG_ Lock : 4|8@1+ (1,0) [0|255] "" Door
BO_ 1057 Window: 2 Door
 SG_ Pos : 0|8@1+ (1,0) [0|255] "" Door
 SG_ Far : 12|8@1+ (1,0) [0|255] "" Door
BO_ 1058 Mirror: 8 Door
 SG_ Angle : 0|8@1+ (1,0) [0|255] "" Door
"""


def door_frames(n: int = 10) -> list[can.Message]:
    return [can.Message(timestamp=T0 + i / 100, arbitration_id=id_, data=bytes(8), channel=0,
                        is_extended_id=False)
            for i in range(n) for id_ in (0x420, 0x421, 0x422)]


def metadata_warnings(path: Path) -> list[str]:
    warnings: list[str] = json.loads(summarize_file(path).metadata["tankviz"]["warnings"])
    return warnings


def test_a_message_cantools_cannot_decode_is_warned_about_at_load(tmp_path: Path) -> None:
    path = tmp_path / "door.dbc"
    path.write_text(DOOR_DBC)
    assert load_database(path).warnings == (
        f"{path}: the signals Lock and Open are overlapping in message DoorState (0x420); "
        "cantools cannot decode any frame of it",
        f"{path}: the signal Far does not fit in message Window (0x421); "
        "cantools cannot decode any frame of it",
    )


def test_a_sound_database_has_no_warnings(shared_dbc: Path) -> None:
    for path in sorted(shared_dbc.glob("*.dbc")):
        if path.name == "toyota_2017_pt.dbc":  # a real car's DBC, one message broken (below)
            continue
        assert load_database(path).warnings == ()


def test_a_real_cars_broken_message_is_warned_about_and_the_rest_decodes(
        shared_dbc: Path) -> None:
    """opendbc's Toyota car bus: PCS_HUD's signals overlap (shared/README says so)."""
    path = shared_dbc / "toyota_2017_pt.dbc"
    assert load_database(path).warnings == (
        f"{path}: the signals PCS_TEMP and SET_ME_X10 are overlapping in message PCS_HUD "
        "(0x411); cantools cannot decode any frame of it",)


def test_convert_warns_at_load_and_at_the_end_and_keeps_the_warnings(
        tmp_path: Path, write_log: WriteLog, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "door.dbc").write_text(DOOR_DBC)
    log = write_log("door.blf", door_frames())
    out = tmp_path / "door.mcap"
    assert main(["convert", str(log), "-o", str(out), "--dbc", str(tmp_path / "door.dbc")]) == 0
    printed = capsys.readouterr()
    warnings = load_database(tmp_path / "door.dbc").warnings
    assert [line for line in printed.err.splitlines() if line.startswith("warning:")] == [
        f"warning: {text}" for text in warnings]
    lines = printed.out.splitlines()
    assert lines[-3:] == ["  warnings (2):", *(f"    {text}" for text in warnings)]
    assert metadata_warnings(out) == list(warnings)
    inspected = format_summary(str(out), summarize_file(out))
    assert all(text in inspected for text in warnings)


def test_a_dbc_for_a_bus_that_no_input_has_is_warned_about(
        tmp_path: Path, shared_dbc: Path, write_log: WriteLog,
        capsys: pytest.CaptureFixture[str]) -> None:
    esr = cantools.database.load_file(shared_dbc / "ESR.dbc")
    log = write_log("esr.blf", [message(esr, "Target1", T0 + i / 20, channel=0)
                                for i in range(20)])  # BLF channel 0: bus can0
    out = tmp_path / "esr.mcap"
    assert main(["convert", str(log), "-o", str(out),
                 "--dbc", f"radar={shared_dbc / 'ESR.dbc'}"]) == 0
    printed = capsys.readouterr().out
    expected = (f"--dbc radar={shared_dbc / 'ESR.dbc'}: no input has bus radar (the inputs have "
                "can0), so nothing was decoded with it")
    assert printed.splitlines()[-2:] == ["  warnings (1):", f"    {expected}"]
    assert "unknown ids 20" in printed
    assert metadata_warnings(out) == [expected]


def test_fd_frames_longer_than_their_message_decode_and_the_extra_bytes_are_noted(
        tmp_path: Path, write_log: WriteLog, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "mirror.dbc").write_text(DOOR_DBC)
    frames = [can.Message(timestamp=T0 + i / 100, arbitration_id=0x422, is_fd=True,
                          is_extended_id=False, data=bytes([7] * length), channel=0)
              for i, length in enumerate([8, 12, 64, 64])]
    log = write_log("mirror.blf", frames)
    out = tmp_path / "mirror.mcap"
    assert main(["convert", str(log), "-o", str(out), "--dbc",
                 str(tmp_path / "mirror.dbc")]) == 0
    printed = capsys.readouterr().out
    stats = json.loads(summarize_file(out).metadata["tankviz"]["statistics"])
    assert stats["decoded"] == {"/can/can0/Mirror": 4}
    assert stats["longer"] == {"/can/can0/Mirror": {"frames": 3, "message_bytes": 8,
                                                     "longest": 64}}
    assert "longer than their message 3" in printed
    assert ("/can/can0/Mirror: 3 frames longer than its 8 bytes (up to 64)"
            in format_summary(str(out), summarize_file(out)))


@pytest.mark.slow
def test_live_warns_at_start_about_a_database_and_a_bus_it_will_never_decode(
        tmp_path: Path) -> None:
    """Live says at once what would silence messages: a database cantools cannot decode all of,
    and a --dbc BUS= for a bus that is not read."""
    import subprocess
    import sys

    (tmp_path / "door.dbc").write_text(DOOR_DBC)
    run = subprocess.run(
        [sys.executable, "-m", "bridge", "live", "--bus", f"body=virtual:warn-{tmp_path.name}",
         "--dbc", f"body={tmp_path / 'door.dbc'}", "--dbc", f"trailer={tmp_path / 'door.dbc'}",
         "--no-server", "--drives", str(tmp_path / "drives"), "--min-free", "0", "--for", "0.5"],
        capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stderr
    warned = [line for line in run.stderr.splitlines() if line.startswith("warning:")]
    assert warned == [
        *(f"warning: {text}" for text in load_database(tmp_path / "door.dbc").warnings),
        f"warning: --dbc trailer={tmp_path / 'door.dbc'}: no --bus trailer, so nothing is "
        "decoded with it"]


def test_a_database_and_a_profile_saved_with_a_byte_order_mark_load(tmp_path: Path) -> None:
    """Editors on Windows save UTF-8 with a byte-order mark (EF BB BF): cantools then failed at
    line 1, column 1, and TOML too, neither naming the mark. Both load as without it."""
    from bridge.decode.database import load_database
    from bridge.profile.loader import load_profile
    from bridge.resources import data_dir

    dbc = tmp_path / "ecocar.dbc"
    dbc.write_bytes(b"\xef\xbb\xbf" + (data_dir() / "ecocar.dbc").read_bytes())
    loaded = load_database(dbc)
    assert {m.name for m in loaded.db.messages} == {
        m.name for m in load_database(data_dir() / "ecocar.dbc").db.messages}
    profile = tmp_path / "ecocar.toml"
    profile.write_bytes(b"\xef\xbb\xbf" + (data_dir() / "ecocar.toml").read_bytes())
    assert load_profile(profile, [loaded.db]).name == "ecocar"


def test_one_file_giving_an_id_two_messages_is_one_line_naming_both(
        tmp_path: Path, write_log: WriteLog, capsys: pytest.CaptureFixture[str]) -> None:
    """#33 item 12: the error advised giving the file to two buses, after cantools' own
    'Overwriting message ...' log line."""
    (tmp_path / "dup.dbc").write_text(DOOR_DBC.replace("BO_ 1058 Mirror", "BO_ 1056 Mirror"))
    log = write_log("door.blf", door_frames(1))
    assert main(["convert", str(log), "-o", str(tmp_path / "door.mcap"), "--dbc",
                 str(tmp_path / "dup.dbc")]) == 1
    printed = capsys.readouterr()
    assert printed.err.splitlines() == [
        f"error: {tmp_path / 'dup.dbc'}: messages DoorState (line 4) and Mirror (line 10) both "
        "have id 0x420: a database gives an id one message; remove or renumber one"]
    assert not (tmp_path / "door.mcap").exists()


def test_an_identical_twin_message_loads_without_a_word(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """cantools logs 'Overwriting message ...' for it (to stderr, without a handler): kept in."""
    twin = 'BO_ 1058 Mirror: 8 Door\n SG_ Angle : 0|8@1+ (1,0) [0|255] "" Door\n'
    (tmp_path / "twin.dbc").write_text(DOOR_DBC + twin)
    loaded = load_database(tmp_path / "twin.dbc")
    assert [m.name for m in loaded.db.messages].count("Mirror") == 2
    assert not any("cantools:" in text for text in loaded.warnings)
    assert [r.getMessage() for r in caplog.records if r.name.startswith("cantools")] == []


WIDE_DBC = """VERSION ""
BS_:
BU_: Meter
BO_ 1024 Odometer: 8 Meter
 SG_ Doubled : 0|64@1+ (2,1) [1|36893488147419103231] "" Meter
BO_ 1025 Counter: 8 Meter
 SG_ Signed : 0|64@1- (1,-1) [0|0] "" Meter
BO_ 1026 Trip: 8 Meter
 SG_ Exact : 0|64@1+ (1,0) [0|18446744073709551615] "" Meter
BO_ 1027 Half: 8 Meter
 SG_ Half : 0|64@1+ (0.5,0) [0|0] "" Meter
"""


def test_an_integer_signal_beyond_64_bits_is_said_to_be_rounded(tmp_path: Path) -> None:
    """#33 item 12: a 64-bit signal with scale 2 and offset 1 is an exact int in cantools but
    fits no 64-bit integer field: it is stored as a double, and the load says so. Scale 1 stays
    an exact uint64; a fractional scale is cantools' own float, no warning."""
    from bridge.decode.decoder import Decoder

    path = tmp_path / "wide.dbc"
    path.write_text(WIDE_DBC)
    loaded = load_database(path)
    assert loaded.warnings == (
        f"{path}: signal Doubled of message Odometer (0x400) ranges over "
        "1..36893488147419103231, beyond any 64-bit integer: it is stored as a double, so "
        "values beyond 2^53 are rounded (the raw frames keep them exact)",
        f"{path}: signal Signed of message Counter (0x401) ranges over "
        "-9223372036854775809..9223372036854775806, beyond any 64-bit integer: it is stored as "
        "a double, so values beyond 2^53 are rounded (the raw frames keep them exact)")
    decoder = Decoder({None: [loaded]})
    codecs = {c.message.name: c for c in decoder.codecs_for("can0")}
    big = 2**64 - 3
    data = big.to_bytes(8, "little")
    assert codecs["Trip"].schema.parse(codecs["Trip"].decode(data).payload) == {
        "Exact": big}  # a uint64: exact
    doubled = codecs["Odometer"].schema.parse(codecs["Odometer"].decode(data).payload)
    assert doubled["Doubled"] == float(2 * big + 1) != 2 * big + 1  # a double: rounded
