"""The documentation says what the code does: README.md (the front page), docs/*.md (the
reference) and DEVELOPING.md.

- every command and every option its ``--help`` lists is in docs/commands.md, in that command's
  section (nested commands too: ``batch convert``, ``profile new``, ``catalog query``);
- every relative link of the documentation points to a file that exists, and a ``#anchor`` to a
  heading of it (GitHub's slugs);
- the front page stays short, with the quick start .ci/run runs (two commands between markers);
- the front page's Python example runs, and prints what the front page says (numbers aside);
- the front page's workflows, typed in a fresh folder, run and print the lines it shows.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridge.cli import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
COMMANDS_MD = ROOT / "docs" / "commands.md"
DOCS = [README, ROOT / "DEVELOPING.md", *sorted((ROOT / "docs").glob("*.md"))]
FRONT_PAGE_MAX_LINES = 220

FENCE = re.compile(r"^(```|~~~)")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")


# --- commands and options ------------------------------------------------------------------------

def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    found: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            found.update(action.choices)
    return found


def _options(parser: argparse.ArgumentParser) -> list[str]:
    return [option for action in parser._actions
            if not isinstance(action, argparse._HelpAction) and action.help != argparse.SUPPRESS
            for option in action.option_strings if option not in ("-h", "--help")]


def every_command() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """Each command as it is typed (``profile new``) with its parser, nested ones included."""
    def walk(path: str, parser: argparse.ArgumentParser,
             ) -> Iterator[tuple[str, argparse.ArgumentParser]]:
        subs = _subcommands(parser)
        if path:
            yield path, parser
        for name, sub in subs.items():
            yield from walk(f"{path} {name}".strip(), sub)

    yield from walk("", build_parser(every=True))
    # `catalog query` is a word of `catalog`'s own arguments, with a parser of its own for --help
    from bridge.apps import catalog
    if hasattr(catalog, "query_parser"):
        yield "catalog query", catalog.query_parser()


def sections(text: str, level: int) -> dict[str, str]:
    """Heading text → the text under it, up to the next heading of that level or above."""
    found: dict[str, str] = {}
    heading: str | None = None
    lines: list[str] = []
    fenced = False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
        m = None if fenced else re.match(r"^(#{1,6}) (.*)", line)
        if m and len(m.group(1)) <= level:
            if heading is not None:
                found[heading] = "\n".join(lines)
            heading, lines = (m.group(2) if len(m.group(1)) == level else None), []
        else:
            lines.append(line)
    if heading is not None:
        found[heading] = "\n".join(lines)
    return found


def command_section(path: str) -> str:
    """The section of docs/commands.md for ``path``'s top command
    (``## `tankviz batch` — …``)."""
    top = path.split()[0]
    for heading, text in sections(COMMANDS_MD.read_text(encoding="utf-8"), 2).items():
        if heading.startswith(f"`tankviz {top}`"):
            return text
    raise AssertionError(f"docs/commands.md has no section '## `tankviz {top}` — …'")


def mentions(text: str, option: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text) is not None


@pytest.mark.parametrize("path, parser", list(every_command()), ids=lambda v: str(v)
                         if isinstance(v, str) else "")
def test_every_command_and_option_is_in_the_command_reference(
        path: str, parser: argparse.ArgumentParser) -> None:
    section = command_section(path)
    assert f"tankviz {path}" in section, f"docs/commands.md does not show `tankviz {path}`"
    missing = [o for o in _options(parser) if not mentions(section, o)]
    assert not missing, f"`tankviz {path}` options missing from docs/commands.md: {missing}"


def test_the_top_level_options_and_every_command_are_documented() -> None:
    reference = COMMANDS_MD.read_text(encoding="utf-8")
    top = build_parser(every=True)
    assert [o for o in _options(top) if not mentions(reference, o)] == []
    assert set(_subcommands(top)) == set(COMMANDS)
    front = README.read_text(encoding="utf-8")
    assert [c for c in COMMANDS if f"`tankviz {c}`" not in front] == []


# --- links -------------------------------------------------------------------------------------

def github_slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text only
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    found: set[str] = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        m = None if fenced else re.match(r"^#{1,6} (.*)", line)
        if m:
            slug = github_slug(m.group(1))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            found.add(slug if n == 0 else f"{slug}-{n}")
    return found


def links(path: Path) -> Iterator[tuple[int, str]]:
    """(line, target) of every Markdown link and image outside code."""
    fenced = False
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            for m in LINK.finditer(CODE_SPAN.sub("", line)):
                yield number, m.group(1)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_points_to_a_file_and_heading_that_exist(doc: Path) -> None:
    broken = []
    for number, target in links(doc):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        linked = (doc.parent / file_part).resolve() if file_part else doc
        if not linked.exists():
            broken.append(f"line {number}: {target}: no such file")
        elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
            broken.append(f"line {number}: {target}: no heading #{anchor} in {linked.name}")
    assert not broken, f"{doc.relative_to(ROOT)}:\n" + "\n".join(broken)


def test_the_reference_pages_are_all_linked_from_the_front_page() -> None:
    linked = {target.partition("#")[0] for _, target in links(README)}
    pages = {str(p.relative_to(ROOT)) for p in DOCS[1:]}
    assert pages - linked == set()


# --- the front page ------------------------------------------------------------------------------

def test_the_front_page_is_short_and_keeps_the_quick_start_ci_runs() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= FRONT_PAGE_MAX_LINES, (
        f"README.md has {len(lines)} lines: the front page stays within "
        f"{FRONT_PAGE_MAX_LINES}; move the detail to docs/")
    begin, end = lines.index("<!-- quickstart:begin -->"), lines.index("<!-- quickstart:end -->")
    assert begin < end
    # what .ci/run reads: the lines between the markers not starting with a backtick
    commands = [line for line in lines[begin + 1:end] if line and not line.startswith("`")]
    assert commands == [
        "python3 -m venv .venv && .venv/bin/pip install '.[dev]' && .venv/bin/tankviz demo",
        ".venv/bin/python -m pytest -n 2",
    ]


def fenced_blocks(text: str) -> list[tuple[str, str]]:
    """(info string, body) of every fenced code block."""
    return [(m.group(1), m.group(2))
            for m in re.finditer(r"^```(\w*)\n(.*?)^```$", text, re.S | re.M)]


#: What differs from run to run of one command: how long it took, and a live run's own clock
#: (the names of its drives, its ports). Every other figure the front page quotes is exact.
_RUN_DEPENDENT = re.compile(r"in [\d.]+ s \([\d,]+ frames/s\)"
                            r"|\d{4}-\d\d-\d\dT\d\d-\d\d-\d\dZ")


def figures(line: str) -> str:
    """A line as the front page and a run must both print it: what depends on the run left out."""
    return _RUN_DEPENDENT.sub("#", line.strip())


@pytest.mark.slow
def test_the_front_page_python_example_runs_and_prints_what_the_front_page_shows(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocks = fenced_blocks(README.read_text(encoding="utf-8"))
    at = next(i for i, (info, _) in enumerate(blocks) if info == "python")
    code, shown = blocks[at][1], blocks[at + 1][1]  # the example, then what it prints
    monkeypatch.chdir(tmp_path)
    # trip.blf as the front page makes it: `tankviz simulate -o trip.blf`
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["simulate", "-o", "trip.blf"]) == 0
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(code, "README.md (python example)", "exec"), {"__name__": "readme_example"})
    assert (tmp_path / "trip-py.mcap").is_file()
    assert printed.getvalue().strip().splitlines() == shown.strip().splitlines()


