"""Loosely coupled GNSS / KNN-predictor / INS integration: the streaming :class:`Navigator` stage.

The paper (Aziez 2021, fig. 2, eqs. 5-10) fuses the KNN predictor's 10 Hz GNSS stream with the INS in a
Kalman filter; it integrates ultra-tightly at the correlator level (eqs. 11-34), which needs I/Q samples a
flight log does not have. This module does the loosely coupled equivalent on position/velocity fixes:

* **INS mode**: error-state KF (15 states: position, velocity, attitude error psi, accelerometer bias,
  gyro bias; see :data:`companion.nav.outputs.INS_STATE_NAMES`) around
  :class:`companion.nav.ins.StrapdownIns`. Errors are true minus estimate, attitude
  ``C_true = (I + [psi x]) C_est``; continuous model ``dp' = dv``, ``dv' = -[f_n x] psi - C dba``,
  ``psi' = -C dbg``, biases first-order Gauss-Markov. The strapdown equations run for every IMU sample
  in plain Python; the KF covariance is propagated at the 10 Hz output rate (and before each update)
  with ``Phi = I + F dt + (F dt)^2 / 2`` built from the mean specific force of the interval (eq. 9), and
  updates use filterpy's algebra (eqs. 7, 8, 10). After each update the error estimate is fed back into
  the INS and reset to zero.
* **Kinematic mode**: a 6-state constant-velocity KF (white-noise acceleration) on the same
  measurements. Used when the source has no IMU, or its IMU rate is below ``min_imu_rate_hz`` (a
  telemetry log streams RAW_IMU at ~1 Hz: far too slow to integrate), or no attitude is available to
  initialise the INS. The choice and its reason are emitted as :class:`ModeChange` and exposed as
  :attr:`Navigator.mode` / :attr:`Navigator.mode_reason`. The kinematic filter always runs alongside, so
  the navigator can fall back at once if the IMU stream stops in flight.

Measurements: real GNSS positions (1-sigma from ``h_acc_m``/``v_acc_m``, else HDOP/VDOP x UERE, else a
default), GNSS NED velocity when the receiver gives it, KNN predictor points at each 10 Hz tick after the
last fix (with the predictor's own growing sigma), and optionally the autopilot's attitude (its AHRS keeps
tilt from gravity and heading from the compass when GNSS is lost). Each is gated on its normalised
innovation squared (chi-square, 3 dof); a glitch is rejected. If GNSS is rejected continuously for
``gate_reset_s`` the filter accepts it again with its position covariance reset (a real step, not a glitch).

Event order: sources can deliver different message types slightly out of time order. Events pass a
reorder buffer of ``reorder_window_s`` (heap on time, type priority IMU < attitude < GNSS, arrival
order) so the result does not depend on arrival order within the window: :func:`run_navigator` on a
sorted list and event-by-event :meth:`Navigator.process` give identical outputs.

Pure: no asyncio, no pymavlink, no wall clock.
"""

from __future__ import annotations

import bisect
import heapq
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import KalmanFilter

from companion.nav.ins import StrapdownIns, dcm_from_quat, quat_from_euler
from companion.nav.knn_predictor import KnnConfig, KnnPredictor
from companion.nav.outputs import (
    FrameInfo,
    FusedState,
    MeasurementUpdate,
    ModeChange,
    PredictorPoint,
)
from companion.constants import CHI2_1DOF_999, CHI2_2DOF_999, CHI2_3DOF_999, receiver_sigma
from companion.events import Attitude, AutopilotAltitude, Event, GnssFix, ImuSample, PositionFix
from companion.nav.frame import LocalFrame, radii_m
from companion.pipeline.stage import Stage



