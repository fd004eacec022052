#!/usr/bin/env python3
"""Generate the Python code for schemas/*.proto into bridge/pb/ (committed).

Run after editing a .proto:  python tools/gen_proto.py
tests/test_generated_code.py fails when the committed code is stale.

Uses protoc from grpcio-tools (the `dev` extra pins a release bundling protoc 29, whose generated
code runs on every protobuf runtime tankviz accepts, >= 5.29.6).
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from importlib import resources
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCHEMAS = ROOT / "schemas"
OUTPUT = ROOT / "bridge" / "pb"
INIT = '"""Generated protobuf code for schemas/*.proto: do not edit, run tools/gen_proto.py."""\n'

# protoc writes `import foo_pb2 as foo__pb2` for a dependency in the same folder; inside our
# package that has to be a relative import.
_LOCAL_IMPORT = re.compile(r"^import (\w+_pb2) as (\w+)$", re.MULTILINE)


def generate(out_dir: Path) -> list[Path]:
    """Compile every schemas/*.proto into ``out_dir``; return the files written."""
    from grpc_tools import protoc

    protos = sorted(SCHEMAS.glob("*.proto"))
    if not protos:
        raise SystemExit(f"no .proto files in {SCHEMAS}")
    well_known = resources.files("grpc_tools") / "_proto"
    out_dir.mkdir(parents=True, exist_ok=True)
    args = [
        "protoc",
        f"-I{SCHEMAS}",
        f"-I{well_known}",
        f"--python_out={out_dir}",
        f"--pyi_out={out_dir}",
        *(str(p) for p in protos),
    ]
    if protoc.main(args) != 0:
        raise SystemExit("protoc failed")
    for path in out_dir.glob("*_pb2.py*"):
        text = path.read_text()
        path.write_text(_LOCAL_IMPORT.sub(r"from . import \1 as \2", text))
    (out_dir / "__init__.py").write_text(INIT)
    return sorted(out_dir.iterdir())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUTPUT,
                        help="output folder (default bridge/pb)")
    args = parser.parse_args()
    if args.out == OUTPUT:
        # Write into a fresh folder first so a failed run leaves the committed code alone.
        with tempfile.TemporaryDirectory() as tmp:
            files = generate(Path(tmp))
            for stale in OUTPUT.glob("*_pb2.py*"):
                stale.unlink()
            OUTPUT.mkdir(exist_ok=True)
            for f in files:
                (OUTPUT / f.name).write_bytes(f.read_bytes())
    else:
        generate(args.out)
    print(f"generated {', '.join(sorted(p.name for p in args.out.glob('*_pb2.py')))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
