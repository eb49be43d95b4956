"""A simulated gravimeter: the map value at the vehicle's true position plus noise (Gaussian, or real
ship-minus-satellite residuals), through a `Placement` of the flight on the map; and `SimulatedGravitySource`, an
async Source of its readings along a list of truth samples (replay and the vehicle simulator)."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from companion.events import GravityReading
from companion.gravity.maps import LocalGravityMap
from companion.gravity.placement import Placement
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