# --- the front page's workflows, as a newcomer types them ----------------------------------------

#: A real-time run's numbers (frames sent in its seconds, ports, dates): the demo's.
_REAL_TIME = re.compile(r"\d[\d,.:TZ-]*")


def workflow_sessions() -> list[tuple[str, list[str]]]:
    """Each ``$ tankviz …`` command of the front page's workflows with the lines shown after it
    (the lines with an ellipsis are shortened: left out)."""
    text = README.read_text().split("## Four workflows", 1)[1].split("\n## ", 1)[0]
    sessions: list[tuple[str, list[str]]] = []
    for block in re.findall(r"```\n(.*?)```", text, flags=re.DOTALL):
        for line in block.splitlines():
            if line.startswith("$ "):
                sessions.append((line[2:], []))
            elif sessions and "…" not in line:
                sessions[-1][1].append(line)
    return sessions


@pytest.mark.slow
def test_the_front_page_workflows_run_as_shown(tmp_path: Path) -> None:
    """The front page's commands, typed in a fresh folder in their order, exit 0 and print the
    lines shown, every figure true (only the demo's, made in real time, and the time a command
    took may differ); the own-car workflow needs the highway car's databases."""
    import os
    import shlex
    import subprocess
    import sys

    from bridge.resources import data_dir

    for name in ("highway_radar.dbc", "highway_car.dbc"):
        (tmp_path / name).write_bytes((data_dir() / name).read_bytes())
    environment = {**{k: v for k, v in os.environ.items() if k != "TANKVIZ_DRIVES"},
                   "TANKVIZ_PORT": "0"}  # drives into ./drives, the default
    sessions = workflow_sessions()
    assert [command.split()[1] for command, _ in sessions] == [
        "demo", "simulate", "convert", "inspect", "simulate", "profile", "profile", "convert",
        "ids", "bits", "bits", "find-signal"]
    for command, shown in sessions:
        words, _, edit = command.partition("#")
        if "lateral" in edit:  # the fix check asked for, made before this command
            profile = tmp_path / "mycar.toml"
            profile.write_text(profile.read_text().replace('lateral = "left"',
                                                           'lateral = "right"'))
        done = subprocess.run([sys.executable, "-m", "bridge", *shlex.split(words)[1:]],
                              cwd=tmp_path, capture_output=True, text=True, env=environment,
                              timeout=300)
        assert done.returncode == 0, f"{command}: {done.stderr}"
        same = (lambda line: _REAL_TIME.sub("#", line.strip())) if "demo" in words else figures
        printed = {same(line) for line in done.stdout.splitlines()}
        for line in shown:
            assert same(line) in printed, f"{command}: {line!r} not in\n" + done.stdout


@pytest.mark.parametrize("path, parser", list(every_command()), ids=lambda v: str(v)
                         if isinstance(v, str) else "")
def test_every_argument_and_option_says_what_it_is_in_help(
        path: str, parser: argparse.ArgumentParser) -> None:
    """docs/commands.md's tables are "as --help lists them": nothing there without its words."""
    silent = [action.option_strings[0] if action.option_strings else action.dest
              for action in parser._actions
              if not isinstance(action, argparse._SubParsersAction) and not action.help]
    assert silent == [], f"`tankviz {path} --help` says nothing of {silent}"
