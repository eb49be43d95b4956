"""The navigator's aids besides the GNSS fix itself, each building the measurements the active filter is offered: the
KNN predictor's points, the zero velocity of a hover, the autopilot's attitude and the non-GNSS position fix
(PositionFix, e.g. gravity matching); and the sigmas a GNSS fix is fused with. Rotor drag, the motion prior and the
autopilot's altitude are their own modules (companion.nav.drag, motion_prior, baro)."""

from __future__ import annotations

import math

from companion.constants import receiver_sigma
from companion.events import Attitude, GnssFix, PositionFix
from companion.nav.config import NavigatorConfig
from companion.nav.frame import LocalFrame
from companion.nav.hover import HoverDetector
from companion.nav.ins import dcm_from_quat, quat_from_euler
from companion.nav.knn_predictor import KnnPredictor, Prediction
from companion.nav.measurements import (AttitudeMeasurement, HorizontalPositionMeasurement,
                                        HorizontalVelocityMeasurement, PositionMeasurement, VelocityMeasurement)
from companion.nav.monitors import AhrsHeadingCheck


def fix_sigmas(ev: GnssFix, config: NavigatorConfig) -> tuple[float, float, float, float]:
    """(update sigma h, v, gate sigma h, v) of a fix (``gnss_sigma_model``). The gate always uses the receiver's
    accuracy."""
    c = config
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


class PredictorAid:
    """The KNN predictor (Aziez 2021: 9 points between 1 Hz fixes, continuing through blockages): learns from every
    accepted fix, gives a point at each output tick after the last fix, fused as a position whose sigma is scaled by
    ``predictor_sigma_scale`` and, the k-th since its fix, by sqrt(k) (``predictor_decorrelate``): points from one
    anchor share one error."""

    def __init__(self, config: NavigatorConfig) -> None:
        self.config = config
        self.predictor = KnnPredictor(config.knn)
        self._n_fused = 0
        self._anchor: float | None = None

    def add_fix(self, t: float, z, sigma_h_m: float, sigma_v_m: float, vel) -> None:
        self.predictor.add_fix(t, z, sigma_h_m, sigma_v_m, vel)

    def point(self, t: float, last_fix_t: float | None) -> tuple[Prediction, PositionMeasurement | None] | None:
        """The point at output tick t (None before ``predictor_min_age_s`` after the last fix, or none to give), and
        its measurement (None when not fused)."""
        c = self.config
        if last_fix_t is None or t - last_fix_t < max(c.predictor_min_age_s, 1e-9):
            return None
        p = self.predictor.predict(t)
        if p is None:
            return None
        if not c.fuse_predictor:
            return p, None
        self._n_fused = self._n_fused + 1 if self._anchor == last_fix_t else 1
        self._anchor = last_fix_t
        infl = c.predictor_sigma_scale * (math.sqrt(self._n_fused) if c.predictor_decorrelate else 1.0)
        return p, PositionMeasurement(t, "predictor", p.ned_m, p.sigma_h_m * infl, p.sigma_v_m * infl,
                                      gate_chi2=c.gate_chi2)


class ZeroVelocityAid:
    """A detected hover during a blockage (companion.nav.hover): the vehicle is not going anywhere, a zero NED velocity
    with ``zupt_sigma_mps`` every ``zupt_interval_s`` once no fix has come for ``zupt_min_age_s``."""

    def __init__(self, config: NavigatorConfig, hover: HoverDetector) -> None:
        self.config, self.hover = config, hover
        self._t = -math.inf

    def measurement(self, t: float, last_fix_t: float | None) -> VelocityMeasurement | None:
        c = self.config
        if not (c.zero_velocity and last_fix_t is not None and t - last_fix_t >= c.zupt_min_age_s
                and t - self._t >= c.zupt_interval_s and self.hover.hover(t)):
            return None
        self._t = t
        return VelocityMeasurement(t, "zero_velocity", (0.0, 0.0, 0.0), c.zupt_sigma_mps, c.gate_chi2)


