"""The navigator's monitors: the autopilot heading check with the INS yaw alignment, and the hold prior of long
blockages (see ``ahrs_check`` and ``hold_prior`` in companion.nav.config.NavigatorConfig). Mixins of
companion.nav.navigator.Navigator (their state lives on the navigator)."""

from __future__ import annotations

import bisect
import math

import numpy as np


class AhrsHeadingCheck:
    """Mixin: autopilot heading vs GNSS, and the coarse in-motion yaw alignment of the INS."""

    def _monitors_init(self) -> None:
        """State of both monitors (heading check and hold prior)."""
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
        # motion prior for long blockages: accepted fixes, forgotten sums of squared displacement per lag
        self._fix_hist_t: list[float] = []
        self._fix_hist_p: list[tuple[float, float, float]] = []
        self._last_fix_ned: tuple[float, float, float] | None = None
        self._last_fix_var: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._msd = np.zeros((self.config.hold_prior_max_lag_s + 1, 3))
        self._msd_w = np.zeros(self.config.hold_prior_max_lag_s + 1)
        self._msd_t: float | None = None

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


class HoldPrior:
    """Mixin: the vehicle's mean squared displacement per lag, learnt from accepted fixes, as a prior on the
    output position during a long blockage."""

    def _learn_motion(self, t: float, z, sh: float, sv: float) -> None:
        """Update D(lag) = mean squared displacement per axis with the new fix (see ``hold_prior``)."""
        c = self.config
        ht, hp = self._fix_hist_t, self._fix_hist_p
        if self._msd_t is not None:
            w = math.exp(-(t - self._msd_t) / c.hold_prior_tau_s)
            self._msd *= w
            self._msd_w *= w
        self._msd_t = t
        for lag in range(1, c.hold_prior_max_lag_s + 1):
            i = bisect.bisect_left(ht, t - lag - 0.5)
            if i >= len(ht) or ht[i] > t - lag + 0.5:
                continue
            p = hp[i]
            self._msd[lag, 0] += (z[0] - p[0]) ** 2
            self._msd[lag, 1] += (z[1] - p[1]) ** 2
            self._msd[lag, 2] += (z[2] - p[2]) ** 2
            self._msd_w[lag] += 1.0
        ht.append(t)
        hp.append(tuple(z))
        if len(ht) > 64 and ht[0] < t - c.hold_prior_max_lag_s - 2.0:
            k = bisect.bisect_left(ht, t - c.hold_prior_max_lag_s - 1.0)
            del ht[:k], hp[:k]
        self._last_fix_ned = tuple(z)
        self._last_fix_var = (sh * sh, sh * sh, sv * sv)

    def _hold_blend(self, tg: float, ned, P_diag):
        """Output position and variances after the product with the last-fix motion prior, or None."""
        c = self.config
        if self._last_fix_ned is None or self._last_fix_t is None:
            return None
        age = tg - self._last_fix_t
        if age < c.hold_prior_min_age_s:
            return None
        lo = min(int(math.floor(age)), c.hold_prior_max_lag_s)
        hi = min(lo + 1, c.hold_prior_max_lag_s)
        if self._msd_w[lo] < 5.0 or self._msd_w[hi] < 5.0:
            return None
        f = min(max(age - lo, 0.0), 1.0) if hi > lo else 0.0
        d = (1 - f) * self._msd[lo] / self._msd_w[lo] + f * self._msd[hi] / self._msd_w[hi]
        out, var = [], []
        for i in range(3):
            q = d[i] + self._last_fix_var[i]
            p = P_diag[i]
            k = p / (p + q) if p + q > 0 else 0.0
            out.append(ned[i] + k * (self._last_fix_ned[i] - ned[i]))
            var.append(p * (1 - k))
        return out, var