@dataclass(frozen=True)
class NavigatorConfig:
    """Navigator settings. Defaults are for a small ArduPilot multicopter with a u-blox receiver.

    Noise levels: ArduPilot logs its IMU as 50 Hz filtered samples on a vibrating airframe, so the
    effective white noise is far above the sensor datasheet (per-sample std ~1 m/s^2 and ~0.03 rad/s in
    the shared logs, i.e. ~0.15 m/s^2/rtHz and ~0.005 rad/s/rtHz). The defaults are twice that: chosen on
    the shared logs' in-between fill and 4/8 s blockages (replay/gap_filling.py), where they did a few per
    cent better than 1x; there is no held-out log, so treat that tuning as in-sample.
    ``predictor_sigma_scale``: a predictor point extrapolates the last fix, so its error is correlated with
    that fix, which the filter has already used; treating it as independent makes the filter
    overconfident (position NEES ~2 per axis on simulated flights). Its sigma is scaled by this factor.
    ``predictor_decorrelate``: the k-th point fused after a fix has its variance multiplied by k: the
    points of one recursion share the anchor's and the neighbours' error, so 80 points in an 8 s blockage
    must not count as 80 independent measurements (that pulled the INS towards the predictor's drift).
    ``gnss_sigma_model``: truth and product frame are the receiver's own solution, whose error wanders
    slowly (metres over minutes) but is smooth from fix to fix. "short_term" updates with the
    fix-to-fix noise (``short_term_sigma_*`` x max(1, HDOP)) so the filter follows the receiver instead of
    averaging it; "accuracy" uses the receiver's accuracy (h_acc, or HDOP x UERE), right for white fix
    noise. The innovation gate always uses the accuracy sigma, so a glitch is judged on the receiver's own
    error scale. ``fuse_attitude_yaw``: off by default: in the Erle log the autopilot's heading is ~90 deg
    from the heading the GNSS-aided INS settles at, and fusing it ruins the fill; the tilt is fused.
    ``gnss_delay_s``: a fix stamped t describes the vehicle at t - delay (receiver latency; ArduPilot's EKF
    assumes ~0.2 s for a u-blox). Fixes and predictor points are compared with the INS state of that
    epoch, kept in a short per-IMU-step history that follows every correction. On the shared logs the
    IMU accelerations best match the GNSS velocity changes ~0.2 s earlier, but modelling it (0.15 s) helped
    8 s blockages (3.8 vs 4.0 m) and hurt the 1 Hz in-between fill (0.33 vs 0.29 m), so the default is 0.
    ``ahrs_check``: the autopilot attitude is only as good as its heading. A DCM AHRS corrects tilt with
    GNSS acceleration resolved through its heading, so a wrong heading (the Erle PXF log: compass ~90 deg
    off) also corrupts its roll/pitch during manoeuvres. The navigator checks the autopilot's heading
    against GNSS, independently of its own INS state: horizontal GNSS velocity changes over
    >= ``ahrs_check_interval_s`` are compared with the integral of the IMU specific force resolved with
    the autopilot's attitude over the same interval (gravity and Coriolis have ~no horizontal part);
    with exponential forgetting (``ahrs_check_tau_s``) the heading offset is the angle of
    sum(dv_gnss * conj(dv_ahrs)) (complex N + iE), valid once both sums of squares exceed
    ``ahrs_check_min_dv_mps``^2 and the normalised coherence is >= ``ahrs_check_min_coherence``. If the
    offset exceeds ``ahrs_max_offset_deg`` the autopilot attitude is declared inconsistent (until the
    offset falls below ``ahrs_ok_offset_deg``). Its tilt is then fused with a sigma that includes the error
    a heading offset d induces: the AHRS levels on an acceleration rotated by d, off by 2 sin(d/2) |a_h|,
    i.e. a tilt error of about 2 sin(d/2) a_rms / g, with a_rms the recent RMS horizontal GNSS
    acceleration (added in quadrature to ``att_sigma_tilt_rad``). The INS heading, which was
    initialised from the autopilot, is re-aligned to autopilot heading + offset (a coarse in-motion
    alignment, cf. Groves 2013 sec. 14.2; the KF's psi is a small-angle state and absorbs a large heading
    error only slowly) when it differs from that by more than ``yaw_align_min_deg`` and 3 x the KF's yaw
    sigma; the yaw variance is then reset to ``yaw_align_sigma_rad``^2.
    ``hold_prior``: during a blockage the INS error grows without bound (t^2 .. t^3), while a loitering or
    circling multicopter stays near where it was. The navigator learns, causally from the GNSS fixes it has
    accepted, the vehicle's mean squared displacement per axis after a lag tau (D(tau) at whole-second
    lags up to ``hold_prior_max_lag_s``, exponential forgetting ``hold_prior_tau_s``): the last fix is then
    an estimate of the current position with variance D(age) + fix variance, independent of the INS
    drift. From ``hold_prior_min_age_s`` after the last fix, the output position is the product of the two
    Gaussians (per axis: inverse-variance weights from the KF covariance and D), so it moves toward the
    last fix only as far as the filter's own covariance says its drift exceeds the vehicle's typical
    excursion. Output only: the INS and KF state are not changed, so aiding resumes from the INS.
    """

    knn: KnnConfig = field(default_factory=KnnConfig)
    imu_index: int = 0
    gnss_instance: int = 0  # GPS1 only (a second receiver may be a different, unrelated source)
    output_rate_hz: float = 10.0
    min_imu_rate_hz: float = 20.0
    rate_window_s: float = 2.0
    imu_timeout_s: float = 3.0  # no IMU for this long in INS mode -> kinematic fallback
    max_imu_step_s: float = 0.1  # longer IMU gaps are not integrated through (covariance inflated)
    reorder_window_s: float = 0.25
    fuse_predictor: bool = True
    predictor_min_age_s: float = 0.0
    predictor_sigma_scale: float = 2.0
    predictor_decorrelate: bool = True
    fuse_attitude: bool = True
    fuse_attitude_yaw: bool = False
    fuse_gnss_velocity: bool = True
    gnss_delay_s: float = 0.0
    gate_chi2: float = CHI2_3DOF_999
    gate_reset_s: float = 5.0
    gnss_sigma_model: str = "short_term"  # "short_term" | "accuracy"
    position_fix_gate_chi2: float = CHI2_2DOF_999  # own gate for PositionFix (horizontal, 2 dof); no reset
    short_term_sigma_h_m: float = 0.3
    short_term_sigma_v_m: float = 0.5
    uere_h_m: float = 1.5
    uere_v_m: float = 2.5
    default_sigma_h_m: float = 2.5
    default_sigma_v_m: float = 4.0
    min_sigma_h_m: float = 0.3
    gnss_vel_sigma_mps: float = 0.3
    att_sigma_tilt_rad: float = 0.03
    att_sigma_yaw_rad: float = 0.1
    accel_noise_mps2_rthz: float = 0.3
    gyro_noise_radps_rthz: float = 0.01
    accel_bias_sigma_mps2: float = 0.3
    gyro_bias_sigma_radps: float = 0.02
    bias_tau_s: float = 300.0
    init_sigma_att_rad: float = 0.05
    init_sigma_yaw_rad: float = 0.2
    kinematic_accel_sigma_mps2: float = 2.0
    ahrs_check: bool = True
    ahrs_check_interval_s: float = 0.9
    ahrs_check_tau_s: float = 20.0
    ahrs_check_min_dv_mps: float = 2.0
    ahrs_check_min_coherence: float = 0.5
    ahrs_max_offset_deg: float = 30.0
    ahrs_ok_offset_deg: float = 15.0
    yaw_align_min_deg: float = 15.0
    yaw_align_sigma_rad: float = 0.1
    att_fuse_interval_s: float = 0.0
    # vertical aid from the autopilot's altitude (AutopilotAltitude, GLOBAL_POSITION_INT; barometric on ArduPilot):
    # while GNSS positions arrive, only the offset between that altitude and ours is learnt (datum, baro bias; time
    # constant alt_offset_tau_s); once none has been fused for alt_gnss_gap_s, the offset-corrected altitude is fused
    # with alt_sigma_m. Off by default (a short blockage does not need it); gravity_nav_config turns it on.
    fuse_autopilot_alt: bool = False
    alt_sigma_m: float = 3.0
    alt_gnss_gap_s: float = 2.0
    alt_offset_tau_s: float = 60.0
    hold_prior: bool = False
    hold_prior_min_age_s: float = 1.5
    hold_prior_max_lag_s: int = 60
    hold_prior_tau_s: float = 120.0

    def __post_init__(self) -> None:
        if self.output_rate_hz <= 0 or self.min_imu_rate_hz <= 0:
            raise ValueError("rates must be positive")
        if self.reorder_window_s < 0:
            raise ValueError("reorder_window_s must be >= 0")
        if self.gnss_sigma_model not in ("short_term", "accuracy"):
            raise ValueError("gnss_sigma_model must be 'short_term' or 'accuracy'")


