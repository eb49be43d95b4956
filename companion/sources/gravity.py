"""Gravimeter sources of their own (not on the MAVLink link): the line protocol over UDP or serial.

Every gravity source yields companion.events.GravityReading (anomaly in mGal, Eotvos-corrected or raw as the sender
states); one reading per line:
      GRAV,<t_s>,<gravity_mgal>[,<sigma_mgal>]      (fields comma- or space-separated, '#' starts a comment)
The same readings come from the link (companion.mavlink.gravimeter) and from the simulator
(companion.sim.gravimeter).
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator

from companion.events import GravityReading
from companion.sources.base import Source, SourceError, SourceInfo



# ---- line protocol ----------------------------------------------------------------------------------
def parse_gravity_line(line: str | bytes, sensor: str = "line") -> GravityReading | None:
    """Parse 'GRAV,<t_s>,<mgal>[,<sigma>]' ; None for blank/comment lines; ValueError with the reason otherwise."""
    if isinstance(line, bytes):
        try:
            line = line.decode("ascii")
        except UnicodeDecodeError as exc:
            raise ValueError("gravity line is not ASCII") from exc
    s = line.split("#", 1)[0].strip()
    if not s:
        return None
    parts = [p for p in s.replace(",", " ").split() if p]
    if parts[0].upper() != "GRAV":
        raise ValueError(f"gravity line must start with GRAV, got {parts[0]!r}")
    if len(parts) not in (3, 4):
        raise ValueError(f"gravity line needs GRAV,t_s,mgal[,sigma]; got {len(parts) - 1} fields")
    try:
        vals = [float(p) for p in parts[1:]]
    except ValueError as exc:
        raise ValueError(f"gravity line has a non-numeric field: {s!r}") from exc
    if not all(math.isfinite(v) for v in vals):
        raise ValueError("gravity line has a non-finite field")
    sigma = vals[2] if len(vals) == 3 else None
    if sigma is not None and sigma <= 0:
        raise ValueError("gravity sigma must be > 0")
    return GravityReading(t_s=vals[0], gravity_mgal=vals[1], sigma_mgal=sigma, sensor=sensor)


def format_gravity_line(r: GravityReading) -> str:
    base = f"GRAV,{r.t_s:.3f},{r.gravity_mgal:.4f}"
    return base + (f",{r.sigma_mgal:.4f}" if r.sigma_mgal is not None else "") + "\n"


# ---- live line sources --------------------------------------------------------------------------------
class _LineSource(Source):
    """A source of line-protocol readings: bad lines are counted (``bad_lines``), the first 20 listed in the
    warnings, and skipped."""

    sensor = "line"
    bad_lines = 0

    def _parse(self, line: str | bytes) -> GravityReading | None:
        try:
            return parse_gravity_line(line, self.sensor)
        except ValueError as exc:
            self.bad_lines += 1
            if len(self.info.warnings) < 20:
                self.info.warnings.append(str(exc))
            return None


class UdpGravitySource(_LineSource):
    """Listen on host:port for line-protocol datagrams (one or more lines each). Bad lines are counted, skipped."""

    def __init__(self, host: str = "0.0.0.0", port: int = 14660, sensor: str = "udp"):
        self.host, self.port, self.sensor = host, int(port), sensor
        self.info = SourceInfo("gravity-udp", f"udp:{host}:{port}")
        self.bad_lines = 0
        self._queue: asyncio.Queue = asyncio.Queue()
        self._transport = None

    async def _open(self):
        loop = asyncio.get_running_loop()
        q = self._queue

        class _Proto(asyncio.DatagramProtocol):
            def datagram_received(self, data, addr):
                q.put_nowait(data)

        try:
            self._transport, _ = await loop.create_datagram_endpoint(_Proto, local_addr=(self.host, self.port))
        except OSError as exc:
            raise SourceError(f"cannot listen for gravity on udp:{self.host}:{self.port}: {exc}") from exc

    @property
    def bound_port(self) -> int:
        return self._transport.get_extra_info("sockname")[1] if self._transport else self.port

    async def start(self) -> None:
        if self._transport is None:
            await self._open()

    async def _iter(self) -> AsyncIterator[GravityReading]:
        await self.start()
        while True:
            data = await self._queue.get()
            if data is None:
                return
            for line in data.splitlines():
                r = self._parse(line)
                if r is not None:
                    yield r

    def __aiter__(self):
        return self._iter()

    async def aclose(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        self._queue.put_nowait(None)


class SerialGravitySource(_LineSource):
    """Line protocol from a serial port (pyserial, read in a worker thread)."""

    def __init__(self, device: str, baud: int = 115200, sensor: str = "serial"):
        self.device, self.baud, self.sensor = device, int(baud), sensor
        self.info = SourceInfo("gravity-serial", f"{device}@{baud}")
        self.bad_lines = 0
        self._port = None

    async def _iter(self):
        from companion.extras import require

        serial = require("serial", "gravity", "a serial gravimeter")  # pyserial
        try:
            self._port = await asyncio.to_thread(serial.Serial, self.device, self.baud, timeout=1.0)
        except Exception as exc:  # serial.SerialException and OSError
            raise SourceError(f"cannot open {self.device}: {exc}") from exc
        while self._port is not None:
            line = await asyncio.to_thread(self._port.readline)
            r = self._parse(line) if line else None
            if r is not None:
                yield r

    def __aiter__(self):
        return self._iter()

    async def aclose(self) -> None:
        if self._port is not None:
            port, self._port = self._port, None
            await asyncio.to_thread(port.close)
