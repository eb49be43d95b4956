"""The navigator's monitor of the autopilot's heading, with the INS yaw alignment (see ``ahrs_check`` in
companion.nav.config.NavigatorConfig). A mixin of companion.nav.navigator.Navigator (its state lives on the navigator);
the motion prior of long blockages is companion.nav.motion_prior."""

from __future__ import annotations

import math

from companion.constants import G0_MPS2
from companion.nav.consistency import NisMonitor


class AhrsHeadingCheck:
    """Mixin: autopilot heading vs GNSS, and the coarse in-motion yaw alignment of the INS."""

    def _monitors_init(self) -> None:
        """State of the heading check."""
        # autopilot heading check: specific force resolved with the autopilot attitude, integrated since
        # the anchor fix; exponentially forgotten correlation sums
        self._att_fused_t = -math.inf
        self._att_c: tuple[float, ...] | None = None  # first two rows of the autopilot's C_b^n
        self._sf_dv = [0.0, 0.0]
        self._al_anchor: tuple[float, float, float] | None = None  # (t, vn, ve) of the anchor fix
        self._al_c = 0j
        self._al_ef = 0.0
        self._al_eg = 0.0
        self._al_acc2 = 0.0  # forgotten sum of squared horizontal GNSS accelerations, and its weight
        self._al_w = 0.0
        self.ahrs_heading_offset_rad = math.nan  # GNSS-observed heading minus autopilot heading
        self.ahrs_consistent = True
        self.yaw_alignments: list[tuple[float, float]] = []  # (t, applied INS heading rotation rad)
        c = self.config
        self._att_nis = NisMonitor(c.att_nis_tau_s, c.att_nis_min_s)  # autopilot tilt vs the INS (att_consistency)

    def _ahrs_check(self, t: float, vel) -> None:
        """Autopilot heading vs GNSS (see ``NavigatorConfig.ahrs_check``); re-align the INS if it is off."""
        c = self.config
        a = self._al_anchor
        if a is None or t - a[0] > 3.0 * c.ahrs_check_interval_s + 1.0:  # start, or a gap: re-anchor
            self._al_anchor = (t, vel[0], vel[1])
            self._sf_dv = [0.0, 0.0]
            return
        if t - a[0] < c.ahrs_check_interval_s:
            return
        zg = complex(vel[0] - a[1], vel[1] - a[2])
        zf = complex(self._sf_dv[0], self._sf_dv[1])
        self._al_anchor = (t, vel[0], vel[1])
        self._sf_dv = [0.0, 0.0]
        w = math.exp(-(t - a[0]) / c.ahrs_check_tau_s)
        self._al_c = self._al_c * w + zg * zf.conjugate()
        self._al_ef = self._al_ef * w + abs(zf) ** 2
        self._al_eg = self._al_eg * w + abs(zg) ** 2
        self._al_acc2 = self._al_acc2 * w + (abs(zg) / (t - a[0])) ** 2
        self._al_w = self._al_w * w + 1.0
        if c.att_consistency:
            self._tilt_residual(t, t - a[0], zg, zf)
        if min(self._al_ef, self._al_eg) < c.ahrs_check_min_dv_mps**2:
            return
        if abs(self._al_c) < c.ahrs_check_min_coherence * math.sqrt(self._al_ef * self._al_eg):
            return
        off = math.atan2(self._al_c.imag, self._al_c.real)
        self.ahrs_heading_offset_rad = off
        if self.ahrs_consistent and abs(off) > math.radians(c.ahrs_max_offset_deg):
            self.ahrs_consistent = False
        elif not self.ahrs_consistent and abs(off) < math.radians(c.ahrs_ok_offset_deg):
            self.ahrs_consistent = True
        if not self.ahrs_consistent and self.mode == "ins":
            self._align_yaw(t)

    def _tilt_residual(self, t: float, dt: float, zg: complex, zf: complex) -> None:
        """Covariance matching of the autopilot's tilt against GNSS, independent of the INS (which follows the
        autopilot's tilt when that is fused at a high rate, so its own attitude innovations cannot show a bias):
        over one interval dt, the GNSS velocity change minus the specific force resolved with the autopilot's
        attitude (rotated by the measured heading offset, 0 until one is measured) leaves per horizontal axis
        variance 2 sigma_v^2 (GNSS velocity noise at both ends) + q_a dt (accelerometer noise) + (g sigma_tilt dt)^2
        (the tilt error) for an autopilot as good as ``att_sigma_tilt_rad``. The excess over the first two,
        in units of the third, is fed to the monitor: its forgotten mean is the factor by which the tilt variance
        must grow to explain what GNSS saw (1 for a consistent autopilot)."""
        c = self.config
        off = self.ahrs_heading_offset_rad if math.isfinite(self.ahrs_heading_offset_rad) else 0.0
        r = zg - zf * complex(math.cos(off), math.sin(off))
        other = 2.0 * c.gnss_vel_sigma_mps**2 + c.accel_noise_mps2_rthz**2 * dt
        tilt = (G0_MPS2 * c.att_sigma_tilt_rad * dt) ** 2
        self._att_nis.add(t, (0.5 * abs(r) ** 2 - other) / tilt, 1)

    def _align_yaw(self, t: float) -> None:
        """Rotate the INS heading to autopilot heading + measured offset if it is far from it."""
        c = self.config
        if self._att is None or self.ins is None:
            return
        target = self._att.yaw_rad + self.ahrs_heading_offset_rad
        d = (target - self.ins.euler()[2] + math.pi) % (2 * math.pi) - math.pi
        sig = math.sqrt(max(self._kf.P[8, 8], 0.0))
        if abs(d) < max(math.radians(c.yaw_align_min_deg), 3.0 * sig):
            return
        self._ins_predict(max(t, self._kf_t))
        self._correct_ins((0, 0, 0), (0, 0, 0), (0.0, 0.0, d), (0, 0, 0), (0, 0, 0))  # exact rotation about down
        P = self._kf.P
        P[8, :] = 0.0
        P[:, 8] = 0.0
        P[8, 8] = c.yaw_align_sigma_rad**2
        self.yaw_alignments.append((t, d))
