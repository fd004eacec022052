"""The layout to import, as live, demo and replay name it at start.

For the bundled ecocar profile the bundled Tank Viz layout, for another profile the layouts made
for it in a folder or else the command that writes them (:func:`layout_hint`), and the bring-up
line at a bus's first unknown id (:class:`BringupHint`).
"""

from __future__ import annotations

import hashlib
import re
import shlex
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from bridge.resources import bundled_database, layouts_dir
from bridge.sinks.server.addresses import LOOPBACK

if TYPE_CHECKING:
    from bridge.pipeline.drive import Stages


#: The profile the bundled layouts (``layouts/*.json``) are made for, with its bundled database.
BUNDLED_PROFILE = "ecocar"
#: The layout a hint points at (the Tank Viz 3D view), as a file name.
HINT_LAYOUT = "tank-viz.json"
#: How ``layout:`` hints go on: the lines after the first, under its text.
HINT_INDENT = " " * len("layout:   ")


def connection_lines(host: str, urls: Sequence[str]) -> list[str]:
    """Where to open Foxglove, and from where: a loopback server (the default) serves this
    machine only, and the line says what serves a laptop beside it."""
    lines = [f"Foxglove: open connection {' or '.join(urls)} (Foxglove WebSocket)"]
    if host in LOOPBACK:
        lines.append(f"{HINT_INDENT}this machine only: --host 0.0.0.0 serves other laptops too")
    return lines


def bundled_layout() -> str:
    """Where the bundled Tank Viz layout to import is."""
    layout = layouts_dir() / HINT_LAYOUT
    return str(layout) if layout.exists() else f"(layouts/{HINT_LAYOUT})"


def is_bundled(stages: Stages) -> bool:
    """Whether the bundled layouts are the ones made for ``stages``: the bundled ecocar profile
    (its bytes, wherever it was read from: a drive's attachment too) with its bundled database
    and no other. (The Tank Viz view a hint points at does not depend on the bus names.)"""
    decoder, profile = stages
    database = bundled_database(BUNDLED_PROFILE)
    if profile is None or database is None or not decoder.files:
        return False
    try:
        same = profile.path.read_bytes() == (database.with_suffix(".toml")).read_bytes()
        digest = hashlib.sha256(database.read_bytes()).hexdigest()
    except OSError:
        return False
    return same and all(f.sha256 == digest for f in decoder.files)


