"""Sequential gravity map matching for slow vehicles: every gravimeter reading updates the filter.

The filter estimates the horizontal error of a reference navigation solution (a free INS, or the navigator's
prediction without gravity aiding): ``error = reference - truth``. Its corrected position is
``reference - error``. Readings are scalar anomalies (mGal) already Eotvos-corrected with the reference velocity
(Gao 2022 eqs. 5-6).

Two back-ends on the same front-end (time handling, map tiles, divergence and signal checks, outputs):

``mpf`` (default) -- marginalised (Rao-Blackwellised) particle filter after Schoen, Gustafsson & Nordlund 2005 in the
    shared-covariance form of MIT MagNav.jl's ``mpf``: the two horizontal position errors are particles (the map is
    the non-linear part); the 13 linear states ride in one Kalman filter per particle that shares its covariance
    ``Pl`` (the model is linear and H is common to all particles, so every particle's Pl is the same):
        xl = [dsN, dsE, dvN, dvE, psiN, psiE, psiD, bgx, bgy, bgz, bax, bay, b_map]
    the dynamic part of the position error (what the Schuler loop feeds back; an initial offset does not excite it),
    velocity error, psi-angle attitude error, body-frame gyro and accelerometer biases (random constants), and the
    map-minus-sensor misfit ``b_map`` as a first-order Gauss-Markov process in distance sailed (correlation length
    ``MapErrorSpec.corr_length_m``). The measurement is
        y = map(reference - dr) - J dv + b_map + v,     v ~ N(0, sigma_mgal^2)
    with J the Eotvos sensitivity (mGal per m/s, Gao eq. 5 differentiated): the correction used the reference
    velocity, so a velocity error leaves -J dv in the reading. Measurement update: Schoen eqs. 22, 25a (weights from
    the predictive variance V = H Pl H' + R); time update: eqs. 23-24, 25b.
``pmf`` -- point-mass filter on a moving 2-D grid over the position error with a per-point misfit state; the INS
    error enters only as a random walk (no velocity states). Kept to compare against (replay/results/gravity_marine.md).

Learnt misfit sigma (``MapErrorSpec.learn_window_m``): the spread of reading minus the cloud's mean map value over a
long window sets the misfit's process noise (docs/decisions/0008-gravity-map-misfit.md).

INS error model (both back-ends, and the INS-alone covariance the filter carries for re-initialisation): the
psi-angle model of Titterton & Weston ch. 12 as in replay.gravity.sim.simulate_ins --
    dr' = dv;  dv' = f x psi + C_b^n ba - (g/R) dr  (Schuler);  psi' = -w_in x psi - C_b^n bg,
with white velocity (VRW) and angle (ARW) noise; yaw-only body-to-nav rotation (a ship is level).
``InsErrorSpec.air_data``: air-data dead reckoning (companion.gravity.air_data): dr' = dv, dv' = white (the held wind's
error walks); ``air_heading`` adds the heading error psiD: dr' += psiD (-vE_air, vN_air), psiD' = bgz + w, bgz' = w.

Divergence (innovations inconsistent, no particle explaining the reading, a spread or estimate implausible under the
INS-alone covariance) re-initialises around the reference; too little map variation along the track over
``signal_window_m`` against the reading noise gives ``no_signal`` (docs/gravity.md).

Pure numpy, no wall clock (CPU time per reading is measured with time.process_time for reporting only).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from companion.gravity.maps import LocalGravityMap
from companion.gravity.particle import FieldSampler
from companion.gravity.wind_shift import WindShiftDetector, WindShiftSpec
from companion.gravity.sequential_backends import (  # noqa: F401 - the model is part of this module's interface
    DEGPH_RADPS, G0_MPS2, IB, IBA, IBG, IPSI, IS, IV, N_ALL, N_LIN, N_NL, UG_MPS2, MisfitVarianceLearner, Status,
    _chol_psd, _Mpf, _Pmf,
    _weighted_moments, continuous_noise, discretise, eotvos_jacobian_mgal_per_mps, error_dynamics, prior_covariance,
)


# ---- configuration -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class InsErrorSpec:
    """1-sigma INS error sources the filter assumes (marine grade: Liu 2019 sec. 4.1 -- 0.01 deg/h gyro drift,
    100 ug accelerometer bias, 0.1' level and 0.5' heading initial errors)."""

    gyro_bias_degph: float = 0.01
    accel_bias_ug: float = 100.0
    gyro_arw_deg_rthr: float = 0.001
    accel_vrw_ug_rthz: float = 10.0
    init_vel_sigma_mps: float = 0.05
    init_tilt_sigma_rad: float = float(np.radians(0.1 / 60))
    init_heading_sigma_rad: float = float(np.radians(0.5 / 60))
    # > 0: the attitude is held by an attitude reference (an AHRS the navigator fuses) whose errors are first-order
    # Gauss-Markov with this time constant and these sigmas; the gyro terms and the Schuler loop then do not apply
    attitude_tau_s: float = 0.0
    attitude_tilt_sigma_rad: float = 0.0
    attitude_heading_sigma_rad: float = 0.0
    # True: the reference is air-data dead reckoning (airspeed along the heading plus a wind held from the GNSS period,
    # companion.gravity.air_data), not an INS: the velocity error is the held wind's error (prior init_vel_sigma_mps,
    # a random walk of wind_walk_mps_rts m/s per sqrt(s)); the gyro, accelerometer and attitude terms do not apply
    air_data: bool = False
    wind_walk_mps_rts: float = 0.0
    # air data with a heading of its own (companion.gravity.gyro_heading: the integrated z-gyro): its error is a state
    # (prior init_heading_sigma_rad, angle random walk gyro_arw_deg_rthr) driven by the residual z-gyro bias (prior
    # gyro_bias_degph, a random walk of gyro_bias_walk_degph_rth); it turns the air velocity (feed's air_vel_ne_mps)
    air_heading: bool = False
    gyro_bias_walk_degph_rth: float = 0.0


@dataclass(frozen=True)
class MapErrorSpec:
    """Map-minus-sensor misfit: a first-order Gauss-Markov process in distance plus a short-scale white part, fitted
    to the structure function of real ship-minus-satellite residuals; its sigma can be learnt along the track
    (docs/decisions/0008-gravity-map-misfit.md)."""

    sigma_mgal: float = 5.3
    corr_length_m: float = 28_000.0
    min_speed_mps: float = 0.5  # below this the misfit is taken as constant in time over min_speed * dt
    # short-scale part (shared by the readings within white_corr_length_m, the residual series' sample spacing)
    white_sigma_mgal: float = 0.3
    white_corr_length_m: float = 330.0
    # > 0: the misfit's sigma is learnt along the track (MisfitVarianceLearner, sigma_mgal its floor) over this much
    # distance (ten correlation lengths), 0: sigma_mgal throughout
    learn_window_m: float = 280_000.0


@dataclass(frozen=True)
class SeqGravConfig:
    method: Literal["mpf", "pmf"] = "mpf"
    n_particles: int = 1000  # mpf
    pmf_grid: int = 40  # pmf: grid points per axis
    pmf_span_sigma: float = 5.0  # pmf grid half-width in (largest) standard deviations
    resample_frac: float = 0.5  # resample when N_eff < resample_frac * N
    # position kernel after resampling (regularised particle filter, Musso, Oudjane & Le Gland 2001): bandwidth h as a
    # fraction of the population std; roughen_shrink first shrinks the positions towards their mean by sqrt(1 - h^2)
    # (Liu & West 2001) so the kernel keeps the covariance; None: their optimal Gaussian bandwidth
    # (4 / (N (d + 2)))^(1 / (d + 4)), 0.32 for N = 1000, d = 2. Off by default: each particle's velocity and biases
    # are conditioned on its own position path (Schoen 2005 eq. 23a), which a jitter of the positions alone breaks;
    # diversity comes from the position process noise below instead (docs/decisions/0009)
    roughen: float | None = 0.0
    roughen_shrink: bool = False
    roughen_multimodal: float = 0.1  # bandwidth cap while the cloud is multimodal (bimodality above multimodal_bc)
    # direct position random walk, m / sqrt(s): also the noise of eq. 23's pseudo-measurement, so it floors each
    # particle's velocity variance (docs/decisions/0009-gravity-particle-diversity.md)
    pos_noise_m_rts: float = 1.0
    # readings are not independent at 1 Hz: each white part is inflated by the number of readings that share one
    # sample of it, so n correlated readings count as one --
    #   R = sigma^2 max(1, noise_corr_s / dt) + white_sigma^2 max(1, white_corr_length_m / (speed dt)),
    # sigma the reading's own noise (correlated over noise_corr_s: a gravimeter's output filter, 1 s for a white
    # 1 Hz sensor, tens of s for a filtered marine gravimeter) and white_sigma the short-scale map misfit
    noise_corr_s: float = 1.0
    init_pos_sigma_m: float = 10.0  # prior 1-sigma per axis when the caller gives no covariance
    ins: InsErrorSpec = field(default_factory=InsErrorSpec)
    map_error: MapErrorSpec = field(default_factory=MapErrorSpec)
    max_step_s: float = 10.0  # longer gaps are propagated in sub-steps
    # map tiles (regular NE resampling of the map around the vehicle)
    tile_cell_m: float = 500.0
    tile_half_m: float = 60_000.0
    tile_margin_m: float = 15_000.0
    # anchored mode: while the caller's reference is at least this good, the position is pinned to it
    anchor_h_sigma_m: float = 50.0
    # divergence detection and re-initialisation
    nis_window_s: float = 900.0
    nis_max: float = 6.0
    lost_loglik_sigma: float = 6.0  # "no particle explains the reading": best residual beyond this many sigma
    lost_count_max: int = 30  # ... this many times inside nis_window_s
    spread_max_factor: float = 2.0  # filter spread above this x the INS-alone spread (and 1 km)
    implausible_chi2: float = 30.0  # estimated error's Mahalanobis^2 under the INS-alone covariance
    reinit_widen: float = 1.0  # prior covariance scale at re-initialisation
    reinit_holdoff_s: float = 600.0
    # signal / multimodality indicators
    signal_window_m: float = 6_000.0
    min_signal_ratio: float = 1.5
    multimodal_bc: float = 0.6  # bimodality coefficient along the major axis
    lat_deg_if_local: float = 45.0  # Eotvos latitude for a map without a geodetic frame
    # air data: a wind shift seen in the innovations adds its step to the held wind's error (companion.gravity.wind_shift)
    wind_shift: WindShiftSpec = field(default_factory=WindShiftSpec)


@dataclass(frozen=True)
class SeqGravEstimate:
    """Output for one reading. Positions in metres N/E of the map's local frame."""

    t_s: float
    pos_ne_m: np.ndarray  # corrected position: reference - error
    err_ne_m: np.ndarray  # estimated reference error (reference - truth)
    cov_ne_m2: np.ndarray  # (2, 2) covariance of the filter's own distribution
    h_acc_m: float  # sqrt(trace cov), the GPS_INPUT horiz_accuracy convention
    lat_deg: float  # NaN for a map without a geodetic frame
    lon_deg: float
    status: Status
    n_eff: float
    bimodality: float  # bimodality coefficient of the distribution along its major axis (>0.555: two modes)
    signal_ratio: float  # along-track map std over the signal window / reading noise
    nis_mean: float  # windowed mean normalised innovation squared (1 when consistent)
    reinit_count: int
    ins_h_sigma_m: float  # INS-alone h-sigma the filter carries (prior for re-initialisation)
    map_bias_mgal: float  # estimated map-minus-sensor misfit
    cpu_s: float  # process time spent on this reading (not part of the filter's state)
    # estimated reference velocity error (reference - truth) and its covariance; None: the back-end has no velocity
    # states (pmf)
    vel_err_ne_mps: np.ndarray | None = None
    vel_cov_ne_m2ps2: np.ndarray | None = None

    @property
    def usable(self) -> bool:
        """A fix the navigator may fuse: tracking with signal, unimodal, not just re-initialised."""
        return self.status == "ok"

    def sigma_ne_m(self) -> tuple[float, float]:
        return float(np.sqrt(self.cov_ne_m2[0, 0])), float(np.sqrt(self.cov_ne_m2[1, 1]))


