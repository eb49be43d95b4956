"""Link addressing: the connection strings of pymavlink's ``mavutil.mavlink_connection`` that fit a companion link.

``parse_url`` checks a connection string before anything opens it and gives a `LinkSpec`; the transports
(companion.mavlink.transport) open it and the link manager (companion.mavlink.link) runs it. Accepted, with
mavutil's meaning (pymavlink 2.4, ``mavutil.mavlink_connection``):

=========================  ==================================================================================
``udpin:HOST:PORT``        listen on HOST:PORT; answer whoever sent last (``udp:`` and a bare ``HOST:PORT`` are
                           the same: mavutil opens both as ``mavudp(..., input=True)``)
``udpout:HOST:PORT``       send to HOST:PORT
``udpbcast:HOST:PORT``     send to the broadcast address HOST:PORT (SO_BROADCAST) until a datagram arrives,
                           then only to its sender (mavutil's ``mavudp(..., broadcast=True)``)
``tcp:HOST:PORT``          connect to a TCP server (ArduPilot SITL: 5760)
``tcpin:HOST:PORT``        accept one TCP client
a device path              a serial port (``/dev/ttyAMA0``, ``/dev/ttyTHS1``, ``COM3``); ``DEV,BAUD`` or ``--baud``
=========================  ==================================================================================

Not supported, refused with a one-line reason: ``mcast:`` (UDP multicast), ``uds:``/``unix:`` (Unix domain
sockets), ``ws:``/``wss:``/``wsserver:`` (WebSocket), ``csv:`` and log files (read logs with ``companion replay``).
A serial device that does not exist yet is a link that is not up yet (a USB adapter plugged in late): the link
manager retries it with back-off; only a malformed setting (an unsupported baud rate, a path that is not a
character device) is refused here.
"""

from __future__ import annotations

import os
import re
import stat
import termios
from dataclasses import dataclass

from companion.sources.base import SourceError

_SCHEMES = ("udpin", "udpout", "udpbcast", "udp", "tcp", "tcpin")
_NET = re.compile(r"^(udpin|udpout|udpbcast|udp|tcp|tcpin):([^:]+):(\d{1,5})$")
_BARE = re.compile(r"^([A-Za-z0-9][A-Za-z0-9.-]*):(\d{1,5})$")  # HOST:PORT, mavutil's default: udpin
#: mavutil prefixes a companion link does not take, and why
_UNSUPPORTED = {
    "mcast:": "UDP multicast is not supported; use udpin:0.0.0.0:PORT or udpbcast:BROADCAST:PORT",
    "uds:": "Unix domain sockets are not supported; use tcp:, udpin: or udpout:",
    "unix:": "Unix domain sockets are not supported; use tcp:, udpin: or udpout:",
    "ws:": "WebSocket links are not supported; use tcp:, udpin: or udpout:",
    "wss:": "WebSocket links are not supported; use tcp:, udpin: or udpout:",
    "wsserver:": "WebSocket links are not supported; use tcpin: or udpin:",
    "csv:": "a CSV log is not a link (replay logs with `companion replay`)",
}
_LOG_SUFFIXES = (".tlog", ".bin", ".log", ".mavlink", ".raw", ".px4log")
#: baud rate -> termios speed constant, the rates this system's serial driver takes
SERIAL_BAUDS = {int(n[1:]): getattr(termios, n) for n in dir(termios) if n.startswith("B") and n[1:].isdigit()}


@dataclass(frozen=True)
class LinkSpec:
    url: str  # what pymavlink gets
    kind: str  # "udpin", "udpout", "udpbcast", "tcp", "tcpin", "serial"
    baud: int | None = None


def parse_url(url: str, baud: int | None = None) -> LinkSpec:
    """Check a connection string before anything opens it; SourceError says what is wrong."""
    for prefix, why in _UNSUPPORTED.items():
        if url.startswith(prefix):
            raise SourceError(f"{url}: {why}")
    if url.lower().endswith(_LOG_SUFFIXES) and not url.startswith(_SCHEMES):
        raise SourceError(f"{url}: a log file is not a link (replay it with `companion replay {url}`)")
    bare = _BARE.match(url)
    if bare and not url.upper().startswith("COM"):
        url = f"udpin:{url}"  # as mavutil: a bare HOST:PORT listens there
    m = _NET.match(url)
    if m:
        scheme, host, port = m.group(1), m.group(2), int(m.group(3))
        if not 0 < port < 65536:
            raise SourceError(f"{url}: port {port} is out of range 1..65535")
        scheme = "udpin" if scheme == "udp" else scheme
        return LinkSpec(url=f"{scheme}:{host}:{port}", kind=scheme)
    if url.startswith(tuple(f"{x}:" for x in _SCHEMES)):
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
        f"{url}: not a connection string; use udpin:HOST:PORT (or HOST:PORT), udpout:HOST:PORT, udpbcast:HOST:PORT, "
        f"tcp:HOST:PORT, tcpin:HOST:PORT or a serial device such as /dev/ttyAMA0 (with --baud, or /dev/ttyAMA0,921600)"
    )
