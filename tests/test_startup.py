"""Start-up: ``tankviz`` imports only what the chosen command needs, and ``tankviz --help``
still lists every command; live's garbage-collector settings (issue #15)."""

from __future__ import annotations

import argparse
import gc
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bridge.cli import COMMANDS, SUMMARIES, build_parser
from bridge.pipeline import collector

#: The heavy libraries that a short command should not pay for unless it uses them.
HEAVY = ("cantools", "can", "mcap", "mcap_protobuf", "foxglove_websocket", "dask", "duckdb")


def imported_after(code: str, cwd: Path) -> set[str]:
    """The HEAVY libraries in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    probe = code + textwrap.dedent(f"""
        import json, sys
        print(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))
    """)
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                            cwd=cwd, timeout=120, env={**os.environ, "PYTHONPATH": str(
                                Path(__file__).resolve().parents[1])})
    assert result.returncode == 0, result.stderr
    return set(json.loads(result.stdout.splitlines()[-1]))


def tankviz(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bridge", *argv], capture_output=True,
                          text=True, cwd=cwd, timeout=120)


def test_help_lists_every_command_with_its_summary(tmp_path: Path) -> None:
    result = tankviz("--help", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    listed = " ".join(result.stdout.split())  # argparse wraps long lines
    for name in COMMANDS:
        assert f"{name} {' '.join(SUMMARIES[name].split())}" in listed, name


def test_the_summaries_are_the_commands_own() -> None:
    """The line ``tankviz --help`` shows for a command is the help its module gives."""
    parser = build_parser(every=True)
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    own = {action.dest: action.help for action in sub._choices_actions}
    assert own == SUMMARIES
    assert list(own) == list(COMMANDS)


def test_importing_the_cli_imports_no_heavy_library(tmp_path: Path) -> None:
    assert imported_after("import bridge.cli", tmp_path) == set()


def test_help_imports_no_heavy_library(tmp_path: Path) -> None:
    code = textwrap.dedent("""
        import contextlib, io
        from bridge.cli import main
        with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):
            main(["--help"])
    """)
    assert imported_after(code, tmp_path) == set()


@pytest.mark.parametrize(("command", "unused"), [
    ("convert", {"foxglove_websocket", "dask", "duckdb"}),
    ("inspect", {"foxglove_websocket", "dask", "duckdb"}),
    ("layouts", {"foxglove_websocket", "dask", "duckdb"}),
    ("profile", {"foxglove_websocket", "dask", "duckdb"}),
])
def test_a_command_loads_only_its_own_module(tmp_path: Path, command: str,
                                              unused: set[str]) -> None:
    code = textwrap.dedent(f"""
        import contextlib, io, sys
        from bridge.cli import main
        with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):
            main([{command!r}, "--help"])
        apps = sorted(m for m in sys.modules if m.startswith("bridge.apps."))
        assert f"bridge.apps.{command}" in apps, apps
        assert not {{"bridge.apps.live", "bridge.apps.batch", "bridge.apps.catalog"}} & (
            set(apps) - {{"bridge.apps.{command}"}}), apps
    """)
    assert not imported_after(code, tmp_path) & unused


def test_a_command_help_shows_its_own_options(tmp_path: Path) -> None:
    result = tankviz("convert", "--help", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "usage: tankviz convert" in result.stdout and "--scene-rate HZ" in result.stdout


def test_an_unknown_command_is_one_usage_error(tmp_path: Path) -> None:
    result = tankviz("converd", cwd=tmp_path)
    assert result.returncode == 2
    assert "invalid choice: 'converd'" in result.stderr
    assert "'convert'" in result.stderr and "Traceback" not in result.stderr


def test_live_collector_settings_are_applied_and_undone() -> None:
    """In live the start-up objects are frozen out of the collector's way, the young
    generation is collected rarely, full collections wait for a quiet moment; on the way out
    the process's own settings come back."""
    gc.unfreeze()  # (what an earlier test may have left frozen)
    before = gc.get_threshold()
    with collector.steady_stream() as settings:
        assert gc.get_threshold() == settings.thresholds == collector.LIVE_THRESHOLDS
        assert settings.thresholds[0] > before[0]  # young collections are rarer
        assert settings.thresholds[2] > before[2]  # full ones are left to quiet()
        assert gc.get_freeze_count() > 1000  # what start-up loaded is out of the way
        assert gc.isenabled()
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == 0


def test_live_collector_frees_cycles_at_a_quiet_moment_when_due() -> None:
    """Reference cycles are still freed: by the full collection that quiet() runs when one is
    due, so memory stays flat."""

    class Node:
        def __init__(self) -> None:
            self.me = self

    now = [100.0]
    with collector.steady_stream(every_s=60.0, clock=lambda: now[0]) as settings:
        nodes = [Node() for _ in range(1000)]
        gc.collect(1)  # they lived long enough to reach the oldest generation
        del nodes  # ... and are garbage there: cycles only a full collection frees
        for _ in range(20_000):  # young and middle collections come and go
            Node()
        assert sum(isinstance(o, Node) for o in gc.get_objects()) >= 1000
        now[0] += 59.0
        assert not settings.quiet()
        assert sum(isinstance(o, Node) for o in gc.get_objects()) >= 1000
        now[0] += 1.0
        assert settings.quiet()
        assert not any(isinstance(o, Node) for o in gc.get_objects())
        assert settings.full_collections == 1
        assert not settings.quiet()  # the next one is due a minute later