# ---- map tiles -----------------------------------------------------------------------------------------
class MapTile:
    """Regular NE resampling of a LocalGravityMap around a centre: anomaly and its N/E gradient (mGal/m)."""

    def __init__(self, lmap: LocalGravityMap, centre_ne_m, half_m: float, cell_m: float):
        c = np.asarray(centre_ne_m, float)
        g, n_ax, e_ax = lmap.regular_ne(cell_m, (c[0] - half_m, c[0] + half_m), (c[1] - half_m, c[1] + half_m))
        gn, ge = np.gradient(g, cell_m, cell_m)
        self.sampler = FieldSampler(n_ax, e_ax, np.stack([g, gn, ge], axis=-1))
        self.lo = np.array([n_ax[0], e_ax[0]])
        self.hi = np.array([n_ax[-1], e_ax[-1]])
        self.centre = c

    def covers(self, pts_ne_m: np.ndarray, margin_m: float) -> bool:
        lo, hi = pts_ne_m.min(axis=0), pts_ne_m.max(axis=0)
        return bool(np.all(lo >= self.lo + margin_m) and np.all(hi <= self.hi - margin_m))

    def __call__(self, north_m, east_m) -> np.ndarray:
        return self.sampler(north_m, east_m)  # (..., 3): g, dg/dN, dg/dE



