"""The one place a drive is assembled: stages from databases and a profile, a pipeline, sinks.

Every command makes its drive here; none wires stages by hand. :func:`load_stages` loads the
decoder and the profile, every name checked against the databases. :class:`Drive` holds the
health monitor, the bring-up stage (on unless ``bring_up=False``) and the
:class:`~bridge.pipeline.pipeline.Pipeline`, its sinks in the order they are added (the live
server first: viewers wait for a scene, the recorder does not); :meth:`Drive.run` and
:meth:`Drive.run_packed` feed it, :meth:`Drive.finish` emits what is due and finishes every sink.
A file sink made with :meth:`Drive.record` or :meth:`Drive.record_parts` gets every database and
the profile as attachments when it (each part) starts, and the ``tankviz`` metadata record
(:meth:`Drive.describe`, plus :attr:`Drive.extra`) just before it is finished.
"""

from __future__ import annotations

import gc
from collections.abc import Callable, Iterable, Mapping, Sequence
from datetime import datetime, timezone
from itertools import islice
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, NamedTuple

from bridge import __version__
from bridge.decode.database import DatabaseFile, load_database, parse_dbc_option
from bridge.decode.decoder import Decoder
from bridge.frame import Frame
from bridge.health.monitor import HealthMonitor
from bridge.packed import PackedFrames
from bridge.pipeline import DEFAULT_SCENE_RATE
from bridge.pipeline.pipeline import Pipeline
from bridge.sinks.base import Sink
from bridge.sinks.drives import PartsRecorder
from bridge.sinks.mcap import LIVE_LEVEL, Recorder

if TYPE_CHECKING:  # (bring-up brings numpy, a profile its stages: loaded when a drive has them)
    from bridge.bringup.monitor import BringUpMonitor
    from bridge.profile.model import Profile


class Stages(NamedTuple):
    """What decodes a drive and says what its signals mean."""

    decoder: Decoder
    profile: Profile | None


def build_decoder(dbc_options: Sequence[str]) -> Decoder:
    """A decoder from ``[BUS=]PATH`` options; each file is loaded once even if named twice."""
    loaded: dict[Path, DatabaseFile] = {}
    by_bus: dict[str | None, list[DatabaseFile]] = {}
    for option in dbc_options:
        bus, path = parse_dbc_option(option)
        key = path.resolve()
        if key not in loaded:
            loaded[key] = load_database(path)
        by_bus.setdefault(bus, []).append(loaded[key])
    return Decoder(by_bus)


def load_stages(dbc_options: Sequence[str], profile: str | Path | None) -> Stages:
    """The decoder and the profile; without --dbc options the profile's own databases are used
    (with them, the profile's ``databases`` are set aside: they need not exist here)."""
    if profile is None:
        return Stages(build_decoder(dbc_options), None)
    from bridge.profile.loader import load_profile, read_profile_databases, resolve_profile

    path = resolve_profile(profile)
    given = bool(dbc_options)
    if not given:
        dbc_options = [str(p) if bus == "*" else f"{bus}={p}"
                       for bus, paths in read_profile_databases(path).items() for p in paths]
    decoder = build_decoder(dbc_options)
    return Stages(decoder, load_profile(path, [f.db for f in decoder.files],
                                        own_databases=not given))


def new_health_monitor(decoder: Decoder, profile: Profile | None,
                       bitrates: Mapping[str, int] | None = None) -> HealthMonitor:
    """The health monitor of a drive; bitrates given here override the profile's."""
    rates = dict(profile.bitrates) if profile is not None else {}
    rates.update(bitrates or {})
    return HealthMonitor(profile, decoder, bitrates=rates,
                         data_bitrates=profile.data_bitrates if profile is not None else None)


#: The prefix of a drive's profile attachment (``profile-car.toml``).
PROFILE_PREFIX = "profile-"


def attachment_names(files: Iterable[DatabaseFile]) -> dict[str, str]:
    """Attachment name per database sha256: the file name, made unique where two collide."""
    names: dict[str, str] = {}
    for f in files:
        name = f.path.name
        if name in names.values():
            name = f"{f.sha256[:8]}-{name}"
        names.setdefault(f.sha256, name)
    return names


