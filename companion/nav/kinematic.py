"""The navigator's kinematic fallback: a 6-state constant-velocity Kalman filter (white-noise acceleration) on the
same measurements as the INS filter, mixed with a hold model (companion.nav.hold_cv, ``kinematic_hold_cv``). Used
when the source has no IMU, or its IMU is too slow to integrate, or no attitude initialises the INS, and after an IMU
that stopped in flight (then started from the next fix; it does not run beside the INS)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from companion.events import Event
from companion.nav.config import NavigatorConfig
from companion.nav.gnss_lag import GnssLatency
from companion.nav.hold_cv import CvFilter, HoldCvFilter
from companion.nav.linalg import small_inverse
from companion.nav.measurements import Measurement, PositionMeasurement
from companion.nav.outputs import MeasurementUpdate


class KinematicFilter:
    """Started at ``t`` from a position ``z`` (local NED) and a velocity (or None: at rest; a NaN vertical: 0).
    ``emit`` receives a MeasurementUpdate for every measurement offered."""

    def __init__(self, config: NavigatorConfig, latency: GnssLatency, emit: Callable[[Event], None], t: float, z,
                 vel) -> None:
        self.config, self.latency, self._emit = config, latency, emit
        v = [0.0, 0.0, 0.0]
        if vel is not None:
            v = [vel[0], vel[1], vel[2] if math.isfinite(vel[2]) else 0.0]
        x0 = np.array([[z[0]], [z[1]], [z[2]], [v[0]], [v[1]], [v[2]]])
        P0 = np.diag([9.0, 9.0, 25.0, 4.0, 4.0, 4.0])
        c = config
        if c.kinematic_hold_cv:  # hold / constant velocity mixed (companion.nav.hold_cv)
            self.kf: CvFilter | HoldCvFilter = HoldCvFilter(x0, P0, c.kinematic_accel_sigma_mps2, c.hold_cv)
        else:
            self.kf = CvFilter(x0, P0, c.kinematic_accel_sigma_mps2)
        self.t_s = t

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(x: position and velocity NED, flat; its covariance P)."""
        return self.kf.x.ravel(), self.kf.P

    def predict(self, t: float) -> None:
        dt = t - self.t_s
        if dt <= 0:
            return
        self.kf.predict(dt)
        self.t_s = t

    def apply(self, m: Measurement) -> tuple[bool, np.ndarray, float]:
        """The one update of the constant-velocity KF (companion.nav.kalman): predict to the measurement, gate, emit a
        MeasurementUpdate, update. Returns (accepted, innovation, NIS)."""
        self.predict(max(m.t_s, self.t_s))
        kf = self.kf
        x = kf.x.ravel()
        y, H, R = m.compute_kin(x, self.latency.delay_s())
        Rg = m.R_gate()
        S = H @ kf.P @ H.T + (R if Rg is None else np.maximum(R, Rg))
        nis = float(y @ small_inverse(S) @ y)
        ok = nis <= m.gate_chi2
        self._emit(MeasurementUpdate(m.t_s, m.kind, "kinematic", tuple(y.tolist()),
                                     tuple(np.sqrt(R.diagonal()).tolist()), nis, m.gate_chi2, ok))
        if ok:
            # a measurement of the vehicle is evidence for a motion model; a pseudo-measurement is not
            kf.update((y + H @ x).reshape(-1, 1), R=R, H=H, evidence=m.kind in ("gnss_pos", "position_fix"))
        return ok, y, nis

    def reset_to_fix(self, m: PositionMeasurement, fix_vel) -> None:
        """Position to the fix with its covariance, and velocity to the fix's when it has one."""
        self.kf.reset_position(m.z(), m.R())
        if fix_vel is not None:
            c = self.config
            self.kf.reset_velocity(fix_vel, c.gnss_vel_sigma_mps**2 * c.reset_cov_scale)

    def trajectory_record(self) -> tuple:
        """(position, velocity, 0, 0): the filter's dead reckoning from now is x + v dt (for the motion prior)."""
        x = self.kf.x.ravel().tolist()
        return (x[0:3], x[3:6], (0.0,) * 3, (0.0,) * 3)
