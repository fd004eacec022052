"""``tankviz layouts``: the bundled layouts listed and copied out, layouts made for a profile
(``--profile P``), and the bring-up layout of a car without one (``--dbc ...``).

Nothing is overwritten unless forced, and every layout is read with :func:`load_layout`, which
refuses (:class:`~bridge.errors.FileError`) a file that is missing, not JSON or not in
Foxglove's layout format.
"""

from __future__ import annotations

import argparse
import json
import shutil
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bridge.apps.options import Subparsers, dbc_option
from bridge.errors import FileError, UsageError
from bridge.pipeline.drive import load_stages
from bridge.resources import layouts_dir
from bridge.view.bringup import BRINGUP_NAME, bringup_layout
from bridge.view.check import PANEL_NAMES, check_format, panel_type
from bridge.view.generate import LAYOUT_NAMES, database_buses, generate_layouts, layout_text


@dataclass(frozen=True)
class BundledLayout:
    """One layout shipped with tankviz."""

    name: str
    path: Path
    #: the preview picture beside it, if there is one
    preview: Path | None
    #: what it shows, e.g. "3D, 3 plots, Raw Messages"
    summary: str


def bundled_layouts(directory: Path | None = None) -> list[BundledLayout]:
    """The layouts in ``layouts/`` (or ``directory``), by name."""
    folder = directory if directory is not None else layouts_dir()
    out = []
    for path in sorted(folder.glob("*.json")):
        preview = path.with_suffix(".png")
        out.append(BundledLayout(path.stem, path, preview if preview.is_file() else None,
                                 summarize(load_layout(path))))
    return out


def select_layouts(names: Iterable[str] = (), directory: Path | None = None
                   ) -> list[BundledLayout]:
    """The bundled layouts called ``names`` in that order (all of them when none is named)."""
    layouts = {layout.name: layout for layout in bundled_layouts(directory)}
    wanted = list(names) or list(layouts)
    unknown = [n for n in wanted if n not in layouts]
    if unknown:
        raise UsageError(", ".join(repr(n) for n in unknown),
                         f"no such bundled layout; bundled: {', '.join(layouts)}")
    return [layouts[n] for n in wanted]


def format_listing(layouts: Iterable[BundledLayout]) -> str:
    """One line per layout: name, panels, file (what ``tankviz layouts`` prints)."""
    rows = [(layout.name, layout.summary, str(layout.path)) for layout in layouts]
    if not rows:
        return ""
    widths = [max(len(row[i]) for row in rows) for i in range(2)]
    return "\n".join(f"{name:<{widths[0]}}  {summary:<{widths[1]}}  {path}"
                     for name, summary, path in rows)


def summarize(layout: Mapping[str, Any]) -> str:
    """The panels of a layout in words: ``3D, 3 plots, Raw Messages``."""
    counts = Counter(panel_type(panel_id) for panel_id in layout["configById"])
    words = []
    for kind, n in counts.items():
        name = PANEL_NAMES.get(kind, kind)
        words.append(name if n == 1 else f"{n} {name}{'s' if name.islower() else ' panels'}")
    return ", ".join(words)


def export_layouts(directory: Path, *, names: Iterable[str] | None = None,
                   force: bool = False, source: Path | None = None) -> list[Path]:
    """Copy bundled layouts (all, or those ``names``) into ``directory`` (created if needed).

    An existing file is not overwritten unless ``force``; nothing is copied then.
    """
    chosen = select_layouts(names or (), source)
    targets = [(layout.path, directory / layout.path.name) for layout in chosen]
    _writable(directory, [target for _, target in targets], force)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for path, target in targets:
            shutil.copyfile(path, target)
    except OSError as exc:
        raise FileError(directory, f"cannot write: {exc.strerror or exc}") from None
    return [target for _, target in targets]


def _writable(directory: Path, targets: Iterable[Path], force: bool) -> None:
    if not force:
        existing = [str(target) for target in targets if target.exists()]
        if existing:
            raise FileError(", ".join(existing), "exists (--force overwrites)")
    if directory.exists() and not directory.is_dir():
        raise FileError(directory, "not a folder")


def select_generated(layouts: Mapping[str, dict[str, Any]], names: Iterable[str] = ()
                     ) -> dict[str, dict[str, Any]]:
    """The generated layouts called ``names`` in that order (all when none is named)."""
    wanted = list(names) or list(layouts)
    unknown = [n for n in wanted if n not in layouts]
    if unknown:
        made = (f"made for a profile: {', '.join(LAYOUT_NAMES)}" if len(layouts) > 1 else
                f"made without a profile: {', '.join(layouts)} (--profile makes the others)")
        raise UsageError(", ".join(repr(n) for n in unknown), f"no such layout; {made}")
    return {n: layouts[n] for n in wanted}


def plot_option(text: str) -> tuple[str, str]:
    """``--plot BUS/ID`` (hex ``0x2C4`` or decimal ``708``): the bus and the id as the bring-up
    topics write it (``0x2C4``)."""
    from bridge.apps.sources import parse_id
    from bridge.bringup.columns import id_text

    bus, key = parse_id(text, "--plot")
    return bus, id_text(key)


