"""Loosely coupled GNSS / KNN-predictor / INS integration: the streaming :class:`Navigator` stage.

The paper (Aziez 2021, fig. 2, eqs. 5-10) fuses the KNN predictor's 10 Hz GNSS stream with the INS in a
Kalman filter; it integrates ultra-tightly at the correlator level (eqs. 11-34), which needs I/Q samples a
flight log does not have. This module does the loosely coupled equivalent on position/velocity fixes:

* **INS mode**: a 15-state error-state KF around :class:`companion.nav.ins.StrapdownIns` (eqs. 7-10,
  companion.nav.ins_filter).
* **Kinematic mode**: a 6-state constant-velocity KF (white-noise acceleration, companion.nav.kinematic) on the same
  measurements. Used when the source has no IMU, or its IMU rate is below ``min_imu_rate_hz`` (a telemetry log
  streams RAW_IMU at ~1 Hz: far too slow to integrate), or no attitude is available to initialise the INS
  (companion.nav.modes). The choice and its reason are emitted as :class:`ModeChange` and exposed as
  :attr:`Navigator.mode` / :attr:`Navigator.mode_reason`. If the IMU stops in flight it falls back at the next fix
  and starts the kinematic filter from it (no standby beside the INS: 6-11 % of a replay's CPU).

The navigator is the dispatcher: it orders the events, hands each to the parts that use it, offers their
measurements (companion.nav.measurements: one ``compute(state) -> (y, H, R)`` contract, one gate) to the active
filter, and emits the outputs at the 10 Hz ticks. The parts own their state: the filters, the GNSS latency
(companion.nav.gnss_lag), the autopilot heading check (monitors), the aids (aids: KNN predictor points, zero velocity
of a hover, autopilot attitude, PositionFix; baro; drag), the motion prior mixed into the output in a blockage
(motion_prior) and the decisions to reset (recovery).

Event order: sources can deliver different message types slightly out of time order. Events pass a
reorder buffer of ``reorder_window_s`` (heap on time, type priority IMU < attitude < GNSS, arrival
order) so the result does not depend on arrival order within the window: :func:`run_navigator` on a
sorted list and event-by-event :meth:`Navigator.process` give identical outputs.

Pure: no asyncio, no pymavlink, no wall clock.
"""

from __future__ import annotations

import math

import numpy as np

from companion.events import Attitude, AutopilotAltitude, Event, GnssFix, ImuSample, PositionFix
from companion.nav.aids import AttitudeAid, PredictorAid, ZeroVelocityAid, fix_sigmas, position_fix_measurements
from companion.nav.baro import BaroAid
from companion.nav.config import NavigatorConfig
from companion.nav.drag import RotorDrag
from companion.nav.frame import LocalFrame
from companion.nav.gnss_lag import GnssLagEstimator, GnssLatency
from companion.nav.hover import HoverDetector
from companion.nav.ins_filter import InsFilter
from companion.nav.kinematic import KinematicFilter
from companion.nav.measurements import Measurement, PositionMeasurement, VelocityMeasurement
from companion.nav.modes import ModeSelector
from companion.nav.monitors import AhrsHeadingCheck
from companion.nav.motion_prior import MotionPrior
from companion.nav.outputs import FrameInfo, FusedState, PredictorPoint
from companion.nav.recovery import Recovery
from companion.nav.reorder import ReorderBuffer
from companion.pipeline.stage import Stage

__all__ = ["Navigator", "NavigatorConfig", "run_navigator"]

_PRIO = {ImuSample: 0, Attitude: 1, GnssFix: 2}
_USED_ORDER = ("gnss", "predictor", "position_fix", "altitude", "zero_velocity", "rotor_drag", "motion_prior")


class _SinceOutput:
    """What happened since the previous FusedState: the aids applied, the last position innovation, gate refusals."""

    def __init__(self) -> None:
        self.used: set[str] = set()
        self.innovation: tuple[float, ...] = (math.nan, math.nan, math.nan)
        self.rejected = 0

    def take(self) -> tuple[str, tuple[float, ...], int]:
        """(aids joined by "+" or "none", innovation, refusals) for a FusedState; starts the next interval."""
        out = ("+".join(sorted(self.used, key=_USED_ORDER.index)) or "none", self.innovation, self.rejected)
        self.used, self.innovation, self.rejected = set(), (math.nan, math.nan, math.nan), 0
        return out