# ---- the filter ----------------------------------------------------------------------------------------
class SequentialGravityFilter:
    """Streaming sequential map matcher. ``feed`` one reading at a time, in time order; see the module doc."""

    def __init__(self, lmap: LocalGravityMap, cfg: SeqGravConfig | None = None,
                 rng: np.random.Generator | int = 0):
        self.lmap = lmap
        self.cfg = cfg or SeqGravConfig()
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.be = _Mpf(self.cfg, self.rng) if self.cfg.method == "mpf" else _Pmf(self.cfg, self.rng)
        self.t_s: float | None = None
        self.tile: MapTile | None = None
        self.P_ins: np.ndarray | None = None
        self._walk_m2 = 0.0  # the position random walk's variance per axis since the last prior (not in P_ins)
        self._last = None  # (ref_pos, ref_vel, heading, lat) of the previous reading
        self._air_vel: np.ndarray | None = None  # the reference's air velocity at the previous reading (air_heading)
        self._nis = deque()  # (t, nis)
        self.wind_shift = WindShiftDetector(self.cfg.wind_shift, self.cfg.nis_window_s)
        self._lost = deque()  # t of readings no particle explained
        self._sig = deque()  # (distance, map value at the estimate)
        self._dist_m = 0.0
        self._holdoff_until = -np.inf
        self.reinit_count = 0
        self._anchored = False
        me = self.cfg.map_error
        self.misfit = MisfitVarianceLearner(me.learn_window_m, me.corr_length_m) if me.learn_window_m > 0 else None

    # -- helpers -----------------------------------------------------------------------------------------
    def _lat(self, north_m: float, lat_deg) -> float:
        if lat_deg is not None:
            return float(lat_deg)
        if self.lmap.frame is None:
            return self.cfg.lat_deg_if_local
        return float(self.lmap.lat_deg_at(north_m))

    def _tau_b(self, speed_mps: float) -> float:
        me = self.cfg.map_error
        return me.corr_length_m / max(speed_mps, me.min_speed_mps)

    def _white_var(self, sigma_mgal: float, speed_mps: float, dt_s: float) -> tuple[float, float]:
        """(R for the update, R of one reading): white variances inflated by the readings that share one sample of
        them (see SeqGravConfig.noise_corr_s)."""
        me = self.cfg.map_error
        s2, w2 = float(sigma_mgal) ** 2, me.white_sigma_mgal**2
        n_s = max(1.0, self.cfg.noise_corr_s / dt_s)
        n_w = max(1.0, me.white_corr_length_m / max(speed_mps * dt_s, 1e-3))
        return s2 * n_s + w2 * n_w, s2 + w2

    def _ensure_tile(self, ref_ne, est_err=None) -> None:
        pts = ref_ne - self.be.positions()
        if self.tile is None or not self.tile.covers(pts, self.cfg.tile_margin_m):
            centre = ref_ne - (np.zeros(2) if est_err is None else est_err)
            self.tile = MapTile(self.lmap, np.round(centre, -3), self.cfg.tile_half_m, self.cfg.tile_cell_m)

    def _prior_pos_cov(self, ref_cov) -> np.ndarray:
        if ref_cov is not None:
            return np.asarray(ref_cov, float).reshape(2, 2)
        return np.eye(2) * self.cfg.init_pos_sigma_m**2

    def _reset_windows(self) -> None:
        self._nis.clear()
        self.wind_shift.reset()
        self._lost.clear()

    # -- public ------------------------------------------------------------------------------------------
    def feed(self, t_s: float, g_mgal: float, ref_pos_ne_m, ref_vel_ne_mps, sigma_mgal: float, *,
             ref_cov_ne_m2=None, heading_rad: float | None = None, lat_deg: float | None = None,
             eotvos_from_reference: bool = True, anchor: bool | None = None,
             air_vel_ne_mps=None) -> SeqGravEstimate | None:
        """One reading. ``ref_*`` is the reference solution at t_s whose error is estimated; ``ref_cov_ne_m2`` the
        navigator's own 2x2 covariance of it (optional; at least as good as ``anchor_h_sigma_m`` pins the filter to
        the reference, e.g. with GNSS). ``eotvos_from_reference``: the reading was Eotvos-corrected with the
        reference velocity (its velocity error leaves an Eotvos error in the reading); False when the sender
        corrected it with a velocity of its own. ``anchor``: None pins the filter whenever ``ref_cov_ne_m2`` is within
        ``anchor_h_sigma_m``; False never (the covariance is then a prior only). ``air_vel_ne_mps``: the reference's air
        velocity (map frame), which a heading error turns (``InsErrorSpec.air_heading``). Returns None for a reading
        that cannot be used (non-finite, not after the previous one)."""
        c0 = time.process_time()
        cfg = self.cfg
        ref = np.asarray(ref_pos_ne_m, float).reshape(2)
        vel = np.asarray(ref_vel_ne_mps, float).reshape(2)
        if not (np.isfinite(t_s) and np.isfinite(g_mgal) and np.all(np.isfinite(ref)) and np.all(np.isfinite(vel))
                and np.isfinite(sigma_mgal) and sigma_mgal > 0):
            return None
        if self.t_s is not None and t_s <= self.t_s:
            return None
        speed = float(np.hypot(*vel))
        air = None if air_vel_ne_mps is None else np.asarray(air_vel_ne_mps, float).reshape(2)
        if air is not None and not np.all(np.isfinite(air)):
            air = None
        if heading_rad is None:
            heading_rad = float(np.arctan2(vel[1], vel[0])) if speed > 0.5 or self._last is None else self._last[2]
        lat = self._lat(ref[0], lat_deg)
        pos_cov = self._prior_pos_cov(ref_cov_ne_m2)
        anchored = (anchor is not False and ref_cov_ne_m2 is not None
                    and np.sqrt(np.trace(pos_cov)) <= cfg.anchor_h_sigma_m)
        status: Status = "ok"
        if self.t_s is None:  # first reading: prior around the reference
            self.P_ins = prior_covariance(cfg, pos_cov)
            self._walk_m2 = 0.0
            self.be.init(self.P_ins)
        else:
            self._propagate(float(t_s), ref, vel, speed, air)
        self._air_vel = air
        if anchored:
            self._anchor(pos_cov)
            status = "anchored"
        elif self._anchored:
            self._anchored = False
            self._reset_windows()
        self._anchored = anchored
        dt_s = 1.0 if self.t_s is None else float(t_s) - self.t_s
        self._dist_m += 0.0 if self._last is None else float(np.hypot(*(ref - self._last[0])))
        self._last = (ref, vel, heading_rad, lat)
        self.t_s = float(t_s)

        H = np.zeros(N_LIN)
        if eotvos_from_reference:
            H[IV:IV + 2] = -eotvos_jacobian_mgal_per_mps(vel, lat)
            if cfg.ins.air_data and cfg.ins.air_heading and air is not None:  # the heading error turns the air velocity
                H[IPSI + 2] = float(H[IV:IV + 2] @ np.array([-air[1], air[0]]))
        H[IB] = 1.0
        m_prev = self.be.moments()[0]
        self._ensure_tile(ref, m_prev)
        r_upd, r_raw = self._white_var(sigma_mgal, speed, dt_s)
        res = self.be.update(self.tile, ref, float(g_mgal), H, r_upd, r_raw)
        m, cov, bc, n_eff, b_mean, b_var = self.be.moments()
        if res is None:
            status = "off_map"
            nis_mean, sig_ratio = float("nan"), 0.0
        else:
            nis, best, hm, _grad = res
            if self.misfit is not None:
                self.misfit.add(self._dist_m, float(g_mgal) - hm, r_raw)
            self._nis.append((self.t_s, nis))
            if (not anchored and cfg.ins.air_data and self.wind_shift.add(self.t_s, nis)
                    and np.any(H[IV:IV + 2] != 0)):
                self._wind_step(H[IV:IV + 2])
            if best > cfg.lost_loglik_sigma:
                self._lost.append(self.t_s)
            while self._nis and self._nis[0][0] < self.t_s - cfg.nis_window_s:
                self._nis.popleft()
            while self._lost and self._lost[0] < self.t_s - cfg.nis_window_s:
                self._lost.popleft()
            nis_mean = float(np.mean([v for _, v in self._nis]))
            self._sig.append((self._dist_m, hm))
            while self._sig and self._sig[0][0] < self._dist_m - cfg.signal_window_m:
                self._sig.popleft()
            span = self._sig[-1][0] - self._sig[0][0]
            vals = np.array([v for _, v in self._sig])
            sig_ratio = float(np.std(vals)) / float(sigma_mgal) if span >= 0.5 * cfg.signal_window_m else 0.0
            if not anchored:
                if self._diverged(m, cov, nis_mean):
                    self._reinit(ref_cov_ne_m2, b_mean, b_var)
                    m, cov, bc, n_eff, b_mean, b_var = self.be.moments()
                    status = "reinit"
                elif sig_ratio < cfg.min_signal_ratio:
                    status = "no_signal"
                elif bc > cfg.multimodal_bc:
                    status = "multimodal"
        if not anchored:
            self.be.resample_if_needed()
        pos = ref - m
        if self.lmap.frame is not None:
            lon, lat_o = self.lmap.ne_to_xy(pos[0], pos[1])
            lat_o, lon = float(lat_o), float(lon)
        else:
            lat_o = lon = float("nan")
        ins_h = float(np.sqrt(self.P_ins[0, 0] + self.P_ins[1, 1]))
        vel = self.be.velocity_moments() or (None, None)
        return SeqGravEstimate(self.t_s, pos, m.copy(), cov, float(np.sqrt(np.trace(cov))), lat_o, lon, status, n_eff,
                               float(bc), sig_ratio, nis_mean, self.reinit_count, ins_h, b_mean,
                               time.process_time() - c0, *vel)

    def apply_correction(self, delta_ne_m, delta_vel_ne_mps=None) -> None:
        """The reference was moved by delta_ne_m, its velocity by delta_vel_ne_mps (a closed-loop correction of the
        navigator, e.g. when it fused this filter's fix): the estimated errors move with it."""
        d = np.asarray(delta_ne_m, float).reshape(2)
        dv = np.zeros(2) if delta_vel_ne_mps is None else np.asarray(delta_vel_ne_mps, float).reshape(2)
        if self.t_s is None or not (np.all(np.isfinite(d)) and np.all(np.isfinite(dv))):
            return
        self.be.shift_errors(d, dv)  # error = reference - truth
        if self._last is not None:  # the previous reference as if it had been corrected already
            ref0, vel0, head0, lat0 = self._last
            self._last = (ref0 + d, vel0 + dv, head0, lat0)

    def ins_alone_cov_ne_m2(self) -> np.ndarray:
        return self.P_ins[:2, :2].copy()

    def unaided_cov_ne_m2(self) -> np.ndarray:
        """The position covariance the filter would state had no reading informed it since its last prior: the
        INS-alone covariance plus the position random walk (``pos_noise_m_rts``) the particles carry. Against the
        covariance it states, it says how much the readings have taught it (docs/decisions/0019)."""
        return self.P_ins[:2, :2] + np.eye(2) * self._walk_m2

    # -- internals ---------------------------------------------------------------------------------------
    def _propagate(self, t_s: float, ref, vel, speed, air=None) -> None:
        cfg = self.cfg
        ref0, vel0, head0, lat0 = self._last
        dt_total = t_s - self.t_s
        acc = (vel - vel0) / dt_total
        vmid = 0.5 * (vel + vel0)
        tau_b = self._tau_b(0.5 * (speed + float(np.hypot(*vel0))))
        nsub = int(np.ceil(dt_total / cfg.max_step_s))
        dt = dt_total / nsub
        air_mid = None
        if cfg.ins.air_data and cfg.ins.air_heading and air is not None:
            air_mid = air if self._air_vel is None else 0.5 * (air + self._air_vel)
        A = error_dynamics(np.radians(lat0), vmid, acc, head0, tau_b, attitude_tau_s=cfg.ins.attitude_tau_s,
                           air_data=cfg.ins.air_data, air_vel_ne_mps=air_mid)
        sig_b = None if self.misfit is None else self.misfit.sigma_mgal(cfg.map_error.sigma_mgal)
        Phi, Qd = discretise(A, continuous_noise(cfg.ins, cfg.map_error, tau_b, sig_b), dt)
        qn = cfg.pos_noise_m_rts**2 * dt
        self._walk_m2 += qn * nsub
        for _ in range(nsub):
            P_before = self.P_ins[:2, :2].copy()
            self.P_ins = Phi @ self.P_ins @ Phi.T + Qd
            self.P_ins = 0.5 * (self.P_ins + self.P_ins.T)
            if isinstance(self.be, _Mpf):
                self.be.predict(Phi, Qd, qn)
            else:
                dP = self.P_ins[:2, :2] - P_before
                w, V = np.linalg.eigh(0.5 * (dP + dP.T))
                dP = (V * np.maximum(w, 0.0)) @ V.T
                self.be.predict(Phi, Qd, qn, dP, float(Phi[N_NL + IB, N_NL + IB]), float(Qd[N_NL + IB, N_NL + IB]))

    def _wind_step(self, h_vel: np.ndarray) -> None:
        """A wind shift (companion.gravity.wind_shift): the held wind's error gains the step's variance along the
        readings' velocity sensitivity h_vel, the component they observe at once."""
        u = h_vel / float(np.hypot(*h_vel))
        Q = self.cfg.wind_shift.step_mps**2 * np.outer(u, u)
        j = N_NL + IV
        self.P_ins[j:j + 2, j:j + 2] += Q
        self.be.add_velocity_cov(Q)

    def _anchor(self, pos_cov) -> None:
        """Reference as good as GNSS: the position is the reference's, INS error states at their prior; only the
        map misfit keeps what the readings taught it."""
        _, _, _, _, b_mean, b_var = self.be.moments()
        self.P_ins = prior_covariance(self.cfg, pos_cov)
        self._walk_m2 = 0.0
        self.be.init(self.P_ins, b_mean=b_mean, b_var=b_var)
        self._holdoff_until = -np.inf

    def _diverged(self, m, cov, nis_mean) -> bool:
        cfg = self.cfg
        if self.t_s < self._holdoff_until:
            return False
        Pn = self.P_ins[:2, :2]
        full = self._nis and (self._nis[-1][0] - self._nis[0][0]) >= 0.5 * cfg.nis_window_s
        if full and nis_mean > cfg.nis_max:
            return True
        if len(self._lost) >= cfg.lost_count_max:
            return True
        if np.trace(cov) > cfg.spread_max_factor**2 * np.trace(Pn) + 1e6:
            return True
        d2 = float(m @ np.linalg.solve(Pn + cov, m))
        return d2 > cfg.implausible_chi2

    def _reinit(self, ref_cov, b_mean, b_var) -> None:
        P = self.P_ins.copy()
        if ref_cov is not None:
            P[:2, :2] = np.asarray(ref_cov, float).reshape(2, 2)
        P[:2, :2] *= self.cfg.reinit_widen**2
        self.be.init(P, b_mean=b_mean, b_var=max(b_var, 1.0))
        self.reinit_count += 1
        self._holdoff_until = self.t_s + self.cfg.reinit_holdoff_s
        self._reset_windows()


