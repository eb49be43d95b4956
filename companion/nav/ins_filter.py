"""The navigator's INS error-state Kalman filter: covariance propagation (eq. 9), gated updates (eqs. 7, 8, 10)
with feedback of the error estimate into the strapdown INS, and the position, velocity and attitude measurements.
A mixin of companion.nav.navigator.Navigator (its state lives on the navigator); the 15 states are listed in
companion.nav.outputs.INS_STATE_NAMES.

The states: position, velocity, attitude error psi, accelerometer bias and gyro bias around
:class:`companion.nav.ins.StrapdownIns`. Errors are true minus estimate, attitude
``C_true = (I + [psi x]) C_est``; continuous model ``dp' = dv``, ``dv' = -[f_n x] psi - C dba``,
``psi' = -C dbg``, biases first-order Gauss-Markov. The strapdown equations run for every IMU sample
in plain Python; the KF covariance is propagated at the 10 Hz output rate (and before each update)
with ``Phi = I + F dt + (F dt)^2 / 2`` built from the mean specific force of the interval (eq. 9), and
updates use the Joseph-form algebra of companion.nav.kalman (eqs. 7, 8, 10). After each update the error
estimate is fed back into the INS and reset to zero.
"""

from __future__ import annotations

import math

import numpy as np
from companion.nav.kalman import KalmanFilter

from companion.events import Attitude, ImuSample
from companion.nav.ins import StrapdownIns, dcm_from_quat, quat_from_euler
from companion.nav.measurements import AttitudeMeasurement, InsView, Measurement, PositionMeasurement, gate, skew
from companion.nav.outputs import MeasurementUpdate