_PRIO = {ImuSample: 0, Attitude: 1, GnssFix: 2}


def _skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class Navigator(Stage):
    """Streaming gap-filling stage: ``process(event) -> list[output]``, then ``finish()``."""

    def __init__(self, config: NavigatorConfig | None = None) -> None:
        self.config = c = config or NavigatorConfig()
        self.mode = "init"
        self.mode_reason = "waiting for the first GNSS fix"
        self._reason_key = "init"
        self.predictor = KnnPredictor(c.knn)
        self.frame: LocalFrame | None = None
        self._heap: list = []
        self._seq = 0
        self._max_t = -math.inf
        self._out: list[Event] = []
        self._t0: float | None = None  # first event time
        self._imu_times: deque[float] = deque()
        self._last_imu_t: float | None = None
        self._att: Attitude | None = None
        self._tick_dt = 1.0 / c.output_rate_hz
        self._next_tick: int | None = None
        self._last_fix_t: float | None = None
        self._alt_off: float | None = None  # autopilot altitude minus ours, learnt while GNSS aids
        self._alt_off_t = -math.inf
        self._n_pred_fused = 0
        self._pred_anchor: float | None = None
        self._reject_since: float | None = None
        # INS filter
        self.ins: StrapdownIns | None = None
        self._kf: KalmanFilter | None = None
        self._kf_t = 0.0
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0
        self._hist: deque[list[float]] = deque()  # [t, n, e, d, vn, ve, vd] per IMU step, last delay + 0.2 s
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
        self._msd = np.zeros((c.hold_prior_max_lag_s + 1, 3))
        self._msd_w = np.zeros(c.hold_prior_max_lag_s + 1)
        self._msd_t: float | None = None
        # kinematic filter
        self._kin: KalmanFilter | None = None
        self._kin_t = 0.0
        # per-output bookkeeping
        self._used: set[str] = set()
        self._last_innov: tuple[float, ...] = (math.nan, math.nan, math.nan)
        self._n_rejected = 0

    # ------------------------------------------------------------------ stream interface
    def process(self, event: Event) -> list[Event]:
        """Consume one event; returns the outputs that became final."""
        self._seq += 1
        heapq.heappush(self._heap, (event.t_s, _PRIO.get(type(event), 3), self._seq, event))
        if event.t_s > self._max_t:
            self._max_t = event.t_s
        horizon = self._max_t - self.config.reorder_window_s
        while self._heap and self._heap[0][0] <= horizon:
            self._handle(heapq.heappop(self._heap)[3])
        out, self._out = self._out, []
        return out

    def metadata(self) -> dict[str, str]:
        """The mode the navigator ended in and why (INS, or the kinematic fallback)."""
        return {k: str(v) for k, v in (("mode", self.mode), ("mode_reason", self.mode_reason)) if v}

    def finish(self) -> list[Event]:
        """Flush the reorder buffer and emit the remaining outputs up to the last event time."""
        while self._heap:
            self._handle(heapq.heappop(self._heap)[3])
        if self._next_tick is not None and self._max_t > -math.inf:
            self._run_ticks(self._max_t, inclusive=True)
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ dispatch
    def _handle(self, ev: Event) -> None:
        t = ev.t_s
        if self._t0 is None:
            self._t0 = t
        if self._next_tick is not None:
            self._run_ticks(t, inclusive=False)
        if isinstance(ev, ImuSample):
            if ev.imu_index == self.config.imu_index:
                self._on_imu(ev)
        elif isinstance(ev, GnssFix):
            if ev.has_position and ev.alt_msl_m is not None and ev.instance == self.config.gnss_instance:
                self._on_fix(ev)
        elif isinstance(ev, PositionFix):
            self._on_position_fix(ev)
        elif isinstance(ev, AutopilotAltitude):
            if self.config.fuse_autopilot_alt:
                self._on_altitude(ev)
        elif isinstance(ev, Attitude):
            self._att = ev
            if self.config.ahrs_check:
                C = dcm_from_quat(quat_from_euler(ev.roll_rad, ev.pitch_rad, ev.yaw_rad))
                self._att_c = tuple(float(x) for x in C[0:2].ravel())
            if (self.mode == "ins" and self.config.fuse_attitude
                    and ev.t_s - self._att_fused_t >= self.config.att_fuse_interval_s):
                self._att_fused_t = ev.t_s
                self._ins_attitude_update(ev)

    def _set_mode(self, t: float, mode: str, reason: str, key: str) -> None:
        """Switch mode; a ModeChange is emitted when the mode or the kind of reason changes."""
        if mode != self.mode or key != self._reason_key:
            self.mode, self.mode_reason, self._reason_key = mode, reason, key
            self._out.append(ModeChange(t, mode, reason, self._imu_rate(t)))

    def _imu_rate(self, t: float) -> float:
        w = self.config.rate_window_s
        while self._imu_times and self._imu_times[0] < t - w:
            self._imu_times.popleft()
        return len(self._imu_times) / w

    # ------------------------------------------------------------------ IMU
    def _on_imu(self, ev: ImuSample) -> None:
        c = self.config
        t = ev.t_s
        self._imu_times.append(t)
        prev_t = self._last_imu_t
        self._last_imu_t = t
        ac = self._att_c
        if ac is not None and prev_t is not None and 0 < t - prev_t <= c.max_imu_step_s:
            dt = t - prev_t
            a = ev.accel_frd_mps2
            self._sf_dv[0] += (ac[0] * a[0] + ac[1] * a[1] + ac[2] * a[2]) * dt
            self._sf_dv[1] += (ac[3] * a[0] + ac[4] * a[1] + ac[5] * a[2]) * dt
        ins = self.ins
        if ins is None or self.mode != "ins":
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
            if c.gnss_delay_s > 0:
                hist = self._hist
                hist.append([t, *self._to_ned(ins.lat_deg, ins.lon_deg, ins.h_m), ins.vn, ins.ve, ins.vd])
                while hist[0][0] < t - c.gnss_delay_s - 0.2:
                    hist.popleft()
            f = ins.f_ned
            self._f_sum[0] += f[0]
            self._f_sum[1] += f[1]
            self._f_sum[2] += f[2]
            self._f_n += 1

    # ------------------------------------------------------------------ GNSS
    def _fix_sigmas(self, ev: GnssFix) -> tuple[float, float, float, float]:
        """(update sigma h, v, gate sigma h, v). The gate always uses the receiver's accuracy."""
        c = self.config
        sh, sv = receiver_sigma(ev, c.uere_h_m, c.uere_v_m)
        if sh is None:
            sh = c.default_sigma_h_m
        if sv is None:
            sv = ev.hdop * c.uere_v_m if ev.hdop is not None and ev.hdop > 0 else c.default_sigma_v_m
        gh, gv = max(sh, c.min_sigma_h_m), max(sv, c.min_sigma_h_m)
        if c.gnss_sigma_model == "short_term":
            scale = max(1.0, ev.hdop) if ev.hdop is not None and ev.hdop > 0 else 2.0
            return c.short_term_sigma_h_m * scale, c.short_term_sigma_v_m * scale, gh, gv
        return gh, gv, gh, gv

    def _to_ned(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        return (
            math.radians(lat_deg - self._ref[0]) * self._rm,
            math.radians((lon_deg - self._ref[1] + 180.0) % 360.0 - 180.0) * self._rn_cos,
            -(alt_m - self._ref[2]),
        )

    def _from_ned(self, n: float, e: float, d: float) -> tuple[float, float, float]:
        lat = self._ref[0] + math.degrees(n / self._rm)
        lon = (self._ref[1] + math.degrees(e / self._rn_cos) + 180.0) % 360.0 - 180.0
        return lat, lon, self._ref[2] - d

    def _on_fix(self, ev: GnssFix) -> None:
        c = self.config
        t = ev.t_s
        if self.frame is None:
            self.frame = LocalFrame(ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
            self._ref = (ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
            rm, rn = (float(x) for x in radii_m(math.radians(ev.lat_deg)))
            self._rm = rm + ev.alt_msl_m
            self._rn_cos = (rn + ev.alt_msl_m) * math.cos(math.radians(ev.lat_deg))
            self._out.append(FrameInfo(t, ev.lat_deg, ev.lon_deg, ev.alt_msl_m))
        z = self._to_ned(ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
        sh, sv, gh, gv = self._fix_sigmas(ev)
        vel = None
        if ev.vel_n_mps is not None and ev.vel_e_mps is not None:
            vel = (ev.vel_n_mps, ev.vel_e_mps, ev.vel_d_mps if ev.vel_d_mps is not None else math.nan)
        self._update_mode(t, ev, z, vel)
        accepted = True
        if c.ahrs_check and vel is not None:
            self._ahrs_check(t, vel)
        if self.mode == "ins":
            accepted = self._ins_position_update(t, z, sh, sv, "gnss_pos", (gh, gv))
            if accepted and vel is not None and c.fuse_gnss_velocity and math.isfinite(vel[2]):
                self._ins_velocity_update(t, vel, c.gnss_vel_sigma_mps)
        if self._kin is None:
            self._kin_init(t, z, vel)
        else:
            acc_k = self._kin_update(t, z, sh, sv, "gnss_pos", record=self.mode != "ins", gate_sigma=(gh, gv))
            if self.mode != "ins":
                accepted = acc_k
        if accepted:
            self._used.add("gnss")
            self._last_fix_t = t
            if c.hold_prior:
                self._learn_motion(t, z, sh, sv)
            self.predictor.add_fix(t, z, sh, sv, None if vel is None or not math.isfinite(vel[2]) else vel)
        if self._next_tick is None:
            self._next_tick = math.floor(t / self._tick_dt) + 1

    def _on_altitude(self, ev: AutopilotAltitude) -> None:
        """The autopilot's altitude: learn its offset from ours while GNSS aids, fuse it (1-dof gate) once GNSS is gone."""
        if self.mode != "ins" or self.frame is None or not math.isfinite(ev.alt_msl_m):
            return
        c, t = self.config, ev.t_s
        self._ins_predict(max(t, self._kf_t))
        down = float(self._ins_state_at(t, delay_s=0.0)[0][2])
        alt_ins = self._ref[2] - down
        if self._last_fix_t is not None and t - self._last_fix_t <= c.alt_gnss_gap_s:
            off = ev.alt_msl_m - alt_ins
            if self._alt_off is None:
                self._alt_off = off
            else:
                self._alt_off += (off - self._alt_off) * min(1.0, max(0.0, t - self._alt_off_t) / c.alt_offset_tau_s)
            self._alt_off_t = t
            return
        if self._alt_off is None:
            return  # never seen beside GNSS: its datum is unknown
        H = np.zeros((1, 15))
        H[0, 2] = 1.0
        y = np.array([(self._ref[2] - (ev.alt_msl_m - self._alt_off)) - down])
        if self._ins_apply(H, y, np.array([[c.alt_sigma_m**2]]), "altitude", t, gate_chi2=CHI2_1DOF_999):
            self._used.add("altitude")

    def _on_position_fix(self, ev: PositionFix) -> None:
        """A non-GNSS horizontal position measurement (e.g. a gravity-matching fix) at its own epoch.

        Fused with its own sigmas and its own 2-dof gate (no reset on persistent rejection: a bad matcher
        must not drag the solution); the GNSS predictor, the motion prior and the fix age are untouched."""
        if self.frame is None or self.mode == "init":
            return  # no frame / no filter yet: GNSS starts the navigator
        sn, se = float(ev.sigma_n_m), float(ev.sigma_e_m)
        if not (math.isfinite(ev.lat_deg) and math.isfinite(ev.lon_deg) and sn > 0 and se > 0
                and math.isfinite(sn) and math.isfinite(se)):
            return
        t = ev.t_s
        z = np.array(self._to_ned(ev.lat_deg, ev.lon_deg, self._ref[2])[:2])
        R = np.diag([sn**2, se**2])
        if self.mode == "ins":
            self._ins_predict(max(t, self._kf_t))
            H = np.zeros((2, 15))
            H[:, 0:2] = np.eye(2)
            y = z - self._ins_state_at(t, delay_s=0.0)[0][:2]
            ok = self._ins_apply(H, y, R, "position_fix", t, gate_chi2=self.config.position_fix_gate_chi2)
        else:
            if self._kin is None:
                return
            self._kin_predict(max(t, self._kin_t))
            kf = self._kin
            H = np.zeros((2, 6))
            H[:, 0:2] = np.eye(2)
            y = z - kf.x.ravel()[0:2]
            nis = float(y @ np.linalg.solve(H @ kf.P @ H.T + R, y))
            ok = nis <= self.config.position_fix_gate_chi2
            self._out.append(MeasurementUpdate(t, "position_fix", "kinematic", tuple(float(v) for v in y), (sn, se),
                                               nis, self.config.position_fix_gate_chi2, ok))
            if ok:
                kf.update(z.reshape(-1, 1), R=R, H=H)
        if ok:
            self._used.add("position_fix")
            self._last_innov = (float(y[0]), float(y[1]), math.nan)
        else:
            self._n_rejected += 1

    def _update_mode(self, t: float, ev: GnssFix, z, vel) -> None:
        c = self.config
        if self._t0 is not None and t - self._t0 < c.rate_window_s and self.mode == "init":
            return  # not enough stream seen to measure the IMU rate yet
        rate = self._imu_rate(t)
        imu_alive = self._last_imu_t is not None and t - self._last_imu_t < c.imu_timeout_s
        if self.mode == "ins":
            if not imu_alive:
                self._set_mode(
                    t, "kinematic", f"IMU{c.imu_index} stream stopped for > {c.imu_timeout_s:g} s", "imu_stopped"
                )
                self.ins = None
            return
        if not imu_alive or self._last_imu_t is None:
            key = "no_imu" if self._last_imu_t is None else "imu_stopped"
            reason = f"no IMU{c.imu_index} samples in the source: kinematic constant-velocity model"
            if key == "imu_stopped":
                reason = f"IMU{c.imu_index} stream stopped for > {c.imu_timeout_s:g} s: kinematic constant-velocity model"
        elif rate < c.min_imu_rate_hz:
            key = "low_rate"
            reason = (
                f"IMU{c.imu_index} rate {rate:.1f} Hz < {c.min_imu_rate_hz:g} Hz needed for strapdown "
                "mechanisation: kinematic constant-velocity model"
            )
        elif self._att is None:
            key = "no_attitude"
            reason = "no attitude source to initialise the INS: kinematic constant-velocity model"
        else:
            self._ins_init(t, z, vel)
            self._set_mode(t, "ins", f"strapdown INS on IMU{c.imu_index} at {rate:.0f} Hz + error-state KF", "ins")
            return
        self._set_mode(t, "kinematic", reason, key)

    # ------------------------------------------------------------------ INS filter
    def _ins_init(self, t: float, z, vel) -> None:
        c = self.config
        lat, lon, alt = self._from_ned(*z)
        v = (0.0, 0.0, 0.0)
        if vel is not None:
            v = (vel[0], vel[1], vel[2] if math.isfinite(vel[2]) else 0.0)
        a = self._att
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
        if not self.ahrs_consistent and math.isfinite(self.ahrs_heading_offset_rad):
            self._align_yaw(t_ins)
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0

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
        F = np.zeros((15, 15))
        F[0:3, 3:6] = np.eye(3)
        F[3:6, 6:9] = -_skew(f)
        F[3:6, 9:12] = -C
        F[6:9, 12:15] = -C
        F[9:15, 9:15] = -np.eye(6) / c.bias_tau_s
        Fd = F * dt
        phi = np.eye(15) + Fd + 0.5 * Fd @ Fd
        q = np.empty(15)
        q[0:3] = 1e-6 * dt
        q[3:6] = c.accel_noise_mps2_rthz**2 * dt
        q[6:9] = c.gyro_noise_radps_rthz**2 * dt
        q[9:12] = 2 * c.accel_bias_sigma_mps2**2 / c.bias_tau_s * dt
        q[12:15] = 2 * c.gyro_bias_sigma_radps**2 / c.bias_tau_s * dt
        self._kf.predict(F=phi, Q=np.diag(q))
        self._kf_t = t

    def _ins_apply(self, H: np.ndarray, z: np.ndarray, R: np.ndarray, kind: str, t: float,
                   R_gate: np.ndarray | None = None, gate_chi2: float | None = None) -> bool:
        kf = self._kf
        S = H @ kf.P @ H.T + (R if R_gate is None else np.maximum(R, R_gate))
        nis = float(z @ np.linalg.solve(S, z))
        gate = self.config.gate_chi2 if gate_chi2 is None else gate_chi2
        ok = nis <= gate
        self._out.append(
            MeasurementUpdate(t, kind, "ins", tuple(float(x) for x in z), tuple(float(x) for x in np.sqrt(np.diag(R))),
                              nis, gate, ok)
        )
        if not ok:
            return False
        kf.update(z.reshape(-1, 1), R=R, H=H)
        dx = kf.x.ravel()
        self._correct_ins(dx[0:3], dx[3:6], dx[6:9], dx[9:12], dx[12:15])
        kf.x = np.zeros((15, 1))
        return True

    def _correct_ins(self, dp, dv, psi, dba, dbg) -> None:
        """Feed an error estimate back into the INS and shift the delay history with it."""
        self.ins.correct(dp, dv, psi, dba, dbg)
        for h in self._hist:
            h[1] += dp[0]
            h[2] += dp[1]
            h[3] += dp[2]
            h[4] += dv[0]
            h[5] += dv[1]
            h[6] += dv[2]

    def _ins_state_at(self, t: float, delay_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """INS position (local NED) and velocity at the epoch ``t - gnss_delay_s`` a fix stamped t refers to.

        From the per-IMU-step history when the epoch is in the past, else extrapolated from the current
        state at constant velocity.
        """
        ins = self.ins
        te = t - (self.config.gnss_delay_s if delay_s is None else delay_s)
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
        n, e, d = self._to_ned(ins.lat_deg, ins.lon_deg, ins.h_m)
        dt = te - ins.t_s
        return np.array([n + ins.vn * dt, e + ins.ve * dt, d + ins.vd * dt]), np.array([ins.vn, ins.ve, ins.vd])

    def _ins_position_update(self, t: float, z, sh: float, sv: float, kind: str, gate_sigma=None) -> bool:
        self._ins_predict(max(t, self._kf_t))
        H = np.zeros((3, 15))
        H[:, 0:3] = np.eye(3)
        y = np.asarray(z) - self._ins_state_at(t)[0]
        R_gate = None if gate_sigma is None else np.diag([gate_sigma[0] ** 2, gate_sigma[0] ** 2, gate_sigma[1] ** 2])
        ok = self._ins_apply(H, y, np.diag([sh**2, sh**2, sv**2]), kind, t, R_gate)
        if kind == "gnss_pos":
            ok = self._gate_bookkeeping(t, ok, y, sh, sv)
        if ok:
            self._last_innov = tuple(float(x) for x in y)
        else:
            self._n_rejected += 1
        return ok

    def _gate_bookkeeping(self, t: float, ok: bool, y, sh: float, sv: float) -> bool:
        """Persisting rejection is a real position step, not a glitch: reset position to GNSS."""
        if ok:
            self._reject_since = None
            return True
        if self._reject_since is None:
            self._reject_since = t
            return False
        if t - self._reject_since < self.config.gate_reset_s:
            return False
        self._reject_since = None
        if self.mode == "ins":
            kf = self._kf
            kf.P[0:3, :] = 0.0
            kf.P[:, 0:3] = 0.0
            kf.P[0:3, 0:3] = np.diag([sh**2, sh**2, sv**2])
            kf.P[3:6, 3:6] += np.eye(3)
            self._correct_ins(y, (0, 0, 0), (0, 0, 0), (0, 0, 0), (0, 0, 0))
        return True

    def _ins_velocity_update(self, t: float, vel, sigma: float) -> None:
        self._ins_predict(max(t, self._kf_t))
        H = np.zeros((3, 15))
        H[:, 3:6] = np.eye(3)
        y = np.asarray(vel, dtype=float) - self._ins_state_at(t)[1]
        self._ins_apply(H, y, np.eye(3) * sigma**2, "gnss_vel", t)

    def _ins_attitude_update(self, ev: Attitude) -> None:
        c = self.config
        self._ins_predict(max(ev.t_s, self._kf_t))
        fuse_yaw = c.fuse_attitude_yaw and self.ahrs_consistent
        # Tilt-only measurement: the autopilot's roll/pitch fix the gravity direction in the body frame
        # whatever its heading, so the measured attitude is built with the INS's own heading. (Built with
        # the autopilot's heading, a heading disagreement of d rotates and mixes the roll/pitch innovations
        # through the small-angle extraction below: at d ~ 90 deg, as in the Erle PXF log, a roll error was
        # read as a pitch error.)
        yaw_meas = ev.yaw_rad if fuse_yaw else self.ins.euler()[2]
        c_meas = dcm_from_quat(quat_from_euler(ev.roll_rad, ev.pitch_rad, yaw_meas))
        E = c_meas @ self.ins.dcm().T  # = I + [psi x] for small psi
        y = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
        H = np.zeros((3, 15))
        H[:, 6:9] = np.eye(3)
        s_yaw = c.att_sigma_yaw_rad if fuse_yaw else 1e3  # 1e3 rad: no heading information
        s_tilt2 = c.att_sigma_tilt_rad**2
        if not self.ahrs_consistent:  # tilt error induced by the AHRS heading offset (see ahrs_check)
            a_rms = math.sqrt(self._al_acc2 / self._al_w) if self._al_w > 0 else 0.0
            s_tilt2 += (2.0 * math.sin(0.5 * abs(self.ahrs_heading_offset_rad)) * a_rms / 9.8) ** 2
        R = np.diag([s_tilt2, s_tilt2, s_yaw**2])
        self._ins_apply(H, y, R, "attitude", ev.t_s)

    # ------------------------------------------------------------------ kinematic filter
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

    # ------------------------------------------------------------------ 10 Hz ticks
    def _run_ticks(self, t: float, inclusive: bool) -> None:
        while True:
            tg = self._next_tick * self._tick_dt
            if tg > t or (tg == t and not inclusive):
                break
            self._tick(tg)
            self._next_tick += 1

    def _tick(self, tg: float) -> None:
        c = self.config
        # predictor point (Aziez 2021: 9 points between 1 Hz fixes, continuing through blockages)
        if self._last_fix_t is not None and tg - self._last_fix_t >= max(c.predictor_min_age_s, 1e-9):
            p = self.predictor.predict(tg)
            if p is not None:
                lat, lon, alt = self._from_ned(*p.ned_m)
                self._out.append(
                    PredictorPoint(tg, *p.ned_m, lat, lon, alt, p.sigma_h_m, p.sigma_v_m, p.age_s, p.method)
                )
                if c.fuse_predictor:
                    # points from one anchor share one error: inflate R by the count fused since the fix
                    self._n_pred_fused = self._n_pred_fused + 1 if self._pred_anchor == self._last_fix_t else 1
                    self._pred_anchor = self._last_fix_t
                    infl = c.predictor_sigma_scale * (math.sqrt(self._n_pred_fused) if c.predictor_decorrelate else 1.0)
                    sh, sv = p.sigma_h_m * infl, p.sigma_v_m * infl
                    if self.mode == "ins":
                        ok = self._ins_position_update(tg, p.ned_m, sh, sv, "predictor")
                    else:
                        ok = self._kin_update(tg, p.ned_m, sh, sv, "predictor", True)
                    if ok:
                        self._used.add("predictor")
        if self.mode == "init":
            return
        if self.mode == "ins":
            self._ins_predict(tg)
            ins = self.ins
            n, e, d = self._to_ned(ins.lat_deg, ins.lon_deg, ins.h_m)
            dt = tg - ins.t_s
            n, e, d = n + ins.vn * dt, e + ins.ve * dt, d + ins.vd * dt
            vel = (ins.vn, ins.ve, ins.vd)
            rpy = ins.euler()
            P = self._kf.P
            if c.hold_prior:
                b = self._hold_blend(tg, (n, e, d), (P[0, 0], P[1, 1], P[2, 2]))
                if b is not None:
                    (n, e, d), pv = b
                    P = P.copy()
                    P[0, 0], P[1, 1], P[2, 2] = pv
        else:
            if self._kin is None:
                return
            self._kin_predict(tg)
            x = self._kin.x.ravel()
            n, e, d = float(x[0]), float(x[1]), float(x[2])
            vel = (float(x[3]), float(x[4]), float(x[5]))
            a = self._att
            rpy = (a.roll_rad, a.pitch_rad, a.yaw_rad) if a is not None and tg - a.t_s < 1.0 else (math.nan,) * 3
            P = self._kin.P
        diag = tuple(float(v) for v in np.diag(P))
        lat, lon, alt = self._from_ned(n, e, d)
        used = "+".join(sorted(self._used, key=("gnss", "predictor", "position_fix", "altitude").index)) or "none"
        self._out.append(
            FusedState(
                tg, lat, lon, alt, n, e, d, *vel, *rpy, diag,
                math.sqrt(diag[0] + diag[1]), math.sqrt(diag[2]), self.mode, used, self._last_innov,
                self._n_rejected,
                tg - self._last_fix_t if self._last_fix_t is not None else math.nan,
            )
        )
        self._used = set()
        self._last_innov = (math.nan, math.nan, math.nan)
        self._n_rejected = 0


def run_navigator(events, config: NavigatorConfig | None = None) -> list[Event]:
    """Batch replay: sort the events by (time, type priority) and run them through one Navigator."""
    nav = Navigator(config)
    order = sorted(range(len(events)), key=lambda i: (events[i].t_s, _PRIO.get(type(events[i]), 3), i))
    out: list[Event] = []
    for i in order:
        out.extend(nav.process(events[i]))
    out.extend(nav.finish())
    return out
