"""The navigator's recovery, as a flight computer's filter does it (ArduPilot EKF3 resets to GNSS after a GPS-glitch
timeout): re-initialisation from the next fix after a stream gap, reset of position/velocity after a GNSS gap or
persistent rejection of a good fix, reset of the attitude after persistent rejection of the autopilot attitude.
Every reset is a :class:`companion.nav.outputs.NavigatorReset` output and counted in ``resets``. A mixin of
companion.nav.navigator.Navigator (its state lives on the navigator)."""

from __future__ import annotations

import math

import numpy as np

from companion.events import FixType
from companion.nav.ins import quat_from_euler
from companion.nav.outputs import NavigatorReset


class Recovery:
    """Mixin: gap detection, re-initialisation and the resets after persistent rejection."""

    def _recovery_init(self) -> None:
        self._last_t: float | None = None  # newest event time handled
        self._reinit_pending: tuple[float, float] | None = None  # (gap start, gap end) of a stream gap
        self._reject_since: float | None = None
        self._n_reject_run = 0  # consecutive rejected GNSS positions of a good 3D fix
        self._fix_good = False  # the fix being processed is a good 3D fix
        self._fix_vel = None
        self._fix_seen_t: float | None = None  # newest GNSS position seen, accepted or not
        self._att_reject_since: float | None = None
        self._n_att_reject_run = 0
        self._att_stale = False  # the INS was re-initialised with an attitude from before the gap
        self.resets: dict[str, int] = {}

    def _emit_reset(self, t: float, kind: str, reason: str, filt: str, dp: float, dv: float) -> None:
        self.resets[kind] = self.resets.get(kind, 0) + 1
        self._out.append(NavigatorReset(t, kind, reason, filt, float(dp), float(dv)))

    # ------------------------------------------------------------------ stream gap
    def _check_stream_gap(self, t: float) -> None:
        """No event at all for > reinit_gap_s: do not emit ticks across it; re-initialise at the next fix."""
        last = self._last_t
        if last is None or t > last:
            self._last_t = t
        if last is None or t - last <= self.config.reinit_gap_s:
            return
        if self.mode != "init":
            self._reinit_pending = (last, t)
        if self._next_tick is not None:
            self._next_tick = max(self._next_tick, math.ceil(t / self._tick_dt - 1e-9))

    def _reinit(self, t: float, z, vel) -> None:
        """Re-initialise the active filter from this fix after a stream gap (whatever the message order)."""
        gap0, gap1 = self._reinit_pending
        self._reinit_pending = None
        self._reject_since, self._n_reject_run = None, 0
        self._att_reject_since, self._n_att_reject_run = None, 0
        self._al_anchor = None
        reason = f"stream gap {gap0:.3f} .. {gap1:.3f} s ({gap1 - gap0:.1f} s)"
        if self.mode == "ins" and self.ins is not None and self._att is not None:
            old = self.ins
            p_old = np.array(self.frame.ned_tuple(old.lat_deg, old.lon_deg, old.h_m))
            v_old = np.array(old.vel_ned)
            pb = self._kf.P[9:15, 9:15].copy()
            ba, bg = list(old.ba), list(old.bg)
            self._ins_init(t, z, vel, t_ins=self._last_imu_t if self._last_imu_t is not None and self._last_imu_t >= gap1
                           else t)
            self.ins.ba, self.ins.bg = ba, bg  # biases are a property of the sensor: kept
            self._kf.P[9:15, 9:15] = pb
            self._att_stale = self._att.t_s < gap1  # its attitude is from before the gap: the next one replaces it
            filt = "ins"
            dp = float(np.linalg.norm(np.asarray(z) - p_old))
            dv = float(np.linalg.norm(np.array(self.ins.vel_ned) - v_old))
        else:
            filt = "kinematic"
            dp = dv = math.nan
            if self._kin is not None:
                x = self._kin.x.ravel()
                dp = float(np.linalg.norm(np.asarray(z) - x[0:3]))
        self._kin_init(t, z, vel)
        if self.drag is not None:
            self.drag.reset()
        if self.motion is not None:
            self.motion.reset()
        self._emit_reset(t, "reinit", reason, filt, dp, dv)

    def _attitude_after_gap(self, ev) -> None:
        """The first autopilot attitude after a stream gap re-initialises the INS attitude when the re-initialisation
        had to use one from before the gap (minutes old, and any tilt while manoeuvring): fused instead, it would be
        an outlier for the gate (45 s cut in log171 at 1 Hz: 30 deg of pitch, every attitude rejected)."""
        self._att_stale = False
        c = self.config
        self._ins_predict(max(ev.t_s, self._kf_t))
        self.ins.q = quat_from_euler(ev.roll_rad, ev.pitch_rad, ev.yaw_rad)
        P = self._kf.P
        P[6:9, :] = 0.0
        P[:, 6:9] = 0.0
        P[6, 6] = P[7, 7] = c.init_sigma_att_rad**2
        P[8, 8] = c.init_sigma_yaw_rad**2
        if not self.ahrs_consistent and math.isfinite(self.ahrs_heading_offset_rad):
            self._align_yaw(ev.t_s)

    # ------------------------------------------------------------------ persistent GNSS rejection
    def _gate_bookkeeping(self, t: float, ok: bool, y, sh: float, sv: float, force: bool = False) -> bool:
        """Persisting rejection of a good 3D fix (N consecutive or T seconds) is a real step, not a glitch: reset
        position (and velocity, when the fix has it) to GNSS with the fix's covariance. ``force``: the first fix
        after a GNSS gap > reinit_gap_s; rejected, it resets at once."""
        c = self.config
        if ok:
            self._reject_since, self._n_reject_run = None, 0
            return True
        if not self._fix_good:
            return False
        if self._reject_since is None:
            self._reject_since = t
        self._n_reject_run += 1
        if not force and self._n_reject_run < c.reset_after_n_rejected and t - self._reject_since < c.gate_reset_s:
            return False
        kind = "gnss_gap" if force else "gnss_rejected"
        reason = (f"first fix after a GNSS gap > {c.reinit_gap_s:g} s outside the gate" if force else
                  f"{self._n_reject_run} GNSS positions rejected over {t - self._reject_since:.1f} s")
        self._reject_since, self._n_reject_run = None, 0
        if self.mode == "ins":
            kf = self._kf
            # each velocity component the fix has (GPS_RAW_INT has no vertical one) is reset with the position: a
            # reset of the position alone kept a velocity 17 m/s off and the output left its stated accuracy
            dv = np.zeros(3)
            var_v = np.full(3, c.gnss_vel_sigma_mps**2 * c.reset_cov_scale + 1.0)
            vel = self._fix_vel
            if vel is not None:
                v_ins = self._ins_state_at(t)[1]
                for i in range(3):
                    if math.isfinite(vel[i]):
                        dv[i] = vel[i] - v_ins[i]
                        var_v[i] -= 1.0
            kf.P[0:6, :] = 0.0
            kf.P[:, 0:6] = 0.0
            kf.P[0:3, 0:3] = np.diag([sh**2, sh**2, sv**2]) * c.reset_cov_scale
            kf.P[3:6, 3:6] = np.diag(var_v)
            self._correct_ins(y, dv, (0, 0, 0), (0, 0, 0), (0, 0, 0))
            self._emit_reset(t, kind, reason, "ins", float(np.linalg.norm(y)), float(np.linalg.norm(dv)))
        else:
            self._emit_reset(t, kind, reason, "kinematic", float(np.linalg.norm(y)), math.nan)
        return True

    # ------------------------------------------------------------------ persistent attitude rejection
    def _attitude_bookkeeping(self, t: float, ok: bool, y) -> None:
        """N consecutive or T seconds of rejected autopilot tilt: reset the INS tilt to it, inflate its variance."""
        c = self.config
        if ok:
            self._att_reject_since, self._n_att_reject_run = None, 0
            return
        if self._att_reject_since is None:
            self._att_reject_since = t
        self._n_att_reject_run += 1
        if self._n_att_reject_run < c.att_reset_after_n_rejected and t - self._att_reject_since < c.gate_reset_s:
            return
        n = self._n_att_reject_run
        self._att_reject_since, self._n_att_reject_run = None, 0
        psi = np.array([y[0], y[1], 0.0])  # tilt only: the heading has its own check (AhrsHeadingCheck)
        self._correct_ins((0, 0, 0), (0, 0, 0), psi, (0, 0, 0), (0, 0, 0))
        P = self._kf.P
        P[6:8, :] = 0.0
        P[:, 6:8] = 0.0
        P[6, 6] = P[7, 7] = c.init_sigma_att_rad**2 * c.reset_cov_scale
        self._emit_reset(t, "attitude_rejected", f"{n} autopilot attitudes rejected", "ins",
                         math.nan, float(np.linalg.norm(psi)))

    def _note_fix(self, ev, vel) -> bool:
        """Remember the fix's quality and velocity; True if it ends a GNSS gap > reinit_gap_s (no fix at all)."""
        self._fix_good = ev.fix_type >= FixType.FIX_3D
        self._fix_vel = vel
        prev, self._fix_seen_t = self._fix_seen_t, ev.t_s
        return prev is not None and ev.t_s - prev > self.config.reinit_gap_s and self.config.reset_after_rejection