class InsFilter:
    """Mixin: the 15-state error-state KF around the Navigator's StrapdownIns (``ins``, ``_kf``, ``_kf_t``)."""

    def _ins_predict(self, t: float) -> None:
        """Propagate the error covariance to ``t`` (eq. 9) with the interval's mean specific force."""
        c = self.config
        dt = t - self._kf_t
        if dt <= 0:
            return
        ins = self.ins
        if self._f_n:
            f = np.array(self._f_sum) / self._f_n
        else:
            f = np.array(ins.f_ned)
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0
        C = ins.dcm()
        F0, eye15, q_per_s = self._ins_model()
        F = F0.copy()
        F[3:6, 6:9] = -skew(f)
        F[3:6, 9:12] = -C
        F[6:9, 12:15] = -C
        Fd = F * dt
        phi = eye15 + Fd + 0.5 * Fd @ Fd
        self._kf.predict(F=phi, Q=np.diag(q_per_s * dt))
        self._kf_t = t

    def _ins_model(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The constant parts of the model of eq. 9 for this (frozen) config, built once: F without its attitude and
        specific-force blocks, I (15 x 15), and the process noise per second (times dt: the same products as
        building them at every step)."""
        m = self.__dict__.get("_ins_model_cache")
        if m is None:
            c = self.config
            F = np.zeros((15, 15))
            F[0:3, 3:6] = np.eye(3)
            F[9:15, 9:15] = -np.eye(6) / c.bias_tau_s
            q = np.empty(15)
            q[0:3] = 1e-6
            q[3:6] = c.accel_noise_mps2_rthz**2
            q[6:9] = c.gyro_noise_radps_rthz**2
            q[9:12] = 2 * c.accel_bias_sigma_mps2**2 / c.bias_tau_s
            q[12:15] = 2 * c.gyro_bias_sigma_radps**2 / c.bias_tau_s
            for a in (F, q):
                a.flags.writeable = False
            m = self._ins_model_cache = (F, np.eye(15), q)
        return m

    def _ins_apply(self, m: Measurement) -> tuple[bool, np.ndarray]:
        """The one update of the error-state KF (eqs. 7, 8, 10; companion.nav.kalman): predict to the measurement,
        gate, record a MeasurementUpdate, update and feed the error estimate back into the INS."""
        self._ins_predict(max(m.t_s, self._kf_t))
        pos, vel = self._ins_state_at(m.t_s, m.delay_s)
        y, H, R = m.compute_ins(InsView(pos, vel, self.ins.dcm()))
        kf = self._kf
        Rg = m.R_gate()
        nis, ok = gate(y, H @ kf.P @ H.T + (R if Rg is None else np.maximum(R, Rg)), m.gate_chi2)
        self._out.append(
            MeasurementUpdate(m.t_s, m.kind, "ins", tuple(y.tolist()), tuple(np.sqrt(R.diagonal()).tolist()), nis,
                              m.gate_chi2, ok)
        )
        if not ok:
            return False, y
        kf.update(y.reshape(-1, 1), R=R, H=H, gain_rows=m.gain_rows_ins())
        dx = kf.x.ravel().tolist()  # Python floats: the same values, and the strapdown INS (plain Python, every IMU
        # sample) then runs on floats rather than numpy scalars, which are several times slower per operation
        self._correct_ins(dx[0:3], dx[3:6], dx[6:9], dx[9:12], dx[12:15])
        kf.x = np.zeros((15, 1))
        return True, y

    def _correct_ins(self, dp, dv, psi, dba, dbg) -> None:
        """Feed an error estimate back into the INS and shift the delay history with it; the sums of the corrections
        give the free (uncorrected) trajectory (``_ins_free``)."""
        self.ins.correct(dp, dv, psi, dba, dbg)
        t, cs = self.ins.t_s, self._corr_sums
        for a in range(3):
            cs[a] += dp[a]
            cs[3 + a] += dv[a]
            cs[6 + a] += dv[a] * t
        for h in self._hist:
            h[1] += dp[0]
            h[2] += dp[1]
            h[3] += dp[2]
            h[4] += dv[0]
            h[5] += dv[1]
            h[6] += dv[2]

    def _ins_free(self, p_ned, v_ned) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Position and velocity of the INS as if no correction had been applied since it was initialised: each
        correction (dp, dv) at t_k moved the position by dp + dv (t - t_k)."""
        t, cs = self.ins.t_s, self._corr_sums
        return (tuple(p_ned[a] - cs[a] - cs[3 + a] * t + cs[6 + a] for a in range(3)),
                tuple(v_ned[a] - cs[3 + a] for a in range(3)))

    def _ins_state_at(self, t: float, delay_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """INS position (local NED) and velocity at the epoch ``t - gnss_delay_s`` a fix stamped t refers to.

        From the per-IMU-step history when the epoch is in the past, else extrapolated from the current
        state at constant velocity.
        """
        ins = self.ins
        te = t - (self._gnss_delay_s() if delay_s is None else delay_s)
        hist = self._hist
        if hist and te < hist[-1][0]:
            if te <= hist[0][0]:
                h = hist[0]
                return np.array(h[1:4]), np.array(h[4:7])
            for i in range(len(hist) - 1, 0, -1):
                a = hist[i - 1]
                if a[0] <= te:
                    b = hist[i]
                    w = (te - a[0]) / (b[0] - a[0]) if b[0] > a[0] else 1.0
                    pa, pb = np.array(a[1:]), np.array(b[1:])
                    x = pa + w * (pb - pa)
                    return x[0:3], x[3:6]
        n, e, d = self.frame.ned_tuple(ins.lat_deg, ins.lon_deg, ins.h_m)
        dt = te - ins.t_s
        return np.array([n + ins.vn * dt, e + ins.ve * dt, d + ins.vd * dt]), np.array([ins.vn, ins.ve, ins.vd])

    def _gnss_delay_s(self) -> float:
        """The GNSS latency the filters model: the online estimate once it is observable (``gnss_delay_estimate``,
        companion.nav.gnss_lag), else ``gnss_delay_s``."""
        est = self._gnss_lag
        lag = est.lag_s if est is not None else None
        return self.config.gnss_delay_s if lag is None else lag

    def _gnss_vel_delay_s(self) -> float:
        """The latency of the GNSS velocity: the measured one when in use (companion.nav.gnss_lag measures it from the
        velocity), else the position's plus the velocity's own (``gnss_vel_delay_s``)."""
        est = self._gnss_lag
        lag = est.lag_s if est is not None else None
        return self.config.gnss_delay_s + self.config.gnss_vel_delay_s if lag is None else lag

    def _check_gnss_delay(self) -> None:
        """Before a GNSS update: when the modelled latency moved by more than ``gnss_lag.relearn_s`` since the INS
        filter last re-learnt, widen its tilt and accelerometer-bias uncertainty (to their initial sigmas): the
        filter explained the mis-modelled lag with those states, and with a tight covariance it would keep the
        wrong values for minutes (on the simulated square: 8 m instead of 2 m after 30 s without GNSS)."""
        if self._gnss_lag is None or self._kf is None:
            return
        d = self._gnss_delay_s()
        if self._delay_learnt_s is not None and abs(d - self._delay_learnt_s) <= self.config.gnss_lag.relearn_s:
            return
        if self._delay_learnt_s is not None:
            c = self.config
            P = self._kf.P
            for i, s in ((6, c.init_sigma_att_rad), (7, c.init_sigma_att_rad), (9, c.accel_bias_sigma_mps2),
                         (10, c.accel_bias_sigma_mps2), (11, c.accel_bias_sigma_mps2)):
                if P[i, i] < s * s:
                    P[i, :] *= 0.0
                    P[:, i] *= 0.0
                    P[i, i] = s * s
        self._delay_learnt_s = d

    def _ins_position_update(self, m: PositionMeasurement, force_reset: bool = False) -> bool:
        if m.kind == "gnss_pos":
            self._check_gnss_delay()
        ok, y = self._ins_apply(m)
        if m.kind == "gnss_pos":
            ok = self._gate_bookkeeping(m.t_s, ok, y, m.sigma_h_m, m.sigma_v_m, force_reset)
        if ok:
            self._last_innov = tuple(y.tolist())
        else:
            self._n_rejected += 1
        return ok

    def _ins_attitude_update(self, ev: Attitude) -> None:
        c = self.config
        if not self.ahrs_consistent and (not c.fuse_flagged_tilt or not c.fuse_flagged_tilt_in_gap and (
                self._last_fix_t is None or ev.t_s - self._last_fix_t >= c.gnss_gap_s)):
            return  # a flagged autopilot's tilt is wrong by degrees in manoeuvres: without GNSS it would only mislead
        # its heading only once the heading check has measured it consistent (before, it may be ~90 deg off)
        fuse_yaw = c.fuse_attitude_yaw and self.ahrs_consistent and math.isfinite(self.ahrs_heading_offset_rad)
        # Tilt-only measurement: the autopilot's roll/pitch fix the gravity direction in the body frame
        # whatever its heading, so the measured attitude is built with the INS's own heading. (Built with
        # the autopilot's heading, a heading disagreement of d rotates and mixes the roll/pitch innovations
        # through the small-angle extraction: at d ~ 90 deg, as in the Erle PXF log, a roll error was
        # read as a pitch error.)
        yaw_meas = ev.yaw_rad if fuse_yaw else self.ins.euler()[2]
        c_meas = dcm_from_quat(quat_from_euler(ev.roll_rad, ev.pitch_rad, yaw_meas))
        s_yaw = c.att_sigma_yaw_rad if fuse_yaw else 1e3  # 1e3 rad: no heading information
        s_tilt2 = c.att_sigma_tilt_rad**2
        if not self.ahrs_consistent:  # tilt error induced by the AHRS heading offset (see ahrs_check)
            a_rms = math.sqrt(self._al_acc2 / self._al_w) if self._al_w > 0 else 0.0
            s_tilt2 += (2.0 * math.sin(0.5 * abs(self.ahrs_heading_offset_rad)) * a_rms / 9.8) ** 2
        if c.att_consistency:  # the tilt variance GNSS has measured (AhrsHeadingCheck._tilt_residual), if larger
            s_tilt2 = max(s_tilt2, c.att_sigma_tilt_rad**2 * self._att_nis.inflation())
        m = AttitudeMeasurement(ev.t_s, "attitude", c_meas=c_meas, var_rad2=(s_tilt2, s_tilt2, s_yaw**2),
                                gate_chi2=c.gate_chi2)
        ok, y = self._ins_apply(m)
        if c.reset_after_rejection:
            self._attitude_bookkeeping(ev.t_s, ok, y)

    # ------------------------------------------------------------------ IMU and initialisation
    def _on_imu(self, ev: ImuSample) -> None:
        c = self.config
        t = ev.t_s
        self._imu_times.append(t)
        self.hover.add_imu(t, ev.accel_frd_mps2, ev.gyro_frd_radps)
        if self.drag is not None:
            self.drag.add_accel(ev.accel_frd_mps2)
        prev_t = self._last_imu_t
        self._last_imu_t = t
        if self._gnss_lag is not None and prev_t is not None:
            if 0 < t - prev_t <= c.max_imu_step_s:
                self._gnss_lag.add_imu(t, t - prev_t, ev.accel_frd_mps2)
            elif t - prev_t > c.max_imu_step_s:
                self._gnss_lag.reset_imu()
        ac = self._att_c
        if ac is not None and prev_t is not None and 0 < t - prev_t <= c.max_imu_step_s:
            dt = t - prev_t
            a = ev.accel_frd_mps2
            dvn = (ac[0] * a[0] + ac[1] * a[1] + ac[2] * a[2]) * dt
            dve = (ac[3] * a[0] + ac[4] * a[1] + ac[5] * a[2]) * dt
            self._sf_dv[0] += dvn
            self._sf_dv[1] += dve
            self.hover.add_horizontal_dv(dvn, dve)
        ins = self.ins
        if ins is None or self.mode != "ins" or self._reinit_pending is not None:
            return
        dt = t - ins.t_s
        if dt > c.max_imu_step_s:
            # a stall in the log (e.g. ArduPilot stops logging ~2 s at arming): do not integrate one
            # sample across it; bring the KF up to the gap start and widen velocity/attitude uncertainty
            self._ins_predict(ins.t_s)
            q = self._kf.P
            for i in range(3, 6):
                q[i, i] += (c.kinematic_accel_sigma_mps2 * dt) ** 2
            for i in range(6, 9):
                q[i, i] += (c.gyro_noise_radps_rthz**2) * dt + 1e-4
            speed = math.sqrt(ins.vn**2 + ins.ve**2 + ins.vd**2)
            for i in range(3):
                q[i, i] += (speed * dt + 0.5 * c.kinematic_accel_sigma_mps2 * dt * dt) ** 2
            ins.coast(t - 0.02)
            self._kf_t = ins.t_s
        if ins.step(t, ev.accel_frd_mps2, ev.gyro_frd_radps) > 0:
            if c.gnss_delay_s > 0 or c.gnss_vel_delay_s > 0 or self._gnss_lag is not None:
                hist = self._hist
                hist.append([t, *self.frame.ned_tuple(ins.lat_deg, ins.lon_deg, ins.h_m), ins.vn, ins.ve, ins.vd])
                keep_s = max(c.gnss_delay_s + c.gnss_vel_delay_s, c.gnss_lag.max_lag_s if self._gnss_lag is not None else 0.0)
                while hist[0][0] < t - keep_s - 0.2:
                    hist.popleft()
            f = ins.f_ned
            self._f_sum[0] += f[0]
            self._f_sum[1] += f[1]
            self._f_sum[2] += f[2]
            self._f_n += 1

    def _ins_init(self, t: float, z, vel, t_ins: float | None = None) -> None:
        c = self.config
        lat, lon, alt = self.frame.geodetic_tuple(*z)
        v = (0.0, 0.0, 0.0)
        if vel is not None:
            v = (vel[0], vel[1], vel[2] if math.isfinite(vel[2]) else 0.0)
        a = self._att
        if t_ins is None:
            t_ins = self._last_imu_t if self._last_imu_t is not None else t
        self.ins = StrapdownIns(t_ins, lat, lon, alt, v, a.roll_rad, a.pitch_rad, a.yaw_rad)
        self._hist.clear()
        kf = KalmanFilter(dim_x=15, dim_z=3)
        sh, sv = 3.0, 5.0
        kf.P = np.diag(
            [sh**2, sh**2, sv**2] + [1.0] * 3 + [c.init_sigma_att_rad**2] * 2 + [c.init_sigma_yaw_rad**2]
            + [c.accel_bias_sigma_mps2**2] * 3 + [c.gyro_bias_sigma_radps**2] * 3
        )
        self._kf = kf
        self._kf_t = t_ins
        self._corr_sums = [0.0] * 9  # sums of dp, dv and dv * t of the corrections since initialisation
        self._ins_epoch += 1
        self._delay_learnt_s = self._gnss_delay_s() if self._gnss_lag is not None else None
        if not self.ahrs_consistent and math.isfinite(self.ahrs_heading_offset_rad):
            self._align_yaw(t_ins)
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0
