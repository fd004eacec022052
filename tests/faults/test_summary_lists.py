"""The lists of convert's summary and of a drive's metadata: the decisive entry is never cut.

A damaged SQLite log stopped at row 7,625 after 89 skipped rows: the summary showed 10 of the 90
issues, and the 90th (``stopped at a row python-can cannot read``) was never shown. Now a stop
comes first, repeated issues are one line with their count, and a list that is cut says how
many entries it left out (the unknown ids too).
"""

from __future__ import annotations

import json
from pathlib import Path

from bridge.apps.convert import format_report
from bridge.apps.inspect import DriveSummary, format_summary
from bridge.io.can_logs import SourceIssue
from bridge.io.issues import summarize_issues
from bridge.pipeline.convert import MAX_ISSUES_RECORDED, ConvertReport, recorded_issues
from bridge.sinks.mcap import METADATA_NAME

STATISTICS = {"decoded": {}, "unknown_ids": {}, "decode_errors": {}, "truncated": {},
              "error_frames": {}}


def skips_then_a_stop(skips: int) -> list[SourceIssue]:
    skipped = [SourceIssue("d.db", f"row {n}", "skipped a frame with no readable timestamp "
                           "(None)", "skip", "frame without a readable timestamp")
               for n in range(1, skips + 1)]
    stop = SourceIssue("d.db", "row 7,625", "stopped at row 7,625, which python-can cannot read "
                       "(DatabaseError): the rest of the file is not read", "stop",
                       "stopped at a row python-can cannot read")
    return [*skipped, stop]


def test_the_stop_is_the_first_issue_of_the_summary_and_the_repeats_one_line() -> None:
    report = ConvertReport(Path("d.mcap"), 10, 10, 1.0, STATISTICS, skips_then_a_stop(89))
    lines = format_report(report).splitlines()
    at = lines.index("  skipped in the inputs: 90")
    assert lines[at + 1] == ("    d.db:row 7,625: stopped at row 7,625, which python-can cannot "
                             "read (DatabaseError): the rest of the file is not read")
    assert lines[at + 2].startswith("    d.db: frame without a readable timestamp (89 times: "
                                    "row 1, row 2, row 3, …)")


def test_a_cut_list_of_unknown_ids_says_how_many_more() -> None:
    statistics = {**STATISTICS, "unknown_ids": {f"can0:0x{n:03x}": n for n in range(1, 21)}}
    lines = format_report(ConvertReport(Path("d.mcap"), 10, 10, 1.0, statistics)).splitlines()
    (line,) = [line for line in lines if line.startswith("  unknown ids: ")]
    assert line.startswith("  unknown ids: can0:0x014 (20), can0:0x013 (19)")
    assert line.endswith(", and 12 more")


def test_the_metadata_keeps_the_stop_however_many_skips_came_before() -> None:
    issues = skips_then_a_stop(MAX_ISSUES_RECORDED + 50)
    recorded = recorded_issues(issues)
    assert recorded["count"] == MAX_ISSUES_RECORDED + 51
    assert len(recorded["first"]) == MAX_ISSUES_RECORDED
    assert recorded["first"][0] == str(issues[-1])
    assert recorded["first"][1:] == [str(i) for i in issues[:MAX_ISSUES_RECORDED - 1]]


def test_issues_kept_as_text_in_the_metadata_are_told_the_same_way() -> None:
    """``inspect`` has only the texts: rows are places, damage comes before a skip."""
    texts = [str(i) for i in skips_then_a_stop(3)[:3]]
    texts.append("d.csv:line 40: damaged data: 4096 zero bytes in this line: no frame is kept "
                 "from it (the lines they overwrote are lost)")
    assert summarize_issues(texts) == [
        "d.csv:line 40: damaged data: 4096 zero bytes in this line: no frame is kept from it "
        "(the lines they overwrote are lost)",
        "d.db: skipped a frame with no readable timestamp (None) (3 times: row 1, row 2, row 3)"]


def test_inspect_prints_each_ids_last_decode_error_under_decode_errors() -> None:
    # #33 item 12: the last error of each id came after "short frames", as if it were one of
    # theirs
    statistics = {**STATISTICS, "frames": {"can0": 10},
                  "decode_errors": {"can0/0x700": 3},
                  "last_decode_error": {"can0/0x700": "SensorDiag: bad multiplexer id 9"},
                  "truncated": {"/can/can0/EgoMotion": 2}}
    summary = DriveSummary(0, 1, 10, [], {METADATA_NAME: {"statistics": json.dumps(statistics)}})
    lines = format_summary("d.mcap", summary).splitlines()
    at = lines.index("  decode errors: 3 — can0/0x700 (3)")
    assert lines[at + 1] == "    can0/0x700: SensorDiag: bad multiplexer id 9"
    assert lines[at + 2] == "  short frames (decoded what fits): 2 — /can/can0/EgoMotion (2)"
