"""Particle filters for gravity(-gradient) aided INS: GF-PF (Liu, Li, Jing 2019), PSO-PF and APO-PF baselines.

State of every particle: the 12-state INS error of Liu et al. eq. 8 in an East-North-Up frame,
    x = [dN, dE, dVE, dVN, phiE (alpha), phiN (beta), phiU (gamma), dAE, dAN, epsE, epsN, epsU],
with the position errors in metres (the paper uses latitude/longitude errors in radians; metres are the same
states scaled by R_M and R_N cos(lat)). Errors are INS minus truth.

The continuous model (eqs. 1-7, 9-11) is rebuilt from the standard phi-angle INS error equations that the
paper cites (Titterton & Weston 2004 ch. 12; Qin Yongyuan, Inertial Navigation), because the extracted text
garbles the matrices A11..A24 of eq. 10:
    dN' = dVN,  dE' = dVE                                                     (eq. 1, metres)
    dVE' = (VN tanL/R) dVE + (2 W sinL + VE tanL/R) dVN + (2 W cosL VN + VE VN sec^2L/R) dN/R
           - g phiN + fN phiU + dAE                                           (eq. 2)
    dVN' = -2 (W sinL + VE tanL/R) dVE - (2 W cosL VE + VE^2 sec^2L/R) dN/R + g phiE - fE phiU + dAN
    phiE' = -dVN/R + (W sinL + VE tanL/R) phiN - (W cosL + VE/R) phiU + epsE  (eq. 3)
    phiN' =  dVE/R - W sinL dN/R - (W sinL + VE tanL/R) phiE - (VN/R) phiU + epsN
    phiU' =  dVE tanL/R + (W cosL + VE sec^2L/R) dN/R + (W cosL + VE/R) phiE + (VN/R) phiN + epsU
    dA' = 0, eps' = 0 (random constants, eqs. 5, 7) plus white noise on velocity and attitude (eqs. 4, 6, 11).
Discretised with the filter period T as eqs. 12-14: A_k = I + T A, B_k = T (I + T/2 A) B.

Observation (eqs. 15-16): y = Gamma(INS position - position error) + v, with Gamma the five gradient components
(Eotvos) from companion.gravity.gradient, or the scalar anomaly (mGal) for the scalar variant.

Optimisers run on the particles' position states between prediction and resampling (Liu Steps 1-6):
  * GF (gravitation field algorithm, eqs. 22-25): attraction of the best particle ("central dust")
    P_i = Ka (x_best - x_i) / d_i (the extracted eq. 22 reads "K a d i (x best - x i)"; a fraction bar is
    lost; we take the unit direction times Ka, which with Ka = 10 is a 10 m pull per iteration) and repulsion
    F_ij = Kr (1/d_ij^2 - 1/d_th^2) (x_i - x_j) / d_ij for d_ij < d_th (eq. 23, pointing away from x_j);
    x_i += sum (eq. 24-25), each axis clamped to [-L_max, L_max].
  * PSO (Bonyadi & Michalewicz): v = w v + c1 r1 (pbest - x) + c2 r2 (gbest - x), x += v.
  * APO (artificial physics optimisation, Liu F.M. et al. 2012, ref. 20 of Liu 2019; not available to us, so
    reconstructed from the APO literature with the stated parameters): particles within r_s of a better particle
    are attracted to it (Ka1 beyond D_th, Ka2 within D_th), repelled by worse ones (Kb), velocity v = Kb v + F/m.
The fitness is the observation log-likelihood with sigma = hypot(sigma_obs, sigma_map): sigma_map (ours) covers
map and interpolation error; with sigma_map = 0 and 1 E the likelihood is so sharp on our maps that the swarm locks
onto wrong local optima, and the GF pull (up to 20 x L_max = 600 m per period towards the best particle) turns
into a random walk when the likelihood is flat, so the value matters (see the benchmark notes); after the iterations the weights are recomputed (Step 4),
resampling (systematic) happens when N_eff < N_th (Step 5), and the estimate is the weighted mean (Step 6).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from companion.constants import EARTH_RATE_RADPS, G0_MPS2, WGS84_A_M

G0 = G0_MPS2
UG = 1e-6 * G0
DEGPH = np.radians(1.0) / 3600.0
N_STATES = 12


# ---- field sampling --------------------------------------------------------------------------------
class FieldSampler:
    """Fast bilinear sampling of m stacked fields on one regular NE grid (north rows, east columns)."""

    def __init__(self, north_m: np.ndarray, east_m: np.ndarray, stack: np.ndarray):
        self.n0, self.e0 = float(north_m[0]), float(east_m[0])
        self.dn = float(north_m[1] - north_m[0])
        self.de = float(east_m[1] - east_m[0])
        s = np.asarray(stack, float)
        self.stack = s if s.ndim == 3 else s[..., None]
        self.nn, self.ne, self.m = self.stack.shape

    @classmethod
    def from_gradient_map(cls, gmap, names) -> "FieldSampler":
        return cls(gmap.north_m, gmap.east_m, np.stack([gmap.comps[n] for n in names], axis=-1))

    def __call__(self, north_m: np.ndarray, east_m: np.ndarray) -> np.ndarray:
        fy = (np.asarray(north_m) - self.n0) / self.dn
        fx = (np.asarray(east_m) - self.e0) / self.de
        inside = (fy >= 0) & (fy <= self.nn - 1) & (fx >= 0) & (fx <= self.ne - 1)
        fy = np.clip(fy, 0, self.nn - 1.000001)
        fx = np.clip(fx, 0, self.ne - 1.000001)
        j = fy.astype(np.intp)
        i = fx.astype(np.intp)
        ty = (fy - j)[..., None]
        tx = (fx - i)[..., None]
        s = self.stack
        out = (1 - ty) * ((1 - tx) * s[j, i] + tx * s[j, i + 1]) + ty * ((1 - tx) * s[j + 1, i] + tx * s[j + 1, i + 1])
        return np.where(inside[..., None], out, np.nan)


# ---- INS error model (Liu eqs. 1-14) -------------------------------------------------------------------
def ins_error_matrix(lat_rad: float, vel_ne_mps, f_ne_mps2=(0.0, 0.0), R: float = WGS84_A_M) -> np.ndarray:
    """Continuous A(t) of eq. 10 for x = [dN, dE, dVE, dVN, phiE, phiN, phiU, dAE, dAN, epsE, epsN, epsU]."""
    vn, ve = float(vel_ne_mps[0]), float(vel_ne_mps[1])
    fn, fe = float(f_ne_mps2[0]), float(f_ne_mps2[1])
    W = EARTH_RATE_RADPS
    sl, cl, tl = np.sin(lat_rad), np.cos(lat_rad), np.tan(lat_rad)
    sec2 = 1.0 / cl**2
    A = np.zeros((N_STATES, N_STATES))
    A[0, 3] = 1.0
    A[1, 2] = 1.0
    # velocity (eq. 2); dN/R is the latitude error
    A[2, 2] = vn * tl / R
    A[2, 3] = 2 * W * sl + ve * tl / R
    A[2, 0] = (2 * W * cl * vn + ve * vn * sec2 / R) / R
    A[2, 5] = -G0
    A[2, 6] = fn
    A[2, 7] = 1.0
    A[3, 2] = -2 * (W * sl + ve * tl / R)
    A[3, 0] = -(2 * W * cl * ve + ve**2 * sec2 / R) / R
    A[3, 4] = G0
    A[3, 6] = -fe
    A[3, 8] = 1.0
    # attitude (eq. 3)
    A[4, 3] = -1.0 / R
    A[4, 5] = W * sl + ve * tl / R
    A[4, 6] = -(W * cl + ve / R)
    A[4, 9] = 1.0
    A[5, 2] = 1.0 / R
    A[5, 0] = -W * sl / R
    A[5, 4] = -(W * sl + ve * tl / R)
    A[5, 6] = -vn / R
    A[5, 10] = 1.0
    A[6, 2] = tl / R
    A[6, 0] = (W * cl + ve * sec2 / R) / R
    A[6, 4] = W * cl + ve / R
    A[6, 5] = vn / R
    A[6, 11] = 1.0
    return A


def discretise(A: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 13-14: A_k = I + T A, B_k = T (I + T/2 A) (B = I)."""
    eye = np.eye(A.shape[0])
    return eye + T * A, T * (eye + 0.5 * T * A)


