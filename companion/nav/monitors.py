"""The autopilot's heading against GNSS, independently of the INS: :class:`AhrsHeadingCheck` (``ahrs_check`` in
companion.nav.config.NavigatorConfig; docs/decisions/0004-autopilot-attitude.md).

A DCM AHRS corrects its tilt with GNSS acceleration resolved through its heading, so a wrong heading also corrupts
its roll and pitch in manoeuvres. Horizontal GNSS velocity changes over >= ``ahrs_check_interval_s`` are compared
with the integral of the IMU specific force resolved with the autopilot's attitude over the same interval (gravity
and Coriolis have ~no horizontal part); with exponential forgetting (``ahrs_check_tau_s``) the heading offset is the
angle of sum(dv_gnss conj(dv_ahrs)) (complex N + iE), valid once both sums of squares exceed
``ahrs_check_min_dv_mps``^2 and the normalised coherence is >= ``ahrs_check_min_coherence``. Above
``ahrs_max_offset_deg`` the autopilot is flagged inconsistent, until the offset falls below ``ahrs_ok_offset_deg``.
"""

from __future__ import annotations

import math

from companion.constants import G0_MPS2
from companion.events import Attitude
from companion.nav.config import NavigatorConfig
from companion.nav.consistency import NisMonitor
from companion.nav.ins import dcm_from_quat, quat_from_euler


class AhrsHeadingCheck:
    """Feed :meth:`add_attitude` with every autopilot attitude, :meth:`add_imu` with every IMU step and :meth:`check`
    with every GNSS velocity; ``consistent`` and ``offset_rad`` (GNSS-observed heading minus the autopilot's) are the
    verdict."""

    def __init__(self, config: NavigatorConfig) -> None:
        c = self.config = config
        self.att_c: tuple[float, ...] | None = None  # first two rows of the autopilot's C_b^n
        self._sf_dv = [0.0, 0.0]  # specific force resolved with it, integrated since the anchor fix
        self._anchor: tuple[float, float, float] | None = None  # (t, vn, ve) of the anchor fix
        self._c = 0j  # forgotten correlation sums
        self._ef = 0.0
        self._eg = 0.0
        self._acc2 = 0.0  # forgotten sum of squared horizontal GNSS accelerations, and its weight
        self._w = 0.0
        self.offset_rad = math.nan
        self.consistent = True
        self.tilt_nis = NisMonitor(c.att_nis_tau_s, c.att_nis_min_s)  # autopilot tilt vs GNSS (att_consistency)

    def add_attitude(self, ev: Attitude) -> tuple[float, ...]:
        """The autopilot's attitude: its rotation's first two rows (NED north and east of each body axis)."""
        C = dcm_from_quat(quat_from_euler(ev.roll_rad, ev.pitch_rad, ev.yaw_rad))
        self.att_c = tuple(float(x) for x in C[0:2].ravel())
        return self.att_c

    def add_imu(self, dt: float, accel_frd_mps2) -> tuple[float, float] | None:
        """One IMU step of ``dt``: its horizontal specific force x dt resolved with the autopilot's attitude (None
        before any attitude), added to the interval's integral."""
        ac = self.att_c
        if ac is None:
            return None
        a = accel_frd_mps2
        dvn = (ac[0] * a[0] + ac[1] * a[1] + ac[2] * a[2]) * dt
        dve = (ac[3] * a[0] + ac[4] * a[1] + ac[5] * a[2]) * dt
        self._sf_dv[0] += dvn
        self._sf_dv[1] += dve
        return dvn, dve

    def reanchor(self) -> None:
        """Start the next interval at the next GNSS velocity (after a stream gap)."""
        self._anchor = None

    def check(self, t: float, vel) -> bool:
        """A GNSS velocity (N, E, ...): close the interval once it is long enough; True if the offset was updated."""
        c = self.config
        a = self._anchor
        if a is None or t - a[0] > 3.0 * c.ahrs_check_interval_s + 1.0:  # start, or a gap: re-anchor
            self._anchor = (t, vel[0], vel[1])
            self._sf_dv = [0.0, 0.0]
            return False
        if t - a[0] < c.ahrs_check_interval_s:
            return False
        zg = complex(vel[0] - a[1], vel[1] - a[2])
        zf = complex(self._sf_dv[0], self._sf_dv[1])
        self._anchor = (t, vel[0], vel[1])
        self._sf_dv = [0.0, 0.0]
        w = math.exp(-(t - a[0]) / c.ahrs_check_tau_s)
        self._c = self._c * w + zg * zf.conjugate()
        self._ef = self._ef * w + abs(zf) ** 2
        self._eg = self._eg * w + abs(zg) ** 2
        self._acc2 = self._acc2 * w + (abs(zg) / (t - a[0])) ** 2
        self._w = self._w * w + 1.0
        if c.att_consistency:
            self._tilt_residual(t, t - a[0], zg, zf)
        if min(self._ef, self._eg) < c.ahrs_check_min_dv_mps**2:
            return False
        if abs(self._c) < c.ahrs_check_min_coherence * math.sqrt(self._ef * self._eg):
            return False
        off = math.atan2(self._c.imag, self._c.real)
        self.offset_rad = off
        if self.consistent and abs(off) > math.radians(c.ahrs_max_offset_deg):
            self.consistent = False
        elif not self.consistent and abs(off) < math.radians(c.ahrs_ok_offset_deg):
            self.consistent = True
        return True

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
        off = self.offset_rad if math.isfinite(self.offset_rad) else 0.0
        r = zg - zf * complex(math.cos(off), math.sin(off))
        other = 2.0 * c.gnss_vel_sigma_mps**2 + c.accel_noise_mps2_rthz**2 * dt
        tilt = (G0_MPS2 * c.att_sigma_tilt_rad * dt) ** 2
        self.tilt_nis.add(t, (0.5 * abs(r) ** 2 - other) / tilt, 1)

    def heading_target_rad(self, autopilot_yaw_rad: float) -> float | None:
        """Where a flagged autopilot says the heading is (its heading + the measured offset); None while consistent
        or before an offset is measured."""
        if self.consistent or not math.isfinite(self.offset_rad):
            return None
        return autopilot_yaw_rad + self.offset_rad

    def fuse_heading(self) -> bool:
        """The autopilot's heading may aid the INS: the check has measured it consistent."""
        return self.consistent and math.isfinite(self.offset_rad)

    def tilt_var_rad2(self) -> float:
        """Variance of the autopilot's tilt: ``att_sigma_tilt_rad``^2, plus for a flagged autopilot the error its
        heading offset d induces (it levels on an acceleration rotated by d: off by 2 sin(d/2) a_rms / g, a_rms the
        recent RMS horizontal GNSS acceleration), at least what GNSS measured (``att_consistency``)."""
        c = self.config
        s_tilt2 = c.att_sigma_tilt_rad**2
        if not self.consistent:
            a_rms = math.sqrt(self._acc2 / self._w) if self._w > 0 else 0.0
            s_tilt2 += (2.0 * math.sin(0.5 * abs(self.offset_rad)) * a_rms / 9.8) ** 2
        if c.att_consistency:
            s_tilt2 = max(s_tilt2, c.att_sigma_tilt_rad**2 * self.tilt_nis.inflation())
        return s_tilt2