def test_live_applies_the_collector_settings(tmp_path: Path) -> None:
    """While live runs, the collector has live's thresholds."""
    from bridge.frame import Frame
    from bridge.io.buses import BusSpec
    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.live_engine import Live

    seen: list[tuple[int, int, int]] = []
    live = Live([BusSpec("can0", "virtual", f"startup-gc-{os.getpid()}")],
                load_stages([], None), drives=tmp_path,
                say=lambda text: None)
    poll = live._poll

    def noted() -> list[Frame]:  # the loop reads the buses
        seen.append(gc.get_threshold())
        live.stop()
        return poll()

    live._poll = noted  # type: ignore[method-assign]
    before = gc.get_threshold()
    live.run()
    assert seen and set(seen) == {collector.LIVE_THRESHOLDS}
    assert gc.get_threshold() == before


@pytest.mark.parametrize("given", [None, "2"])
def test_a_command_starts_no_blas_threads_unless_told(tmp_path: Path, given: str | None) -> None:
    """numpy's OpenBLAS starts a thread per core at import, a tenth of a second of CPU for
    nothing: tankviz does no linear algebra that threads speed up (find-signal's products
    take as long on one). A user's own OPENBLAS_NUM_THREADS is kept."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    probe = textwrap.dedent("""
        import os, sys
        from bridge.cli import main
        sys.argv = ["tankviz", "layouts"]  # (main() without arguments: tankviz is the program)
        main()
        import numpy
        print(os.environ.get("OPENBLAS_NUM_THREADS"), len(os.listdir("/proc/self/task")))
    """)
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                            cwd=tmp_path, env=env, timeout=120)
    assert result.returncode == 0, result.stderr
    setting, threads = result.stdout.split()[-2:]
    assert setting == (given or "1")
    if given is None:
        assert threads == "1"


def test_a_command_runs_with_its_start_up_frozen_and_the_collector_on(tmp_path: Path) -> None:
    """Importing a command's libraries makes no garbage worth a collection, yet the collector
    ran dozens of times over the growing heap (a tenth of a short convert's CPU): tankviz keeps
    it off while it starts, then freezes what start-up made (it lives as long as the process)
    and turns it back on for the command, unless it was off already. Only as the program: a
    program that calls ``main(argv)`` keeps its collector as it is."""
    probe = textwrap.dedent("""
        import gc, json, sys
        from bridge.cli import main
        from bridge.apps import layouts
        seen = []
        run = layouts.run
        layouts.run = lambda args: seen.append((gc.isenabled(), gc.get_freeze_count())) or run(args)
        sys.argv = ["tankviz", "layouts"]  # (main() without arguments: tankviz is the program)
        main()
        gc.disable()
        main()
        print(json.dumps([*seen, gc.isenabled()]))
    """)
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                            cwd=tmp_path, timeout=120)
    assert result.returncode == 0, result.stderr
    (on, frozen_then), (off, _), after = json.loads(result.stdout.splitlines()[-1])
    assert on and frozen_then > 10_000
    assert not off and not after  # (a program that turned it off keeps it off)


def test_main_called_with_arguments_leaves_the_collector_and_blas_as_they_are(
        tmp_path: Path) -> None:
    """A program that calls ``main(argv)`` keeps its own process settings."""
    probe = textwrap.dedent("""
        import gc, os
        from bridge.cli import main
        main(["layouts"])
        print(gc.isenabled(), gc.get_freeze_count(), os.environ.get("OPENBLAS_NUM_THREADS"))
    """)
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                            cwd=tmp_path, env=env, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split()[-3:] == ["True", "0", "None"]


#: What only a drive with a profile uses: its rules, the world, the scene, perception (the
#: health monitor imports the lateral sign check's module, which loads none of them itself).
PROFILE_STAGES = ("bridge.profile", "bridge.world.model", "bridge.world.observe",
                  "bridge.world.lead", "bridge.world.pages", "bridge.scene",
                  "bridge.pipeline.perception", "bridge.health.overlay")


def loaded_stages(argv: list[str], cwd: Path) -> list[str]:
    code = textwrap.dedent(f"""
        import json, sys
        from bridge.cli import main
        assert main({argv!r}) == 0
        print(json.dumps(sorted(m for m in sys.modules if m.startswith({PROFILE_STAGES!r}))))
    """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            cwd=cwd, timeout=120)
    assert result.returncode == 0, result.stderr
    return list(json.loads(result.stdout.splitlines()[-1]))


def test_a_drive_without_a_profile_never_loads_the_profile_stages(tmp_path: Path) -> None:
    """A convert with databases alone (a new car's first drive, a fleet's raw logs) makes no
    scene: loading the profile's rules, the world and the scene cost it 0.05 s of CPU."""
    log = tmp_path / "short.asc"
    assert subprocess.run([sys.executable, "-m", "bridge", "simulate", "-o", str(log),
                           "--duration", "1"], capture_output=True, cwd=tmp_path,
                          timeout=120).returncode == 0
    assert loaded_stages(["convert", str(log), "--dbc", "ecocar", "-o",
                          str(tmp_path / "a.mcap"), "--quiet"], tmp_path) == []
    with_profile = loaded_stages(["convert", str(log), "--profile", "ecocar", "-o",
                                  str(tmp_path / "b.mcap"), "--quiet"], tmp_path)
    assert "bridge.pipeline.perception" in with_profile and "bridge.world.model" in with_profile
