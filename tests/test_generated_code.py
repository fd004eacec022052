"""The committed protobuf code in bridge/pb is what tools/gen_proto.py makes from schemas/."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_generated_code_is_fresh(tmp_path: Path) -> None:
    subprocess.run([sys.executable, str(ROOT / "tools" / "gen_proto.py"), "--out", str(tmp_path)],
                   check=True, capture_output=True)
    committed = ROOT / "bridge" / "pb"
    fresh = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.suffix in {".py", ".pyi"}}
    current = {p.name: p.read_bytes() for p in committed.iterdir()
               if p.suffix in {".py", ".pyi"}}
    stale = sorted(name for name in fresh.keys() | current.keys()
                   if fresh.get(name) != current.get(name))
    assert not stale, f"bridge/pb is stale ({', '.join(stale)}): run python tools/gen_proto.py"


def test_every_schema_has_generated_code() -> None:
    protos = {p.stem for p in (ROOT / "schemas").glob("*.proto")}
    generated = {p.name.removesuffix("_pb2.py") for p in (ROOT / "bridge" / "pb").glob("*_pb2.py")}
    assert protos == generated
