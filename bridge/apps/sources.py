"""The source of the bring-up commands (``ids``, ``bits``, ``find-signal``): what ``convert``
reads, read as ``convert`` reads it.

Logs of any format python-can reads, or one recorded drive (decoded with its attached databases
unless ``--dbc`` names others), as packed frames from the read-ahead; times on the command line
are seconds from the source's first frame, as ``tankviz replay --start`` takes them.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bridge.apps.options import dbc_option
from bridge.apps.progress import ProgressBar
from bridge.decode.decoder import Decoder
from bridge.errors import InputError, UsageError
from bridge.frame import EXTENDED_KEY, NS
from bridge.packed import PackedFrames


def add_source_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", type=Path, metavar="SOURCE",
                        help="CAN logs (any format convert reads; several are merged in time "
                        "order) or one recorded drive (.mcap)")
    parser.add_argument("--dbc", action="append", metavar="[BUS=]PATH",
                        help="signal database for BUS, or for every bus without BUS=; "
                        "repeatable; a recorded drive's attached databases without it")
    parser.add_argument("--profile", metavar="NAME|PATH",
                        help="vehicle profile: its databases, where no --dbc is given")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress line")


@dataclass
class Source:
    """Opened inputs, their decoder, and where their time starts once read."""

    inputs: list[Path]
    decoder: Decoder
    sources: list[Any]
    quiet: bool
    #: the first frame's log time, once the first pack is read
    origin_ns: int | None = None
    _messages: dict[str, dict[int, Any]] | None = None

    def packs(self) -> Iterator[PackedFrames]:
        """The frames in packs, in order, with a progress line."""
        from bridge.io.readahead import ReadAhead

        reading = ReadAhead(self.sources)
        bar = None if self.quiet else ProgressBar(sys.stderr)
        frames = 0
        try:
            for pack in reading.packs():
                if not len(pack):
                    continue
                if self.origin_ns is None:
                    self.origin_ns = pack.t[0]
                frames += len(pack)
                if bar is not None:
                    done, total = reading.progress()
                    bar(frames, done / total if total else None)
                yield pack
        finally:
            if bar is not None:
                bar.close()
        if self.origin_ns is None:
            raise InputError(self.inputs[0], "no CAN frames in this source")

    def message(self, bus: str, key: int) -> Any:
        """The database message of (bus, key), or None."""
        if self._messages is None:
            self._messages = {}
        table = self._messages.get(bus)
        if table is None:
            table = self._messages[bus] = {frame_key_of(c.message): c.message
                                           for c in self.decoder.codecs_for(bus)}
        return table.get(key)


def frame_key_of(message: Any) -> int:
    return int(message.frame_id) | (EXTENDED_KEY if message.is_extended_frame else 0)


@contextlib.contextmanager
def opened(args: argparse.Namespace) -> Iterator[Source]:
    """The source ``args`` name (inputs, ``--dbc``, ``--profile``), checked before any frame is
    read."""
    from bridge.io.can_logs import LogSource
    from bridge.io.drives import ArchiveSource, is_drive, read_drive
    from bridge.pipeline.convert import refuse_repeated
    from bridge.pipeline.drive import load_stages
    from bridge.pipeline.rederive import rederive_stages

    inputs: list[Path] = list(args.inputs)
    refuse_repeated(inputs)
    dbcs = [dbc_option(text) for text in args.dbc or []]
    drives = [p for p in inputs if is_drive(p)]
    with tempfile.TemporaryDirectory(prefix="tankviz-bringup-") as folder:
        if drives:
            if len(inputs) > 1:
                raise InputError(drives[0], "read one recorded drive at a time, without logs "
                                 f"beside it ({len(inputs)} sources given)")
            drive = read_drive(drives[0])
            decoder = rederive_stages(drive, dbcs, args.profile, Path(folder)).decoder
            sources: list[Any] = [ArchiveSource(drive.path)]
        else:
            decoder = load_stages(dbcs, args.profile).decoder
            sources = [LogSource(p) for p in inputs]
        yield Source(inputs, decoder, sources, args.quiet)


def parse_window(text: str, option: str) -> tuple[float, float]:
    """``A0:A1`` seconds: a window (either end may be left out: from the start, to the end)."""
    start, colon, end = text.partition(":")
    if not colon:
        raise UsageError(option, "expected START:END in seconds from the source's "
                         "first frame, e.g. 40:60", value=text)
    try:
        a = float(start) if start.strip() else 0.0
        b = float(end) if end.strip() else float("inf")
    except ValueError:
        raise UsageError(option, "expected START:END in seconds, e.g. 40:60", value=text) from None
    if not b > a:
        raise UsageError(option, "the window's end must come after its start", value=text)
    return a, b


def window_ns(origin_ns: int, window: tuple[float, float]) -> tuple[int, int]:
    """A window of seconds from the first frame as log times, ns."""
    a, b = window
    end = (1 << 62) if b == float("inf") else origin_ns + round(b * NS)
    return origin_ns + round(a * NS), end


def parse_id(text: str, option: str = "--id") -> tuple[str, int]:
    """``BUS/ID``, the id in hex (``0x1A0``, ``1A0h``) or decimal: the bus and frame key (an id
    above 0x7FF is a 29-bit one)."""
    bus, slash, ident = text.rpartition("/")
    if not slash or not bus or not ident:
        raise UsageError(option, "expected BUS/ID, e.g. can0/0x1A0", value=text)
    raw = ident.strip().lower()
    try:
        if raw.startswith("0x"):
            number = int(raw[2:], 16)
        elif raw.endswith("h"):
            number = int(raw[:-1], 16)
        else:
            number = int(raw, 10)
    except ValueError:
        raise UsageError(option, f"{ident!r} is not an id (hex 0x1A0, or decimal "
                         "416)", value=text) from None
    if not 0 <= number < 1 << 29:
        raise UsageError(option, "a CAN id has at most 29 bits", value=text)
    return bus, number | EXTENDED_KEY if number > 0x7FF else number


def known_buses(census_buses: Sequence[str], bus: str, option: str, text: str) -> None:
    if bus not in census_buses:
        raise UsageError(option, f"the source has no bus {bus!r} (its buses: "
                         f"{', '.join(sorted(census_buses)) or 'none'})", value=text)