def export_generated(directory: Path, layouts: Mapping[str, dict[str, Any]], *,
                     force: bool = False) -> list[Path]:
    """Write layouts (name -> layout) into ``directory`` (created if needed) as
    ``<name>.json``. An existing file is not overwritten unless ``force``; nothing is written
    then."""
    targets = [(directory / f"{name}.json", data) for name, data in layouts.items()]
    _writable(directory, [target for target, _ in targets], force)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for target, data in targets:
            target.write_text(layout_text(data), encoding="utf-8")
    except OSError as exc:
        raise FileError(directory, f"cannot write: {exc.strerror or exc}") from None
    return [target for target, _ in targets]


def load_layout(path: Path) -> dict[str, Any]:
    """Read a layout file and check its shape (keys, panel ids, the mosaic tree)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileError(path, "no such file") from None
    except json.JSONDecodeError as exc:
        raise FileError(path, f"not JSON: line {exc.lineno}: {exc.msg}") from None
    problems = check_format(data)
    if problems:
        raise FileError(path, "; ".join(problems))
    return dict(data)


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "layouts", help="list the bundled Foxglove layouts, or copy them out to import them",
        description="List the bundled Foxglove layouts (tank-viz: the Tank Viz 3D view; "
        "engineer: 3D, plots and the lead vehicle; can-debug: decoded signals and raw frames), "
        "or copy them into a folder with --export; import them in Foxglove from the Layouts "
        "menu (Import layout). With --profile, the layouts are made for that profile (its "
        "object groups, sensor frames, buses, ego signals and alarms), and the bring-up "
        "layout beside them: tankviz layouts --profile car.toml --dbc radar=radar.dbc --export "
        "DIR. Without a profile, --dbc (or --bus, --plot) makes the bring-up layout alone "
        "(bring-up.json: each bus's ids, the bit-change map, one unknown id's bytes): "
        "tankviz layouts --dbc can0=car.dbc --plot can0/0x2C4 --export DIR")
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help="only these layouts (default: all)")
    parser.add_argument("--export", type=Path, metavar="DIR",
                        help="copy the layout files (JSON) into DIR (created if needed)")
    parser.add_argument("--force", action="store_true",
                        help="overwrite layout files that already exist in DIR")
    parser.add_argument("--profile", metavar="NAME|PATH",
                        help="make the layouts for this vehicle profile (a bundled name such "
                        "as 'ecocar' works too) instead of the bundled ones")
    parser.add_argument("--dbc", action="append", metavar="[BUS=]PATH",
                        help="signal database for BUS, or for every bus without BUS=; "
                        "repeatable; with --profile default: the profile's own; without "
                        "--profile only the bring-up layout is made")
    parser.add_argument("--bus", action="append", metavar="NAME",
                        help="a bus the layouts show; repeatable; default: the buses --dbc "
                        "(or the profile's databases) name, or can0 for a database for every "
                        "bus (the bus of a log without channels); without --profile only the "
                        "bring-up layout is made")
    parser.add_argument("--plot", metavar="BUS/ID",
                        help="the unknown id the bring-up layout plots at first, e.g. "
                        "can0/0x2C4 (hex or decimal; its bus is added to the layout's); "
                        "default: none, set it in Foxglove's Variables (unknown_id); without "
                        "--profile only the bring-up layout is made")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.profile is not None:
        return _run_generated(args)
    if args.dbc or args.bus or args.plot:
        return _run_bringup(args)
    if args.export is None:
        print(format_listing(select_layouts(args.names)))
        return 0
    for path in export_layouts(args.export, names=args.names, force=args.force):
        print(f"wrote {path}")
    print("import in Foxglove: Layouts menu > Import layout")
    return 0


def _run_generated(args: argparse.Namespace) -> int:
    decoder, profile = load_stages([dbc_option(text) for text in args.dbc or []], args.profile)
    assert profile is not None
    plot_id = plot_option(args.plot) if args.plot else None
    layouts = select_generated(generate_layouts(profile, decoder, args.bus, plot_id=plot_id),
                               args.names)
    return _say_or_export(args, layouts, f"made for profile {profile.name}")


def _run_bringup(args: argparse.Namespace) -> int:
    """The bring-up layout of a car without a profile: its databases only tell the buses."""
    decoder, _ = load_stages([dbc_option(text) for text in args.dbc or []], None)
    plot_id = plot_option(args.plot) if args.plot else None
    buses = list(args.bus or []) or (
        [plot_id[0]] if plot_id is not None and not decoder.files else database_buses(decoder))
    layouts = select_generated({BRINGUP_NAME: bringup_layout(buses, plot_id)}, args.names)
    return _say_or_export(args, layouts, f"made for bus{'es' if len(buses) > 1 else ''} "
                          f"{', '.join(buses)}")


def _say_or_export(args: argparse.Namespace, layouts: Mapping[str, dict[str, Any]],
                   made: str) -> int:
    if args.export is None:
        rows = [(name, summarize(data)) for name, data in layouts.items()]
        width = max(len(name) for name, _ in rows)
        print("\n".join(f"{name:<{width}}  {summary}" for name, summary in rows))
        print(f"{made}; --export DIR writes {'them' if len(rows) > 1 else 'it'}")
        return 0
    for path in export_generated(args.export, layouts, force=args.force):
        print(f"wrote {path}")
    print(f"{made}; import in Foxglove: Layouts menu > Import layout")
    return 0
