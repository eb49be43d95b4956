"""The navigator's kinematic fallback: a 6-state constant-velocity Kalman filter (white-noise acceleration) on the
same measurements as the INS filter, mixed with a hold model (companion.nav.hold_cv, ``kinematic_hold_cv``). Used
when the source has no IMU, or its IMU is too slow to integrate, or no attitude initialises the INS, and after an IMU
that stopped in flight (then started from the next fix; it does not run beside the INS). A mixin of
companion.nav.navigator.Navigator (its state lives on the navigator)."""

from __future__ import annotations

import math

import numpy as np
from companion.nav.hold_cv import CvFilter, HoldCvFilter

from companion.nav.measurements import Measurement, PositionMeasurement, gate
from companion.nav.outputs import MeasurementUpdate


class KinematicFilter:
    """Mixin: the constant-velocity filter of the Navigator (``_kin``, ``_kin_t``)."""

    def _kin_init(self, t: float, z, vel) -> None:
        v = [0.0, 0.0, 0.0]
        if vel is not None:
            v = [vel[0], vel[1], vel[2] if math.isfinite(vel[2]) else 0.0]
        x0 = np.array([[z[0]], [z[1]], [z[2]], [v[0]], [v[1]], [v[2]]])
        P0 = np.diag([9.0, 9.0, 25.0, 4.0, 4.0, 4.0])
        c = self.config
        if c.kinematic_hold_cv:  # hold / constant velocity mixed (companion.nav.hold_cv)
            self._kin = HoldCvFilter(x0, P0, c.kinematic_accel_sigma_mps2, c.hold_cv)
        else:
            self._kin = CvFilter(x0, P0, c.kinematic_accel_sigma_mps2)
        self._kin_t = t

    def _kin_predict(self, t: float) -> None:
        dt = t - self._kin_t
        if dt <= 0:
            return
        self._kin.predict(dt)
        self._kin_t = t

    def _kin_apply(self, m: Measurement, record: bool) -> tuple[bool, np.ndarray, float]:
        """The one update of the constant-velocity KF (companion.nav.kalman): predict to the measurement, gate,
        record a MeasurementUpdate (if ``record``: the filter drives the output), update."""
        self._kin_predict(max(m.t_s, self._kin_t))
        kf = self._kin
        x = kf.x.ravel()
        y, H, R = m.compute_kin(x, self._gnss_delay_s())
        Rg = m.R_gate()
        nis, ok = gate(y, H @ kf.P @ H.T + (R if Rg is None else np.maximum(R, Rg)), m.gate_chi2)
        if record:
            self._out.append(MeasurementUpdate(m.t_s, m.kind, "kinematic", tuple(float(v) for v in y),
                                               tuple(float(v) for v in np.sqrt(np.diag(R))), nis, m.gate_chi2, ok))
        if ok:
            # a measurement of the vehicle is evidence for a motion model; a pseudo-measurement is not
            kf.update((y + H @ x).reshape(-1, 1), R=R, H=H, evidence=m.kind in ("gnss_pos", "position_fix"))
        return ok, y, nis

    def _kin_update(self, m: PositionMeasurement, record: bool) -> bool:
        """A position measurement; a GNSS fix persistently rejected resets the position to it."""
        kf = self._kin
        ok, y, nis = self._kin_apply(m, record)
        if m.kind == "gnss_pos" and record:
            ok = self._gate_bookkeeping(m.t_s, ok, y, m.sigma_h_m, m.sigma_v_m)
            if ok and nis > m.gate_chi2:  # reset after persistent rejection: position, and velocity when the fix has it
                kf.reset_position(m.z(), m.R())
                if self._fix_vel is not None:
                    c = self.config
                    kf.reset_velocity(self._fix_vel, c.gnss_vel_sigma_mps**2 * c.reset_cov_scale)
                self._last_innov = tuple(float(v) for v in y)
                return True
        if not ok:
            if record:
                self._n_rejected += 1
            return False
        if record:
            self._last_innov = tuple(float(v) for v in y)
        return True
