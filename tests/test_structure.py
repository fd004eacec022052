"""The folders of ``bridge/`` follow the data path, and imports only run down it.

Each stage is a package; a package imports only the shared modules at the top of ``bridge/``
(errors, frame, packed, protowire, topics, resources, the generated protobuf code) and the
packages before it in :data:`DATA_PATH`. So the longest chain of imports is no deeper than the
data path itself, and a newcomer finds each stage in the folder named after it.

``python tests/test_structure.py [ROOT]`` prints the longest import chain and the largest
modules of the package at ROOT (default: this checkout), e.g. to compare with an older one.
"""

from __future__ import annotations

import ast
import sys
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The packages of bridge/ in data-path order: each may import those before it.
DATA_PATH = ("io", "decode", "profile", "world", "scene", "health", "bringup", "sinks", "pipeline",
             "view", "sim", "fleet", "apps")
#: Modules at the top of bridge/ that every stage may use; they import no stage.
SHARED = ("__init__", "errors", "frame", "packed", "protowire", "topics", "resources", "pb",
          "fences")


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the ``bridge`` package under ``root``, by dotted name."""
    out = {}
    for path in sorted((root / "bridge").rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imports(path: Path, known: set[str]) -> set[str]:
    """The bridge modules a module imports, wherever in it (also inside functions)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            if name in known and name != "bridge":
                found.add(name)
                break
    return found


def graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module → the bridge modules it imports; cli imports the apps it loads by name."""
    known = modules(root)
    edges = {name: imports(path, set(known)) - {name} for name, path in known.items()}
    for node in ast.walk(ast.parse(known["bridge.cli"].read_text())):
        if (isinstance(node, ast.Assign) and isinstance(target := node.targets[0], ast.Name)
                and target.id == "COMMANDS"):
            edges["bridge.cli"] |= {f"bridge.apps.{name.replace('-', '_')}"
                                    for name in ast.literal_eval(node.value)}
    return edges


def longest_chain(edges: dict[str, set[str]]) -> list[str]:
    """The longest path of imports (modules importing modules), e.g. cli → apps.live → …"""

    @cache
    def chain(name: str) -> tuple[str, ...]:
        below = [chain(other) for other in edges.get(name, ()) if not other.startswith("bridge.pb")]
        return (name, *max(below, key=len, default=()))

    return list(max((chain(name) for name in edges), key=len))


def stage(module: str) -> str:
    """The package of a module (``bridge.world.observe`` → ``world``), or its shared name."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_module_is_in_a_stage_or_shared() -> None:
    allowed = {*DATA_PATH, *SHARED, "cli", "__main__"}
    assert {stage(m) for m in modules()} <= allowed


def test_imports_only_run_down_the_data_path() -> None:
    order = {name: i for i, name in enumerate(DATA_PATH)}
    wrong = []
    for module, imported in graph().items():
        here = stage(module)
        for other in imported:
            there = stage(other)
            if there == here or there in SHARED:
                continue
            if here in SHARED or (here not in order and here not in ("cli", "__main__")):
                wrong.append(f"{module} (shared) imports {other}")
            elif here in order and (there not in order or order[there] > order[here]):
                wrong.append(f"{module} ({here}) imports {other} ({there}), later in the path")
    assert not wrong, "\n".join(sorted(wrong))


@pytest.mark.slow
def test_no_import_chain_is_deeper_than_the_data_path() -> None:
    """cli → an app → the pipeline → … → a shared module: at most one module per stage, plus
    cli, the modules within one stage that build on each other, and a shared module."""
    chain = longest_chain(graph())
    stages = [stage(m) for m in chain]
    assert len(set(stages)) <= len(DATA_PATH) + 2, chain
    assert len(chain) <= 16, chain


#: The most lines a module of bridge/ may have: a newcomer reads one in a sitting.
MAX_LINES = 800


def module_lines(root: Path = ROOT) -> dict[str, int]:
    """The lines of each module of ``bridge`` (its generated protobuf code apart)."""
    return {name: len(path.read_text().splitlines()) for name, path in modules(root).items()
            if not name.startswith("bridge.pb")}


def test_no_module_is_longer_than_the_cap() -> None:
    longer = {name: lines for name, lines in module_lines().items() if lines > MAX_LINES}
    assert not longer, (f"modules over {MAX_LINES} lines (split them along what they do): "
                        + ", ".join(f"{name} ({lines})" for name, lines in sorted(longer.items())))


def report(root: Path) -> str:
    edges = graph(root)
    chain = longest_chain(edges)
    sizes = sorted(((lines, n) for n, lines in module_lines(root).items()), reverse=True)
    crossed = list(dict.fromkeys(stage(m) for m in chain))
    return "\n".join([f"longest import chain: {len(chain)} modules in {len(crossed)} folders "
                      f"({', '.join(crossed)})", "  " + " → ".join(chain),
                      "largest modules: " + ", ".join(f"{n} ({lines})"
                                                      for lines, n in sizes[:5])])


if __name__ == "__main__":
    print(report(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT))