# ---- batch ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SeqGravTrack:
    """run_batch output: one row per reading that produced an estimate (index into the inputs in ``index``)."""

    index: np.ndarray
    t_s: np.ndarray
    pos_ne_m: np.ndarray
    err_ne_m: np.ndarray
    cov_ne_m2: np.ndarray  # (n, 2, 2)
    h_acc_m: np.ndarray
    status: np.ndarray  # str
    n_eff: np.ndarray
    bimodality: np.ndarray
    signal_ratio: np.ndarray
    nis_mean: np.ndarray
    reinit_count: np.ndarray
    ins_h_sigma_m: np.ndarray
    map_bias_mgal: np.ndarray
    cpu_s: np.ndarray


def stack_estimates(index, ests: list[SeqGravEstimate]) -> SeqGravTrack:
    return SeqGravTrack(
        np.asarray(index, int), np.array([e.t_s for e in ests]), np.array([e.pos_ne_m for e in ests]).reshape(-1, 2),
        np.array([e.err_ne_m for e in ests]).reshape(-1, 2), np.array([e.cov_ne_m2 for e in ests]).reshape(-1, 2, 2),
        np.array([e.h_acc_m for e in ests]), np.array([e.status for e in ests], dtype=object),
        np.array([e.n_eff for e in ests]), np.array([e.bimodality for e in ests]),
        np.array([e.signal_ratio for e in ests]), np.array([e.nis_mean for e in ests]),
        np.array([e.reinit_count for e in ests], int), np.array([e.ins_h_sigma_m for e in ests]),
        np.array([e.map_bias_mgal for e in ests]), np.array([e.cpu_s for e in ests]))


