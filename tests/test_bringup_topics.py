"""The bring-up topics every drive publishes (bridge/bringup/monitor.py), checked against counts
made here from the frames of the simulated highway car, whose ids 0x2C4, 0x3B7 and 0x4C8 on can0
and 0x2E0 on can1 no database of it defines:

- ``/can/<bus>/ids``: a row per id, once a second, counting the frames before its time;
- ``/can/<bus>/unknown``: every frame of the unknown ids to a viewer, at most ``FILE_HZ`` a
  second per id (the first of each slot of log time) into a file; never a known id;
- ``/can/bits`` (a PNG, read back with the small reader below) and ``/can/bits/labels``;
- the same messages frame by frame, in live's reads and in packs; none with ``--no-bring-up``.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections import defaultdict
from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader

from bridge.bringup import bitmap
from bridge.bringup.bitmap import MAX_ROWS, MapRow, bit_map
from bridge.bringup.census import gap_figures
from bridge.bringup.columns import id_text
from bridge.bringup.font import ADVANCE, GLYPHS, draw_text, glyph
from bridge.bringup.monitor import FILE_HZ, FILE_PERIOD_S
from bridge.bringup.payload import encode, id_field
from bridge.cli import main
from bridge.frame import NS, Frame
from bridge.packed import PackedFrames
from bridge.pb.bringup_pb2 import CanIds, CanPayload
from bridge.pipeline.drive import Drive, load_stages
from bridge.sim.highway import simulate_highway
from bridge.sim.highway_body import BRAKE_ID, CAR_IDS, CONSTANT_ID, HEARTBEAT_ID, RADAR_IDS
from bridge.sinks.base import Serialized, Sink
from bridge.sinks.can_log_writer import write_log
from bridge.topics import BITS_LABELS_TOPIC, BITS_TOPIC, ids_topic, unknown_topic

UNKNOWN = {"can0": set(CAR_IDS), "can1": set(RADAR_IDS)}
#: The highway car's databases' messages on each bus (what the tables name)
KNOWN = {"can0": {0x024: "KINEMATICS", 0x025: "STEER_ANGLE_SENSOR", 0x0AA: "WHEEL_SPEEDS",
                  0x0B4: "SPEED"}}

Messages = dict[str, list[tuple[int, bytes]]]


class Viewer(Sink):
    """What a live viewer is sent: a sink that records no file."""

    def __init__(self) -> None:
        self.topics: Messages = defaultdict(list)

    def on_messages(self, messages: Sequence[Serialized], /) -> None:
        for m in messages:
            self.topics[m.topic].append((m.t_ns, m.payload))


def highway(seconds: float = 6.0) -> list[Frame]:
    return list(simulate_highway(duration_s=seconds, seed=2))


def viewed(frames: list[Frame], feed: str = "frames", size: int = 0) -> Messages:
    """Every message a viewer gets of a drive of ``frames``: fed one by one, in live's reads or
    in packs of ``size``."""
    viewer = Viewer()
    drive = Drive(load_stages([], "highway"), [viewer])
    if feed == "frames":
        drive.run(frames)
    elif feed == "reads":
        for i in range(0, len(frames), size):
            drive.pipeline.process_many(frames[i:i + size])
    else:
        drive.run_packed(PackedFrames.from_frames(frames[i:i + size])
                         for i in range(0, len(frames), size))
    drive.finish()
    return dict(viewer.topics)


def recorded(frames: list[Frame], *, bring_up: bool = True) -> Messages:
    """Every message of a converted drive of ``frames``, per topic, in file order."""
    drive = Drive(load_stages([], "highway"), bring_up=bring_up)
    out = io.BytesIO()
    drive.record(out, attachment_time_ns=0)
    drive.run_packed([PackedFrames.from_frames(frames)])
    drive.finish()
    out.seek(0)
    topics: Messages = defaultdict(list)
    for _, channel, message in make_reader(out).iter_messages(log_time_order=False):
        topics[channel.topic].append((message.log_time, message.data))
    return dict(topics)


def frames_of(frames: list[Frame], bus: str, key: int) -> list[Frame]:
    return [f for f in frames if f.bus == bus and f.arbitration_id == key]


def flipped(frames: list[Frame], since: int = 0) -> set[int]:
    """Bits (byte * 8 + bit) that differ between a frame and the one before, from frame
    ``since`` on."""
    bits = set()
    for before, after in pairwise(frames[max(since - 1, 0):]):
        changed = int.from_bytes(before.data, "little") ^ int.from_bytes(after.data, "little")
        bits |= {b for b in range(64) if changed >> b & 1}
    return bits


@pytest.mark.slow
def test_each_second_the_ids_table_counts_the_frames_before_it() -> None:
    frames = highway()
    got = viewed(frames)

    tables = [(t, CanIds.FromString(data)) for t, data in got[ids_topic("can0")]]
    # once a second of log time, on whole seconds; the last after the last frame (with the final
    # scene tick, the next 20th of a second: here a whole second)
    assert [t % NS for t, _ in tables] == [0] * 6 and tables[-1][0] > frames[-1][0]
    previous = 0
    for t, table in tables:
        assert table.bus == "can0"
        assert [r.id for r in table.rows] == sorted(r.id for r in table.rows)
        for row in table.rows:
            key = int(row.id, 16)
            mine = [f for f in frames_of(frames, "can0", key) if f.timestamp_ns <= t]
            assert row.frames == len(mine), row
            assert row.dlc == ",".join(sorted({str(len(f.data)) for f in mine}))
            assert row.changing_bits == len(flipped(mine))
            new = sum(1 for f in mine if f.timestamp_ns < previous)
            assert row.changed_last_s == len(flipped(mine, new))
            if key in UNKNOWN["can0"]:
                assert row.message == "unknown"
                assert row.unexplained_bits == row.changing_bits  # all: no signal covers any
            else:
                assert row.message == KNOWN["can0"][key] and row.unexplained_bits == 0
        previous = t
    last = {r.id: r for r in tables[-1][1].rows}
    assert set(last) == {id_text(k) for k in KNOWN["can0"].keys() | UNKNOWN["can0"]}
    # the gaps of about the last 10 s (here all of them): 20, 100 and 500 ms, a little jitter
    for key, period_ms in ((BRAKE_ID, 20), (HEARTBEAT_ID, 100), (CONSTANT_ID, 500)):
        row = last[id_text(key)]
        times = [f.timestamp_ns for f in frames_of(frames, "can0", key)]
        median, p5, p95 = gap_figures(np.diff(times))
        assert row.period_ms == median == pytest.approx(period_ms, abs=0.3)
        assert row.jitter_ms == pytest.approx(p95 - p5) and row.jitter_ms < 0.4
    assert last[id_text(CONSTANT_ID)].changing_bits == 0
    radar = CanIds.FromString(got[ids_topic("can1")][-1][1])
    assert [(r.id, r.message) for r in radar.rows if r.message == "unknown"] == [("0x2E0",
                                                                                 "unknown")]


@pytest.mark.slow
def test_a_viewer_gets_every_frame_of_the_unknown_ids_and_no_known_one() -> None:
    frames = highway()
    got = viewed(frames)
    for bus, unknown in UNKNOWN.items():
        sent = [(t, CanPayload.FromString(data)) for t, data in got[unknown_topic(bus)]]
        mine = [f for f in frames if f.bus == bus and f.arbitration_id in unknown]
        assert [(t, int(p.id, 16)) for t, p in sent] == [
            (f.timestamp_ns, f.arbitration_id) for f in mine]
        for (_, payload), frame in zip(sent, mine, strict=True):
            d = frame.data
            assert list(payload.bytes) == list(d)
            assert list(payload.be16) == [d[i] << 8 | d[i + 1] for i in range(len(d) - 1)]
            assert list(payload.le16) == [d[i] | d[i + 1] << 8 for i in range(len(d) - 1)]
    # the counter nibble of 0x2C4: bits 8..11, +1 a frame
    counters = [CanPayload.FromString(data).bytes[1] & 0x0F
                for _, data in got[unknown_topic("can0")][:40]
                if CanPayload.FromString(data).id == "0x2C4"]
    assert all((b - a) % 16 == 1 for a, b in pairwise(counters))


@pytest.mark.slow
def test_a_file_gets_the_first_frame_of_each_id_in_each_slot_and_the_tables_now_and_then(
) -> None:
    frames = highway(12.0)
    got = recorded(frames)
    slot = round(NS / FILE_HZ)
    for bus, unknown in UNKNOWN.items():
        expected, last = [], {}
        for f in frames:
            if f.bus == bus and f.arbitration_id in unknown:
                if last.get(f.arbitration_id) != f.timestamp_ns // slot:
                    expected.append((f.timestamp_ns, f.arbitration_id, f.data))
                last[f.arbitration_id] = f.timestamp_ns // slot
        sent = [(t, CanPayload.FromString(data)) for t, data in got[unknown_topic(bus)]]
        assert [(t, int(p.id, 16), bytes(p.bytes)) for t, p in sent] == expected
    period = round(FILE_PERIOD_S * NS)
    for topic in (ids_topic("can0"), ids_topic("can1"), BITS_TOPIC, BITS_LABELS_TOPIC):
        times = [t for t, _ in got[topic]]
        assert times == [t for t in range(frames[0][0] // NS * NS, frames[-1][0], NS)
                         if t % period == 0 and t > frames[0][0]] + [frames[-1][0]], topic
    final = CanIds.FromString(got[ids_topic("can0")][-1][1])
    assert {r.id: r.frames for r in final.rows} == {
        id_text(k): len(frames_of(frames, "can0", k)) for k in KNOWN["can0"].keys() | CAR_IDS}


def read_png(data: bytes) -> tuple[np.ndarray[Any, Any], list[tuple[int, int, int]]]:
    """A paletted PNG's palette indices (rows of pixels) and palette: what tankviz writes (bit
    depth 1 to 8, no interlace; the filters none, sub and up)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    at, chunks = 8, defaultdict(bytes)
    while at < len(data):
        (length,) = struct.unpack(">I", data[at:at + 4])
        kind, body = data[at + 4:at + 8], data[at + 8:at + 8 + length]
        assert struct.unpack(">I", data[at + 8 + length:at + 12 + length])[0] == zlib.crc32(
            kind + body)
        chunks[kind] += body
        at += 12 + length
    width, height, depth, color, _, _, interlace = struct.unpack(">IIBBBBB", chunks[b"IHDR"])
    assert color == 3 and interlace == 0
    stride = (width * depth + 7) // 8
    raw = zlib.decompress(chunks[b"IDAT"])
    rows, above = [], bytes(stride)
    for y in range(height):
        start = y * (stride + 1)
        kind, line = raw[start], bytearray(raw[start + 1:start + 1 + stride])
        for x in range(stride):
            if kind == 1 and x:
                line[x] = (line[x] + line[x - 1]) % 256
            elif kind == 2:
                line[x] = (line[x] + above[x]) % 256
        rows.append(bytes(line))
        above = bytes(line)
    bits = np.unpackbits(np.frombuffer(b"".join(rows), dtype=np.uint8)).reshape(height, -1)
    per = bits.reshape(height, -1, depth) @ (1 << np.arange(depth)[::-1])
    palette = list(zip(*[iter(chunks[b"PLTE"])] * 3, strict=True))
    return per[:, :width], palette


