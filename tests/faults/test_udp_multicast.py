"""python-can's udp_multicast buses, with the car in another process (as on a network):

- a datagram python-can cannot unpack (an error frame with an id >= 2**29, anything that is no
  msgpack frame) is one datagram skipped and counted; the bus is not taken for lost (a reopen
  lost the frames queued behind it), reading goes on, and not one good frame is lost;
- each bus gets only its own group's frames, with two and three groups on one host (Linux
  delivers every group the host joined to every socket bound to the port, and python-can binds
  them all to one: ``IP_MULTICAST_ALL``), IPv6 groups too.
"""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import summary_counts, timeout_scale
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from multicast import multicast_or_skip, send, unique_group
from test_live_losses import metadata
from waiting import wait_for

from bridge.frame import Frame
from bridge.io.buses import BusEvent, BusLink, BusSpec

LIMIT_S = 60.0


@pytest.fixture(autouse=True)
def _multicast() -> None:
    multicast_or_skip()


def links(*groups: str) -> tuple[list[BusLink], queue.SimpleQueue[BusEvent]]:
    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    opened = [BusLink(BusSpec(f"bus{i}", "udp_multicast", group), events)
              for i, group in enumerate(groups)]
    for link in opened:
        link.start()
    for link in opened:
        assert link.opened.wait(10 * timeout_scale())
    return opened, events


def read_all(link: BusLink, frames: list[Frame], until: int) -> None:
    """Polls ``link`` into ``frames`` until it holds ``until`` (or the time budget ends), and
    once more: what came with them (another group's frames, sent together) is read too."""
    wait_for(lambda: bool(frames.extend(link.poll())) or len(frames) >= until,
             LIMIT_S * timeout_scale())
    frames.extend(link.poll())


def close(opened: list[BusLink]) -> None:
    for link in opened:
        link.stop()
        link.close()


@pytest.mark.slow
def test_a_datagram_python_can_cannot_unpack_is_skipped_and_counted() -> None:
    (link,), events = links(unique_group())
    try:
        sent, bad = send(link.spec.channel or "", 9_900, bad_every=100)
        frames: list[Frame] = []
        read_all(link, frames, sent)
    finally:
        close([link])
    assert bad == 99
    assert len(frames) == sent  # none lost behind a bad one (a reopen lost ~20 each)
    assert [int.from_bytes(f.data, "big") for f in frames] == list(range(sent))
    assert events.empty()  # not a lost bus
    assert link.receive.unreadable == bad
    assert link.receive.last_unreadable.startswith(
        "CanOperationError: could not unpack received message (")
    assert link.receive.kernel_drops == 0


@pytest.mark.slow
@pytest.mark.parametrize(("groups", "ipv6"), [(2, False), (3, False), (2, True)])
def test_each_bus_gets_only_its_own_groups_frames(groups: int, ipv6: bool) -> None:
    multicast_or_skip(ipv6=ipv6)
    opened, events = links(*[unique_group(i, ipv6=ipv6) for i in range(groups)])
    counts = [100, 40, 7][:groups]
    try:
        for link, n in zip(opened, counts, strict=True):
            assert send(link.spec.channel or "", n) == (n, 0)
        got: list[list[Frame]] = [[] for _ in opened]
        for link, frames, n in zip(opened, got, counts, strict=True):
            read_all(link, frames, n)
    finally:
        close(opened)
    assert [len(frames) for frames in got] == counts
    assert events.empty()


@pytest.mark.slow
def test_live_records_each_group_on_its_own_bus_and_skips_what_is_no_frame(
        tmp_path: Path) -> None:
    """``tankviz live`` with two udp_multicast buses: frames sent to the first group only are
    on ``a`` alone; the datagrams among them that are no frame are counted and said."""
    a, b = unique_group(0), unique_group(1)
    process = subprocess.Popen(
        [sys.executable, "-m", "bridge", "live", "--bus", f"a=udp_multicast:{a}",
         "--bus", f"b=udp_multicast:{b}", "--profile", "ecocar", "--no-server",
         "--drives", str(tmp_path / "drives")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    assert process.stdout is not None
    seen = []
    for line in process.stdout:
        seen.append(line)
        if line.startswith("Ctrl+C stops"):
            break
    try:
        sent, bad = send(a, 990, bad_every=100)
        sent_b, _ = send(b, 100)
    finally:
        process.send_signal(signal.SIGTERM)
    out = "".join(seen) + process.communicate(timeout=LIMIT_S * timeout_scale())[0]
    assert process.returncode == 0, out
    assert (sent, bad, sent_b) == (990, 9, 100)
    (drive,) = (tmp_path / "drives").glob("*.mcap")
    frames = {"/can/a/frames": 0, "/can/b/frames": 0}
    with drive.open("rb") as f:
        for _, channel, _, block in make_reader(
                f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=[*frames]):
            frames[channel.topic] += len(block.frames)
    assert summary_counts(drive)["/can/a/frames"] > 0  # (a complete file)
    assert list(frames.values()) == [990, 100], out
    assert "0 bus gaps" in out, out
    assert (f"bus a: {bad} messages that are not CAN frames (skipped; the latest: "
            "CanOperationError: could not unpack received message (") in out, out
    assert metadata(tmp_path / "drives")["bus_receive"]["a"]["unreadable"] == bad
