"""Where viewers connect: the server's URLs, and this machine's own addresses to name in them.

A loopback server is ``ws://localhost:PORT``. Bound to every address (``0.0.0.0``, ``::``), the
server names each of the machine's own addresses (:func:`machine_addresses`), which a laptop on
the car's network can open.
"""

from __future__ import annotations

import contextlib
import ipaddress
import socket
import struct

#: Hosts that mean every address of the machine.
EVERY_ADDRESS = ("0.0.0.0", "::", "")
#: Hosts that mean this machine only.
LOOPBACK = ("127.0.0.1", "::1", "localhost")

_SIOCGIFADDR = 0x8915  # Linux: an interface's address


def viewer_urls(host: str, port: int) -> list[str]:
    """Where viewers connect to a server bound to ``host``: ``localhost`` for a loopback server;
    for one on every address each of the machine's own addresses (:func:`machine_addresses`;
    ``localhost`` when it has none); else the address it was given."""
    if host in EVERY_ADDRESS:
        hosts = [url_host(a) for a in machine_addresses()] or ["localhost"]
    elif host in LOOPBACK:
        hosts = ["localhost"]
    else:
        hosts = [url_host(host)]
    return [f"ws://{name}:{port}" for name in hosts]


def machine_addresses() -> list[str]:
    """This machine's IPv4 addresses but loopback, in interface order: read from the network
    interfaces (Linux's SIOCGIFADDR), then what the host name resolves to. Asks no network and
    no name server beyond the host's own resolver."""
    found: list[str] = []
    try:
        import fcntl

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            for _, name in socket.if_nameindex():
                with contextlib.suppress(OSError):  # (an interface without an IPv4 address)
                    request = struct.pack("256s", name.encode()[:15])
                    found.append(socket.inet_ntoa(
                        fcntl.ioctl(probe.fileno(), _SIOCGIFADDR, request)[20:24]))
    except (ImportError, OSError):  # not Linux, or no interfaces to list
        pass
    with contextlib.suppress(OSError):
        found += [str(info[4][0]) for info in socket.getaddrinfo(
            socket.gethostname(), None, socket.AF_INET, socket.SOCK_STREAM)]
    addresses = [ipaddress.ip_address(a) for a in found]
    return list(dict.fromkeys(str(a) for a in addresses
                              if not (a.is_loopback or a.is_unspecified)))


def url_host(address: str) -> str:
    """An address as the host part of a URL (IPv6 in brackets)."""
    return f"[{address}]" if ":" in address else address