@dataclass(frozen=True)
class ParticleInsNoise:
    """1-sigma of the particles' initial errors and of the white noises W of eq. 11."""

    init_pos_m: float = 2000.0
    init_vel_mps: float = 0.5
    init_tilt_rad: float = np.radians(0.1 / 60)
    init_heading_rad: float = np.radians(0.5 / 60)
    accel_bias_ug: float = 100.0
    gyro_bias_degph: float = 0.01
    accel_noise_ug: float = 10.0  # w_a (per filter period, as a rate)
    gyro_noise_degph: float = 0.002  # w_g
    roughen_m: float = 10.0  # position jitter after resampling (regularisation, keeps diversity)


# ---- filter configuration -----------------------------------------------------------------------------
@dataclass(frozen=True)
class GfParams:  # Liu sec. 4.2
    d_th_m: float = 20.0
    ka: float = 10.0
    kr: float = 1.0
    l_max_m: float = 30.0


@dataclass(frozen=True)
class PsoParams:  # Liu sec. 4.2, after Bonyadi & Michalewicz
    inertia: float = 0.99
    c1: float = 0.1
    c2: float = 0.1
    l_max_m: float = 30.0


@dataclass(frozen=True)
class ApoParams:  # Liu sec. 4.2, after Liu F.M. et al. 2012
    ka1: float = 10.0
    ka2: float = 1.0
    kb: float = 0.9
    r_s_m: float = 150.0
    d_th_m: float = 10.0
    l_max_m: float = 30.0