class Drive:
    """One drive: stages, health monitor, pipeline and sinks."""

    def __init__(self, stages: Stages, sinks: Iterable[Sink] = (), *,
                 scene_rate: float = DEFAULT_SCENE_RATE,
                 bitrates: Mapping[str, int] | None = None,
                 extra: Mapping[str, Any] | None = None, bring_up: bool = True) -> None:
        self.decoder, self.profile = stages
        self.scene_rate = scene_rate
        self.health = new_health_monitor(self.decoder, self.profile, bitrates)
        #: the bring-up stage (None: ``bring_up=False``); its ``on_unknown`` is told the first
        #: unknown id of each bus
        self.bringup: BringUpMonitor | None = None
        if bring_up:  # (imported here: bring-up brings numpy, which a drive without it skips)
            from bridge.bringup.monitor import BringUpMonitor

            self.bringup = BringUpMonitor(self.decoder)
        self.pipeline = Pipeline(self.decoder, profile=self.profile, scene_rate=scene_rate,
                                 sinks=sinks, health=self.health, bringup=self.bringup)
        #: what the command adds to the metadata record (inputs, buses, the simulation)
        self.extra: dict[str, Any] = dict(extra or {})
        #: the decode statistics of the last description
        self.statistics: dict[str, Any] = {}

    def add(self, sink: Sink) -> Sink:
        """One more sink, after those there are (before the first frame)."""
        self.pipeline.add_sink(sink)
        return sink

    def record(self, output: IO[bytes], *, attachment_time_ns: int | None = None,
               level: int = LIVE_LEVEL) -> Recorder:
        """Record the drive into the open binary ``output``, described when it is finished
        (``attachment_time_ns``: a fixed create time of the attachments, for the same bytes;
        ``level``: the chunks' zstd level, :data:`~bridge.sinks.mcap.OFFLINE_LEVEL` offline)."""
        recorder = Recorder(output, describe=self.describe, attach=self.attach,
                            attachment_time_ns=attachment_time_ns, level=level)
        self.add(recorder)
        return recorder

    def record_parts(self, folder: Path, *, split_size: int | None = None,
                     split_duration_s: float | None = None) -> PartsRecorder:
        """Record the drive into ``folder``, one MCAP per part, each described."""
        recorder = PartsRecorder(folder, self.describe, split_size, split_duration_s,
                                 attach=self.attach)
        self.add(recorder)
        return recorder

    def run(self, frames: Iterable[Frame], *, progress: Callable[[int], None] | None = None,
            every: int = 16384) -> int:
        """Every frame through the pipeline; ``progress`` is called with the count now and
        then. Returns how many frames there were."""
        process = self.pipeline.process_many
        count = 0
        frames = iter(frames)
        # The hot loop makes millions of short-lived tuples and no reference cycles: the cyclic
        # garbage collector would only walk the long-lived caches over and over (about 8 %).
        collecting = gc.isenabled()
        gc.disable()
        try:
            while chunk := list(islice(frames, every)):
                process(chunk)
                count += len(chunk)
                if progress is not None and len(chunk) == every:
                    progress(count)
        finally:
            if collecting:
                gc.enable()
        return count

    def run_packed(self, packs: Iterable[PackedFrames], *,
                   progress: Callable[[int], None] | None = None, every: int = 16384) -> int:
        """:meth:`run` for frames in packs (offline: :meth:`Pipeline.process_packed`)."""
        process = self.pipeline.process_packed
        count = 0
        collecting = gc.isenabled()
        gc.disable()  # as in run
        try:
            for pack in packs:
                process(pack)
                before, count = count, count + len(pack)
                if progress is not None and count // every != before // every:
                    progress(count)
        finally:
            if collecting:
                gc.enable()
        return count

    def finish(self) -> None:
        """Emit what is still due and finish every sink (files are complete after this)."""
        self.pipeline.finish()
        for sink in self.pipeline.sinks:
            sink.finish()

    def attach(self, recorder: Recorder) -> None:
        """Attach the databases and the profile (as a recording starts, before any message)."""
        names = attachment_names(self.decoder.files)
        for f in self.decoder.files:
            recorder.add_attachment(names[f.sha256], f.content)
        if self.profile is not None:
            recorder.add_attachment(f"{PROFILE_PREFIX}{self.profile.path.name}",
                                    self.profile.path.read_bytes(), media="application/toml")

    def describe(self, recorder: Recorder, part: Mapping[str, Any] | None = None) -> None:
        """Write the ``tankviz`` metadata record (with :attr:`extra`, the alarms so far and
        ``part``'s own entries); :meth:`attach` has attached the databases and the profile.
        The open window of raw frames is recorded first, so the frames the statistics count are
        those the file holds."""
        self.pipeline.flush_raw()
        decoder, profile = self.decoder, self.profile
        names = attachment_names(decoder.files)
        buses: dict[str, list[str]] = {}
        for f in decoder.files:
            for bus in decoder.buses_for(f):
                buses.setdefault(bus, []).append(names[f.sha256])
        self.statistics = decoder.stats.to_dict(decoder.codecs())
        perception = self.pipeline.perception
        if perception is not None:  # validity rules that could not be evaluated, per group
            self.statistics["rule_errors"] = dict(sorted(perception.world.rule_errors.items()))
            self.statistics["last_rule_error"] = dict(
                sorted(perception.world.last_rule_error.items()))
        recorder.add_metadata({
            "tankviz_version": __version__,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "profile": ({"name": profile.name, "attachment": f"{PROFILE_PREFIX}{profile.path.name}",
                         "scene_rate_hz": self.scene_rate} if profile is not None else None),
            "databases": [{"name": f.name, "attachment": names[f.sha256], "sha256": f.sha256,
                           "path": str(f.path), "buses": decoder.buses_for(f)}
                          for f in decoder.files],
            "bus_databases": buses,
            "statistics": self.statistics,
            "warnings": decoder.warnings(),
            **self.extra,
            "alarms": self.health.event_records(),
            "lateral_sign": self.health.lateral_sign_records(),
            "clock_steps": [step.to_dict() for step in self.pipeline.steps],
            **(part or {}),
        })
