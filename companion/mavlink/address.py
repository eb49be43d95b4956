"""Link addressing: ``udpin:``, ``udpout:``, ``tcp:``, ``tcpin:`` or a serial device with a baud rate.

``parse_url`` checks a connection string before anything opens it and gives a `LinkSpec`; the transports
(companion.mavlink.transport) open it and the link manager (companion.mavlink.link) runs it. A serial device
that does not exist yet is a link that is not up yet (a USB adapter plugged in late): the link manager retries
it with back-off; only a malformed setting (an unsupported baud rate, a path that is not a character device)
is refused here.
"""

from __future__ import annotations

import os
import re
import stat
import termios
from dataclasses import dataclass

from companion.sources.base import SourceError

_NET = re.compile(r"^(udpin|udpout|udp|tcp|tcpin):([^:]+):(\d{1,5})$")
#: baud rate -> termios speed constant, the rates this system's serial driver takes
SERIAL_BAUDS = {int(n[1:]): getattr(termios, n) for n in dir(termios) if n.startswith("B") and n[1:].isdigit()}


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
        baud = baud or 115200
        if baud not in SERIAL_BAUDS:
            raise SourceError(f"{dev}: baud rate {baud} is not supported (use one of {sorted(SERIAL_BAUDS)[-8:]})")
        try:
            mode = os.stat(dev).st_mode
        except FileNotFoundError:
            mode = None  # not there yet: opened once it appears
        except OSError as err:
            raise SourceError(f"{dev}: {err.strerror}") from None
        if mode is not None and not stat.S_ISCHR(mode):
            raise SourceError(f"{dev}: not a serial device (not a character device)")
        return LinkSpec(url=dev, kind="serial", baud=baud)
    raise SourceError(
        f"{url}: not a connection string; use udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or a serial "
        f"device such as /dev/ttyAMA0 (with --baud, or /dev/ttyAMA0,921600)"
    )