class AttitudeAid:
    """The autopilot's attitude as a measurement of the INS attitude, at most every ``att_fuse_interval_s``: its tilt,
    with the variance the heading check allows (companion.nav.monitors), and its heading only once the check has
    confirmed it; a flagged autopilot's tilt only while GNSS aids (``fuse_flagged_tilt_in_gap``), if at all
    (``fuse_flagged_tilt``). docs/decisions/0004-autopilot-attitude.md."""

    def __init__(self, config: NavigatorConfig, heading: AhrsHeadingCheck) -> None:
        self.config, self.heading = config, heading
        self._fused_t = -math.inf

    def due(self, t: float) -> bool:
        """An attitude at t is to be offered (``fuse_attitude``, ``att_fuse_interval_s``)."""
        c = self.config
        if not c.fuse_attitude or t - self._fused_t < c.att_fuse_interval_s:
            return False
        self._fused_t = t
        return True

    def measurement(self, ev: Attitude, ins_yaw_rad, last_fix_t: float | None) -> AttitudeMeasurement | None:
        """``ins_yaw_rad()``: the INS's own heading, used while the autopilot's is not fused."""
        c, heading = self.config, self.heading
        if not heading.consistent and (not c.fuse_flagged_tilt or not c.fuse_flagged_tilt_in_gap and (
                last_fix_t is None or ev.t_s - last_fix_t >= c.gnss_gap_s)):
            return None  # a flagged autopilot's tilt is wrong by degrees in manoeuvres: without GNSS it would mislead
        fuse_yaw = c.fuse_attitude_yaw and heading.fuse_heading()
        # Tilt only: the autopilot's roll/pitch fix the gravity direction in the body frame whatever its heading, so
        # the measured attitude is built with the INS's own heading (built with the autopilot's, a heading
        # disagreement d rotates and mixes the roll/pitch innovations: at d ~ 90 deg a roll error reads as pitch)
        yaw_meas = ev.yaw_rad if fuse_yaw else ins_yaw_rad()
        c_meas = dcm_from_quat(quat_from_euler(ev.roll_rad, ev.pitch_rad, yaw_meas))
        s_yaw = c.att_sigma_yaw_rad if fuse_yaw else 1e3  # 1e3 rad: no heading information
        s_tilt2 = heading.tilt_var_rad2()
        return AttitudeMeasurement(ev.t_s, "attitude", c_meas=c_meas, var_rad2=(s_tilt2, s_tilt2, s_yaw**2),
                                   gate_chi2=c.gate_chi2)


def position_fix_measurements(ev: PositionFix, frame: LocalFrame, config: NavigatorConfig):
    """A non-GNSS horizontal position fix (e.g. gravity matching) at its own epoch, with its own sigmas and its own
    2-dof gate (no reset on persistent rejection: a bad matcher must not drag the solution), and the producer's
    velocity when it gives one: (position, velocity or None), or None for a fix without a usable position."""
    sn, se = float(ev.sigma_n_m), float(ev.sigma_e_m)
    if not (math.isfinite(ev.lat_deg) and math.isfinite(ev.lon_deg) and sn > 0 and se > 0
            and math.isfinite(sn) and math.isfinite(se)):
        return None
    c = config
    z = frame.ned_tuple(ev.lat_deg, ev.lon_deg, frame.ref_alt_m)[:2]
    m = HorizontalPositionMeasurement(ev.t_s, "position_fix", z, sn, se, c.position_fix_gate_chi2,
                                      c.position_fix_position_only)
    mv = None
    svn, sve = float(ev.sigma_vn_mps), float(ev.sigma_ve_mps)
    if (math.isfinite(ev.vel_n_mps) and math.isfinite(ev.vel_e_mps) and math.isfinite(svn) and math.isfinite(sve)
            and svn > 0 and sve > 0):
        mv = HorizontalVelocityMeasurement(ev.t_s, "velocity_fix", (float(ev.vel_n_mps), float(ev.vel_e_mps)),
                                           svn, sve, c.position_fix_gate_chi2, c.position_fix_position_only)
    return m, mv
