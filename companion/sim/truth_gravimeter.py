"""A gravimeter on a simulated vehicle whose truth comes from outside (ArduPilot SITL's SIMSTATE): what it reads at
the true position and velocity, as a real marine or airborne gravimeter would deliver it.

reading(t) = mean over the output window of [map(true position) + misfit(distance sailed)]
             + Eotvos(true velocity, latitude) + bias + drift_rate * t + white noise

* map: the anomaly grid, bilinear, at the true latitude/longitude (geographic grids) or at the true NE metres from
  a chosen map point (grids in a local metric frame);
* misfit: the real ship-minus-satellite differences of the shared tracks (companion.sim.gravity_residuals), indexed
  by distance travelled (their median spacing), from a seeded start -- the sensor-vs-map disagreement of real data;
* Eotvos at the true velocity (Gao 2022 eq. 5): the reading is *not* Eotvos-corrected, the receiver corrects it
  with its own velocity estimate;
* bias drawn once, a linear drift, white noise per reading; all draws from the caller's seeded Generator;
* the output window (``window_s``): a gravimeter's low-pass output filter, the mean of the samples it took over
  that much time (a moving aircraft's gravimeter is filtered over tens of seconds).

Pure: no MAVLink, no wall clock (companion.sim.sitl_gravimeter_link runs it against an autopilot).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from companion.gravity.eotvos import eotvos_from_ne_mgal
from companion.gravity.maps import LocalGravityMap
from companion.nav.frame import LocalFrame

#: median spacing of the ship track the misfit series comes from (MANIFEST sec. 4: 0.33 km)
MISFIT_SPACING_M = 330.0


@dataclass(frozen=True)
class GravimeterSpec:
    """The sensor's error sources (1 sigma where drawn)."""

    white_sigma_mgal: float = 1.0  # per output reading
    bias_sigma_mgal: float = 2.0  # constant bias, drawn once
    drift_sigma_mgal_per_h: float = 0.5  # drift rate, drawn once
    window_s: float = 30.0  # output filter: the mean of the samples over this long (0: the newest sample)
    eotvos: bool = True  # the reading contains the Eotvos term at the true velocity
    misfit: bool = True  # the real ship-minus-satellite misfit is added

    def __post_init__(self):
        if min(self.white_sigma_mgal, self.bias_sigma_mgal, self.drift_sigma_mgal_per_h, self.window_s) < 0:
            raise ValueError("gravimeter sigmas and window must be >= 0")


class TruthGravimeter:
    """Feed it the truth (``sample``) as it arrives, ask for a reading (``read``) at the output rate.

    ``origin_lat_lon``: for a grid in a local metric frame, the latitude/longitude its (0, 0) stands for (the truth is
    laid on it in metres from there); ignored for geographic grids."""

    def __init__(self, lmap: LocalGravityMap, spec: GravimeterSpec, rng: np.random.Generator,
                 misfit_mgal: np.ndarray | None = None, origin_lat_lon: tuple[float, float] | None = None):
        self.lmap, self.spec, self.rng = lmap, spec, rng
        self.bias_mgal = float(rng.normal(0.0, spec.bias_sigma_mgal)) if spec.bias_sigma_mgal > 0 else 0.0
        self.drift_mgal_per_s = (float(rng.normal(0.0, spec.drift_sigma_mgal_per_h)) / 3600.0
                                 if spec.drift_sigma_mgal_per_h > 0 else 0.0)
        self.misfit = None if (misfit_mgal is None or not spec.misfit) else np.asarray(misfit_mgal, float)
        self._mis_start = int(rng.integers(0, self.misfit.size)) if self.misfit is not None else 0
        self._local0 = None if lmap.frame is not None else LocalFrame(*(origin_lat_lon or (0.0, 0.0)), 0.0)
        self._win: deque[tuple[float, float]] = deque()  # (t, map + misfit + Eotvos) samples in the window
        self._last: tuple[float, float, float] | None = None  # t, lat, lon of the previous truth sample
        self.distance_m = 0.0
        self.t0_s: float | None = None

    def truth_value_mgal(self, lat_deg: float, lon_deg: float) -> float:
        """The map at a true position (NaN off the map)."""
        if self._local0 is None:
            n, e = self.lmap.xy_to_ne(np.array(lon_deg), np.array(lat_deg))
        else:
            n, e, _ = self._local0.to_ned_m(lat_deg, lon_deg, 0.0)
        return float(self.lmap.interp_ne(n, e))

    def misfit_mgal(self) -> float:
        if self.misfit is None:
            return 0.0
        return float(self.misfit[(self._mis_start + int(self.distance_m // MISFIT_SPACING_M)) % self.misfit.size])

    def sample(self, t_s: float, lat_deg: float, lon_deg: float, vel_ne_mps: tuple[float, float] | None = None) -> None:
        """One truth sample. Without ``vel_ne_mps`` the velocity is the difference from the previous sample."""
        if self.t0_s is None:
            self.t0_s = float(t_s)
        if self._last is not None:
            dt = t_s - self._last[0]
            if dt <= 0:
                return
            fr = LocalFrame(self._last[1], self._last[2], 0.0)
            dn, de, _ = fr.to_ned_m(lat_deg, lon_deg, 0.0)
            self.distance_m += math.hypot(dn, de)
            if vel_ne_mps is None:
                vel_ne_mps = (dn / dt, de / dt)
        self._last = (float(t_s), float(lat_deg), float(lon_deg))
        if vel_ne_mps is None:
            return  # the first sample: no velocity yet
        g = self.truth_value_mgal(lat_deg, lon_deg)
        if not math.isfinite(g):
            self._win.clear()
            return
        g += self.misfit_mgal()
        if self.spec.eotvos:
            g += float(eotvos_from_ne_mgal(np.asarray(vel_ne_mps, float), lat_deg))
        self._win.append((float(t_s), g))
        keep = max(self.spec.window_s, 0.0)
        while self._win and self._win[0][0] <= t_s - keep and len(self._win) > 1:
            self._win.popleft()

    def read(self, t_s: float) -> float | None:
        """The output reading at ``t_s`` (mGal), None before any sample or off the map."""
        if not self._win:
            return None
        mean = float(np.mean([g for _t, g in self._win]))
        noise = float(self.rng.normal(0.0, self.spec.white_sigma_mgal)) if self.spec.white_sigma_mgal > 0 else 0.0
        t0 = t_s if self.t0_s is None else self.t0_s
        return mean + self.bias_mgal + self.drift_mgal_per_s * (t_s - t0) + noise
