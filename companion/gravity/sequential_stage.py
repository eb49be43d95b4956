"""The sequential gravity filter (companion.gravity.sequential) as a stage of the product's pipeline.

    ... --> Navigator --> FusedState, FrameInfo
      --> SequentialGravityStage (every GravityReading updates the filter at the navigator's state) --> PositionFix,
          SequentialRecord
      --> (PositionFix goes back to the Navigator like any other measurement: companion.pipeline.core)

The filter estimates the navigator's own horizontal position and velocity error (its reference is the navigator's
state at each reading, interpolated between the two bracketing FusedState outputs). Two things keep the loop
honest when the navigator fuses the filter's output:

* **What the navigator already knows is not counted twice.** The filter's distribution already contains the
  navigator's prior (the same INS, the same GNSS before the cut), so the fix sent is the filter's posterior with the
  navigator's prior divided out, per axis (the channel filter of distributed estimation):
  ``1/R = 1/P_filter - 1/P_nav``, ``z = R (m_filter/P_filter - x_nav/P_nav)``. Fusing it makes the navigator's
  horizontal mean and variance the filter's; a fix is sent only when the filter is at least ``min_gain`` more certain
  than the navigator on an axis, only while the filter says "ok" (tracking, map signal, one mode).
* **The navigator's correction moves the filter's errors with it.** When a FusedState reports that a position_fix
  was applied, the jump of its position and velocity over that output interval (beyond the motion and acceleration
  of the previous interval) is the correction: the filter's error particles and velocity-error states move by it
  (SequentialGravityFilter.apply_correction), so the filter keeps estimating the error of the corrected navigator.

While GNSS keeps the navigator better than ``anchor_h_sigma_m`` (a fix accepted within ``gnss_recent_s``) the
filter is pinned to it and learns the map misfit.
Readings come in the navigator's vehicle time; Eotvos: a reading the sender did not correct
(``eotvos_corrected=False``) is corrected here with the navigator's velocity (Gao 2022 eqs. 5-6), and its velocity
error then shows in the reading (the filter's Eotvos Jacobian). Pure: vehicle time only (CPU time per reading is
recorded for reporting).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from companion.events import Event, GravityReading, PositionFix
from companion.gravity.eotvos import eotvos_from_ne_mgal
from companion.gravity.maps import LocalGravityMap
from companion.gravity.placement import MapView, Placement
from companion.gravity.reading_stage import GravityReadingStage
from companion.gravity.sequential import InsErrorSpec, SeqGravConfig, SequentialGravityFilter
from companion.gravity.wind_shift import WindShiftSpec
from companion.nav.outputs import FusedState

#: a fix leaves this as a position sigma on an axis the filter adds nothing to (no information there)
NO_INFO_SIGMA_M = 1.0e7
#: the same for a velocity axis
NO_INFO_SIGMA_MPS = 1.0e4


@dataclass(frozen=True, slots=True)
class SequentialRecord(Event):
    """The sequential filter after one reading. north_m/east_m: its position in the navigator's frame; h_acc_m
    sqrt(trace P) of its own distribution; status: ok | anchored | no_signal | multimodal | reinit | off_map; sent:
    a PositionFix went to the navigator (fix_sigma_*: its per-axis sigma, NaN if none)."""

    status: str
    north_m: float
    east_m: float
    lat_deg: float
    lon_deg: float
    h_acc_m: float
    nav_sigma_h_m: float
    n_eff: float
    signal_ratio: float
    nis_mean: float
    reinit_count: int
    map_bias_mgal: float
    sent: bool
    fix_sigma_n_m: float
    fix_sigma_e_m: float
    compute_time_s: float
    topic: ClassVar[str] = "/gravity/sequential"


def channel_fix(m_filter: float, p_filter: float, x_nav: float, p_nav: float, min_gain: float) -> tuple[float, float] | None:
    """(z, R) of the pseudo-measurement that turns the navigator's (x_nav, p_nav) into the filter's (m_filter,
    p_filter) on one axis, or None when the filter is not at least ``min_gain`` (fraction) more certain."""
    if not (p_filter > 0 and p_nav > 0 and p_filter < (1.0 - min_gain) * p_nav):
        return None
    r = 1.0 / (1.0 / p_filter - 1.0 / p_nav)
    return r * (m_filter / p_filter - x_nav / p_nav), r


class SequentialGravityStage(GravityReadingStage):
    """FusedState + GravityReading -> SequentialGravityFilter.feed -> PositionFix + SequentialRecord (module doc).

    A reading is used once a FusedState at or after its time is seen (older than every state: dropped)."""

    def __init__(self, lmap: LocalGravityMap, cfg: SeqGravConfig | None = None, placement: Placement | None = None, *,
                 geographic: bool = False, sigma_mgal: float = 1.0, source: str = "gravity:sequential",
                 seed: int = 0, min_gain: float = 0.1, gnss_recent_s: float = 2.0, velocity_fixes: bool = False) -> None:
        if not (sigma_mgal > 0 and 0.0 <= min_gain < 1.0):
            raise ValueError("sigma_mgal must be > 0 and min_gain in [0, 1)")
        self.lmap = lmap
        self.cfg = cfg or SeqGravConfig()
        self.view = MapView(lmap, placement or Placement(), bool(geographic))
        self.filter = SequentialGravityFilter(lmap, self.cfg, np.random.default_rng(seed))
        self.sigma_mgal = float(sigma_mgal)
        self.source = source
        self.min_gain = float(min_gain)
        self.gnss_recent_s = float(gnss_recent_s)
        self.velocity_fixes = bool(velocity_fixes)
        self.matcher_name = f"sequential-{self.cfg.method}"
        super().__init__()
        self._prev: tuple[FusedState, np.ndarray] | None = None  # last state and its map sample
        self._acc_ne = np.zeros(2)  # map-frame acceleration over the previous output interval
        self._fix_out = False  # a fix was sent and the navigator has not reported fusing it yet
        self.n_readings = self.n_fixes = self.n_corrections = 0
        self.status_counts: Counter = Counter()
        self.reinit_count = 0
        self.cpu_s: list[float] = []

    # -- stream ------------------------------------------------------------------------------------
    def _state(self, s: FusedState) -> list[Event]:
        x = self.view.state(s, self._frame)
        if not np.all(np.isfinite(x)):
            return []
        prev = self._prev
        if prev is not None and s.t_s > prev[0].t_s:
            a, xa = prev
            dt = s.t_s - a.t_s
            if "position_fix" in s.measurement.split("+") and self._fix_out:
                # the navigator fused our fix in this interval: its jump beyond the motion is the correction
                v_pred = xa[2:] + self._acc_ne * dt
                d_vel = x[2:] - v_pred
                d_pos = x[:2] - (xa[:2] + 0.5 * (xa[2:] + x[2:]) * dt)
                self.filter.apply_correction(d_pos, d_vel)
                self.n_corrections += 1
                self._fix_out = False
                xa = np.concatenate([xa[:2] + d_pos, xa[2:] + d_vel])  # the earlier state as if corrected already
            else:
                self._acc_ne = (x[2:] - xa[2:]) / dt
            out: list[Event] = []
            while self._pending and self._pending[0].t_s <= s.t_s:
                r = self._pending.popleft()
                if r.t_s >= a.t_s:
                    out += self._reading(r, a, s, xa, x)
            self._prev = (s, x)
            return out
        while self._pending and self._pending[0].t_s <= s.t_s:
            self._pending.popleft()  # older than every state
        self._prev = (s, x)
        return []

    def _reading(self, r: GravityReading, a: FusedState, b: FusedState, xa: np.ndarray, xb: np.ndarray) -> list[Event]:
        w = (r.t_s - a.t_s) / (b.t_s - a.t_s) if b.t_s > a.t_s else 1.0
        x = xa + w * (xb - xa)
        var_n = (1 - w) * a.cov_diag[0] + w * b.cov_diag[0]
        var_e = (1 - w) * a.cov_diag[1] + w * b.cov_diag[1]
        nav_cov = np.diag([var_n, var_e])
        lat = (1 - w) * a.lat_deg + w * b.lat_deg
        heading = self._map_heading(a if w < 0.5 else b, x)
        g = float(r.gravity_mgal)
        if not r.eotvos_corrected:
            g -= float(eotvos_from_ne_mgal(x[2:], lat))
        sigma = float(r.sigma_mgal) if r.sigma_mgal is not None and r.sigma_mgal > 0 else self.sigma_mgal
        # pinned to the navigator only while GNSS keeps it good (not while it is good because of our own fixes)
        gnss_age = b.age_since_fix_s if w >= 0.5 else a.age_since_fix_s
        anchored = (math.sqrt(max(var_n + var_e, 0.0)) <= self.cfg.anchor_h_sigma_m
                    and math.isfinite(gnss_age) and gnss_age <= self.gnss_recent_s)
        first = self.filter.t_s is None  # the prior: the navigator's own covariance
        e = self.filter.feed(r.t_s, g, x[:2], x[2:], sigma, ref_cov_ne_m2=nav_cov if anchored or first else None,
                             heading_rad=heading, lat_deg=lat, eotvos_from_reference=not r.eotvos_corrected,
                             anchor=anchored)
        if e is None:
            return []
        self.n_readings += 1
        self.status_counts[e.status] += 1
        self.reinit_count = e.reinit_count
        self.cpu_s.append(e.cpu_s)
        out: list[Event] = []
        fix_sig = (math.nan, math.nan)
        sent = False
        if e.usable:
            pf = np.diag(e.cov_ne_m2)
            axes = [channel_fix(e.pos_ne_m[i], pf[i], x[i], (var_n, var_e)[i], self.min_gain) for i in range(2)]
            if any(ax is not None for ax in axes):
                z = np.array([ax[0] if ax is not None else x[i] for i, ax in enumerate(axes)])
                sig = [math.sqrt(ax[1]) if ax is not None else NO_INFO_SIGMA_M for ax in axes]
                lat_z, lon_z, _ = self.view.to_geodetic(z, self._frame)
                vel = self._velocity_fix(e, a if w < 0.5 else b, x, w, a, b) if self.velocity_fixes else None
                out.append(PositionFix(float(r.t_s), lat_z, lon_z, sig[0], sig[1], self.source,
                                       *(vel if vel is not None else ())))
                fix_sig = (sig[0], sig[1])
                sent = True
                self.n_fixes += 1
                self._fix_out = True
        lat_o, lon_o, ne = self.view.to_geodetic(e.pos_ne_m, self._frame)
        out.insert(0, SequentialRecord(float(r.t_s), e.status, float(ne[0]), float(ne[1]), lat_o, lon_o, float(e.h_acc_m),
                                       math.sqrt(max(var_n + var_e, 0.0)), float(e.n_eff), float(e.signal_ratio),
                                       float(e.nis_mean), int(e.reinit_count), float(e.map_bias_mgal), sent, *fix_sig,
                                       float(e.cpu_s)))
        return out

    def _velocity_fix(self, e, s: FusedState, x: np.ndarray, w: float, a: FusedState, b: FusedState):
        """(vel_n, vel_e, sigma_vn, sigma_ve) in the navigator's NED: its velocity less the filter's estimate of its
        error, with the navigator's velocity variance divided out per axis as for the position (channel_fix); None
        when the filter has no velocity states or adds nothing on either axis."""
        if e.vel_err_ne_mps is None or not np.all(np.isfinite(e.vel_err_ne_mps)) or len(a.cov_diag) < 5:
            return None
        A = self._map_to_ned(s, x)
        dv = A @ e.vel_err_ne_mps
        pf = np.diag(A @ e.vel_cov_ne_m2ps2 @ A.T)
        v_nav = ((1 - w) * a.vel_n_mps + w * b.vel_n_mps, (1 - w) * a.vel_e_mps + w * b.vel_e_mps)
        p_nav = ((1 - w) * a.cov_diag[3] + w * b.cov_diag[3], (1 - w) * a.cov_diag[4] + w * b.cov_diag[4])
        axes = [channel_fix(v_nav[i] - dv[i], pf[i], v_nav[i], p_nav[i], self.min_gain) for i in range(2)]
        if all(ax is None for ax in axes):
            return None
        z = [ax[0] if ax is not None else v_nav[i] for i, ax in enumerate(axes)]
        sig = [math.sqrt(ax[1]) if ax is not None else NO_INFO_SIGMA_MPS for ax in axes]
        return float(z[0]), float(z[1]), sig[0], sig[1]

    def _map_to_ned(self, s: FusedState, x: np.ndarray) -> np.ndarray:
        """The 2x2 map that turns a map-frame horizontal vector into the navigator's north/east."""
        if not self.view.geographic:
            pl = self.view.placement
            return np.column_stack([pl.to_flight(np.array([1.0, 0.0])) - pl.to_flight(np.zeros(2)),
                                    pl.to_flight(np.array([0.0, 1.0])) - pl.to_flight(np.zeros(2))])
        rot = 0.0  # the map's north against the navigator's: the angle between the velocity in both frames
        if math.hypot(s.vel_n_mps, s.vel_e_mps) > 0.5:
            rot = math.atan2(x[3], x[2]) - math.atan2(s.vel_e_mps, s.vel_n_mps)
        c, sn = math.cos(rot), math.sin(rot)
        return np.array([[c, sn], [-sn, c]])

    def _map_heading(self, s: FusedState, x: np.ndarray) -> float | None:
        """The navigator's yaw turned into the map frame (by the angle between its velocity in both frames)."""
        if not math.isfinite(s.yaw_rad):
            return None
        if self.view.geographic or self.view.placement.rotation_deg == 0.0:
            rot = 0.0
            if self.view.geographic and math.hypot(s.vel_n_mps, s.vel_e_mps) > 0.5:
                rot = math.atan2(x[3], x[2]) - math.atan2(s.vel_e_mps, s.vel_n_mps)
        else:
            rot = math.radians(self.view.placement.rotation_deg)
        return s.yaw_rad + rot

    # -- reporting ---------------------------------------------------------------------------------
    def metadata(self) -> dict[str, str]:
        cpu = np.asarray(self.cpu_s) * 1e3
        c = self.cfg
        return {"matcher": self.matcher_name, "readings": str(self.n_readings), "fixes": str(self.n_fixes),
                "corrections_seen": str(self.n_corrections), "reinit": str(self.reinit_count),
                "status": ", ".join(f"{k}={v}" for k, v in sorted(self.status_counts.items())),
                "particles": str(c.n_particles) if c.method == "mpf" else f"{c.pmf_grid}x{c.pmf_grid}",
                "ins_model": (f"gyro {c.ins.gyro_bias_degph:g} deg/h, accel {c.ins.accel_bias_ug:g} ug, "
                              f"ARW {c.ins.gyro_arw_deg_rthr:g} deg/rt(h), VRW {c.ins.accel_vrw_ug_rthz:g} ug/rt(Hz)"
                              + (f", attitude held by a reference: tau {c.ins.attitude_tau_s:g} s, tilt "
                                 f"{c.ins.attitude_tilt_sigma_rad:g} rad, heading {c.ins.attitude_heading_sigma_rad:g} rad"
                                 if c.ins.attitude_tau_s > 0 else "")),
                "min_gain": f"{self.min_gain:g}", "placement": self.view.describe(),
                "cpu_ms_per_reading_p50": f"{np.median(cpu):.3f}" if cpu.size else "nan",
                "cpu_ms_per_reading_p99": f"{np.percentile(cpu, 99):.3f}" if cpu.size else "nan"}

    def summary_lines(self) -> list[str]:
        cpu = np.asarray(self.cpu_s) * 1e3
        st = ", ".join(f"{k} {v}" for k, v in sorted(self.status_counts.items())) or "none"
        cpu_txt = f"; CPU {np.median(cpu):.2f} ms median, {np.percentile(cpu, 99):.2f} ms p99 per reading" if cpu.size else ""
        return [f"gravity      {self.n_readings} readings ({self.matcher_name}), {self.n_fixes} fixes sent, "
                f"{self.n_corrections} navigator corrections followed, {self.reinit_count} re-initialisations; "
                f"status: {st}{cpu_txt}"]


