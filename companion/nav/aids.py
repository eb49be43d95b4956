"""The navigator's aids besides GNSS: the KNN predictor's points, the non-GNSS position fix (PositionFix, e.g. gravity
matching), the zero velocity of a hover, rotor drag and the motion prior; and the GNSS sigmas. A mixin of
companion.nav.navigator.Navigator (its state lives on the navigator)."""

from __future__ import annotations

import math

import numpy as np

from companion.constants import receiver_sigma
from companion.events import GnssFix, PositionFix
from companion.nav.measurements import (DragMeasurement, HorizontalPositionMeasurement, HorizontalVelocityMeasurement,
                                        PositionMeasurement,
                                         VelocityMeasurement)
from companion.nav.motion_prior import blend
from companion.nav.outputs import PredictorPoint


class Aids:
    """Mixin: fix sigmas, the PositionFix aid, the zero-velocity pseudo-measurement, rotor drag and the motion prior."""

    def _predictor_tick(self, tg: float) -> None:
        """The KNN predictor's point at an output tick (Aziez 2021: 9 points between 1 Hz fixes, continuing through
        blockages), fused as a position measurement."""
        c = self.config
        if self._last_fix_t is not None and tg - self._last_fix_t >= max(c.predictor_min_age_s, 1e-9):
            p = self.predictor.predict(tg)
            if p is not None:
                lat, lon, alt = self.frame.geodetic_tuple(*p.ned_m)
                self._out.append(
                    PredictorPoint(tg, *p.ned_m, lat, lon, alt, p.sigma_h_m, p.sigma_v_m, p.age_s, p.method)
                )
                if c.fuse_predictor:
                    # points from one anchor share one error: inflate R by the count fused since the fix
                    self._n_pred_fused = self._n_pred_fused + 1 if self._pred_anchor == self._last_fix_t else 1
                    self._pred_anchor = self._last_fix_t
                    infl = c.predictor_sigma_scale * (math.sqrt(self._n_pred_fused) if c.predictor_decorrelate else 1.0)
                    m = PositionMeasurement(tg, "predictor", p.ned_m, p.sigma_h_m * infl, p.sigma_v_m * infl,
                                            gate_chi2=c.gate_chi2)
                    ok = self._ins_position_update(m) if self.mode == "ins" else self._kin_update(m, True)
                    if ok:
                        self._used.add("predictor")

    def _motion_learn(self, t: float, z, v3, sh: float, sv: float) -> None:
        """An accepted fix for the motion prior, with the INS state and its free (uncorrected) trajectory."""
        ins, epoch = None, self._ins_epoch
        if self.mode == "ins" and self.ins is not None:
            i = self.ins
            p, v = self.frame.ned_tuple(i.lat_deg, i.lon_deg, i.h_m), i.vel_ned
            ins = (p, v, *self._ins_free(p, v))
        elif self.motion.config.select and self._kin is not None:  # the kinematic filter's dead reckoning: x + v dt
            x = self._kin.x.ravel().tolist()
            ins, epoch = (x[0:3], x[3:6], (0.0,) * 3, (0.0,) * 3), -2
        self.motion.add_fix(t, z, v3, (sh * sh, sh * sh, sv * sv), self.hover.hover(t), ins, epoch)

    def _motion_blend(self, t: float, ned, P: np.ndarray):
        """The output position after the product with the motion prior (companion.nav.motion_prior), and its
        covariance; unchanged while the prior has nothing to say."""
        if self.motion.config.select and self.mode != "ins":  # see MotionPriorConfig.select
            sel = self.motion.select(t, ned)
            if sel is None:
                return ned, P
            P = P.copy()
            P[0, 0], P[1, 1], P[2, 2] = sel[1]
            self._used.add("motion_prior")
            return tuple(sel[0]), P
        prior = self.motion.predict(t)
        if prior is None:
            return ned, P
        if self.mode != "ins" or not self.ahrs_consistent:  # the learnt INS error is that of an attitude-aided INS
            prior = (prior[0], prior[1], None)
        ned, var = blend(ned, (P[0, 0], P[1, 1], P[2, 2]), prior, self.motion.config.consistency_sigma)
        P = P.copy()
        P[0, 0], P[1, 1], P[2, 2] = var
        self._used.add("motion_prior")
        return ned, P

    def _rotor_drag_tick(self, t: float) -> None:
        """INS mode, at an output tick: learn the rotor-drag model while GNSS aids, fuse it once GNSS is gone
        (companion.nav.drag)."""
        drag, ins = self.drag, self.ins
        iv = drag.tick(t, ins.dcm(), ins.vel_ned)
        if iv is None or self._last_fix_t is None:
            return
        dc = drag.config
        age = t - self._last_fix_t
        if age <= dc.learn_max_fix_age_s:
            if math.hypot(ins.vn, ins.ve) >= dc.learn_min_speed_mps:
                drag.learn(iv)
            return
        model = drag.model() if age >= dc.min_fix_age_s else None
        if model is None:
            return
        th, cov, s2 = model
        k = float(th[0])
        R = np.diag(s2) * dc.sigma_scale**2 + iv.rows_end @ cov @ iv.rows_end.T
        # the interval mean carried to its end with the model (the innovation is that of the interval means)
        z = np.asarray(iv.f_xy) + (iv.rows_end - iv.rows) @ th
        m = DragMeasurement(t, "rotor_drag", (float(z[0]), float(z[1])), k, (float(th[1] / k), float(th[2] / k)),
                            (float(th[3]), float(th[4])), (float(R[0, 0]), float(R[0, 1]), float(R[1, 1])))
        if self._ins_apply(m)[0]:
            self._used.add("rotor_drag")

    def _zero_velocity_update(self, t: float) -> None:
        """A detected hover during a blockage: the vehicle is not going anywhere (companion.nav.hover)."""
        c = self.config
        self._zupt_t = t
        m = VelocityMeasurement(t, "zero_velocity", (0.0, 0.0, 0.0), c.zupt_sigma_mps, c.gate_chi2)
        ok = self._ins_apply(m)[0] if self.mode == "ins" else (self._kin is not None and self._kin_apply(m, True)[0])
        if ok:
            self._used.add("zero_velocity")

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
        z = self.frame.ned_tuple(ev.lat_deg, ev.lon_deg, self._ref[2])[:2]
        m = HorizontalPositionMeasurement(ev.t_s, "position_fix", z, sn, se, self.config.position_fix_gate_chi2,
                                          self.config.position_fix_position_only)
        if self.mode != "ins" and self._kin is None:
            return
        ok, y = self._fix_apply(m)
        if ok:
            self._used.add("position_fix")
            self._last_innov = (float(y[0]), float(y[1]), math.nan)
        else:
            self._n_rejected += 1
        svn, sve = float(ev.sigma_vn_mps), float(ev.sigma_ve_mps)
        if (math.isfinite(ev.vel_n_mps) and math.isfinite(ev.vel_e_mps) and math.isfinite(svn) and math.isfinite(sve)
                and svn > 0 and sve > 0):  # the producer's velocity: its own measurement, its own gate
            mv = HorizontalVelocityMeasurement(ev.t_s, "velocity_fix", (float(ev.vel_n_mps), float(ev.vel_e_mps)),
                                               svn, sve, self.config.position_fix_gate_chi2,
                                               self.config.position_fix_position_only)
            if self._fix_apply(mv)[0]:
                self._used.add("position_fix")
            else:
                self._n_rejected += 1

    def _fix_apply(self, m) -> tuple[bool, np.ndarray]:
        if self.mode == "ins":
            return self._ins_apply(m)
        ok, y, _nis = self._kin_apply(m, record=True)
        return ok, y
