"""Matcher fixes as position measurements for a Kalman integrator (beyond the papers).

Li et al. 2022 reset the INS with the matched path and name a proper fusion as future work. `FixFusionFilter`: a small error-state KF on the horizontal INS errors (position error, velocity error as a
  random walk) with each MatchResult as a position measurement of covariance sigma_m^2 I. Between fixes the
  error estimate propagates with the estimated velocity error, so a velocity bias that a reset leaves in
  place is learned and removed. Innovations are gated (chi-square, 2 dof). Pure numpy, no clock.
(The product's streaming Navigator takes matcher fixes as companion.events.PositionFix instead:
companion.gravity.stage.)

Errors are INS minus truth; corrected = INS - error estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.constants import CHI2_2DOF_999
from companion.gravity.matchers.base import MatchResult



@dataclass(frozen=True)
class FixFusionConfig:
    init_pos_sigma_m: float = 2000.0
    init_vel_sigma_mps: float = 30.0
    vel_random_walk_mps_rts: float = 0.05  # velocity-error random walk, m/s / sqrt(s)
    pos_noise_m_rts: float = 1.0  # position process noise, m / sqrt(s) (INS velocity white noise)
    gate_chi2: float | None = CHI2_2DOF_999  # None disables gating
    max_rejects_before_reset: int = 3  # consecutive gated fixes before the filter accepts one with inflated P


class FixFusionFilter:
    """4-state KF: x = [dn, de, dvn, dve] (INS error, metres and m/s)."""

    def __init__(self, cfg: FixFusionConfig | None = None, t0_s: float = 0.0):
        self.cfg = cfg or FixFusionConfig()
        self.x = np.zeros(4)
        self.P = np.diag([self.cfg.init_pos_sigma_m**2] * 2 + [self.cfg.init_vel_sigma_mps**2] * 2)
        self.t_s = float(t0_s)
        self.n_rejected = 0
        self._rejects_in_row = 0

    def predict(self, t_s: float) -> None:
        dt = float(t_s) - self.t_s
        if dt < 0:
            raise ValueError("time went backwards")
        if dt == 0:
            return
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        qv = self.cfg.vel_random_walk_mps_rts**2 * dt
        qp = self.cfg.pos_noise_m_rts**2 * dt
        Q = np.diag([qp + qv * dt**2 / 3, qp + qv * dt**2 / 3, qv, qv])
        Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = qv * dt / 2
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q
        self.t_s = float(t_s)

    def error_at(self, t_s: float) -> np.ndarray:
        """Predicted position error at t_s (>= current time) without changing the filter."""
        return self.x[:2] + self.x[2:] * (float(t_s) - self.t_s)

    def corrected(self, t_s: float, ins_ne_m, ins_vel_ne_mps=None):
        """INS position (and velocity) minus the predicted error at t_s."""
        pos = np.asarray(ins_ne_m, float) - self.error_at(t_s)
        if ins_vel_ne_mps is None:
            return pos
        return pos, np.asarray(ins_vel_ne_mps, float) - self.x[2:]

    def update(self, t_s: float, ins_ne_m, fix_ne_m, sigma_m: float) -> bool:
        """Fuse a position fix taken at t_s, with the INS position at t_s. Returns False if gated out."""
        self.predict(t_s)
        H = np.zeros((2, 4))
        H[0, 0] = H[1, 1] = 1.0
        z = np.asarray(ins_ne_m, float) - np.asarray(fix_ne_m, float)  # measured INS error
        R = np.eye(2) * max(float(sigma_m), 1e-3) ** 2
        y = z - H @ self.x
        S = H @ self.P @ H.T + R
        nis = float(y @ np.linalg.solve(S, y))
        if self.cfg.gate_chi2 is not None and nis > self.cfg.gate_chi2:
            self.n_rejected += 1
            self._rejects_in_row += 1
            if self._rejects_in_row < self.cfg.max_rejects_before_reset:
                return False
            # persistent disagreement: the filter, not the matcher, is likely wrong -> re-open position
            self.P[:2, :2] += np.eye(2) * float(y @ y)
            S = H @ self.P @ H.T + R
        self._rejects_in_row = 0
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ y
        IKH = np.eye(4) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T  # Joseph form
        return True

    def update_from(self, res: MatchResult, ins_ne_m) -> bool:
        if not res.ok:
            return False
        return self.update(res.t_s, ins_ne_m, res.position_ne_m, res.sigma_m)
