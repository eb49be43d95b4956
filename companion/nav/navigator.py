"""Loosely coupled GNSS / KNN-predictor / INS integration: the streaming :class:`Navigator` stage.

The paper (Aziez 2021, fig. 2, eqs. 5-10) fuses the KNN predictor's 10 Hz GNSS stream with the INS in a
Kalman filter; it integrates ultra-tightly at the correlator level (eqs. 11-34), which needs I/Q samples a
flight log does not have. This module does the loosely coupled equivalent on position/velocity fixes:

* **INS mode**: a 15-state error-state KF around :class:`companion.nav.ins.StrapdownIns` (eqs. 7-10; the model is
  described in companion.nav.ins_filter).
* **Kinematic mode**: a 6-state constant-velocity KF (white-noise acceleration) on the same
  measurements. Used when the source has no IMU, or its IMU rate is below ``min_imu_rate_hz`` (a
  telemetry log streams RAW_IMU at ~1 Hz: far too slow to integrate), or no attitude is available to
  initialise the INS. The choice and its reason are emitted as :class:`ModeChange` and exposed as
  :attr:`Navigator.mode` / :attr:`Navigator.mode_reason`. If the IMU stops in flight it falls back at the next
  fix and starts the kinematic filter from it (no standby beside the INS: 6-11 % of a replay's CPU).

Measurements (companion.nav.measurements: one ``compute(state) -> (y, H, R)`` contract, one gate): GNSS position
and velocity, KNN predictor points at each 10 Hz tick after the last fix, the autopilot's attitude, altitude and
PositionFix aids (companion.nav.aids, baro), the zero velocity of a hover and rotor drag in a blockage
(companion.nav.hover, drag); the motion prior mixes hold and constant velocity into the output in a blockage
(companion.nav.motion_prior); resets and re-initialisation are companion.nav.recovery.

Event order: sources can deliver different message types slightly out of time order. Events pass a
reorder buffer of ``reorder_window_s`` (heap on time, type priority IMU < attitude < GNSS, arrival
order) so the result does not depend on arrival order within the window: :func:`run_navigator` on a
sorted list and event-by-event :meth:`Navigator.process` give identical outputs.

Pure: no asyncio, no pymavlink, no wall clock.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from companion.nav.kalman import KalmanFilter

from companion.nav.aids import Aids
from companion.nav.baro import BaroAid
from companion.nav.config import NavigatorConfig
from companion.nav.ins import StrapdownIns, dcm_from_quat, quat_from_euler
from companion.nav.ins_filter import InsFilter
from companion.nav.kinematic import KinematicFilter
from companion.nav.hold_cv import CvFilter, HoldCvFilter
from companion.nav.drag import RotorDrag
from companion.nav.motion_prior import MotionPrior
from companion.nav.hover import HoverDetector
from companion.nav.knn_predictor import KnnPredictor
from companion.nav.measurements import PositionMeasurement, VelocityMeasurement
from companion.nav.modes import Modes
from companion.nav.monitors import AhrsHeadingCheck
from companion.nav.outputs import FrameInfo, FusedState
from companion.events import Attitude, AutopilotAltitude, Event, GnssFix, ImuSample, PositionFix
from companion.nav.frame import LocalFrame
from companion.nav.gnss_lag import GnssLagEstimator
from companion.nav.recovery import Recovery
from companion.nav.reorder import ReorderBuffer
from companion.pipeline.stage import Stage

__all__ = ["Navigator", "NavigatorConfig", "run_navigator"]

_PRIO = {ImuSample: 0, Attitude: 1, GnssFix: 2}
_USED_ORDER = ("gnss", "predictor", "position_fix", "altitude", "zero_velocity", "rotor_drag", "motion_prior")


class Navigator(Modes, InsFilter, KinematicFilter, Aids, Recovery, AhrsHeadingCheck, BaroAid, Stage):
    """Streaming gap-filling stage: ``process(event) -> list[output]``, then ``finish()``."""

    def __init__(self, config: NavigatorConfig | None = None) -> None:
        self.config = c = config or NavigatorConfig()
        self.mode = "init"
        self.mode_reason = "waiting for the first GNSS fix"
        self._reason_key = "init"
        self.predictor = KnnPredictor(c.knn)
        self.frame: LocalFrame | None = None
        self._reorder = ReorderBuffer(c.reorder_window_s, _PRIO, default_priority=3, outlier_s=c.future_outlier_s,
                                      confirm_n=c.future_confirm_n)
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
        self._recovery_init()
        # INS filter
        self.ins: StrapdownIns | None = None
        self._kf: KalmanFilter | None = None
        self._kf_t = 0.0
        self._f_sum = [0.0, 0.0, 0.0]
        self._f_n = 0
        self._hist: deque[list[float]] = deque()  # [t, n, e, d, vn, ve, vd] per IMU step, last delay + 0.2 s
        self._gnss_lag = GnssLagEstimator(c.gnss_lag) if c.gnss_delay_estimate else None
        self._delay_learnt_s: float | None = None
        self._corr_sums = [0.0] * 9
        self._ins_epoch = 0
        self._monitors_init()
        self.hover = HoverDetector(c.hover)
        self._zupt_t = -math.inf
        self.drag = RotorDrag(c.drag) if c.rotor_drag else None
        self.motion = MotionPrior(c.motion) if c.motion_prior else None
        # kinematic filter
        self._kin: CvFilter | HoldCvFilter | None = None
        self._kin_t = 0.0
        # per-output bookkeeping
        self._used: set[str] = set()
        self._last_innov: tuple[float, ...] = (math.nan, math.nan, math.nan)
        self._n_rejected = 0

    # ------------------------------------------------------------------ stream interface
    def process(self, event: Event) -> list[Event]:
        """Consume one event; returns the outputs that became final."""
        for ev in self._reorder.push(event):
            self._handle(ev)
        out, self._out = self._out, []
        return out

    def metadata(self) -> dict[str, str]:
        """The mode the navigator ended in and why (INS, or the kinematic fallback); resets and dropped outliers."""
        meta = {k: str(v) for k, v in (("mode", self.mode), ("mode_reason", self.mode_reason)) if v}
        if self.resets:
            meta["resets"] = ", ".join(f"{k}={n}" for k, n in sorted(self.resets.items()))
        if self._reorder.dropped_future:
            meta["dropped_future_events"] = str(self._reorder.dropped_future)
        if self._gnss_lag is not None:
            sig = self._gnss_lag.sigma_s()
            meta["gnss_lag_s"] = f"{self._gnss_delay_s():.3f}" + (
                f" (measured, sigma {sig:.3f})" if self._gnss_lag.lag_s is not None else " (configured)")
        return meta

    def finish(self) -> list[Event]:
        """Flush the reorder buffer and emit the remaining outputs up to the last event time."""
        for ev in self._reorder.flush():
            self._handle(ev)
        newest = self._reorder.newest_s
        if self._next_tick is not None and newest > -math.inf:
            self._run_ticks(newest, inclusive=True)
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ dispatch
    def _handle(self, ev: Event) -> None:
        t = ev.t_s
        if self._t0 is None:
            self._t0 = t
        self._check_stream_gap(t)
        if self._next_tick is not None:
            self._run_ticks(t, inclusive=False)
        if isinstance(ev, ImuSample):
            if ev.imu_index == self.config.imu_index:
                self._on_imu(ev)
        elif isinstance(ev, GnssFix):
            if ev.has_position and ev.alt_msl_m is not None and ev.instance == self.config.gnss_instance:
                self._on_fix(ev)
        elif self._reinit_pending is not None:
            if isinstance(ev, Attitude):
                self._att = ev  # aids wait for the re-initialisation
        elif isinstance(ev, PositionFix):
            self._on_position_fix(ev)
        elif isinstance(ev, AutopilotAltitude):
            if self.config.fuse_autopilot_alt:
                self._on_altitude(ev)
        elif isinstance(ev, Attitude):
            self._att = ev
            if self._att_stale and self.mode == "ins" and self.ins is not None:
                self._attitude_after_gap(ev)
            if self.config.ahrs_check:
                C = dcm_from_quat(quat_from_euler(ev.roll_rad, ev.pitch_rad, ev.yaw_rad))
                self._att_c = tuple(float(x) for x in C[0:2].ravel())
                if self._gnss_lag is not None:
                    self._gnss_lag.add_attitude(ev.t_s, self._att_c)
            if (self.mode == "ins" and self.config.fuse_attitude
                    and ev.t_s - self._att_fused_t >= self.config.att_fuse_interval_s):
                self._att_fused_t = ev.t_s
                self._ins_attitude_update(ev)

    # ------------------------------------------------------------------ GNSS
    def _on_fix(self, ev: GnssFix) -> None:
        c = self.config
        t = ev.t_s
        if self.frame is None:
            self.frame = LocalFrame(ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
            self._ref = (ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
            self._out.append(FrameInfo(t, ev.lat_deg, ev.lon_deg, ev.alt_msl_m))
        z = self.frame.ned_tuple(ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
        sh, sv, gh, gv = self._fix_sigmas(ev)
        vel = None
        if ev.vel_n_mps is not None and ev.vel_e_mps is not None:
            vel = (ev.vel_n_mps, ev.vel_e_mps, ev.vel_d_mps if ev.vel_d_mps is not None else math.nan)
        gnss_gap = self._note_fix(ev, vel)
        if vel is not None:
            self.hover.add_speed(t, math.hypot(vel[0], vel[1]))
            if self._gnss_lag is not None and self.ahrs_consistent:
                self._gnss_lag.add_gnss_velocity(t, vel[0], vel[1])
        if self._reinit_pending is not None:
            self._reinit(t, z, vel)
            self._fix_accepted(t, z, sh, sv, vel)
            return
        self._update_mode(t, ev, z, vel)
        accepted = True
        if c.ahrs_check and vel is not None:
            self._ahrs_check(t, vel)
        m = PositionMeasurement(t, "gnss_pos", z, sh, sv, (gh, gv), c.gate_chi2)
        if self.mode == "ins":
            accepted = self._ins_position_update(m, gnss_gap)
            if accepted and vel is not None and c.fuse_gnss_velocity and math.isfinite(vel[2]):
                self._ins_apply(VelocityMeasurement(t, "gnss_vel", vel, c.gnss_vel_sigma_mps, c.gate_chi2,
                                                    self._gnss_vel_delay_s()))
        if self.mode == "ins":
            self._kin = None  # not kept as a standby: a fallback to kinematic mode starts it from that fix
        elif self._kin is None:
            self._kin_init(t, z, vel)
        else:
            accepted = self._kin_update(m, record=True)
        if accepted:
            self._fix_accepted(t, z, sh, sv, vel)
        if self._next_tick is None:
            self._next_tick = math.floor(t / self._tick_dt) + 1

    def _fix_accepted(self, t: float, z, sh: float, sv: float, vel) -> None:
        self._used.add("gnss")
        self._last_fix_t = t
        v3 = None if vel is None or not math.isfinite(vel[2]) else vel
        if self.motion is not None:
            self._motion_learn(t, z, v3, sh, sv)
        self.predictor.add_fix(t, z, sh, sv, v3)

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
        if self._reinit_pending is not None:
            return  # after a stream gap nothing is known until the next fix re-initialises
        self._predictor_tick(tg)
        if self.mode == "init":
            return
        if (c.zero_velocity and self._last_fix_t is not None and tg - self._last_fix_t >= c.zupt_min_age_s
                and tg - self._zupt_t >= c.zupt_interval_s and self.hover.hover(tg)):
            self._zero_velocity_update(tg)
        if self.mode == "ins":
            self._ins_predict(tg)
            if self.drag is not None:
                self._rotor_drag_tick(tg)
            ins = self.ins
            n, e, d = self.frame.ned_tuple(ins.lat_deg, ins.lon_deg, ins.h_m)
            dt = tg - ins.t_s
            n, e, d = n + ins.vn * dt, e + ins.ve * dt, d + ins.vd * dt
            vel = (ins.vn, ins.ve, ins.vd)
            rpy = ins.euler()
            P = self._kf.P
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
        if self.motion is not None:
            (n, e, d), P = self._motion_blend(tg, (n, e, d), P)
        diag = tuple(P.diagonal().tolist())
        lat, lon, alt = self.frame.geodetic_tuple(n, e, d)
        used = "+".join(sorted(self._used, key=_USED_ORDER.index)) or "none"
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
