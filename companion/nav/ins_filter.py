"""The navigator's INS filter: a 15-state error-state Kalman filter around one :class:`companion.nav.ins.StrapdownIns`,
from one (re)initialisation to the next; the states are listed in companion.nav.outputs.INS_STATE_NAMES.

Errors are true minus estimate: position, velocity, attitude error psi (``C_true = (I + [psi x]) C_est``),
accelerometer bias and gyro bias. Continuous model ``dp' = dv``, ``dv' = -[f_n x] psi - C dba``, ``psi' = -C dbg``,
biases first-order Gauss-Markov. The strapdown equations run for every IMU sample in plain Python; the covariance is
propagated at the output rate (and before each update) with ``Phi = I + F dt + (F dt)^2 / 2`` built from the mean
specific force of the interval (Aziez 2021 eq. 9), and updates use the Joseph-form algebra of companion.nav.kalman
(eqs. 7, 8, 10). After each update the error estimate is fed back into the INS and reset to zero.

The filter keeps a short per-IMU-step history of its position and velocity, shifted by every correction, so a fix
is compared with the state of the epoch it describes (companion.nav.gnss_lag.GnssLatency), and the sums of its
corrections, which give the trajectory the INS would have flown uncorrected (the motion prior scores that).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np

from companion.events import Attitude, Event
from companion.nav.config import NavigatorConfig
from companion.nav.frame import LocalFrame
from companion.nav.gnss_lag import GnssLatency
from companion.nav.imu_accumulator import ImuAccumulator
from companion.nav.ins import StrapdownIns, quat_from_euler
from companion.nav.kalman import KalmanFilter
from companion.nav.linalg import small_inverse
from companion.nav.measurements import InsView, Measurement, selected_columns
from companion.nav.outputs import MeasurementUpdate


def _model(c: NavigatorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The constant parts of the model of eq. 9: F without its attitude and specific-force blocks, I (15 x 15), and
    the process noise per second (times dt at each step)."""
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
    return F, np.eye(15), q


_ZERO_X = np.zeros((15, 1))
_ZERO_X.flags.writeable = False  # the error state between updates (replaced, never changed in place)