def layout_folder(name: str) -> str:
    """A profile's name as a folder name (``DRIVES/layouts/<name>``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "profile"


def layouts_command(profile: str | Path, dbcs: Sequence[str], export: Path | str,
                    *extra: str) -> str:
    """The ``tankviz layouts`` command that writes the layouts for ``profile`` and ``dbcs``
    (``--dbc`` arguments) into ``export``, quoted for a shell."""
    return shlex.join(["tankviz", "layouts", "--profile", str(profile),
                       *(word for dbc in dbcs for word in ("--dbc", dbc)),
                       "--export", str(export), *extra])


@dataclass
class LayoutHint:
    """What to tell the user about the layout to import: the ``layout:`` lines, warnings
    (printed as ``warning: ...`` on stderr) and whether layouts were written for them."""

    lines: list[str]
    warnings: list[str] = field(default_factory=list)
    written: bool = False

    def text(self) -> str:
        return "\n".join(("layout:   " if i == 0 else HINT_INDENT) + line
                         for i, line in enumerate(self.lines))

    def say(self) -> None:
        for text in self.warnings:
            print(f"warning: {text}", file=sys.stderr)
        if self.lines:
            print(self.text())


#: The layouts made for a profile (:func:`bridge.view.generate.generate_layouts` of the
#: stages on these buses, or the databases' buses for None), as files: ``tank-viz.json`` -> text.
#: (Given by the command: this module, loaded for ``tankviz --help``, does not import the view.)
MakeLayouts = Callable[["Stages", "Sequence[str] | None"], Mapping[str, str]]


def layout_hint(stages: Stages, make: MakeLayouts, *, profile: str | Path | None,
                dbcs: Sequence[str], folder: Path | None = None,
                buses: Sequence[str] | None = None, write: bool = False,
                note: str | None = None) -> LayoutHint:
    """The layout to import for ``stages`` (what ``--profile`` and ``--dbc`` loaded).

    The bundled ecocar profile (:func:`is_bundled`): the bundled layout. Another profile: the
    layouts made for it (``make``, on ``buses``) in
    ``folder`` (default ``<profile>-layouts``) when they are there, else the ``tankviz layouts``
    command that writes them there, naming the profile as ``profile`` and the databases as
    ``dbcs`` (``--dbc`` arguments), with ``note`` (what they are) under it. With ``write``, the
    layouts are written into ``folder`` first: a file that is there already is never
    overwritten (a warning names it when it differs), and a failure is one warning, never an
    error. No profile: the commands that draft one and make its layouts.
    """
    loaded = stages.profile
    if loaded is None:
        return _no_profile_hint(dbcs)
    if is_bundled(stages):
        return LayoutHint([f"import {bundled_layout()} (Layouts menu)"])
    name = loaded.name
    folder = folder if folder is not None else Path(f"{layout_folder(name)}-layouts")
    target = folder / HINT_LAYOUT
    made = f"import {target} (Layouts menu), made for profile {name}"
    command = layouts_command(profile if profile is not None else loaded.path, dbcs, folder)
    warnings: list[str] = []
    try:
        texts = make(stages, buses)
        if write:
            kept = write_layouts(folder, texts)
            if kept:
                files = ", ".join(str(p) for p in kept)
                one = len(kept) == 1
                warnings.append(
                    f"kept {files}: {'it differs' if one else 'they differ'} from the "
                    f"layout{'' if one else 's'} made for profile {name} now; "
                    f"{command} --force replaces {'it' if one else 'them'}")
            if target in kept:
                return LayoutHint([f"import {target} (Layouts menu)"], warnings, written=True)
            return LayoutHint([made], warnings, written=True)
        if _read(target) == texts[HINT_LAYOUT]:
            return LayoutHint([made])
    except Exception as exc:  # the drive goes on: a layout is never worth stopping it
        if write:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            warnings.append(f"cannot write the layouts into {folder}: "
                            f"{reason or type(exc).__name__}")
    lines = [f"made for profile {name} by: {command}", *([note] if note else []),
             f"then import {target} (Layouts menu)"]
    return LayoutHint(lines, warnings)


def _no_profile_hint(dbcs: Sequence[str]) -> LayoutHint:
    if not dbcs:
        return LayoutHint(["none: the layouts are made for a vehicle profile (--profile) "
                           "and its databases (--dbc)"])
    # as given: `profile new` takes --dbc [BUS=]PATH too, and drafts the databases per bus
    draft = shlex.join(["tankviz", "profile", "new",
                        *(word for text in dict.fromkeys(dbcs) for word in ("--dbc", text)),
                        "-o", "car.toml"])
    return LayoutHint([f"none without a profile: draft one with: {draft}",
                       f"then: {layouts_command('car.toml', dbcs, 'car-layouts')}"])


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None


def write_layouts(folder: Path, texts: Mapping[str, str]) -> list[Path]:
    """Write each layout (file name -> text) into ``folder`` (created if needed) where no file
    of its name is; returns the files left as they were because they differ."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocking = next((p for p in (folder, *folder.parents) if p.exists() and not p.is_dir()),
                        folder)
        raise OSError(f"{blocking} is not a folder") from None
    kept = []
    for name, text in texts.items():
        target = folder / name
        try:
            with target.open("x", encoding="utf-8") as stream:  # never over an existing file
                try:
                    stream.write(text)
                except BaseException:
                    stream.close()
                    target.unlink(missing_ok=True)
                    raise
        except FileExistsError:
            if _read(target) != text:
                kept.append(target)
    return kept


# --- bring-up: a bus carries ids no database knows -----------------------------------------------

#: The bring-up layout's file (:mod:`bridge.view.bringup`), as ``tankviz layouts`` writes it.
BRINGUP_LAYOUT = "bring-up.json"
#: Where the bring-up command writes it when no folder of layouts is there (no profile).
BRINGUP_FOLDER = "bring-up-layouts"
#: The layout variable of the unknown id its plots follow (:data:`bridge.view.bringup.ID_VARIABLE`).
BRINGUP_VARIABLE = "unknown_id"

#: The bring-up layout made for these buses (:func:`bridge.view.bringup.bringup_layout`), as
#: its file's text. (Given by the command: this module does not import the view.)
MakeBringup = Callable[["Sequence[str]"], str]


