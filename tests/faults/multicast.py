"""A car on python-can's udp_multicast interface, in a process of its own (as a car on the network
would be), for the fault tests: groups of their own per test, frames and foreign datagrams sent
to them, and a check that multicast works on this machine at all (else the test is skipped,
saying why)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading

import can
import pytest

_COUNTER = iter(range(1, 1 << 30))
_LOCK = threading.Lock()

#: The car's script: ``GROUP FRAMES BAD_EVERY [FOREVER]``; prints ``sent N frames, M bad``.
CAR = textwrap.dedent("""
    import sys, time
    import can
    from can.interfaces.udp_multicast.utils import pack_message
    group, frames, bad_every = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    forever = len(sys.argv) > 4
    bus = can.Bus(interface="udp_multicast", channel=group)
    sock = bus._multicast._socket
    # An error frame with an id python-can refuses to unpack (>= 2**29), and a datagram that is
    # no msgpack at all: what another program on the group may send.
    foreign = [pack_message(can.Message(arbitration_id=0x20000080, is_extended_id=True,
                                        is_error_frame=True, data=bytes(8), check=False)),
               b"not msgpack at all"]
    sent = bad = i = 0
    while forever or sent < frames:
        i += 1
        if bad_every and i % bad_every == 0:
            sock.sendto(foreign[bad % 2], (group, bus._multicast.port))
            bad += 1
            continue
        bus.send(can.Message(arbitration_id=0x100 + sent % 0x100, data=sent.to_bytes(8, "big")))
        sent += 1
        if forever:
            time.sleep(0.001)
        elif sent % 50 == 0:
            time.sleep(0.0005)  # a car's pace, not a flood the receive buffer cannot hold
    bus.shutdown()
    print(f"sent {sent} frames, {bad} bad", flush=True)
""")


def unique_group(index: int = 0, *, ipv6: bool = False) -> str:
    """A multicast group no other test (nor process) uses at the same time (IPv4, or IPv6 of
    site-local scope)."""
    with _LOCK:
        n = next(_COUNTER)
    pid = os.getpid()
    if ipv6:
        return f"ff15::7a:{78 + index:x}:{pid % 0xFFFF:x}:{n:x}"
    return f"239.{78 + index}.{pid % 250}.{(pid // 250 * 7 + n) % 250 + 1}"


def send(group: str, frames: int, *, bad_every: int = 0) -> tuple[int, int]:
    """Sends ``frames`` frames to ``group`` from another process, a foreign datagram after each
    ``bad_every - 1`` frames (0: none); returns (frames sent, foreign datagrams sent)."""
    done = subprocess.run([sys.executable, "-c", CAR, group, str(frames), str(bad_every)],
                          capture_output=True, text=True, timeout=120, check=True)
    words = done.stdout.split()
    return int(words[1]), int(words[3])


class Sender:
    """A car sending a frame every millisecond to ``group`` until :meth:`stop`."""

    def __init__(self, group: str) -> None:
        self.process = subprocess.Popen([sys.executable, "-c", CAR, group, "0", "0", "forever"],
                                        stdout=subprocess.DEVNULL)

    def stop(self) -> None:
        self.process.kill()
        self.process.wait()


_checked: dict[bool, str] = {}


def multicast_or_skip(*, ipv6: bool = False) -> None:
    """Skips the test, saying why, where a frame sent to a multicast group on this host does not
    come back to a socket of that group (no multicast route, a kernel without multicast)."""
    if ipv6 in _checked:
        if _checked[ipv6]:
            pytest.skip(_checked[ipv6])
        return
    group, why = unique_group(9, ipv6=ipv6), ""
    try:
        with can.Bus(interface="udp_multicast", channel=group) as rx, \
                can.Bus(interface="udp_multicast", channel=group) as tx:
            tx.send(can.Message(arbitration_id=1, data=b"x"))
            if rx.recv(5.0) is None:
                why = f"a frame sent to multicast group {group} did not come back on this host"
    except Exception as exc:
        why = f"no udp_multicast bus on this host: {type(exc).__name__}: {exc}"
    _checked[ipv6] = why
    if why:
        pytest.skip(why)
