"""Gravity measurement sources behind one interface (issue 6 item 4).

Every source yields `GravityReading` events (anomaly in mGal, Eotvos-corrected or raw as the sender states):

* live MAVLink: a gravimeter reading arriving as NAMED_VALUE_FLOAT with a configurable name
  (`NamedValueGravityDecoder`, to be plugged into a live link's message loop);
* live line protocol over UDP or serial (`UdpGravitySource`, `SerialGravitySource`), one reading per line:
      GRAV,<t_s>,<gravity_mgal>[,<sigma_mgal>]      (fields comma- or space-separated, '#' starts a comment)
* simulated (`SimulatedGravimeter`): the map value at the vehicle's true position plus part I's noise models
  (Gaussian, or real ship-minus-satellite residuals), with a configurable `Placement` that lays the flight's
  local track onto a chosen area of the map (a replayed drone log flies near (0, 0) of its own frame; the map
  area it is pretended to fly over is elsewhere). `SimulatedGravitySource` wraps it as an async Source over a
  list of truth samples, for replay and for the vehicle simulator.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator, Iterable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from companion.events import Event
from companion.gravity.maps import LocalGravityMap
from companion.sources.base import Source, SourceError, SourceInfo

DEFAULT_NAMED_VALUE = "GRAV"  # NAMED_VALUE_FLOAT.name is at most 10 characters


@dataclass(frozen=True, slots=True)
class GravityReading(Event):
    """One gravimeter reading. ``sigma_mgal`` is None when the sender gives none."""

    gravity_mgal: float
    sigma_mgal: float | None = None
    eotvos_corrected: bool = True
    sensor: str = ""
    topic: ClassVar[str] = "/input/gravity"


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


# ---- MAVLink NAMED_VALUE_FLOAT ------------------------------------------------------------------------
class NamedValueGravityDecoder:
    """NAMED_VALUE_FLOAT(name == `name`) -> GravityReading; time from time_boot_ms (s), else the receive time."""

    def __init__(self, name: str = DEFAULT_NAMED_VALUE, sigma_mgal: float | None = None):
        if not name or len(name) > 10:
            raise ValueError("NAMED_VALUE_FLOAT names are 1-10 characters")
        self.name = name
        self.sigma_mgal = sigma_mgal

    def value(self, msg) -> float | None:
        """The reading (mGal) if ``msg`` is a NAMED_VALUE_FLOAT of this name with a finite value, else None."""
        if msg is None or msg.get_type() != "NAMED_VALUE_FLOAT":
            return None
        name = msg.name.decode("ascii", "ignore") if isinstance(msg.name, bytes) else str(msg.name)
        if name.rstrip("\x00").strip() != self.name:
            return None
        v = float(msg.value)
        return v if math.isfinite(v) else None

    def reading(self, t_s: float, value_mgal: float) -> GravityReading:
        return GravityReading(t_s=float(t_s), gravity_mgal=value_mgal, sigma_mgal=self.sigma_mgal, sensor=f"mavlink:{self.name}")

    def decode(self, msg, recv_s: float | None = None) -> GravityReading | None:
        """Standalone use: time = time_boot_ms (s), else the receive time. (On a live link the MavlinkDecoder puts
        the reading on its vehicle clock instead.)"""
        v = self.value(msg)
        if v is None:
            return None
        t = msg.time_boot_ms / 1000.0 if getattr(msg, "time_boot_ms", 0) else recv_s
        return None if t is None else self.reading(t, v)


# ---- live line sources --------------------------------------------------------------------------------
class UdpGravitySource(Source):
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
                try:
                    r = parse_gravity_line(line, self.sensor)
                except ValueError as exc:
                    self.bad_lines += 1
                    if len(self.info.warnings) < 20:
                        self.info.warnings.append(str(exc))
                    continue
                if r is not None:
                    yield r

    def __aiter__(self):
        return self._iter()

    async def aclose(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        self._queue.put_nowait(None)


class SerialGravitySource(Source):
    """Line protocol from a serial port (pyserial, read in a worker thread)."""

    def __init__(self, device: str, baud: int = 115200, sensor: str = "serial"):
        self.device, self.baud, self.sensor = device, int(baud), sensor
        self.info = SourceInfo("gravity-serial", f"{device}@{baud}")
        self.bad_lines = 0
        self._port = None

    async def _iter(self):
        try:
            import serial  # pyserial (already used by the live MAVLink link)
        except ImportError as exc:
            raise SourceError("serial gravity input needs pyserial") from exc
        try:
            self._port = await asyncio.to_thread(serial.Serial, self.device, self.baud, timeout=1.0)
        except Exception as exc:  # serial.SerialException and OSError
            raise SourceError(f"cannot open {self.device}: {exc}") from exc
        while self._port is not None:
            line = await asyncio.to_thread(self._port.readline)
            if not line:
                continue
            try:
                r = parse_gravity_line(line, self.sensor)
            except ValueError:
                self.bad_lines += 1
                continue
            if r is not None:
                yield r

    def __aiter__(self):
        return self._iter()

    async def aclose(self) -> None:
        if self._port is not None:
            port, self._port = self._port, None
            await asyncio.to_thread(port.close)


# ---- simulated --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Placement:
    """Lays a flight's local NE track (metres from its own origin) onto map NE metres:
    map_ne = origin_ne_m + R(rotation_deg) @ flight_ne (rotation clockwise, as a heading change)."""

    origin_ne_m: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0

    def _r(self) -> np.ndarray:
        c, s = math.cos(math.radians(self.rotation_deg)), math.sin(math.radians(self.rotation_deg))
        return np.array([[c, -s], [s, c]])

    def to_map(self, flight_ne_m) -> np.ndarray:
        return np.asarray(self.origin_ne_m, float) + np.asarray(flight_ne_m, float) @ self._r().T

    def to_flight(self, map_ne_m) -> np.ndarray:
        return (np.asarray(map_ne_m, float) - np.asarray(self.origin_ne_m, float)) @ self._r()

    @classmethod
    def at_lat_lon(cls, lmap: LocalGravityMap, lat_deg: float, lon_deg: float, rotation_deg: float = 0.0) -> "Placement":
        """Start the flight at a chosen point of a geographic map."""
        n, e = lmap.xy_to_ne(np.array(lon_deg), np.array(lat_deg))
        return cls((float(n), float(e)), rotation_deg)


class SimulatedGravimeter:
    """Map value at the true position (placed on the map) plus noise (part I's GravimeterModel; no Eotvos
    term is added: readings are Eotvos-corrected). Seeded: the same rng gives the same readings."""

    def __init__(self, lmap: LocalGravityMap, placement: Placement, rng: np.random.Generator, sigma_mgal: float = 1.0,
                 bias_mgal: float = 0.0, residuals_mgal: np.ndarray | None = None, residual_spacing_m: float = 330.0):
        if sigma_mgal < 0:
            raise ValueError("sigma_mgal must be >= 0")
        self.lmap, self.placement, self.rng = lmap, placement, rng
        self.sigma_mgal, self.bias_mgal = float(sigma_mgal), float(bias_mgal)
        self.residuals = None if residuals_mgal is None else np.asarray(residuals_mgal, float)
        self.spacing = float(residual_spacing_m)
        self._dist = 0.0
        self._last = None
        self._res_start = int(rng.integers(0, self.residuals.size)) if self.residuals is not None else 0

    def read(self, t_s: float, true_flight_ne_m) -> GravityReading | None:
        """Reading at the true flight position; None off the map (or on masked cells)."""
        p = self.placement.to_map(true_flight_ne_m)
        if self._last is not None:
            self._dist += float(np.hypot(*(p - self._last)))
        self._last = p
        g = float(self.lmap.interp_ne(p[0], p[1]))
        if not math.isfinite(g):
            return None
        if self.residuals is not None:
            noise = self.residuals[(self._res_start + int(round(self._dist / self.spacing))) % self.residuals.size]
        else:
            noise = self.rng.normal(0.0, self.sigma_mgal) if self.sigma_mgal > 0 else 0.0
        return GravityReading(t_s=float(t_s), gravity_mgal=g + noise + self.bias_mgal,
                              sigma_mgal=self.sigma_mgal if self.residuals is None else None, sensor="simulated")


class SimulatedGravitySource(Source):
    """Async Source of simulated readings along truth samples (t_s, north_m, east_m), every `period_s`."""

    def __init__(self, gravimeter: SimulatedGravimeter, truth: Iterable[tuple[float, float, float]], period_s: float = 1.0):
        self.g = gravimeter
        self.truth = list(truth)
        self.period_s = float(period_s)
        self.info = SourceInfo("gravity-sim", "simulated")

    def readings(self) -> list[GravityReading]:
        out, next_t = [], -math.inf
        for t, n, e in self.truth:
            if t + 1e-9 >= next_t:
                r = self.g.read(t, (n, e))
                if r is not None:
                    out.append(r)
                next_t = t + self.period_s
        return out

    async def _iter(self):
        for r in self.readings():
            yield r

    def __aiter__(self):
        return self._iter()
