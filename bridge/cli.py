"""The ``tankviz`` command line.

Every user error is a :class:`~bridge.errors.BridgeError`, printed as one ``error: …`` line with
exit status 1; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bridge import __version__
from bridge.errors import BridgeError

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


def _dbc_option(text: str) -> str:
    """``--dbc [BUS=]PATH``, where PATH may also name a bundled database (``ecocar``)."""
    from bridge.decode.decoder import parse_dbc_option
    from bridge.resources import bundled_database

    bus, path = parse_dbc_option(text)
    if not path.exists() and (bundled := bundled_database(str(path))) is not None:
        return f"{bus}={bundled}" if bus else str(bundled)
    return text


def _cmd_convert(args: argparse.Namespace) -> int:
    from bridge.apps.convert import convert
    from bridge.apps.progress import ProgressBar
    from bridge.resources import data_dir

    inputs: list[Path] = list(args.inputs)
    dbcs = [_dbc_option(text) for text in args.dbc or []]
    profile = args.profile
    if args.sample:
        inputs.append(data_dir() / "ecocar_sample.blf")
        profile = profile or "ecocar"
    if not inputs:
        raise BridgeError("convert: name at least one input log (or --sample)")
    if not dbcs and profile is None:
        print("warning: no --dbc and no --profile: only raw frames are recorded", file=sys.stderr)
    bar = ProgressBar(sys.stderr) if not args.quiet else None
    try:
        report = convert(inputs, args.output, dbcs, profile=profile, scene_rate=args.scene_rate,
                         force=args.force, strict=args.strict, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        stats = report.statistics
        rate = report.frames / report.seconds if report.seconds else 0.0
        print(f"wrote {report.output}: {report.frames:,} frames, {report.messages:,} messages "
              f"in {report.seconds:.1f} s ({rate:,.0f} frames/s)")
        print(f"  decoded {sum(stats['decoded'].values()):,}, "
              f"unknown ids {sum(stats['unknown_ids'].values()):,}, "
              f"decode errors {sum(stats['decode_errors'].values()):,}, "
              f"short frames {sum(stats['truncated'].values()):,}, "
              f"error frames {sum(stats['error_frames'].values()):,}")
        for key, title in (("unknown_ids", "unknown ids"), ("decode_errors", "decode errors")):
            top = sorted(stats[key].items(), key=lambda kv: -kv[1])[:8]
            if top:
                print(f"  {title}: " + ", ".join(f"{k} ({n})" for k, n in top))
        if report.issues:
            print(f"  skipped in the inputs: {len(report.issues)}")
            for issue in report.issues[:10]:
                print(f"    {issue}")
            if len(report.issues) > 10:
                print(f"    … {len(report.issues) - 10} more (tankviz inspect lists them)")
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from bridge.apps.inspect import format_summary, summarize_file

    for path in args.files:
        print(format_summary(str(path), summarize_file(path)))
    return 0


def _env(name: str, default: str) -> str:
    """Settings: command line > environment (TANKVIZ_*) > default."""
    return os.environ.get(f"TANKVIZ_{name}", default)


def _add_stage_options(parser: argparse.ArgumentParser, *, profile_default: str | None) -> None:
    parser.add_argument("--dbc", action="append", metavar="[BUS=]PATH",
                        help="signal database (DBC, KCD, SYM, ARXML) for BUS, or for every bus "
                        "without BUS=; repeatable; a bundled name such as 'ecocar' works too")
    parser.add_argument("--profile", metavar="NAME|PATH", default=profile_default,
                        help="vehicle profile (TOML) that says what the signals mean: adds the "
                        "scene and perception topics; a bundled name such as 'ecocar' works too; "
                        "without --dbc the profile's own databases are used"
                        + (f" (default {profile_default})" if profile_default else ""))
    parser.add_argument("--scene-rate", type=float, default=20.0, metavar="HZ",
                        help="scene updates per second of log time (default 20, at most 50)")


def _add_server_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default=_env("HOST", "127.0.0.1"),
                        help="address to serve Foxglove on (default 127.0.0.1, env TANKVIZ_HOST; "
                        "0.0.0.0 serves the car network: the protocol has no authentication)")
    parser.add_argument("--port", type=int, default=int(_env("PORT", "8765")),
                        help="WebSocket port (default 8765, env TANKVIZ_PORT)")


def _add_record_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--drives", type=Path, default=Path(_env("DRIVES", "drives")),
                        help="folder for the recordings, one MCAP per drive named by its UTC "
                        "start time (default ./drives, env TANKVIZ_DRIVES)")
    parser.add_argument("--split-size", type=float, metavar="MB",
                        help="start a new part when the current one reaches this size")
    parser.add_argument("--split-duration", type=float, metavar="S",
                        help="start a new part after this many seconds")
    parser.add_argument("--no-record", action="store_true", help="view only: record nothing")
    parser.add_argument("--no-server", action="store_true",
                        help="record only: no WebSocket server, no display load")
    _add_run_for(parser)


def _add_run_for(parser: argparse.ArgumentParser) -> None:
    default = _env("RUN_FOR", "")
    parser.add_argument("--for", dest="run_for", type=float, metavar="S",
                        default=float(default) if default else None,
                        help="stop by itself after this many seconds (env TANKVIZ_RUN_FOR)")


def _stages(args: argparse.Namespace) -> tuple[Any, Any]:
    from bridge.apps.convert import build_stages

    return build_stages([_dbc_option(text) for text in args.dbc or []], args.profile)


def _server(args: argparse.Namespace, *, server_time: bool = False) -> Any:
    from bridge.sinks.websocket import LiveServer

    server = LiveServer(host=args.host, port=args.port, server_time=server_time)
    server.start()
    return server


def _layout_hint() -> str:
    from bridge.resources import layouts_dir

    layout = layouts_dir() / "tank-viz.json"
    return str(layout) if layout.exists() else "(layouts/tank-viz.json)"


def _run_live(args: argparse.Namespace, buses: list[Any], *, start_feed: Any = None,
              stop_feed: Any = None) -> int:
    """Live on ``buses``; ``start_feed``/``stop_feed`` run a frame source beside it (demo)."""
    import threading

    from bridge.apps.live import Live, install_stop_signals

    decoder, profile = _stages(args)
    if args.no_record and args.no_server:
        raise BridgeError("--no-record and --no-server: nothing would be done")
    if args.split_size is not None and args.split_size <= 0:
        raise BridgeError(f"--split-size {args.split_size:g}: must be above 0")
    if args.split_duration is not None and args.split_duration <= 0:
        raise BridgeError(f"--split-duration {args.split_duration:g}: must be above 0")
    server = None if args.no_server else _server(args)
    try:
        live = Live(buses, decoder, profile=profile, scene_rate=args.scene_rate,
                    drives=None if args.no_record else args.drives, server=server,
                    split_size=(round(args.split_size * 1e6) if args.split_size else None),
                    split_duration_s=args.split_duration)

        def stop() -> None:
            if stop_feed is not None:
                stop_feed()  # first, so that every frame it sent is read and recorded
            live.stop()

        install_stop_signals(stop)
        if args.run_for:
            threading.Timer(args.run_for, stop).start()
        print(f"buses: {', '.join(str(b) for b in buses)}")
        if server is not None:
            print(f"Foxglove: open connection {server.url} (Foxglove WebSocket)")
            print(f"layout:   import {_layout_hint()} (Layouts menu)")
        if live.recorder is not None:
            print(f"recording into {args.drives}/")
        print("Ctrl+C stops and finishes the recording.", flush=True)
        live.start()
        if start_feed is not None:
            start_feed()
        report = live.run()
    finally:
        if server is not None:
            server.stop()
    for path in report.files:
        print(f"recorded {path}")
    print(f"{report.frames:,} frames; {len(report.gaps)} bus gaps; "
          f"{report.dropped:,} messages dropped for slow viewers")
    return 0


def _cmd_live(args: argparse.Namespace) -> int:
    from bridge.apps.live import BusSpec

    if args.print_systemd_unit:
        print(systemd_unit(args.argv))
        return 0
    if not args.bus:
        raise BridgeError("live: name at least one --bus NAME=INTERFACE:CHANNEL[@BITRATE]")
    return _run_live(args, [BusSpec.parse(text) for text in args.bus])


def systemd_unit(argv: Sequence[str]) -> str:
    """A systemd service that runs ``tankviz live`` with these arguments at boot."""
    import shlex

    kept = [a for a in argv if a != "--print-systemd-unit"]
    command = " ".join(shlex.quote(a) for a in [sys.executable, "-m", "bridge", *kept])
    return "\n".join([
        "# tankviz live at boot. Install: sudo cp tankviz.service /etc/systemd/system/ &&",
        "#   sudo systemctl daemon-reload && sudo systemctl enable --now tankviz",
        "[Unit]",
        "Description=tankviz: CAN to Foxglove bridge and drive recorder",
        "After=network-online.target",
        "Wants=network-online.target",
        "",
        "[Service]",
        f"WorkingDirectory={Path.cwd()}",
        f"ExecStart={command}",
        "KillSignal=SIGTERM",
        "TimeoutStopSec=15",
        "Restart=on-failure",
        "RestartSec=2",
        "",
        "[Install]",
        "WantedBy=multi-user.target",
        "",
    ])


def _cmd_demo(args: argparse.Namespace) -> int:
    from bridge.apps.live import BusSpec
    from bridge.sim.car import DEMO_CHANNEL, SimulatedCar

    car = SimulatedCar(seed=args.seed, scenario_s=args.scenario)

    def stop_car() -> None:
        car.stop()
        if car.is_alive():
            car.join(2.0)

    try:
        return _run_live(args, [BusSpec("can0", "virtual", DEMO_CHANNEL)],
                         start_feed=car.start, stop_feed=stop_car)
    finally:
        stop_car()
        print(f"the simulated car sent {car.sent:,} frames")


def _cmd_simulate(args: argparse.Namespace) -> int:
    from bridge.apps.convert import check_output
    from bridge.sim.drive import simulate

    output: Path = args.output
    check_output(output, force=args.force)
    frames = simulate(duration_s=args.duration, seed=args.seed)
    if output.suffix.lower() == ".mcap":
        from bridge.apps.convert import build_stages
        from bridge.pipeline.pipeline import Pipeline, describe_drive, new_health_monitor
        from bridge.sinks.mcap import Recorder, atomic_output

        decoder, profile = build_stages([], "ecocar")
        with atomic_output(output) as stream:
            recorder = Recorder(stream)
            health = new_health_monitor(decoder, profile)
            pipeline = Pipeline(decoder, profile=profile, recorder=recorder, health=health)
            for frame in frames:
                pipeline.process(frame)
            pipeline.finish()
            describe_drive(recorder, decoder, profile, pipeline.scene_rate,
                           {"simulated": {"seed": args.seed, "duration_s": args.duration},
                            "alarms": health.event_records()})
            recorder.finish()
        count = pipeline.frames
    else:
        import can

        from bridge.io.logs import supported_suffixes

        if not any(str(output).lower().endswith(s) for s in supported_suffixes()):
            raise BridgeError(f"{output}: unknown log format; write .blf, .asc, .log, .trc, "
                              ".csv, .db or .mcap")
        count = 0
        with can.Logger(output) as logger:
            for frame in frames:
                logger.on_message_received(can.Message(
                    timestamp=frame.timestamp_ns / 1e9, arbitration_id=frame.arbitration_id,
                    data=frame.data, is_extended_id=frame.is_extended, is_fd=frame.is_fd,
                    bitrate_switch=frame.bitrate_switch, dlc=frame.dlc, channel=0))
                count += 1
    print(f"wrote {output}: {count:,} frames, {args.duration:g} s of the simulated ecocar drive "
          f"(seed {args.seed})")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    import threading

    from bridge.apps.live import install_stop_signals
    from bridge.apps.replay import replay_log, replay_mcap

    stopping = threading.Event()
    mcap = [p for p in args.files if p.suffix.lower() == ".mcap"]
    if mcap and len(args.files) > 1:
        raise BridgeError("replay: one MCAP at a time (CAN logs can be several)")
    stages = None if mcap else _stages(args)
    server = _server(args, server_time=True)
    install_stop_signals(stopping.set)
    if args.run_for:
        threading.Timer(args.run_for, stopping.set).start()
    print(f"Foxglove: open connection {server.url} (Foxglove WebSocket)")
    print(f"layout:   import {_layout_hint()} (Layouts menu)", flush=True)
    try:
        if mcap:
            report = replay_mcap(mcap[0], server, speed=args.speed, loop=args.loop,
                                 start_s=args.start, stopping=stopping)
        else:
            assert stages is not None
            decoder, profile = stages
            report = replay_log(list(args.files), decoder, server, profile=profile,
                                scene_rate=args.scene_rate, speed=args.speed, loop=args.loop,
                                start_s=args.start, stopping=stopping)
    finally:
        server.stop()
    print(f"replayed {report.messages:,} messages ({report.loops} pass"
          f"{'es' if report.loops != 1 else ''})")
    return 0


def _cmd_recover(args: argparse.Namespace) -> int:
    from bridge.apps.progress import ProgressBar
    from bridge.apps.recover import format_report, recover_file

    bar = ProgressBar(sys.stderr, unit="messages") if not args.quiet else None
    try:
        report = recover_file(args.input, args.output, force=args.force, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        print(format_report(report, args.input, args.output))
    return 0


def _cmd_layouts(args: argparse.Namespace) -> int:
    from bridge.apps.layouts import export_layouts, format_listing, select_layouts

    if args.export is None:
        print(format_listing(select_layouts(args.names)))
        return 0
    for path in export_layouts(args.export, names=args.names, force=args.force):
        print(f"wrote {path}")
    print("import in Foxglove: Layouts menu > Import layout")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tankviz",
        description="CAN buses to Foxglove: decode with DBC files, draw the perception scene, "
        "stream it live and record every drive as MCAP.",
    )
    parser.add_argument("--version", action="version", version=f"tankviz {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    convert = sub.add_parser(
        "convert", help="convert CAN logs into one decoded MCAP drive archive",
        description="Convert CAN logs (any format python-can reads: .asc .blf .log .trc .csv "
        ".db, their .gz, .mf4 with tankviz[mf4]) into one MCAP with every raw frame, every "
        "decoded message, the statistics and the databases attached.")
    convert.add_argument("inputs", nargs="*", type=Path, metavar="INPUT",
                         help="log files; several are merged in time order")
    convert.add_argument("-o", "--output", type=Path, required=True, help="the MCAP to write")
    _add_stage_options(convert, profile_default=None)
    convert.add_argument("--sample", action="store_true",
                         help="also convert the bundled sample drive (with the ecocar profile)")
    convert.add_argument("--force", action="store_true", help="overwrite an existing output")
    convert.add_argument("--strict", action="store_true",
                         help="fail on the first unreadable line, damaged object or backwards "
                         "time jump instead of skipping and reporting it")
    convert.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no summary")
    convert.set_defaults(run=_cmd_convert)

    inspect = sub.add_parser("inspect", help="show what a drive archive (MCAP) holds",
                             description="Duration, start and end, topics with schemas and "
                             "counts, metadata, attachments and decode statistics of MCAP files.")
    inspect.add_argument("files", nargs="+", type=Path, metavar="FILE.mcap")
    inspect.set_defaults(run=_cmd_inspect)

    live = sub.add_parser(
        "live", help="CAN buses in, Foxglove live, every drive recorded",
        description="Read CAN buses live (any python-can interface, several at once), decode, "
        "draw the scene, serve it to Foxglove and record every drive as MCAP.")
    live.add_argument("--bus", action="append", metavar="NAME=INTERFACE:CHANNEL[@BITRATE]",
                      help="a bus to read, e.g. radar=socketcan:can0 or car=pcan:PCAN_USBBUS1"
                      "@500000; or NAME: that section of python-can's config file; repeatable")
    _add_stage_options(live, profile_default=None)
    _add_server_options(live)
    _add_record_options(live)
    live.add_argument("--print-systemd-unit", action="store_true",
                      help="print a systemd service running this command at boot, then exit")
    live.set_defaults(run=_cmd_live)

    demo = sub.add_parser(
        "demo", help="the simulated ecocar drive, live: open Foxglove and watch",
        description="Play the simulated ecocar drive onto a python-can virtual bus in real time "
        "and run the live pipeline on it: serve Foxglove and record to ./drives.")
    demo.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    demo.add_argument("--scenario", type=float, default=60.0, metavar="S",
                      help="length of the scenario before it starts again (default 60 s)")
    _add_stage_options(demo, profile_default="ecocar")
    _add_server_options(demo)
    _add_record_options(demo)
    demo.set_defaults(run=_cmd_demo)

    simulate = sub.add_parser(
        "simulate", help="write the simulated ecocar drive as a CAN log or an MCAP",
        description="Write the simulated ecocar drive: a CAN log (.blf .asc .log .trc .csv .db) "
        "or a converted drive (.mcap with the ecocar profile).")
    simulate.add_argument("-o", "--output", type=Path, required=True)
    simulate.add_argument("--duration", type=float, default=60.0, metavar="S",
                          help="seconds of driving (default 60)")
    simulate.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    simulate.add_argument("--force", action="store_true", help="overwrite an existing output")
    simulate.set_defaults(run=_cmd_simulate)

    replay = sub.add_parser(
        "replay", help="serve a recorded drive or CAN logs to Foxglove in real time",
        description="Serve a recorded drive (MCAP) as recorded, or CAN logs decoded through the "
        "pipeline, in real time; the server publishes log time so Foxglove follows it.")
    replay.add_argument("files", nargs="+", type=Path, metavar="FILE")
    replay.add_argument("--speed", type=float, default=1.0, help="playback speed (default 1)")
    replay.add_argument("--loop", action="store_true", help="start again at the end")
    replay.add_argument("--start", type=float, default=0.0, metavar="SECONDS",
                        help="skip this many seconds of the drive")
    _add_run_for(replay)
    _add_stage_options(replay, profile_default=None)
    _add_server_options(replay)
    replay.set_defaults(run=_cmd_replay)

    recover = sub.add_parser(
        "recover", help="salvage a drive (MCAP) cut short by a power loss or a crash",
        description="Copy every complete record of an MCAP file that was cut short (power loss, "
        "killed recorder) into a complete new MCAP, and say what was recovered and where and why "
        "reading stopped. Damaged chunks (CRC mismatch) are skipped and reported.")
    recover.add_argument("input", type=Path, metavar="BROKEN.mcap")
    recover.add_argument("-o", "--output", type=Path, required=True, metavar="FIXED.mcap",
                         help="the complete MCAP to write")
    recover.add_argument("--force", action="store_true", help="overwrite an existing output")
    recover.add_argument("-q", "--quiet", action="store_true", help="no progress bar, no report")
    recover.set_defaults(run=_cmd_recover)

    layouts = sub.add_parser(
        "layouts", help="list the bundled Foxglove layouts, or copy them out to import them",
        description="List the bundled Foxglove layouts (tank-viz: the Tank Viz 3D view; "
        "engineer: 3D, plots and the lead vehicle; can-debug: decoded signals and raw frames), "
        "or copy them into a folder with --export; import them in Foxglove from the Layouts "
        "menu (Import layout).")
    layouts.add_argument("names", nargs="*", metavar="NAME",
                         help="only these layouts (default: all)")
    layouts.add_argument("--export", type=Path, metavar="DIR",
                         help="copy the layout files (JSON) into DIR (created if needed)")
    layouts.add_argument("--force", action="store_true",
                         help="overwrite layout files that already exist in DIR")
    layouts.set_defaults(run=_cmd_layouts)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(argv) if argv is not None else sys.argv[1:]
    try:
        code: int = args.run(args)
        return code
    except BridgeError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0

