"""A simulated gravimeter: the map value at the vehicle's true position plus noise (Gaussian, or real
ship-minus-satellite residuals), through a `Placement` of the flight on the map; `SimulatedGravitySource`, an
async Source of its readings along a list of truth samples (replay and the vehicle simulator); and
`GravitySimStage`, the same gravimeter as a pipeline stage reading at the truth a GNSS denial withheld."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from typing import Any

from companion.events import Event, GravityReading
from companion.gravity.maps import LocalGravityMap
from companion.gravity.placement import Placement
from companion.nav.frame import LocalFrame
from companion.nav.outputs import FrameInfo
from companion.pipeline.denial import WithheldFix, frame_of
from companion.pipeline.stage import Stage
from companion.sources.base import Source, SourceInfo


class SimulatedGravimeter:
    """Map value at the true position (placed on the map) plus noise (companion.sim.gravity_scenario.GravimeterModel; no Eotvos
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


class GravitySimStage(Stage):
    """Simulated gravimeter along the GNSS fixes a denial withheld (the truth, companion.pipeline.denial), one
    reading per `period_s`."""

    def __init__(self, gravimeter: SimulatedGravimeter, period_s: float = 1.0) -> None:
        self.g, self.period_s = gravimeter, float(period_s)
        self._frame: LocalFrame | None = None
        self._next_t = -math.inf
        self.readings = 0

    def process(self, item: Any) -> list[Event]:
        if isinstance(item, FrameInfo):
            self._frame = frame_of(item)
        elif isinstance(item, WithheldFix) and self._frame is not None:
            fix = item.fix
            if fix.has_position and fix.instance == 0 and fix.t_s + 1e-9 >= self._next_t:
                ne = self._frame.to_ned_m(fix.lat_deg, fix.lon_deg, fix.alt_msl_m or 0.0)[:2]
                r = self.g.read(fix.t_s, ne)
                if r is not None:
                    self._next_t = fix.t_s + self.period_s
                    self.readings += 1
                    return [r]
        return []

    def metadata(self) -> dict[str, str]:
        return {"readings": str(self.readings), "period_s": f"{self.period_s:g}", "sigma_mgal": f"{self.g.sigma_mgal:g}"}