class InsFilter:
    """One strapdown INS and its error-state KF. ``emit`` receives a MeasurementUpdate for every measurement offered.

    Started at ``t_ins`` from a position ``z`` (local NED), a velocity (or None: at rest; a NaN vertical: 0) and the
    autopilot's attitude; ``epoch`` tells this INS's records apart from an earlier one's."""

    def __init__(self, config: NavigatorConfig, frame: LocalFrame, latency: GnssLatency, emit: Callable[[Event], None],
                 t_ins: float, z, vel, att: Attitude, epoch: int) -> None:
        c = self.config = config
        self.frame, self.latency, self._emit, self.epoch = frame, latency, emit, epoch
        lat, lon, alt = frame.geodetic_tuple(*z)
        v = (0.0, 0.0, 0.0)
        if vel is not None:
            v = (vel[0], vel[1], vel[2] if math.isfinite(vel[2]) else 0.0)
        self.strapdown = StrapdownIns(t_ins, lat, lon, alt, v, att.roll_rad, att.pitch_rad, att.yaw_rad)
        # (t, n, e, d, vn, ve, vd) per IMU step (history_s + 0.2 s), each less the corrections made before it: every
        # correction shifts the whole history alike, so it is added once to _shift, not to every entry
        self._hist: deque[tuple[float, ...]] = deque()
        self._shift = [0.0] * 6
        self._keep_s = latency.history_s()
        kf = KalmanFilter(dim_x=15, dim_z=3)
        sh, sv = 3.0, 5.0
        kf.P = np.diag(
            [sh**2, sh**2, sv**2] + [1.0] * 3 + [c.init_sigma_att_rad**2] * 2 + [c.init_sigma_yaw_rad**2]
            + [c.accel_bias_sigma_mps2**2] * 3 + [c.gyro_bias_sigma_radps**2] * 3
        )
        self.kf = kf
        self.t_s = t_ins  # time the covariance has been propagated to
        self._corr_sums = [0.0] * 9  # sums of dp, dv and dv * t of the corrections since initialisation
        self._delay_learnt_s = latency.delay_s() if latency.estimator is not None else None
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0
        self._model = _model(c)
        self._F = self._model[0].copy()
        self._acc = ImuAccumulator()
        self._step_s = 1.0 / c.ins_rate_hz

    # ------------------------------------------------------------------ propagation
    def step_imu(self, t: float, accel_frd_mps2, gyro_frd_radps) -> None:
        """One IMU sample. Samples faster than ``ins_rate_hz`` are summed (coning and sculling, ImuAccumulator) and
        the strapdown steps once per its period; slower ones step it each. A stall longer than ``max_imu_step_s``
        (ArduPilot stops logging ~2 s at arming) is not integrated through: the covariance is brought to the stall's
        start and widened for it."""
        ins, acc = self.strapdown, self._acc
        dt = t - (acc.t_s if acc.n else ins.t_s)
        if dt <= 0.0:
            return
        if dt >= 0.75 * self._step_s:  # a sample at (or below) the strapdown's rate, or after a stall: a step of its own
            self.flush_imu()
            self._step(t, accel_frd_mps2, gyro_frd_radps)
            return
        ba, bg = ins.ba, ins.bg
        acc.add(t, dt, (accel_frd_mps2[0] - ba[0], accel_frd_mps2[1] - ba[1], accel_frd_mps2[2] - ba[2]),
                (gyro_frd_radps[0] - bg[0], gyro_frd_radps[1] - bg[1], gyro_frd_radps[2] - bg[2]))
        if acc.dt_s >= self._step_s - 0.5 * dt:  # the step closest to the strapdown's period
            self.flush_imu()

    def flush_imu(self) -> None:
        """Step the strapdown by the samples summed since its last step (a measurement or an output needs its state)."""
        acc = self._acc
        if acc.n:
            t = acc.t_s
            _dt, rot, dv = acc.take()
            if self.strapdown.step_increments(t, rot, dv) > 0:
                self._stepped(t)

    def _step(self, t: float, accel_frd_mps2, gyro_frd_radps) -> None:
        c, ins = self.config, self.strapdown
        dt = t - ins.t_s
        if dt > c.max_imu_step_s:
            self.predict(ins.t_s)
            q = self.kf.P
            for i in range(3, 6):
                q[i, i] += (c.kinematic_accel_sigma_mps2 * dt) ** 2
            for i in range(6, 9):
                q[i, i] += (c.gyro_noise_radps_rthz**2) * dt + 1e-4
            speed = math.sqrt(ins.vn**2 + ins.ve**2 + ins.vd**2)
            for i in range(3):
                q[i, i] += (speed * dt + 0.5 * c.kinematic_accel_sigma_mps2 * dt * dt) ** 2
            ins.coast(t - 0.02)
            self.t_s = ins.t_s
        if ins.step(t, accel_frd_mps2, gyro_frd_radps) > 0:
            self._stepped(t)

    def _stepped(self, t: float) -> None:
        """After a strapdown step to t: its history entry and the specific force for the next covariance step."""
        ins = self.strapdown
        if self._keep_s is not None:
            hist, sh = self._hist, self._shift
            n, e, d = self.frame.ned_tuple(ins.lat_deg, ins.lon_deg, ins.h_m)
            hist.append((t, n - sh[0], e - sh[1], d - sh[2], ins.vn - sh[3], ins.ve - sh[4], ins.vd - sh[5]))
            while hist[0][0] < t - self._keep_s - 0.2:
                hist.popleft()
        f = ins.f_ned
        self._f_sum[0] += f[0]
        self._f_sum[1] += f[1]
        self._f_sum[2] += f[2]
        self._f_n += 1

    def predict(self, t: float) -> None:
        """Propagate the error covariance to ``t`` (eq. 9) with the interval's mean specific force."""
        self.flush_imu()
        dt = t - self.t_s
        if dt <= 0:
            return
        ins = self.strapdown
        n = self._f_n
        if n:
            fs = self._f_sum
            fx, fy, fz = fs[0] / n, fs[1] / n, fs[2] / n
        else:
            fx, fy, fz = ins.f_ned
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0
        F = self._F  # the model's constant blocks, and these set in place
        F[3:6, 6:9] = ((0.0, fz, -fy), (-fz, 0.0, fx), (fy, -fx, 0.0))  # -[f x]
        F[3:6, 9:12] = F[6:9, 12:15] = ins.dcm_neg()
        Fd = F * dt
        phi = Fd @ Fd  # phi = I + F dt + (F dt)^2 / 2
        phi *= 0.5
        phi += Fd
        phi.flat[::16] += 1.0
        kf = self.kf  # P = phi P phi' + Q dt; the error state x is zero between updates, and stays so
        P = phi @ kf.P @ phi.T
        P.flat[::16] += self._model[2] * dt
        kf.P = P
        self.t_s = t

    # ------------------------------------------------------------------ measurements
    def apply(self, m: Measurement) -> tuple[bool, np.ndarray]:
        """The one update of the error-state KF (eqs. 7, 8, 10): predict to the measurement, gate, emit a
        MeasurementUpdate, update and feed the error estimate back into the INS. Returns (accepted, innovation)."""
        self.predict(max(m.t_s, self.t_s))
        pos, vel = self.state_at(m.t_s, m.delay_s)
        y, H, R = m.compute_ins(InsView(pos, vel, self.strapdown.dcm()))
        kf = self.kf
        P = kf.P
        cols = selected_columns(H)
        if cols is None:
            PHT = P @ H.T
            HPHT = H @ PHT
        else:  # H picks consecutive states: P H' and H P H' are slices
            PHT = P[:, cols]
            HPHT = P[cols, cols]
        S = HPHT + R
        S_inv = small_inverse(S)
        Rg = m.R_gate()
        nis = float(y @ (S_inv if Rg is None else small_inverse(HPHT + np.maximum(R, Rg))) @ y)
        ok = nis <= m.gate_chi2
        self._emit(
            MeasurementUpdate(m.t_s, m.kind, "ins", tuple(y.tolist()), tuple(np.sqrt(R.diagonal()).tolist()), nis,
                              m.gate_chi2, ok)
        )
        if not ok:
            return False, y
        # (x is zero between updates: y = z - H x)
        dx = kf.update_innovation(y, R, H, PHT, S, m.gain_rows_ins(), cols, S_inv).tolist()  # Python floats: the
        # strapdown INS (plain Python, every IMU sample) then runs on floats rather than numpy scalars
        self.correct(dx[0:3], dx[3:6], dx[6:9], dx[9:12], dx[12:15])
        kf.x = _ZERO_X
        return True, y

    def correct(self, dp, dv, psi, dba, dbg) -> None:
        """Feed an error estimate back into the INS and shift the delay history with it."""
        self.flush_imu()
        self.strapdown.correct(dp, dv, psi, dba, dbg)
        t, cs = self.strapdown.t_s, self._corr_sums
        for a in range(3):
            cs[a] += dp[a]
            cs[3 + a] += dv[a]
            cs[6 + a] += dv[a] * t
        sh = self._shift
        for a in range(3):
            sh[a] += dp[a]
            sh[3 + a] += dv[a]

    def state_at(self, t: float, delay_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """INS position (local NED) and velocity at the epoch ``t - delay`` (default: the GNSS latency) a measurement
        stamped t describes: from the history when the epoch is in the past, else extrapolated at constant velocity."""
        ins = self.strapdown
        te = t - (self.latency.delay_s() if delay_s is None else delay_s)
        hist = self._hist
        if hist and te < hist[-1][0]:
            sh = np.array(self._shift)
            if te <= hist[0][0]:
                x = np.array(hist[0][1:]) + sh
                return x[0:3], x[3:6]
            for i in range(len(hist) - 1, 0, -1):
                a = hist[i - 1]
                if a[0] <= te:
                    b = hist[i]
                    w = (te - a[0]) / (b[0] - a[0]) if b[0] > a[0] else 1.0
                    pa, pb = np.array(a[1:]), np.array(b[1:])
                    x = pa + w * (pb - pa) + sh
                    return x[0:3], x[3:6]
        n, e, d = self.frame.ned_tuple(ins.lat_deg, ins.lon_deg, ins.h_m)
        dt = te - ins.t_s
        return np.array([n + ins.vn * dt, e + ins.ve * dt, d + ins.vd * dt]), np.array([ins.vn, ins.ve, ins.vd])

    def relearn_if_latency_moved(self) -> None:
        """Before a GNSS update: when the modelled latency moved by more than ``gnss_lag.relearn_s`` since this filter
        last re-learnt, widen its tilt and accelerometer-bias uncertainty (to their initial sigmas): the filter
        explained the mis-modelled lag with those states, and with a tight covariance it would keep the wrong values
        for minutes, and drift on them once GNSS stops."""
        if self.latency.estimator is None:
            return
        d = self.latency.delay_s()
        if self._delay_learnt_s is not None and abs(d - self._delay_learnt_s) <= self.config.gnss_lag.relearn_s:
            return
        if self._delay_learnt_s is not None:
            c = self.config
            P = self.kf.P
            for i, s in ((6, c.init_sigma_att_rad), (7, c.init_sigma_att_rad), (9, c.accel_bias_sigma_mps2),
                         (10, c.accel_bias_sigma_mps2), (11, c.accel_bias_sigma_mps2)):
                if P[i, i] < s * s:
                    P[i, :] *= 0.0
                    P[:, i] *= 0.0
                    P[i, i] = s * s
        self._delay_learnt_s = d

    # ------------------------------------------------------------------ what others read
    def position_ned(self) -> tuple[float, float, float]:
        ins = self.strapdown
        return self.frame.ned_tuple(ins.lat_deg, ins.lon_deg, ins.h_m)

    def trajectory_record(self) -> tuple[tuple[float, ...], ...]:
        """(position, velocity, free position, free velocity) now: the free ones as if no correction had been applied
        since this INS started (each correction (dp, dv) at t_k moved the position by dp + dv (t - t_k))."""
        i = self.strapdown
        p, v = self.position_ned(), i.vel_ned
        t, cs = i.t_s, self._corr_sums
        return (p, v, tuple(p[a] - cs[a] - cs[3 + a] * t + cs[6 + a] for a in range(3)),
                tuple(v[a] - cs[3 + a] for a in range(3)))

    # ------------------------------------------------------------------ resets
    def keep_biases(self, other: InsFilter) -> None:
        """Take another INS's biases and their covariance (a property of the sensor, kept across a restart)."""
        self.strapdown.ba, self.strapdown.bg = list(other.strapdown.ba), list(other.strapdown.bg)
        self.kf.P[9:15, 9:15] = other.kf.P[9:15, 9:15].copy()

    def reset_to_fix(self, t: float, dp, fix_vel, sigma_h_m: float, sigma_v_m: float) -> np.ndarray:
        """Reset position by ``dp`` and each velocity component the fix has (GPS_RAW_INT has no vertical one) to it,
        with the fix's covariance x ``reset_cov_scale`` (a position reset alone keeps a wrong velocity, and the output
        leaves its stated accuracy). Returns the velocity jump."""
        c = self.config
        kf = self.kf
        dv = np.zeros(3)
        var_v = np.full(3, c.gnss_vel_sigma_mps**2 * c.reset_cov_scale + 1.0)
        if fix_vel is not None:
            v_ins = self.state_at(t)[1]
            for i in range(3):
                if math.isfinite(fix_vel[i]):
                    dv[i] = fix_vel[i] - v_ins[i]
                    var_v[i] -= 1.0
        kf.P[0:6, :] = 0.0
        kf.P[:, 0:6] = 0.0
        kf.P[0:3, 0:3] = np.diag([sigma_h_m**2, sigma_h_m**2, sigma_v_m**2]) * c.reset_cov_scale
        kf.P[3:6, 3:6] = np.diag(var_v)
        self.correct(dp, dv, (0, 0, 0), (0, 0, 0), (0, 0, 0))
        return dv

    def reset_tilt(self, psi_n_rad: float, psi_e_rad: float) -> None:
        """Rotate the tilt by psi and widen its variance (initial sigma, x ``reset_cov_scale``)."""
        c = self.config
        self.correct((0, 0, 0), (0, 0, 0), (psi_n_rad, psi_e_rad, 0.0), (0, 0, 0), (0, 0, 0))
        P = self.kf.P
        P[6:8, :] = 0.0
        P[:, 6:8] = 0.0
        P[6, 6] = P[7, 7] = c.init_sigma_att_rad**2 * c.reset_cov_scale

    def reset_attitude(self, t: float, roll_rad: float, pitch_rad: float, yaw_rad: float) -> None:
        """Replace the attitude, with its initial uncertainty."""
        c = self.config
        self.predict(max(t, self.t_s))
        self.strapdown.q = quat_from_euler(roll_rad, pitch_rad, yaw_rad)
        P = self.kf.P
        P[6:9, :] = 0.0
        P[:, 6:9] = 0.0
        P[6, 6] = P[7, 7] = c.init_sigma_att_rad**2
        P[8, 8] = c.init_sigma_yaw_rad**2

    def align_yaw(self, t: float, target_yaw_rad: float) -> float | None:
        """Coarse in-motion alignment (Groves 2013 sec. 14.2; the KF's psi is a small-angle state and absorbs a large
        heading error only slowly): rotate the heading to the target when it is further than ``yaw_align_min_deg``
        and 3 x its sigma; the yaw variance is then ``yaw_align_sigma_rad``^2. Returns the rotation, or None."""
        c = self.config
        d = (target_yaw_rad - self.strapdown.euler()[2] + math.pi) % (2 * math.pi) - math.pi
        sig = math.sqrt(max(self.kf.P[8, 8], 0.0))
        if abs(d) < max(math.radians(c.yaw_align_min_deg), 3.0 * sig):
            return None
        self.predict(max(t, self.t_s))
        self.correct((0, 0, 0), (0, 0, 0), (0.0, 0.0, d), (0, 0, 0), (0, 0, 0))  # exact rotation about down
        P = self.kf.P
        P[8, :] = 0.0
        P[:, 8] = 0.0
        P[8, 8] = c.yaw_align_sigma_rad**2
        return d
