"""Link addressing: ``udpin:``, ``udpout:``, ``tcp:``, ``tcpin:`` or a serial device with a baud rate.

``parse_url`` checks a connection string before anything opens it and gives a `LinkSpec`; the transports
(companion.mavlink.transport) open it and the link manager (companion.mavlink.link) runs it.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

from companion.sources.base import SourceError

_NET = re.compile(r"^(udpin|udpout|udp|tcp|tcpin):([^:]+):(\d{1,5})$")


@dataclass(frozen=True)
class LinkSpec:
    url: str  # what pymavlink gets
    kind: str  # "udpin", "udpout", "tcp", "tcpin", "serial"
    baud: int | None = None


def parse_url(url: str, baud: int | None = None) -> LinkSpec:
    """Check a connection string before anything opens it; SourceError says what is wrong."""
    m = _NET.match(url)
    if m:
        scheme, host, port = m.group(1), m.group(2), int(m.group(3))
        if not 0 < port < 65536:
            raise SourceError(f"{url}: port {port} is out of range 1..65535")
        scheme = "udpin" if scheme == "udp" else scheme
        return LinkSpec(url=f"{scheme}:{host}:{port}", kind=scheme)
    if url.startswith(("udpin:", "udpout:", "udp:", "tcp:", "tcpin:")):
        raise SourceError(f"{url}: expected SCHEME:HOST:PORT, e.g. udpin:0.0.0.0:14550 or tcp:127.0.0.1:5760")
    dev, _, b = url.partition(",")
    if url.startswith("serial:"):
        parts = url.split(":")
        dev = parts[1]
        b = parts[2] if len(parts) > 2 else ""
    if b:
        if not b.isdigit():
            raise SourceError(f"{url}: baud rate {b!r} is not a number")
        baud = int(b)
    if dev.startswith("/dev/") or dev.upper().startswith("COM"):
        if not os.path.exists(dev) and not dev.upper().startswith("COM"):
            raise SourceError(f"{dev}: no such serial device")
        return LinkSpec(url=dev, kind="serial", baud=baud or 115200)
    raise SourceError(
        f"{url}: not a connection string; use udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or a serial "
        f"device such as /dev/ttyAMA0 (with --baud, or /dev/ttyAMA0,921600)"
    )
