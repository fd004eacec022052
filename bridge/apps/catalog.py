"""``tankviz catalog``: index an archive of drives into a DuckDB file, and ask it questions.

``tankviz catalog DRIVES... -o CATALOG`` (re)indexes them (:func:`bridge.fleet.catalog.index`);
``tankviz catalog query CATALOG "SQL"`` prints an answer as a table, with the ``tankviz
replay`` command and Foxglove time that open each row's moment.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bridge.apps.options import Subparsers
from bridge.errors import UsageError, shown
from bridge.fleet import catalog, questions

USAGE = """tankviz catalog DRIVES... -o CATALOG.duckdb [--workers N | --scheduler ADDRESS]
       tankviz catalog query CATALOG.duckdb ["SQL" | --alarm ID | --topic T | --mark TEXT]
                             [--between T1 T2]"""
QUERY_USAGE = ('tankviz catalog query CATALOG.duckdb ["SQL" | --alarm ID | --topic T | '
               "--mark TEXT] [--between T1 T2]")
#: Questions the help shows (as written, after the options).
EXAMPLES = """examples:
  every mark with 'ghost' in the fleet:
    tankviz catalog query catalog.duckdb \\
      "SELECT drive, mark, t_s, text FROM marks WHERE text ILIKE '%ghost%'"
    (or: tankviz catalog query catalog.duckdb --mark ghost)
  every time an alarm was raised:
    tankviz catalog query catalog.duckdb --alarm radar-camera.misaligned
  cut-ins within 20 m:
    tankviz catalog query catalog.duckdb \\
      "SELECT drive, t_ns, distance_m FROM lead_changes WHERE cut_in AND distance_m < 20\""""


def query_parser() -> argparse.ArgumentParser:
    """What ``tankviz catalog query --help`` shows (the query's own arguments)."""
    parser = argparse.ArgumentParser(
        prog="tankviz catalog query", usage=QUERY_USAGE,
        description="Ask a catalogue: SQL on its tables (drives, databases, alarms, topics, "
        "objects_summary, lead_changes, marks), or a canned question; each answer row with a "
        "drive and a log time (or a mark) comes with the tankviz replay command that opens it "
        "there.", epilog=EXAMPLES, formatter_class=_Formatter)
    parser.add_argument("catalog", metavar="CATALOG.duckdb", help="the catalogue to ask")
    parser.add_argument("sql", nargs="?", metavar="SQL", help="a query (read only)")
    _add_query_options(parser)
    return parser


def _add_query_options(parser: argparse.ArgumentParser, prefix: str = "") -> None:
    parser.add_argument("--alarm", metavar="ID", help=f"{prefix}every time alarm ID was raised")
    parser.add_argument("--topic", metavar="T", help=f"{prefix}every drive with topic T")
    parser.add_argument("--mark", metavar="TEXT",
                        help=f"{prefix}every mark whose text contains TEXT (in any case)")
    parser.add_argument("--between", nargs=2, metavar=("T1", "T2"),
                        help=f"{prefix}drives recorded between two UTC times (2026-01-01 or "
                        "2026-01-01T12:00:00); narrows --alarm, --topic and --mark")


class _Formatter(argparse.HelpFormatter):
    """argparse's, but :data:`EXAMPLES` as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith("examples:"):
            return text
        return super()._fill_text(text, width, indent)


class _Help(argparse.Action):
    """``-h``: the query's help after ``query``, else the indexing help."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                         help="show this help message and exit (after query: the query's)")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        items = getattr(namespace, "items", None) or []
        (query_parser() if items[:1] == ["query"] else parser).print_help()
        parser.exit()


def add_parser(sub: Subparsers) -> None:
    parser = sub.add_parser(
        "catalog", help="index drives into a DuckDB catalogue, or query it", usage=USAGE,
        add_help=False, epilog=EXAMPLES, formatter_class=_Formatter,
        description="tankviz catalog DRIVES... -o CATALOG.duckdb: (re)index drives (files, "
        "folders searched recursively for *.mcap, globs); only new or changed drives are read. "
        "tankviz catalog query CATALOG.duckdb \"SQL\" (or --alarm/--topic/--mark/--between): "
        "ask it, with the tankviz replay command that opens each answer (tankviz catalog query "
        "--help).")
    parser.add_argument("-h", "--help", action=_Help)
    parser.add_argument("items", nargs="+", metavar="DRIVES",
                        help="drive files, folders (searched recursively for *.mcap) or globs; "
                        "or query, the catalogue and the SQL")
    parser.add_argument("-o", "--output", type=Path, metavar="CATALOG.duckdb",
                        help="the catalogue to (re)index")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="read the drives on a local Dask cluster of N worker processes")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="read the drives on an existing Dask cluster (tcp://host:8786); "
                        "its workers must see the same paths")
    _add_query_options(parser, "query: ")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    items: list[str] = args.items
    if items[0] == "query":
        return _query(args, items[1:])
    for option in ("alarm", "topic", "mark", "between"):
        if getattr(args, option) is not None:
            raise UsageError(f"--{option}", "asks a catalogue: tankviz catalog query CATALOG "
                             f"--{option} ...")
    if args.output is None:
        raise UsageError("catalog", "name the catalogue to index into: tankviz catalog DRIVES... "
                         "-o catalog.duckdb")
    reader: catalog.Reader = catalog.read_here
    if args.workers is not None or args.scheduler is not None:
        reader = catalog.dask_reader(workers=args.workers, scheduler=args.scheduler)
    report = catalog.index(args.output, items, reader=reader)
    for _, error in report.failed:
        print(f"skipped: {error}", file=sys.stderr)
    for path in report.recording:
        print(f"skipped {path}: being recorded (a recording is writing it): index it once the "
              "drive has ended", file=sys.stderr)
    print(shown(report.summary(args.output)))
    return 1 if report.failed else 0


def _query(args: argparse.Namespace, rest: list[str]) -> int:
    if args.output is not None or args.workers is not None or args.scheduler is not None:
        raise UsageError("catalog query", "-o, --workers and --scheduler are for indexing, not for "
                         "query")
    if not rest or len(rest) > 2:
        raise UsageError("catalog query", f"usage: {QUERY_USAGE}")
    path = Path(rest[0])
    sql = rest[1] if len(rest) == 2 else None
    between: tuple[str, str] | None = (
        None if args.between is None else (args.between[0], args.between[1]))
    asked = (sql, args.alarm, args.topic, args.mark)
    if sum(x is not None for x in asked) != 1 and not (
            all(x is None for x in asked) and between is not None):
        raise UsageError("catalog query", 'ask one thing: "SQL", --alarm ID, --topic T or --mark '
                         "TEXT (each may be narrowed with --between T1 T2, except SQL), or "
                         "--between T1 T2 alone")
    if sql is not None:
        if between is not None:
            raise UsageError("--between", "narrows --alarm, --topic and --mark; write it into the "
                             "SQL")
        answer = questions.query(path, sql)
    elif args.alarm is not None:
        answer = questions.alarm_query(path, args.alarm, between)
    elif args.topic is not None:
        answer = questions.topic_query(path, args.topic, between)
    elif args.mark is not None:
        answer = questions.mark_query(path, args.mark, between)
    else:
        assert between is not None
        answer = questions.between_query(path, between)
    print(questions.format_answer(answer))
    return 0
