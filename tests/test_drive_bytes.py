"""The same input makes the same drive: a hash of every topic's messages of two conversions.

``tests/golden/drive_hashes.json`` holds, per topic, the SHA-256 of every message (log time,
publish time and data, in file order) of

- ``sample``: the bundled sample log converted with the ecocar profile (``convert --sample``);
- ``gm``: a drive of a car unlike ecocar (the public GM object DBC with tests/profiles/
  gm_object.toml: polar radar tracks and camera lanes), written here with python-can.

A change of the code that is not meant to change what a drive holds (a restructuring, a speed-up)
must leave every hash as it is. After a deliberate change of the output, regenerate them with
``TANKVIZ_REGENERATE_GOLDENS=1 python -m pytest tests/test_drive_bytes.py`` and say why in the
commit.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import can
import pytest
from conftest import GOLDEN, T0, WriteLog, check_golden, message
from mcap.reader import make_reader

from bridge.pipeline.convert import convert

HASHES = GOLDEN / "drive_hashes.json"
PROFILES = Path(__file__).resolve().parent / "profiles"


def topic_hashes(path: Path) -> dict[str, str]:
    """SHA-256 of each topic's messages (log time, publish time, data) in file order."""
    hashes: dict[str, hashlib._Hash] = {}
    with path.open("rb") as f:
        for _, channel, msg in make_reader(f).iter_messages(log_time_order=False):
            h = hashes.setdefault(channel.topic, hashlib.sha256())
            h.update(msg.log_time.to_bytes(8, "little") + msg.publish_time.to_bytes(8, "little"))
            h.update(len(msg.data).to_bytes(4, "little") + msg.data)
    return {topic: h.hexdigest() for topic, h in sorted(hashes.items())}


def check(name: str, hashes: dict[str, str]) -> None:
    """``name``'s entry of the golden is ``hashes`` (the other drives' entries are kept)."""
    golden = json.loads(HASHES.read_text()) if HASHES.exists() else {}
    before = golden.get(name, {})
    changed = sorted(t for t in before.keys() | hashes.keys() if before.get(t) != hashes.get(t))
    check_golden(HASHES, json.dumps({**golden, name: hashes}, indent=1, sort_keys=True) + "\n",
                 f"{name} (these topics: {changed})")


@pytest.mark.slow
def test_the_sample_drive_converts_to_the_same_messages(sample_drive: Path) -> None:
    hashes = topic_hashes(sample_drive)  # (converted as tankviz convert does: conftest)
    assert "/scene/tracks" in hashes and "/can/can0/frames" in hashes
    check("sample", hashes)


@pytest.mark.slow
def test_a_gm_drive_converts_to_the_same_messages(shared_dbc: Path, write_log: WriteLog,
                                                   tmp_path: Path) -> None:
    import cantools

    dbc = shared_dbc / "gm_global_a_object.dbc"
    db = cantools.database.load_file(dbc)
    messages: list[can.Message] = []
    for i in range(200):
        t = T0 + i * 0.01
        for slot in (1, 2, 3):
            messages.append(message(db, f"LRRObject{slot:02d}", t + slot * 1e-4, 0,
                                    TrkRange=20 + slot * 10 - i * 0.05, TrkAzimuth=slot - 2,
                                    TrkRangeRate=-1.5, TrkObjectID=slot + 4))
    log = write_log("gm.blf", messages)
    out = tmp_path / "gm.mcap"
    convert([log], out, [str(dbc)], profile=PROFILES / "gm_object.toml")
    hashes = topic_hashes(out)
    assert "/scene/ego" in hashes
    check("gm", hashes)
