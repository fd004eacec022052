"""python-can's udp_multicast buses, with the car in another process (as on a network):

- a datagram python-can cannot unpack (an error frame with an id >= 2**29, anything that is no
  msgpack frame) is one datagram skipped and counted; the bus is not taken for lost (a reopen
  lost the frames queued behind it), reading goes on, and not one good frame is lost;
- each bus gets only its own group's frames, with two and three groups on one host (Linux
  delivers every group the host joined to every socket bound to the port, and python-can binds
  them all to one: ``IP_MULTICAST_ALL``), IPv6 groups too;
- a bus read from its socket (:mod:`bridge.io.udp_frames`) gets of every datagram, usual or
  odd, what the same bus read through python-can gets: the same frames, stamps, skips and
  counts.
"""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
from pathlib import Path

import can
import pytest
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast.utils import msgpack
from conftest import summary_counts, timeout_scale
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from multicast import multicast_or_skip, send, unique_group
from test_live_losses import metadata
from waiting import wait_for

from bridge.frame import Frame
from bridge.io.buses import BusEvent, BusLink, BusSpec
from bridge.io.udp_frames import udp_reader

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


class ThroughPythonCan(UdpMulticastBus):  # type: ignore[misc]
    """python-can's udp_multicast bus, read as any other bus: through its ``_recv_internal``."""


#: pack_message's fields of a frame (timestamp and channel as python-can's sender writes them)
USUAL: dict[str, object] = {
    "timestamp": 1.5, "arbitration_id": 0x123, "is_extended_id": False,
    "is_remote_frame": False, "is_error_frame": False, "channel": None, "dlc": 3,
    "data": b"abc", "is_fd": False, "bitrate_switch": False, "error_state_indicator": False}
ODD: list[dict[str, object] | bytes] = [
    USUAL, {**USUAL, "arbitration_id": 0x1ABCDEF0, "is_extended_id": True, "channel": "can0"},
    {**USUAL, "is_error_frame": True, "dlc": 0, "data": b""},
    {**USUAL, "is_remote_frame": True, "data": b"xy"},  # (python-can drops a remote's data)
    {**USUAL, "dlc": None}, {**USUAL, "data": [1, 2, 3]}, {**USUAL, "arbitration_id": 7.0},
    {**USUAL, "is_extended_id": 1}, {**USUAL, "dlc": 4}, {**USUAL, "arbitration_id": 0x800},
    {**USUAL, "arbitration_id": 1 << 29, "is_extended_id": True},
    {**USUAL, "is_fd": True, "bitrate_switch": True, "error_state_indicator": True, "dlc": 12,
     "data": bytes(12)},
    {**USUAL, "bitrate_switch": True}, {**USUAL, "foo": 1}, {**USUAL, "check": False},
    {k: v for k, v in USUAL.items() if k != "channel"},
    {k: v for k, v in USUAL.items() if k != "timestamp"},
    {**{k: v for k, v in USUAL.items() if k != "channel"}, "is_rx": False},
    {**USUAL, "data": "abc"}, {**USUAL, "arbitration_id": [1]}, b"not msgpack at all",
    msgpack.packb([1, 2, 3]), USUAL]


@pytest.mark.parametrize("fd", [False, True])
def test_a_bus_read_from_its_socket_gets_what_python_can_gives(fd: bool) -> None:
    """Two buses on one group, one read by :mod:`bridge.io.udp_frames`, the other (a subclass:
    not python-can's own bus) through python-can's ``_recv_internal``: every datagram, usual
    or odd, makes the same frames (stamps within a millisecond: each socket has its own), the
    same skips and counts; an FD frame on a bus without FD ends a read on both."""
    group = unique_group()
    events: queue.SimpleQueue[BusEvent] = queue.SimpleQueue()
    spec = BusSpec("bus", "udp_multicast", group)
    fast = BusLink(spec, events, open_bus=lambda s: can.Bus(interface="udp_multicast",
                                                                channel=s.channel, fd=fd))
    slow = BusLink(spec, events, open_bus=lambda s: ThroughPythonCan(channel=s.channel, fd=fd))
    opened = [fast, slow]
    for link in opened:
        link.start()
    try:
        for link in opened:
            assert link.opened.wait(10 * timeout_scale())
        assert udp_reader(fast._bus) is not None and udp_reader(slow._bus) is None
        with can.Bus(interface="udp_multicast", channel=group) as tx:
            for odd in ODD:
                tx._multicast._socket.sendto(
                    odd if isinstance(odd, bytes) else msgpack.packb(odd, use_bin_type=True),
                    (group, tx._multicast.port))
        got: list[list[Frame]] = [[], []]
        expected = len(ODD) - (0 if fd else 1)  # (an FD frame on a bus without FD is none)
        for link, frames in zip(opened, got, strict=True):
            assert wait_for(lambda link=link, frames=frames: bool(frames.extend(link.poll()))
                            or len(frames) + link.receive.unreadable >= expected,
                            10 * timeout_scale())
    finally:
        close(opened)
    assert [f[1:] for f in got[0]] == [f[1:] for f in got[1]]
    assert [[type(v) for v in f] for f in got[0]] == [[type(v) for v in f] for f in got[1]]
    assert all(abs(a[0] - b[0]) < 1_000_000 for a, b in zip(*got, strict=True))
    assert fast.receive == slow.receive
    assert fast.receive.unreadable == 10 and len(got[0]) == expected - 10
    assert events.empty()