def seq_config_of(gravity) -> SeqGravConfig:
    """The filter's settings from ``[gravity]`` (companion.config.GravityConfig: its ``seq_*`` keys)."""
    ins = InsErrorSpec(gyro_bias_degph=gravity.seq_gyro_bias_degph, accel_bias_ug=gravity.seq_accel_bias_ug,
                       gyro_arw_deg_rthr=gravity.seq_gyro_arw_deg_rthr, accel_vrw_ug_rthz=gravity.seq_accel_vrw_ug_rthz,
                       init_vel_sigma_mps=gravity.seq_init_vel_sigma_mps, attitude_tau_s=gravity.seq_attitude_tau_s,
                       attitude_tilt_sigma_rad=gravity.seq_attitude_tilt_sigma_rad,
                       attitude_heading_sigma_rad=gravity.seq_attitude_heading_sigma_rad,
                       air_data=getattr(gravity, "reference", "navigator") == "air_data",
                       wind_walk_mps_rts=getattr(gravity, "seq_wind_walk_mps_rts", 0.0),
                       air_heading=getattr(gravity, "reference", "navigator") == "air_data"
                       and getattr(gravity, "air_heading", "attitude") == "gyro",
                       gyro_bias_walk_degph_rth=getattr(gravity, "air_gyro_bias_walk_degph_rth", 0.0))
    shift = WindShiftSpec(step_mps=getattr(gravity, "seq_wind_shift_mps", 0.0),
                          nis_ratio=getattr(gravity, "seq_wind_shift_nis_ratio", WindShiftSpec.nis_ratio))
    return SeqGravConfig(n_particles=gravity.seq_particles, noise_corr_s=gravity.seq_noise_corr_s, ins=ins,
                         wind_shift=shift)