@pytest.mark.slow
def test_the_bit_map_is_a_png_with_a_row_per_id_bright_where_a_bit_flips_every_frame() -> None:
    frames = highway()
    got = viewed(frames)
    image = CompressedImage.FromString(got[BITS_TOPIC][3][1])
    labels = ImageAnnotations.FromString(got[BITS_LABELS_TOPIC][3][1])
    assert image.format == "png" and image.timestamp == labels.timestamp
    assert all(text.timestamp == image.timestamp for text in labels.texts)
    pixels, palette = read_png(image.data)
    height, width = pixels.shape
    assert width <= 1200 and height <= 2000
    # a label per row, sorted by bus and id, naming its message (or "unknown")
    ids = sorted({(f.bus, f.arbitration_id) for f in frames})
    named = [t.text.split(" ") for t in labels.texts if t.text.startswith("can")]
    assert [(bus, ident) for bus, ident, _ in named] == [(b, id_text(k)) for b, k in ids]
    assert {(bus, ident) for bus, ident, name in named if name == "unknown"} == {
        (bus, id_text(k)) for bus, keys in UNKNOWN.items() for k in keys}
    assert ["can0", "0x0B4", "SPEED"] in named
    assert labels.texts[0].text.startswith(f"bits flipped in the last second: {len(ids)} ids on "
                                           "can0, can1, 4 unknown")

    def cell(key: int, byte: int, bit: int) -> tuple[int, int, int]:
        """The colour at the middle of a bit's cell, found by the labels of its row and byte."""
        row = next(t for t in labels.texts if t.text.startswith(f"can0 {id_text(key)} "))
        column = next(t for t in labels.texts if t.text == f"byte {byte}")
        x = round(column.position.x + (7 - bit) * bitmap.CELL + bitmap.CELL // 2)
        y = round(row.position.y - bitmap.FONT - 1 + bitmap.ROW // 2)
        return palette[pixels[y, x]]

    # the labels are in the pixels too: amber for an unknown id, at its row's left
    unknown_row = next(t for t in labels.texts if t.text.startswith(f"can0 {id_text(BRAKE_ID)} "))
    top = round(unknown_row.position.y - bitmap.FONT)
    assert (pixels[top:top + bitmap.FONT, :bitmap.margin([])] == bitmap.AMBER).sum() > 100
    known_row = next(t for t in labels.texts if t.text.startswith("can0 0x0B4 "))
    top = round(known_row.position.y - bitmap.FONT)
    assert (pixels[top:top + bitmap.FONT, :bitmap.margin([])] == bitmap.TEXT).sum() > 100

    white = (255, 255, 255)
    assert cell(BRAKE_ID, 1, 0) == white  # the counter's lowest bit: every frame
    assert sum(cell(BRAKE_ID, 1, 1)) < sum(white)  # its next: every other frame
    assert cell(BRAKE_ID, 0, 7) == palette[bitmap.NEVER]  # byte 0 is 0xA5, always
    assert cell(CONSTANT_ID, 0, 0) == palette[bitmap.NEVER]
    assert cell(BRAKE_ID, 7, 0) not in (palette[bitmap.NEVER], palette[bitmap.QUIET])  # checksum


def _glyph_by_glyph(canvas: np.ndarray, x: int, y: int, text: str, value: int,
                    scale: int) -> None:
    """How the font drew a text before it drew it at once: each glyph scaled with np.kron."""
    height, width = canvas.shape
    for i, char in enumerate(text):
        shape = glyph(char)
        if shape is None:
            continue
        big = np.kron(shape, np.ones((scale, scale), dtype=bool))
        left, top = x + i * ADVANCE * scale, y
        right, bottom = min(width, left + big.shape[1]), min(height, top + big.shape[0])
        if left >= width or top >= height or right <= max(left, 0) or bottom <= max(top, 0):
            continue
        part = big[max(0, -top):bottom - top, max(0, -left):right - left]
        canvas[max(top, 0):bottom, max(left, 0):right][part] = value


@given(st.text(alphabet=[*GLYPHS, "a", "?", " ", "é"], max_size=12),
       st.integers(-80, 100), st.integers(-30, 40), st.integers(1, 3),
       st.integers(1, 40), st.integers(1, 90))
def test_a_text_is_drawn_at_once_as_glyph_by_glyph(text: str, x: int, y: int, scale: int,
                                                   height: int, width: int) -> None:
    """The labels are drawn a whole text at a time (a cached mask: the map of a short drive
    drew its glyphs for a quarter of a second), pixel for pixel as each glyph scaled alone,
    cut at every edge of the canvas."""
    canvas = np.zeros((height, width), dtype=np.uint8)
    expected = canvas.copy()
    draw_text(canvas, x, y, text, 7, scale=scale)
    _glyph_by_glyph(expected, x, y, text, 7, scale)
    assert np.array_equal(canvas, expected)


def test_with_many_ids_the_map_stays_small_and_says_how_many_it_shows() -> None:
    rows = [MapRow("can0", key, None if key % 3 else "M", 8, np.ones(64, dtype=np.bool_),
                   np.full(64, 0.5)) for key in range(400)]
    image, labels = bit_map(rows, 5 * NS)
    pixels, _ = read_png(image.data)
    assert pixels.shape[0] <= 2500 and pixels.shape[1] <= 1200
    assert f"({MAX_ROWS} shown, unknown first)" in labels.texts[0].text
    shown = [t.text for t in labels.texts if t.text.startswith("can0 ")]
    assert len(shown) == MAX_ROWS and all(t.endswith("unknown") for t in shown)


@pytest.mark.slow
def test_frame_by_frame_in_reads_and_in_blocks_a_viewer_gets_the_same_messages() -> None:
    frames = highway(4.0)
    # a clock that steps back 3 s, and forward a minute
    frames = [f._replace(timestamp_ns=f.timestamp_ns - (3 * NS if i > len(frames) // 3 else 0)
                         + (60 * NS if i > 2 * len(frames) // 3 else 0))
              for i, f in enumerate(frames)]
    one_by_one = viewed(frames)
    assert one_by_one[unknown_topic("can0")] and one_by_one[BITS_TOPIC]
    for feed, size in (("reads", 83), ("packs", 1), ("packs", 97), ("packs", 4096)):
        assert viewed(frames, feed, size) == one_by_one, (feed, size)


def test_without_bring_up_there_is_no_bring_up_topic(tmp_path: Path) -> None:
    log = tmp_path / "highway.blf"
    write_log(iter(highway(3.0)), log, ".blf")
    topics = {}
    for name, options in (("with", []), ("without", ["--no-bring-up"])):
        out = tmp_path / f"{name}.mcap"
        assert main(["convert", str(log), "-o", str(out), "--profile", "highway", "-q",
                     *options]) == 0
        with out.open("rb") as f:
            topics[name] = {c.topic for c in make_reader(f).get_summary().channels.values()}
    added = {ids_topic("can0"), ids_topic("can1"), unknown_topic("can0"),
             unknown_topic("can1"), BITS_TOPIC, BITS_LABELS_TOPIC}
    assert topics["with"] - topics["without"] == added
    assert not topics["without"] & added


def test_the_first_unknown_id_of_each_bus_is_told_once() -> None:
    frames = highway(2.0)
    told: list[tuple[str, int]] = []
    drive = Drive(load_stages([], "highway"))
    assert drive.bringup is not None
    drive.bringup.on_unknown = lambda bus, key: told.append((bus, key))
    drive.run(frames)
    drive.finish()
    first = {}
    for f in frames:
        if f.arbitration_id in UNKNOWN[f.bus]:
            first.setdefault(f.bus, f.arbitration_id)
    assert told == list(first.items()) and drive.bringup.first_unknown == first


@given(st.binary(max_size=64), st.sampled_from([0x2C4, 0x7FF, 0x18FF0012 | 1 << 31, 0]))
def test_a_payload_is_written_as_protobuf_writes_it(data: bytes, key: int) -> None:
    expected = CanPayload(id=id_text(key), bytes=list(data),
                          be16=[data[i] << 8 | data[i + 1] for i in range(len(data) - 1)],
                          le16=[data[i] | data[i + 1] << 8 for i in range(len(data) - 1)])
    assert encode(id_field(key), data) == expected.SerializeToString()