def id_text(key: int) -> str:
    """A frame key as the bring-up topics write its id: ``0x2C4``, a 29-bit id with eight
    digits (:func:`bridge.bringup.columns.id_text`, without importing numpy)."""
    from bridge.frame import EXTENDED_KEY, key_id

    return f"0x{key_id(key):08X}" if key & EXTENDED_KEY else f"0x{key:03X}"


def bringup_command(buses: Sequence[str], plot: tuple[str, str], export: Path | str) -> str:
    """The ``tankviz layouts`` command that writes the bring-up layout for ``buses``, its plots
    on ``plot`` (bus, id), into ``export``, quoted for a shell. (The layout depends on the buses
    only: no databases, no profile.)"""
    return shlex.join(["tankviz", "layouts", *(w for bus in buses for w in ("--bus", bus)),
                       "--plot", f"{plot[0]}/{plot[1]}", "--export", str(export)])


def same_layout(path: Path, text: str) -> bool:
    """Whether the layout file ``path`` is the layout ``text`` but for its variables' values
    (the bring-up layout's first id: the user's to change)."""
    import json

    try:
        there, made = json.loads(path.read_text(encoding="utf-8")), json.loads(text)
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    if not isinstance(there, dict) or not isinstance(there.get("globalVariables"), dict):
        return False
    return ({**there, "globalVariables": set(there["globalVariables"])}
            == {**made, "globalVariables": set(made["globalVariables"])})


@dataclass
class BringupHint:
    """What live, demo and replay say when a bus first carries an id no database knows
    (:meth:`tell`, given to the pipeline's bring-up stage): one line, ``bring-up: can0 carries
    ids no database knows (first 0x2C4): ...``, naming the bring-up layout in ``folder`` when it
    is there and made for these buses (its variable set to the id, :data:`BRINGUP_VARIABLE`),
    else the ``tankviz layouts`` command that writes it there, the id in its plots.

    ``buses``: those the drive is known to have (a bus that tells is added); ``make``: the
    layout for some buses as its file's text; ``bundled``: a layout to name as it is for these
    buses (the bundled one, for the bundled profile on can0)."""

    folder: Path
    buses: list[str]
    make: MakeBringup
    bundled: Path | None = None
    told: dict[str, str] = field(default_factory=dict)

    def line(self, bus: str, ident: str) -> str:
        if bus not in self.buses:
            self.buses.append(bus)
        head = f"bring-up: {bus} carries ids no database knows (first {ident}): "
        target = self.folder / BRINGUP_LAYOUT
        try:
            there = self.bundled if self.bundled is not None else (
                target if same_layout(target, self.make(self.buses)) else None)
        except Exception:  # a layout is never worth stopping the drive: say the command
            there = None
        if there is not None:
            return (f"{head}import {there} (Layouts menu), then set its variable "
                    f'{BRINGUP_VARIABLE} to "{ident}" (Variables)')
        command = bringup_command(self.buses, (bus, ident), self.folder)
        if target.exists():
            return f"{head}import {target} (Layouts menu) once {command} --force replaces it"
        return f"{head}import {target} (Layouts menu) once {command} writes it"

    def tell(self, bus: str, key: int) -> None:
        """Say the line for ``bus``, whose first unknown id is ``key`` (a frame key), once."""
        if bus in self.told:
            return
        self.tell_text(bus, id_text(key))

    def tell_text(self, bus: str, ident: str) -> None:
        """:meth:`tell`, the id as the bring-up topics write it (``0x2C4``)."""
        if bus in self.told:
            return
        self.told[bus] = ident
        # one write, newline included: the line is said from the pipeline's thread, and the
        # reading thread's lines must not come inside it
        sys.stdout.write(self.line(bus, ident) + "\n")
        sys.stdout.flush()


def watch_unknown(drive: object, tell: Callable[[str, int], None]) -> bool:
    """Have ``tell`` told ``(bus, frame key)`` of the first id no database knows on each bus of
    ``drive`` (a :class:`~bridge.pipeline.drive.Drive`: its bring-up stage's ``on_unknown``);
    False when the drive has no bring-up stage."""
    monitor = getattr(drive, "bringup", None)
    if monitor is None:
        return False
    monitor.on_unknown = tell
    return True
