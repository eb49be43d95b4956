"""A live MAVLink link as a source: ``udpin:``, ``udpout:``, ``tcp:``, or a serial device with a baud rate.

pymavlink's blocking I/O runs in one reader thread; decoded events cross into the asyncio loop through
a queue (``call_soon_threadsafe``), so the loop never blocks on the link. The reader also sends a
HEARTBEAT as an onboard controller once a second, which is what makes an autopilot (or a ``udpout:``
peer) start talking to us. Events are stamped by the autopilot's boot time; only messages without one
use the receive time (``time.monotonic``), which is this edge's own clock.
"""

from __future__ import annotations

import asyncio
import os
import re
import threading
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass

from companion.events import Event
from companion.sources.base import Source, SourceError, SourceInfo
from companion.sources.mavlink_decode import MavlinkDecoder

MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_COMP_ID_ONBOARD_COMPUTER = 191

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


class LiveSource(Source):
    def __init__(
        self,
        url: str,
        baud: int | None = None,
        *,
        source_system: int = 1,
        source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
        heartbeat_period_s: float = 1.0,
    ) -> None:
        self.spec = parse_url(url, baud)
        self.info = SourceInfo(kind="live", location=self.spec.url)
        if self.spec.baud:
            self.info.details["baud"] = str(self.spec.baud)
        self.source_system = source_system
        self.source_component = source_component
        self.heartbeat_period_s = heartbeat_period_s
        self.decoder = MavlinkDecoder()
        self.messages_in = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._conn = None

    def _connect(self):
        from pymavlink import mavutil

        kw = dict(source_system=self.source_system, source_component=self.source_component, autoreconnect=True)
        if self.spec.baud:
            kw["baud"] = self.spec.baud
        try:
            return mavutil.mavlink_connection(self.spec.url, **kw)
        except OSError as err:
            raise SourceError(f"{self.spec.url}: cannot open link ({err.strerror or err})") from None
        except Exception as err:  # noqa: BLE001 - pymavlink raises bare Exceptions for bad links
            raise SourceError(f"{self.spec.url}: cannot open link ({err})") from None

    def _reader(self, loop: asyncio.AbstractEventLoop, queue: asyncio.Queue) -> None:
        conn = self._conn
        next_hb = 0.0
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= next_hb:
                    try:
                        conn.mav.heartbeat_send(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, 0)
                    except OSError:
                        pass  # udpin before the peer is known, or link down: try again next period
                    next_hb = now + self.heartbeat_period_s
                msg = conn.recv_match(blocking=True, timeout=0.1)
                if msg is None:
                    continue
                self.messages_in += 1
                evs = self.decoder.decode(msg, time.monotonic())
                if evs:
                    loop.call_soon_threadsafe(queue.put_nowait, evs)
        except Exception as err:  # noqa: BLE001 - report any link failure to the consumer
            loop.call_soon_threadsafe(queue.put_nowait, SourceError(f"{self.spec.url}: link failed ({err})"))
        finally:
            loop.call_soon_threadsafe(queue.put_nowait, None)

    async def _iterate(self) -> AsyncIterator[Event]:
        loop = asyncio.get_running_loop()
        self._conn = await asyncio.to_thread(self._connect)
        queue: asyncio.Queue = asyncio.Queue()
        self._thread = threading.Thread(target=self._reader, args=(loop, queue), name="mavlink-reader", daemon=True)
        self._thread.start()
        try:
            while True:
                item = await queue.get()
                if item is None:
                    return
                if isinstance(item, Exception):
                    raise item
                for ev in item:
                    yield ev
        finally:
            await self.aclose()

    def __aiter__(self) -> AsyncIterator[Event]:
        return self._iterate()

    async def aclose(self) -> None:
        self._stop.set()
        if self._thread is not None:
            await asyncio.to_thread(self._thread.join, 2.0)
            self._thread = None
        if self._conn is not None:
            try:
                self._conn.close()
            except Exception:  # noqa: BLE001
                pass
            self._conn = None
        for why, n in sorted(self.decoder.dropped.items()):
            msg = f"dropped {n} messages: {why}"
            if msg not in self.info.warnings:
                self.info.warnings.append(msg)
