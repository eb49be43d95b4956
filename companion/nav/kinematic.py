"""The navigator's kinematic fallback: a 6-state constant-velocity Kalman filter (white-noise acceleration) on the
same measurements as the INS filter. Used when the source has no IMU, or its IMU is too slow to integrate, or no
attitude initialises the INS; it always runs alongside, so the navigator can fall back at once. A mixin of
companion.nav.navigator.Navigator (its state lives on the navigator)."""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import KalmanFilter

from companion.nav.outputs import MeasurementUpdate


class KinematicFilter:
    """Mixin: the constant-velocity filter of the Navigator (``_kin``, ``_kin_t``)."""

    def _kin_init(self, t: float, z, vel) -> None:
        kf = KalmanFilter(dim_x=6, dim_z=3)
        v = [0.0, 0.0, 0.0]
        if vel is not None:
            v = [vel[0], vel[1], vel[2] if math.isfinite(vel[2]) else 0.0]
        kf.x = np.array([[z[0]], [z[1]], [z[2]], [v[0]], [v[1]], [v[2]]])
        kf.P = np.diag([9.0, 9.0, 25.0, 4.0, 4.0, 4.0])
        self._kin = kf
        self._kin_t = t

    def _kin_predict(self, t: float) -> None:
        dt = t - self._kin_t
        if dt <= 0:
            return
        F = np.eye(6)
        F[0:3, 3:6] = np.eye(3) * dt
        s2 = self.config.kinematic_accel_sigma_mps2**2
        Q = np.zeros((6, 6))
        Q[0:3, 0:3] = np.eye(3) * dt**4 / 4 * s2
        Q[0:3, 3:6] = Q[3:6, 0:3] = np.eye(3) * dt**3 / 2 * s2
        Q[3:6, 3:6] = np.eye(3) * dt**2 * s2
        self._kin.predict(F=F, Q=Q)
        self._kin_t = t

    def _kin_update(self, t: float, z, sh: float, sv: float, kind: str, record: bool, gate_sigma=None) -> bool:
        self._kin_predict(max(t, self._kin_t))
        kf = self._kin
        H = np.zeros((3, 6))
        H[:, 0:3] = np.eye(3)
        # the fix refers to t - delay
        x = kf.x.ravel()
        y = np.asarray(z, dtype=float) - (x[0:3] - x[3:6] * self.config.gnss_delay_s)
        R = np.diag([sh**2, sh**2, sv**2])
        gh, gv = gate_sigma if gate_sigma is not None else (sh, sv)
        S = H @ kf.P @ H.T + np.maximum(R, np.diag([gh**2, gh**2, gv**2]))
        nis = float(y @ np.linalg.solve(S, y))
        ok = nis <= self.config.gate_chi2
        if record:
            self._out.append(
                MeasurementUpdate(t, kind, "kinematic", tuple(float(v) for v in y), (sh, sh, sv), nis,
                                  self.config.gate_chi2, ok)
            )
        if kind == "gnss_pos" and record:
            ok = self._gate_bookkeeping(t, ok, y, sh, sv)
            if ok and nis > self.config.gate_chi2:  # reset after persistent rejection
                kf.x[0:3, 0] = np.asarray(z, dtype=float)
                kf.P[0:3, 0:3] = R
                kf.P[0:3, 3:6] = kf.P[3:6, 0:3] = 0.0
                self._last_innov = tuple(float(v) for v in y)
                return True
        if not ok:
            if record:
                self._n_rejected += 1
            return False
        kf.update((y + H @ kf.x.ravel()).reshape(-1, 1), R=R, H=H)
        if record:
            self._last_innov = tuple(float(v) for v in y)
        return True
