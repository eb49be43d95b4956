"""A live MAVLink link as a source: ``udpin:``, ``udpout:``, ``tcp:``, or a serial device with a baud rate.

``parse_url`` checks a connection string. The link itself (reader thread, heartbeat, stream requests,
reconnection) is :class:`companion.mavlink.link.MavlinkLink`; :class:`LiveSource` adapts it to the
:class:`~companion.sources.base.Source` interface. Events are stamped by the autopilot's boot time; only
messages without one use the receive time (``time.monotonic``), which is this edge's own clock.
"""

from __future__ import annotations

import asyncio
import os
import re
from collections.abc import AsyncIterator
from dataclasses import dataclass

from companion.events import Event
from companion.sources.base import Source, SourceError, SourceInfo

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
    """A live link as a plain :class:`Source` (events only), on the runtime's link manager.

    ``companion run`` uses :class:`companion.runtime.Runtime`, which also records link events and sends
    GPS_INPUT; this adaptor is for code that wants ``async for ev in source`` over a link.
    """

    def __init__(
        self,
        url: str,
        baud: int | None = None,
        *,
        source_system: int = 1,
        source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
        heartbeat_period_s: float = 1.0,
    ) -> None:
        from companion.config import LinkConfig, StreamConfig
        from companion.mavlink.link import MavlinkLink

        self.spec = parse_url(url, baud)
        self.info = SourceInfo(kind="live", location=self.spec.url)
        if self.spec.baud:
            self.info.details["baud"] = str(self.spec.baud)
        cfg = LinkConfig(
            connect=url, baud=self.spec.baud or 115200, system_id=source_system, component_id=source_component,
            heartbeat_hz=1.0 / heartbeat_period_s,
        )
        self.link = MavlinkLink(cfg, StreamConfig())
        self.decoder = self.link.decoder

    @property
    def messages_in(self) -> int:
        return self.link.messages_in

    async def _iterate(self) -> AsyncIterator[Event]:
        from companion.mavlink.link import Batch

        queue: asyncio.Queue = asyncio.Queue()
        self.link.start(asyncio.get_running_loop(), queue.put_nowait)
        try:
            while True:
                item = await queue.get()
                if isinstance(item, Batch):
                    for ev in item.events:
                        yield ev
        finally:
            await self.aclose()

    def __aiter__(self) -> AsyncIterator[Event]:
        return self._iterate()

    async def aclose(self) -> None:
        await asyncio.to_thread(self.link.stop)
        for why, n in sorted(self.decoder.dropped.items()):
            msg = f"dropped {n} messages: {why}"
            if msg not in self.info.warnings:
                self.info.warnings.append(msg)