def run_batch(lmap: LocalGravityMap, t_s, g_mgal, ref_pos_ne_m, ref_vel_ne_mps, sigma_mgal, *,
              ref_cov_ne_m2=None, heading_rad=None, lat_deg=None, cfg: SeqGravConfig | None = None,
              rng: np.random.Generator | int = 0) -> SeqGravTrack:
    """The streaming filter over arrays (n readings): identical to feeding them one by one. ``sigma_mgal`` may be a
    scalar; ``ref_cov_ne_m2`` (n, 2, 2) with NaN rows meaning "no navigator covariance at this reading"."""
    f = SequentialGravityFilter(lmap, cfg, rng)
    t = np.asarray(t_s, float)
    n = t.size
    sig = np.broadcast_to(np.asarray(sigma_mgal, float), (n,))
    pos = np.asarray(ref_pos_ne_m, float).reshape(n, 2)
    vel = np.asarray(ref_vel_ne_mps, float).reshape(n, 2)
    g = np.asarray(g_mgal, float).reshape(n)
    idx, out = [], []
    for k in range(n):
        rc = None
        if ref_cov_ne_m2 is not None and np.all(np.isfinite(ref_cov_ne_m2[k])):
            rc = ref_cov_ne_m2[k]
        e = f.feed(t[k], g[k], pos[k], vel[k], float(sig[k]), ref_cov_ne_m2=rc,
                   heading_rad=None if heading_rad is None else float(heading_rad[k]),
                   lat_deg=None if lat_deg is None else float(lat_deg[k]))
        if e is not None:
            idx.append(k)
            out.append(e)
    return stack_estimates(idx, out)