class Navigator(Stage):
    """Streaming gap-filling stage: ``process(event) -> list[output]``, then ``finish()``."""

    def __init__(self, config: NavigatorConfig | None = None) -> None:
        self.config = c = config or NavigatorConfig()
        self._out: list[Event] = []
        self._emit = emit = self._out.append  # every part's outputs, in the order they happen
        self._reorder = ReorderBuffer(c.reorder_window_s, _PRIO, default_priority=3, outlier_s=c.future_outlier_s,
                                      confirm_n=c.future_confirm_n)
        self._modes = ModeSelector(c)
        self.recovery = Recovery(c, emit)
        self.latency = GnssLatency(c.gnss_delay_s, c.gnss_vel_delay_s,
                                   GnssLagEstimator(c.gnss_lag) if c.gnss_delay_estimate else None)
        self.heading = AhrsHeadingCheck(c)
        self.hover = HoverDetector(c.hover)
        self.predictor = PredictorAid(c)
        self._zero_velocity = ZeroVelocityAid(c, self.hover)
        self._attitude = AttitudeAid(c, self.heading)
        self._baro = BaroAid(c)
        self.drag = RotorDrag(c.drag) if c.rotor_drag else None
        self.motion = MotionPrior(c.motion) if c.motion_prior else None
        self.ins: InsFilter | None = None  # the filter of INS mode
        self.kin: KinematicFilter | None = None  # ... and of the others (never run beside the INS)
        self._ins_epoch = 0
        self.yaw_alignments: list[tuple[float, float]] = []  # (t, applied INS heading rotation rad)
        self.frame: LocalFrame | None = None
        self._t0: float | None = None  # first event time
        self._last_imu_t: float | None = None
        self._att: Attitude | None = None
        self._tick_dt = 1.0 / c.output_rate_hz
        self._next_tick: int | None = None
        self._last_fix_t: float | None = None
        self._since = _SinceOutput()
        self._imu_index = c.imu_index

    @property
    def mode(self) -> str:
        """"init", "ins" or "kinematic"."""
        return self._modes.mode

    @property
    def mode_reason(self) -> str:
        return self._modes.reason

    @property
    def resets(self) -> dict[str, int]:
        return self.recovery.resets

    # ------------------------------------------------------------------ stream interface
    def process(self, event: Event) -> list[Event]:
        """Consume one event; returns the outputs that became final. The samples of the IMUs it does not navigate
        with (IMU2, IMU3: two thirds of a dataflash log's events) are not its input: passed over at once."""
        if type(event) is ImuSample and event.imu_index != self._imu_index:
            return []
        for ev in self._reorder.push(event):
            self._handle(ev)
        return self._take_outputs()

    def metadata(self) -> dict[str, str]:
        """The mode the navigator ended in and why (INS, or the kinematic fallback); resets and dropped outliers."""
        meta = {k: str(v) for k, v in (("mode", self.mode), ("mode_reason", self.mode_reason)) if v}
        if self.resets:
            meta["resets"] = ", ".join(f"{k}={n}" for k, n in sorted(self.resets.items()))
        if self._reorder.dropped_future:
            meta["dropped_future_events"] = str(self._reorder.dropped_future)
        if self.latency.estimator is not None:
            meta["gnss_lag_s"] = self.latency.describe()
        return meta

    @property
    def next_output_s(self) -> float:
        """The time of the next 10 Hz output (its tick), +inf before the first fix schedules one. No FusedState can
        come out of an event stamped at most this plus ``reorder_window_s``, unless it arrives older than the newest
        event by more than the window (it is released at once): what the live runtime may leave for later."""
        return math.inf if self._next_tick is None else self._next_tick * self._tick_dt

    @property
    def dropped_future_events(self) -> int:
        return self._reorder.dropped_future

    def finish(self) -> list[Event]:
        """Flush the reorder buffer and emit the remaining outputs up to the last event time."""
        for ev in self._reorder.flush():
            self._handle(ev)
        newest = self._reorder.newest_s
        if self._next_tick is not None and newest > -math.inf:
            self._run_ticks(newest, inclusive=True)
        return self._take_outputs()

    def _take_outputs(self) -> list[Event]:
        out = self._out.copy()  # the parts hold this list's append: emptied, not replaced
        self._out.clear()
        return out

    # ------------------------------------------------------------------ dispatch
    def _handle(self, ev: Event) -> None:
        t = ev.t_s
        if self._t0 is None:
            self._t0 = t
        if self.recovery.stream_gap(t, self.mode != "init") and self._next_tick is not None:
            self._next_tick = max(self._next_tick, math.ceil(t / self._tick_dt - 1e-9))
        if self._next_tick is not None:
            self._run_ticks(t, inclusive=False)
        if isinstance(ev, ImuSample):
            if ev.imu_index == self.config.imu_index:
                self._on_imu(ev)
        elif isinstance(ev, GnssFix):
            if ev.has_position and ev.alt_msl_m is not None and ev.instance == self.config.gnss_instance:
                self._on_fix(ev)
        elif self.recovery.pending is not None:
            if isinstance(ev, Attitude):
                self._att = ev  # aids wait for the re-initialisation
        elif isinstance(ev, PositionFix):
            self._on_position_fix(ev)
        elif isinstance(ev, AutopilotAltitude):
            if self.config.fuse_autopilot_alt:
                self._on_altitude(ev)
        elif isinstance(ev, Attitude):
            self._on_attitude(ev)

    def _on_imu(self, ev: ImuSample) -> None:
        c = self.config
        t = ev.t_s
        self._modes.note_imu(t)
        self.hover.add_imu(t, ev.accel_frd_mps2, ev.gyro_frd_radps)
        if self.drag is not None:
            self.drag.add_accel(ev.accel_frd_mps2)
        prev_t = self._last_imu_t
        self._last_imu_t = t
        est = self.latency.estimator
        if est is not None and prev_t is not None:
            if 0 < t - prev_t <= c.max_imu_step_s:
                est.add_imu(t, t - prev_t, ev.accel_frd_mps2)
            elif t - prev_t > c.max_imu_step_s:
                est.reset_imu()
        if prev_t is not None and 0 < t - prev_t <= c.max_imu_step_s:
            dv = self.heading.add_imu(t - prev_t, ev.accel_frd_mps2)
            if dv is not None:
                self.hover.add_horizontal_dv(*dv)
        if self.ins is not None and self.mode == "ins" and self.recovery.pending is None:
            self.ins.step_imu(t, ev.accel_frd_mps2, ev.gyro_frd_radps)

    def _on_attitude(self, ev: Attitude) -> None:
        c = self.config
        self._att = ev
        if self.recovery.attitude_stale and self.mode == "ins" and self.ins is not None:
            # the INS was re-initialised after a stream gap with an attitude from before it (minutes old, and any tilt
            # while manoeuvring): the first one after the gap replaces it; fused, it would be an outlier for the gate
            self.recovery.attitude_stale = False
            self.ins.reset_attitude(ev.t_s, ev.roll_rad, ev.pitch_rad, ev.yaw_rad)
            self._align_yaw(ev.t_s)
        if c.ahrs_check:
            att_c = self.heading.add_attitude(ev)
            if self.latency.estimator is not None:
                self.latency.estimator.add_attitude(ev.t_s, att_c)
        if self.mode == "ins" and self._attitude.due(ev.t_s):
            m = self._attitude.measurement(ev, lambda: self.ins.strapdown.euler()[2], self._last_fix_t)
            if m is None:
                return
            ok, y = self.ins.apply(m)
            if c.reset_after_rejection:
                reason = self.recovery.attitude_reset(ev.t_s, ok)
                if reason is not None:
                    psi = np.array([y[0], y[1], 0.0])  # tilt only: the heading has its own check
                    self.ins.reset_tilt(psi[0], psi[1])
                    self.recovery.record(ev.t_s, "attitude_rejected", reason, "ins", math.nan,
                                         float(np.linalg.norm(psi)))

    # ------------------------------------------------------------------ GNSS
    def _on_fix(self, ev: GnssFix) -> None:
        c = self.config
        t = ev.t_s
        if self.frame is None:
            self.frame = LocalFrame(ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
            self._emit(FrameInfo(t, ev.lat_deg, ev.lon_deg, ev.alt_msl_m))
        z = self.frame.ned_tuple(ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
        sh, sv, gh, gv = fix_sigmas(ev, c)
        vel = None
        if ev.vel_n_mps is not None and ev.vel_e_mps is not None:
            vel = (ev.vel_n_mps, ev.vel_e_mps, ev.vel_d_mps if ev.vel_d_mps is not None else math.nan)
        gnss_gap = self.recovery.note_fix(ev, vel)
        if vel is not None:
            self.hover.add_speed(t, math.hypot(vel[0], vel[1]))
            if self.latency.estimator is not None and self.heading.consistent:
                self.latency.estimator.add_gnss_velocity(t, vel[0], vel[1])
        if self.recovery.pending is not None:
            self._reinit(t, z, vel)
            self._fix_accepted(t, z, sh, sv, vel)
            return
        self._update_mode(t, z, vel)
        accepted = True
        if c.ahrs_check and vel is not None:
            if self.heading.check(t, vel) and not self.heading.consistent and self.mode == "ins":
                self._align_yaw(t)
        m = PositionMeasurement(t, "gnss_pos", z, sh, sv, (gh, gv), c.gate_chi2)
        if self.mode == "ins":
            accepted = self._ins_position(m, gnss_gap)
            if accepted and vel is not None and c.fuse_gnss_velocity and math.isfinite(vel[2]):
                self.ins.apply(VelocityMeasurement(t, "gnss_vel", vel, c.gnss_vel_sigma_mps, c.gate_chi2,
                                                   self.latency.vel_delay_s()))
        if self.mode == "ins":
            self.kin = None  # not kept as a standby: a fallback to kinematic mode starts it from that fix
        elif self.kin is None:
            self.kin = KinematicFilter(c, self.latency, self._emit, t, z, vel)
        else:
            accepted = self._kin_position(m)
        if accepted:
            self._fix_accepted(t, z, sh, sv, vel)
        if self._next_tick is None:
            self._next_tick = math.floor(t / self._tick_dt) + 1

    def _fix_accepted(self, t: float, z, sh: float, sv: float, vel) -> None:
        self._since.used.add("gnss")
        self._last_fix_t = t
        v3 = None if vel is None or not math.isfinite(vel[2]) else vel
        if self.motion is not None:
            rec, epoch = None, self._ins_epoch
            if self.mode == "ins" and self.ins is not None:
                rec = self.ins.trajectory_record()
            elif self.motion.config.select and self.kin is not None:  # the kinematic filter's dead reckoning
                rec, epoch = self.kin.trajectory_record(), -2
            self.motion.add_fix(t, z, v3, (sh * sh, sh * sh, sv * sv), self.hover.hover(t), rec, epoch)
        self.predictor.add_fix(t, z, sh, sv, v3)

    def _update_mode(self, t: float, z, vel) -> None:
        choice = self._modes.choose(t, self._t0, self._last_imu_t, self._att is not None)
        if choice is None:
            return
        mode, reason, key = choice
        if mode == "ins":
            self._start_ins(t, z, vel, self._last_imu_t if self._last_imu_t is not None else t)
        elif self.mode == "ins":
            self.ins = None
        change = self._modes.switch(t, mode, reason, key)
        if change is not None:
            self._emit(change)

    def _start_ins(self, t: float, z, vel, t_ins: float) -> None:
        self._ins_epoch += 1
        self.ins = InsFilter(self.config, self.frame, self.latency, self._emit, t_ins, z, vel, self._att,
                             self._ins_epoch)
        self._align_yaw(t_ins)

    def _align_yaw(self, t: float) -> None:
        """Re-align the INS heading to a flagged autopilot's heading + the offset the heading check measured."""
        if self._att is None or self.ins is None:
            return
        target = self.heading.heading_target_rad(self._att.yaw_rad)
        if target is None:
            return
        d = self.ins.align_yaw(t, target)
        if d is not None:
            self.yaw_alignments.append((t, d))

    def _reinit(self, t: float, z, vel) -> None:
        """Re-initialise the active filter from this fix after a stream gap (whatever the message order)."""
        gap_end, reason = self.recovery.take_gap()
        self.heading.reanchor()
        if self.mode == "ins" and self.ins is not None and self._att is not None:
            old = self.ins
            p_old = np.array(old.position_ned())
            v_old = np.array(old.strapdown.vel_ned)
            lt = self._last_imu_t
            self._start_ins(t, z, vel, lt if lt is not None and lt >= gap_end else t)
            self.ins.keep_biases(old)
            self.recovery.attitude_stale = self._att.t_s < gap_end  # the next attitude replaces it
            filt = "ins"
            dp = float(np.linalg.norm(np.asarray(z) - p_old))
            dv = float(np.linalg.norm(np.array(self.ins.strapdown.vel_ned) - v_old))
        else:
            filt = "kinematic"
            dp = dv = math.nan
            if self.kin is not None:
                x = self.kin.state()[0]
                dp = float(np.linalg.norm(np.asarray(z) - x[0:3]))
        self.kin = KinematicFilter(self.config, self.latency, self._emit, t, z, vel)
        if self.drag is not None:
            self.drag.reset()
        if self.motion is not None:
            self.motion.reset()
        self.recovery.record(t, "reinit", reason, filt, dp, dv)

    # ------------------------------------------------------------------ measurements into the active filter
    def _ins_position(self, m: PositionMeasurement, after_gap: bool = False) -> bool:
        """A position into the INS filter; a GNSS one goes by the recovery's verdict (reset on persistent rejection)."""
        ins = self.ins
        if m.kind == "gnss_pos":
            ins.relearn_if_latency_moved()
        ok, y = ins.apply(m)
        if m.kind == "gnss_pos":
            reset = self.recovery.gnss_reset(m.t_s, ok, after_gap)
            if reset is not None:
                dv = ins.reset_to_fix(m.t_s, y, self.recovery.fix_vel, m.sigma_h_m, m.sigma_v_m)
                self.recovery.record(m.t_s, *reset, "ins", float(np.linalg.norm(y)), float(np.linalg.norm(dv)))
                ok = True
        if ok:
            self._since.innovation = tuple(y.tolist())
        else:
            self._since.rejected += 1
        return ok

    def _kin_position(self, m: PositionMeasurement) -> bool:
        """A position into the kinematic filter; a GNSS fix persistently rejected resets position (and velocity) to it."""
        kin = self.kin
        ok, y, nis = kin.apply(m)
        if m.kind == "gnss_pos":
            reset = self.recovery.gnss_reset(m.t_s, ok)
            if reset is not None:
                self.recovery.record(m.t_s, *reset, "kinematic", float(np.linalg.norm(y)), math.nan)
                ok = True
            if ok and nis > m.gate_chi2:
                kin.reset_to_fix(m, self.recovery.fix_vel)
                self._since.innovation = tuple(float(v) for v in y)
                return True
        if not ok:
            self._since.rejected += 1
            return False
        self._since.innovation = tuple(float(v) for v in y)
        return True

    def _apply(self, m: Measurement) -> tuple[bool, np.ndarray]:
        """Any other measurement into the active filter."""
        if self.mode == "ins":
            return self.ins.apply(m)
        ok, y, _nis = self.kin.apply(m)
        return ok, y

    def _on_position_fix(self, ev: PositionFix) -> None:
        """A non-GNSS horizontal position (e.g. a gravity-matching fix): the predictor, the motion prior and the fix
        age are untouched."""
        if self.frame is None or self.mode == "init":
            return  # no frame / no filter yet: GNSS starts the navigator
        ms = position_fix_measurements(ev, self.frame, self.config)
        if ms is None or (self.mode != "ins" and self.kin is None):
            return
        m, mv = ms
        ok, y = self._apply(m)
        if ok:
            self._since.used.add("position_fix")
            self._since.innovation = (float(y[0]), float(y[1]), math.nan)
        else:
            self._since.rejected += 1
        if mv is not None:  # the producer's velocity: its own measurement, its own gate
            if self._apply(mv)[0]:
                self._since.used.add("position_fix")
            else:
                self._since.rejected += 1

    def _on_altitude(self, ev: AutopilotAltitude) -> None:
        if self.mode != "ins" or self.frame is None or not math.isfinite(ev.alt_msl_m):
            return
        t, ins = ev.t_s, self.ins
        ins.predict(max(t, ins.t_s))
        down = float(ins.state_at(t, delay_s=0.0)[0][2])
        ref = self.frame.ref_alt_m
        m = self._baro.measurement(t, ev.alt_msl_m, ref - down, ref, self._last_fix_t)
        if m is not None and ins.apply(m)[0]:
            self._since.used.add("altitude")

    # ------------------------------------------------------------------ 10 Hz ticks
    def _run_ticks(self, t: float, inclusive: bool) -> None:
        while True:
            tg = self._next_tick * self._tick_dt
            if tg > t or (tg == t and not inclusive):
                break
            self._tick(tg)
            self._next_tick += 1

    def _tick(self, tg: float) -> None:
        if self.recovery.pending is not None:
            return  # after a stream gap nothing is known until the next fix re-initialises
        pt = self.predictor.point(tg, self._last_fix_t)
        if pt is not None:
            p, m = pt
            lat, lon, alt = self.frame.geodetic_tuple(*p.ned_m)
            self._emit(PredictorPoint(tg, *p.ned_m, lat, lon, alt, p.sigma_h_m, p.sigma_v_m, p.age_s, p.method))
            if m is not None and (self._ins_position(m) if self.mode == "ins" else self._kin_position(m)):
                self._since.used.add("predictor")
        if self.mode == "init":
            return
        zv = self._zero_velocity.measurement(tg, self._last_fix_t)
        if zv is not None:
            ok = self.ins.apply(zv)[0] if self.mode == "ins" else (self.kin is not None and self.kin.apply(zv)[0])
            if ok:
                self._since.used.add("zero_velocity")
        if self.mode == "ins":
            ins = self.ins
            ins.predict(tg)
            s = ins.strapdown
            if self.drag is not None:
                age = tg - self._last_fix_t if self._last_fix_t is not None else None
                md = self.drag.measurement(tg, s.dcm(), s.vel_ned, age)
                if md is not None and ins.apply(md)[0]:
                    self._since.used.add("rotor_drag")
            n, e, d = ins.position_ned()
            dt = tg - s.t_s
            n, e, d = n + s.vn * dt, e + s.ve * dt, d + s.vd * dt
            vel = (s.vn, s.ve, s.vd)
            rpy = s.euler()
            P = ins.kf.P
        else:
            if self.kin is None:
                return
            self.kin.predict(tg)
            x, P = self.kin.state()
            n, e, d = float(x[0]), float(x[1]), float(x[2])
            vel = (float(x[3]), float(x[4]), float(x[5]))
            a = self._att
            rpy = (a.roll_rad, a.pitch_rad, a.yaw_rad) if a is not None and tg - a.t_s < 1.0 else (math.nan,) * 3
        if self.motion is not None:
            (n, e, d), P, applied = self.motion.output(tg, (n, e, d), P, self.mode == "ins", self.heading.consistent)
            if applied:
                self._since.used.add("motion_prior")
        diag = tuple(P.diagonal().tolist())
        lat, lon, alt = self.frame.geodetic_tuple(n, e, d)
        used, innovation, rejected = self._since.take()
        self._emit(
            FusedState(
                tg, lat, lon, alt, n, e, d, *vel, *rpy, diag,
                math.sqrt(diag[0] + diag[1]), math.sqrt(diag[2]), self.mode, used, innovation, rejected,
                tg - self._last_fix_t if self._last_fix_t is not None else math.nan,
            )
        )


def run_navigator(events, config: NavigatorConfig | None = None) -> list[Event]:
    """Batch replay: sort the events by (time, type priority) and run them through one Navigator."""
    nav = Navigator(config)
    order = sorted(range(len(events)), key=lambda i: (events[i].t_s, _PRIO.get(type(events[i]), 3), i))
    out: list[Event] = []
    for i in order:
        out.extend(nav.process(events[i]))
    out.extend(nav.finish())
    return out