@dataclass(frozen=True)
class PfConfig:
    optimizer: Literal["gf", "pso", "apo", "none"] = "gf"
    n_particles: int = 100
    iterations: int = 20
    period_s: float = 10.0
    sigma_obs: float = 1.0  # per component, Eotvos (gradient) or mGal (scalar)
    sigma_map: float = 0.0  # added in quadrature in the likelihood: map / interpolation / model error (same unit)
    neff_frac: float = 0.5  # N_th = neff_frac * N
    noise: ParticleInsNoise = field(default_factory=ParticleInsNoise)
    gf: GfParams = field(default_factory=GfParams)
    pso: PsoParams = field(default_factory=PsoParams)
    apo: ApoParams = field(default_factory=ApoParams)

    @property
    def name(self) -> str:
        return {"gf": "GF-PF", "pso": "PSO-PF", "apo": "APO-PF", "none": "PF"}[self.optimizer]


@dataclass
class PfEstimate:
    t_s: float
    position_ne_m: np.ndarray  # corrected position (INS minus estimated error)
    error_ne_m: np.ndarray  # estimated INS position error
    cov_ne_m2: np.ndarray  # (2, 2) weighted particle covariance
    n_eff: float
    resampled: bool
    compute_time_s: float


class GravityParticleFilter:
    """GF-PF / PSO-PF / APO-PF on a FieldSampler (5 gradient components or the scalar anomaly)."""

    def __init__(self, field_sampler: FieldSampler, cfg: PfConfig, rng: np.random.Generator, t0_s: float, lat_rad: float):
        self.f = field_sampler
        self.cfg = cfg
        self.rng = rng
        self.t_s = float(t0_s)
        self.lat_rad = float(lat_rad)
        nz = cfg.noise
        N = cfg.n_particles
        x = np.zeros((N, N_STATES))
        x[:, 0:2] = rng.normal(0.0, nz.init_pos_m, (N, 2))  # Step 1: sample p(x0)
        x[:, 2:4] = rng.normal(0.0, nz.init_vel_mps, (N, 2))
        x[:, 4:6] = rng.normal(0.0, nz.init_tilt_rad, (N, 2))
        x[:, 6] = rng.normal(0.0, nz.init_heading_rad, N)
        x[:, 7:9] = rng.normal(0.0, nz.accel_bias_ug * UG, (N, 2))
        x[:, 9:12] = rng.normal(0.0, nz.gyro_bias_degph * DEGPH, (N, 3))
        self.x = x
        self.w = np.full(N, 1.0 / N)
        self._sigma = float(np.hypot(cfg.sigma_obs, cfg.sigma_map))
        if not self._sigma > 0:
            raise ValueError("sigma_obs and sigma_map cannot both be 0")

    # -- likelihood ----------------------------------------------------------------------------------------
    def _loglik(self, pos_err_ne: np.ndarray, ins_ne: np.ndarray, y: np.ndarray) -> np.ndarray:
        pred = self.f(ins_ne[0] - pos_err_ne[:, 0], ins_ne[1] - pos_err_ne[:, 1])  # eq. 16
        r = (pred - y) / self._sigma
        ll = -0.5 * np.sum(r * r, axis=1)
        return np.where(np.isfinite(ll), ll, -1e12)

    # -- optimisers on the position states ------------------------------------------------------------------
    def _gf(self, p: np.ndarray, fit) -> np.ndarray:
        g = self.cfg.gf
        n = p.shape[0]
        for _ in range(self.cfg.iterations):
            ll = fit(p)
            best = p[np.argmax(ll)]  # central dust
            d_b = best - p
            db = np.hypot(d_b[:, 0], d_b[:, 1])
            P = g.ka * d_b / np.maximum(db, 1e-9)[:, None]  # eq. 22
            P[db < 1e-9] = 0.0
            F = P
            pairs = cKDTree(p).query_pairs(g.d_th_m, output_type="ndarray")  # only pairs within d_th repel
            if pairs.size:
                i, j = pairs[:, 0], pairs[:, 1]
                diff = p[i] - p[j]
                d = np.maximum(np.hypot(diff[:, 0], diff[:, 1]), 1e-9)
                f = (g.kr * (1.0 / d**2 - 1.0 / g.d_th_m**2) / d)[:, None] * diff  # eq. 23, on i away from j
                F = F + np.column_stack([np.bincount(i, f[:, 0], n) - np.bincount(j, f[:, 0], n),
                                         np.bincount(i, f[:, 1], n) - np.bincount(j, f[:, 1], n)])  # eq. 24
            p = p + np.clip(F, -g.l_max_m, g.l_max_m)  # eq. 25
        return p

    def _pso(self, p: np.ndarray, fit) -> np.ndarray:
        c = self.cfg.pso
        v = np.zeros_like(p)
        ll = fit(p)
        pbest, pbest_ll = p.copy(), ll.copy()
        for _ in range(self.cfg.iterations):
            gbest = pbest[np.argmax(pbest_ll)]
            r1 = self.rng.random((p.shape[0], 1))
            r2 = self.rng.random((p.shape[0], 1))
            v = c.inertia * v + c.c1 * r1 * (pbest - p) + c.c2 * r2 * (gbest - p)
            v = np.clip(v, -c.l_max_m, c.l_max_m)
            p = p + v
            ll = fit(p)
            up = ll > pbest_ll
            pbest[up], pbest_ll[up] = p[up], ll[up]
        return p

    def _apo(self, p: np.ndarray, fit) -> np.ndarray:
        a = self.cfg.apo
        n = p.shape[0]
        v = np.zeros(n, complex)
        z = p[:, 0] + 1j * p[:, 1]
        others = ~np.eye(n, dtype=bool)
        for _ in range(self.cfg.iterations):
            ll = fit(np.column_stack([z.real, z.imag]))
            lo, hi = ll.min(), ll.max()
            m = np.exp((ll - hi) / max(hi - lo, 1e-12))  # masses in (0, 1], best = 1
            diff = z[None, :] - z[:, None]  # x_j - x_i
            dij = np.abs(diff)
            unit = diff / np.maximum(dij, 1e-9)
            within = (dij < a.r_s_m) & others
            better = ll[None, :] > ll[:, None]
            k_att = np.where(dij > a.d_th_m, a.ka1, a.ka2)
            mag = (np.where(within & better, k_att, 0.0) - np.where(within & ~better, a.kb, 0.0)) * m[None, :]
            ib = int(np.argmax(ll))
            mag[:, ib] = np.where(np.arange(n) != ib, np.where(within[:, ib], mag[:, ib], a.ka1), 0.0)  # the best pulls all
            F = (mag * unit).sum(axis=1)
            v = a.kb * v + F / np.maximum(m, 1e-3)
            v = np.clip(v.real, -a.l_max_m, a.l_max_m) + 1j * np.clip(v.imag, -a.l_max_m, a.l_max_m)
            z = z + v
        return np.column_stack([z.real, z.imag])

    # -- one filter period -------------------------------------------------------------------------------
    def step(self, t_s: float, ins_ne_m, ins_vel_ne_mps, y, f_ne_mps2=(0.0, 0.0)) -> PfEstimate:
        t0 = time.perf_counter()
        cfg, nz, rng = self.cfg, self.cfg.noise, self.rng
        ins = np.asarray(ins_ne_m, float)
        y = np.atleast_1d(np.asarray(y, float))
        dt = float(t_s) - self.t_s
        if dt < 0:
            raise ValueError("time went backwards")
        if dt > 0:  # Step 2: prediction with eqs. 12-14
            Ak, Bk = discretise(ins_error_matrix(self.lat_rad, ins_vel_ne_mps, f_ne_mps2), dt)
            W = np.zeros((self.x.shape[0], N_STATES))
            W[:, 2:4] = rng.normal(0.0, nz.accel_noise_ug * UG, (self.x.shape[0], 2))
            W[:, 4:7] = rng.normal(0.0, nz.gyro_noise_degph * DEGPH, (self.x.shape[0], 3))
            self.x = self.x @ Ak.T + W @ Bk.T
            self.t_s = float(t_s)
        fit = lambda pos: self._loglik(pos, ins, y)  # noqa: E731
        if cfg.optimizer != "none":  # Step 3
            opt = {"gf": self._gf, "pso": self._pso, "apo": self._apo}[cfg.optimizer]
            self.x[:, 0:2] = opt(self.x[:, 0:2].copy(), fit)
        ll = fit(self.x[:, 0:2])  # Step 4
        lw = np.log(np.maximum(self.w, 1e-300)) + ll
        lw -= lw.max()
        w = np.exp(lw)
        w /= w.sum()
        n_eff = 1.0 / float(np.sum(w * w))
        resampled = False
        est = w @ self.x
        d = self.x[:, 0:2] - est[0:2]
        cov = (w[:, None] * d).T @ d
        if n_eff < cfg.neff_frac * w.size:  # Step 5: systematic resampling
            u = (rng.random() + np.arange(w.size)) / w.size
            idx = np.minimum(np.searchsorted(np.cumsum(w), u), w.size - 1)
            self.x = self.x[idx]
            self.x[:, 0:2] += rng.normal(0.0, nz.roughen_m, (w.size, 2))
            w = np.full(w.size, 1.0 / w.size)
            resampled = True
        self.w = w
        err = est[0:2]  # Step 6
        return PfEstimate(float(t_s), ins - err, err.copy(), cov, n_eff, resampled, time.perf_counter() - t0)

    def feedback_reset(self, est_err_ne_m: np.ndarray) -> None:
        """After the INS is corrected by est_err (closed loop), particles are re-centred on the new INS."""
        self.x[:, 0:2] -= np.asarray(est_err_ne_m, float)
