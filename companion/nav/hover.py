"""Low-dynamics (hover) detection for the navigator's zero-velocity pseudo-measurement.

A hovering multicopter's IMU vibrates (per-sample std ~1 m/s^2 on the shared logs) but its *low-passed* specific
force and rate barely change, and GNSS says it is not going anywhere. The detector keeps, per IMU sample, a
low-passed specific force and rate (time constant ``lp_tau_s``) and their exponentially forgotten variance
(``var_tau_s``; a steady yaw rotation or a gyro bias is still a hover); hover = the last GNSS horizontal speed below
``max_speed_mps`` and both IMU statistics below their thresholds. During a blockage the GNSS speed is the last one
seen, and a multicopter leaving a hover barely shows in those statistics (it tilts gently and its accelerometers
keep reading the thrust along the body's down axis). So the horizontal specific force resolved with the autopilot's
attitude (``add_horizontal_dv``) is integrated from the last GNSS speed: once it adds up to ``max_dv_mps`` the
vehicle has moved, and there is no hover until a new speed says slow (else a vehicle cruising away from a stop is a
hover, and the zero-velocity aid pins its velocity to zero). Pure: O(1) per sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class HoverConfig:
    lp_tau_s: float = 0.5
    var_tau_s: float = 3.0
    max_accel_std_mps2: float = 0.35  # of the low-passed specific force, summed over the axes
    max_rate_std_radps: float = 0.08  # of the low-passed body rate, summed over the axes (docs/decisions/0006)
    max_speed_mps: float = 0.7  # last GNSS horizontal speed
    max_speed_age_s: float = 30.0  # an older GNSS speed says nothing
    max_dv_mps: float = 1.0  # horizontal velocity change since the last GNSS speed (autopilot-resolved specific force)


class HoverDetector:
    def __init__(self, config: HoverConfig | None = None) -> None:
        self.config = config or HoverConfig()
        self._t: float | None = None
        self._a = [0.0, 0.0, 0.0]
        self._g = [0.0, 0.0, 0.0]
        self._m = [0.0, 0.0, 0.0]
        self._v = [0.0, 0.0, 0.0]
        self._mg = [0.0, 0.0, 0.0]
        self._vg = [0.0, 0.0, 0.0]
        self._warm_s = 0.0
        self._speed_mps = math.inf
        self._speed_t = -math.inf
        self._dv = [0.0, 0.0]  # horizontal NED velocity change since the last GNSS speed

    def add_imu(self, t: float, accel, gyro) -> None:
        c = self.config
        if self._t is None or not 0 < t - self._t <= 0.5:
            self._t = t
            self._a, self._g, self._m, self._mg = list(accel), list(gyro), list(accel), list(gyro)
            self._v, self._vg, self._warm_s = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.0
            return
        dt = t - self._t
        self._t = t
        k1, k2 = min(1.0, dt / c.lp_tau_s), min(1.0, dt / c.var_tau_s)
        a, g, m, v, mg, vg = self._a, self._g, self._m, self._v, self._mg, self._vg
        for i in range(3):
            a[i] += k1 * (accel[i] - a[i])
            g[i] += k1 * (gyro[i] - g[i])
            d = a[i] - m[i]
            m[i] += k2 * d
            v[i] += k2 * (d * d - v[i])
            d = g[i] - mg[i]
            mg[i] += k2 * d
            vg[i] += k2 * (d * d - vg[i])
        self._warm_s += dt

    def add_speed(self, t: float, speed_h_mps: float) -> None:
        if math.isfinite(speed_h_mps):
            self._speed_mps, self._speed_t = speed_h_mps, t
            self._dv = [0.0, 0.0]

    def add_horizontal_dv(self, dv_n_mps: float, dv_e_mps: float) -> None:
        """One IMU step's horizontal specific force x dt, resolved in NED with the autopilot's attitude."""
        self._dv[0] += dv_n_mps
        self._dv[1] += dv_e_mps

    @property
    def accel_std_mps2(self) -> float:
        return math.sqrt(sum(self._v))

    @property
    def rate_std_radps(self) -> float:
        return math.sqrt(sum(self._vg))

    def hover(self, t: float) -> bool:
        c = self.config
        return (self._warm_s >= c.var_tau_s and t - self._speed_t <= c.max_speed_age_s
                and self._speed_mps < c.max_speed_mps and math.hypot(*self._dv) < c.max_dv_mps
                and self.accel_std_mps2 < c.max_accel_std_mps2
                and self.rate_std_radps < c.max_rate_std_radps)
