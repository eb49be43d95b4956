"""A simulated water-speed log on an ArduPilot SITL boat: SITL's truth in, the log's speed through the water out.

The speed is the truth's horizontal velocity over the last ``window_s`` (SIMSTATE positions differenced: SIMSTATE has
no velocity) less the water's current, as a calibrated log gives it: a scale error (a log's calibration leaves a
percent or two), a bias and white noise, drawn once / per value from a seeded generator. SITL's motorboat is a
SIM_Sailboat whose hull the tide (SIM_TIDE_SPEED / SIM_TIDE_DIR) carries over the ground while it steers through the
water, so the speed through the water is the velocity over the ground minus the tide's. Pure: vehicle time only;
memory bounded by the window.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from companion.gravity.air_data import radii_m


@dataclass(frozen=True)
class SpeedLogSpec:
    period_s: float = 0.5  # one value every this long (s of vehicle time)
    window_s: float = 1.0  # the speed over this long of truth
    scale_sigma: float = 0.01  # 1-sigma of the calibration's scale error (fraction)
    bias_sigma_mps: float = 0.02
    white_sigma_mps: float = 0.05

    def __post_init__(self) -> None:
        if not (self.period_s > 0 and self.window_s > 0 and self.scale_sigma >= 0 and self.bias_sigma_mps >= 0
                and self.white_sigma_mps >= 0):
            raise ValueError("speed log: period and window > 0, sigmas >= 0")


class SpeedLog:
    """``truth(t_s, lat_deg, lon_deg, current_ne_mps)`` in time order; each returns the (t_s, speed_mps) values due
    (none or one)."""

    def __init__(self, spec: SpeedLogSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.scale = 1.0 + float(rng.normal(0.0, spec.scale_sigma))
        self.bias_mps = float(rng.normal(0.0, spec.bias_sigma_mps))
        self._pts: deque[tuple[float, float, float]] = deque()  # (t, lat, lon) over the window
        self._next_s: float | None = None

    def truth(self, t_s: float, lat_deg: float, lon_deg: float,
              current_ne_mps: tuple[float, float] = (0.0, 0.0)) -> list[tuple[float, float]]:
        if not (math.isfinite(t_s) and math.isfinite(lat_deg) and math.isfinite(lon_deg)):
            return []
        if self._pts and t_s <= self._pts[-1][0]:
            return []  # not after the previous truth: a repeat or a reboot's restart
        self._pts.append((float(t_s), float(lat_deg), float(lon_deg)))
        while len(self._pts) > 2 and self._pts[1][0] <= t_s - self.spec.window_s:
            self._pts.popleft()
        if self._next_s is None:
            self._next_s = t_s + self.spec.period_s
        if t_s + 1e-9 < self._next_s:
            return []
        self._next_s += self.spec.period_s * max(1, math.floor((t_s - self._next_s) / self.spec.period_s) + 1)
        t0, lat0, lon0 = self._pts[0]
        if t_s - t0 < 0.5 * self.spec.window_s:
            return []
        rm, rn = radii_m(0.5 * (lat0 + lat_deg))
        dn = math.radians(lat_deg - lat0) * rm
        de = math.radians(lon_deg - lon0) * rn * math.cos(math.radians(0.5 * (lat0 + lat_deg)))
        v = math.hypot(dn / (t_s - t0) - current_ne_mps[0], de / (t_s - t0) - current_ne_mps[1])
        s = v * self.scale + self.bias_mps + float(self.rng.normal(0.0, self.spec.white_sigma_mps))
        return [(float(t_s), max(0.0, s))]
