"""The sequential gravity filter's INS error model and its two back-ends: the marginalised particle filter (nonlinear
horizontal position particles, a linear INS-error Kalman filter per particle, as in MIT MagNav.jl's MPF) and the
point-mass filter it is compared with. The front-end (time handling, map tiles, divergence and signal checks,
outputs) is :mod:`companion.gravity.sequential`. Pure numpy."""

from __future__ import annotations

from collections import deque
from typing import Literal

import numpy as np

from companion.constants import EARTH_RATE_RADPS, G0_MPS2, WGS84_A_M
from companion.gravity.eotvos import MPS_PER_KNOT
from companion.gravity.particle import FieldSampler

# SeqGravConfig, InsErrorSpec, MapErrorSpec and MapTile in annotations are companion.gravity.sequential's (not imported:
# that module imports this one)
UG_MPS2 = 1e-6 * G0_MPS2
DEGPH_RADPS = np.radians(1.0) / 3600.0

# state layout: xn = [drN, drE] (total position error); xl = [dsN, dsE, dvN, dvE, psiN, psiE, psiD, bgx, bgy, bgz,
# bax, bay, b_map] with ds the part of the position error that the INS dynamics made (the Schuler feedback acts on
# it; an initial position offset is psi-angle consistent and does not excite the loop, as in simulate_ins)
N_NL = 2
N_LIN = 13
N_ALL = N_NL + N_LIN
IS, IV, IPSI, IBG, IBA, IB = 0, 2, 4, 7, 10, 12  # offsets inside xl

Status = Literal["anchored", "ok", "no_signal", "multimodal", "reinit", "off_map"]


# ---- INS error model -----------------------------------------------------------------------------------
def eotvos_jacobian_mgal_per_mps(vel_ne_mps, lat_deg: float) -> np.ndarray:
    """dE/d(vN, vE) of Gao eq. 5, E = 7.5 vE/k cos(lat) + 0.004 (vN^2 + vE^2)/k^2 (k = m/s per knot)."""
    vn, ve = float(vel_ne_mps[0]), float(vel_ne_mps[1])
    k = MPS_PER_KNOT
    return np.array([0.008 * vn / k**2, 7.5 * np.cos(np.radians(lat_deg)) / k + 0.008 * ve / k**2])


def error_dynamics(lat_rad: float, vel_ne_mps, acc_ne_mps2, heading_rad: float, tau_b_s: float,
                   R: float = WGS84_A_M, attitude_tau_s: float = 0.0, air_data: bool = False,
                   air_vel_ne_mps=None) -> np.ndarray:
    """Continuous A for [drN, drE | dsN, dsE, dvN, dvE, psiN, psiE, psiD, bgx, bgy, bgz, bax, bay, b_map].

    attitude_tau_s > 0: an INS whose attitude is held by an attitude reference (the companion's navigator fuses the
    autopilot's AHRS): psi is that reference's error, first-order Gauss-Markov with this time constant, not the
    integral of the gyro errors; the Schuler feedback through the attitude is cut (the reference, not the INS's own
    position, sets the vertical).
    air_data: the reference is air-data dead reckoning (companion.gravity.air_data): its velocity error is the error
    of the wind it holds (a random walk, continuous_noise), integrated into the position; no attitude, sensor-bias
    or Schuler terms (psi and the biases stay at zero); with ``air_vel_ne_mps`` (the reference's air velocity, its
    heading of its own: InsErrorSpec.air_heading) the heading error psiD turns it, dr' += psiD (-vE_air, vN_air), and
    psiD integrates the residual z-gyro bias bgz."""
    vN, vE = float(vel_ne_mps[0]), float(vel_ne_mps[1])
    aN, aE = float(acc_ne_mps2[0]), float(acc_ne_mps2[1])
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    wx = EARTH_RATE_RADPS * np.cos(lat_rad) + vE / R
    wy = -vN / R
    wz = -EARTH_RATE_RADPS * np.sin(lat_rad) - vE * np.tan(lat_rad) / R
    g = G0_MPS2
    A = np.zeros((N_ALL, N_ALL))
    rN, rE, sN, sE, vn, ve, pn, pe, pd, gx, gy, gz, ax, ay, b = range(N_ALL)
    A[rN, vn] = A[rE, ve] = A[sN, vn] = A[sE, ve] = 1.0
    A[b, b] = -1.0 / tau_b_s
    if air_data:
        if air_vel_ne_mps is not None:
            aN_, aE_ = float(air_vel_ne_mps[0]), float(air_vel_ne_mps[1])
            A[rN, pd] = A[sN, pd] = -aE_
            A[rE, pd] = A[sE, pd] = aN_
            A[pd, gz] = 1.0
        return A
    # dv' = f x psi + C ba - (g/R) ds, f = (aN, aE, -g)
    A[vn, pe], A[vn, pd], A[vn, ax], A[vn, ay] = g, aE, c, -s
    A[ve, pn], A[ve, pd], A[ve, ax], A[ve, ay] = -g, -aN, s, c
    if attitude_tau_s > 0:  # attitude held by a reference: its error, Gauss-Markov
        A[pn, pn] = A[pe, pe] = A[pd, pd] = -1.0 / attitude_tau_s
    else:
        A[vn, sN] = A[ve, sE] = -g / R
        # psi' = -w x psi - C bg
        A[pn, pe], A[pn, pd], A[pn, gx], A[pn, gy] = wz, -wy, -c, s
        A[pe, pn], A[pe, pd], A[pe, gx], A[pe, gy] = -wz, wx, -s, -c
        A[pd, pn], A[pd, pe], A[pd, gz] = wy, -wx, -1.0
    return A


def continuous_noise(spec: InsErrorSpec, mspec: MapErrorSpec, tau_b_s: float,
                     misfit_sigma_mgal: float | None = None) -> np.ndarray:
    """misfit_sigma_mgal: the map misfit's sigma if not mspec.sigma_mgal (a learnt one, see MisfitVarianceLearner)."""
    q = np.zeros(N_ALL)
    q[N_NL + IV:N_NL + IV + 2] = (spec.accel_vrw_ug_rthz * UG_MPS2) ** 2
    if spec.air_data:  # the held wind's error walks; nothing else moves (but the heading of its own, if any)
        q[N_NL + IV:N_NL + IV + 2] = spec.wind_walk_mps_rts**2
        if spec.air_heading:
            q[N_NL + IPSI + 2] = (np.radians(spec.gyro_arw_deg_rthr) / 60.0) ** 2
            q[N_NL + IBG + 2] = (spec.gyro_bias_walk_degph_rth * DEGPH_RADPS / 60.0) ** 2
    elif spec.attitude_tau_s > 0:  # stationary reference errors: q = 2 sigma^2 / tau
        q[N_NL + IPSI:N_NL + IPSI + 2] = 2.0 * spec.attitude_tilt_sigma_rad**2 / spec.attitude_tau_s
        q[N_NL + IPSI + 2] = 2.0 * spec.attitude_heading_sigma_rad**2 / spec.attitude_tau_s
    else:
        q[N_NL + IPSI:N_NL + IPSI + 3] = (np.radians(spec.gyro_arw_deg_rthr) / 60.0) ** 2
    sig = mspec.sigma_mgal if misfit_sigma_mgal is None else misfit_sigma_mgal
    q[N_NL + IB] = 2.0 * sig**2 / tau_b_s
    return np.diag(q)


def discretise(A: np.ndarray, Qc: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Phi = exp(A dt) by a 4th-order Taylor series (|A| dt << 1 for dt <= max_step_s); trapezoidal Qd."""
    Ad = A * dt_s
    Ad2 = Ad @ Ad
    Phi = np.eye(A.shape[0]) + Ad + Ad2 / 2.0 + Ad2 @ Ad / 6.0 + Ad2 @ Ad2 / 24.0
    Qd = 0.5 * (Phi @ Qc @ Phi.T + Qc) * dt_s
    return Phi, 0.5 * (Qd + Qd.T)


def prior_covariance(cfg: SeqGravConfig, pos_cov_ne_m2: np.ndarray) -> np.ndarray:
    s = cfg.ins
    d = np.zeros(N_ALL)
    o = N_NL
    d[o + IV:o + IV + 2] = s.init_vel_sigma_mps**2
    if s.air_data and s.air_heading:  # a heading of its own: its error and its z-gyro's residual bias
        d[o + IPSI + 2] = s.init_heading_sigma_rad**2
        d[o + IBG + 2] = (s.gyro_bias_degph * DEGPH_RADPS) ** 2
    if not s.air_data:  # (air data: no attitude or sensor-bias states)
        aided = s.attitude_tau_s > 0
        d[o + IPSI:o + IPSI + 2] = (s.attitude_tilt_sigma_rad if aided else s.init_tilt_sigma_rad) ** 2
        d[o + IPSI + 2] = (s.attitude_heading_sigma_rad if aided else s.init_heading_sigma_rad) ** 2
        d[o + IBG:o + IBG + 3] = (s.gyro_bias_degph * DEGPH_RADPS) ** 2
        d[o + IBA:o + IBA + 2] = (s.accel_bias_ug * UG_MPS2) ** 2
    d[o + IB] = cfg.map_error.sigma_mgal**2
    P = np.diag(d)
    P[:2, :2] = pos_cov_ne_m2
    return P


def _chol_psd(P: np.ndarray) -> np.ndarray:
    P = 0.5 * (P + P.T)
    jitter = 1e-12 * max(float(np.trace(P)) / P.shape[0], 1e-30)
    for _ in range(8):
        try:
            return np.linalg.cholesky(P + jitter * np.eye(P.shape[0]))
        except np.linalg.LinAlgError:
            jitter *= 100.0
    w, V = np.linalg.eigh(P)
    return V * np.sqrt(np.maximum(w, 0.0))


def _weighted_moments(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Mean, covariance and the bimodality coefficient (skew^2 + 1) / kurtosis along the major axis."""
    m = w @ x
    d = x - m
    cov = (w[:, None] * d).T @ d
    evals, evecs = np.linalg.eigh(cov)
    p = d @ evecs[:, -1]
    m2 = float(w @ p**2)
    if m2 <= 0:
        return m, cov, 0.0
    skew = float(w @ p**3) / m2**1.5
    kurt = float(w @ p**4) / m2**2
    return m, cov, (skew**2 + 1.0) / kurt


def rpf_bandwidth(n_particles: int, dim: int) -> float:
    """Optimal Gaussian kernel bandwidth of the regularised particle filter (Musso, Oudjane & Le Gland 2001), in
    units of the population standard deviation: (4 / (N (d + 2)))^(1 / (d + 4))."""
    return float((4.0 / (n_particles * (dim + 2.0))) ** (1.0 / (dim + 4.0)))


class MisfitVarianceLearner:
    """The map misfit's variance learnt along the track: the sample variance of r = reading - (the cloud's weighted
    mean map value) over the last ``window_m`` of distance, less the readings' own white variance. Under the misfit
    model r is the misfit (sigma^2 after its level is removed by the window mean, less the part of a Gauss-Markov
    process of length L a window of W >> L does not see, ~ 1 - L / W) plus the reading noise plus the map error of the
    position error; when the cloud sits where the map does not fit the readings, the last term shows here even while
    every particle's own innovation (the misfit state absorbs it) looks consistent. Running sums over a distance
    window, O(1) per reading; memory bounded by MAX_ENTRIES (one entry per reading inside the window)."""

    #: memory bound whatever the speed: a vehicle slower than window_m / MAX_ENTRIES per reading (2.8 m at 280 km)
    #: keeps only its newest readings, whose span never fills the window, so the floor stays in force
    MAX_ENTRIES = 100_000

    def __init__(self, window_m: float, corr_length_m: float):
        self.window_m = float(window_m)
        self.corr_length_m = float(corr_length_m)
        self._q: deque = deque()  # (distance, r, white variance)
        self._s = np.zeros(3)  # sum r, sum r^2, sum white variance

    def add(self, dist_m: float, r_mgal: float, white_var_mgal2: float) -> None:
        self._q.append((dist_m, r_mgal, white_var_mgal2))
        self._s += (r_mgal, r_mgal * r_mgal, white_var_mgal2)
        while self._q and (self._q[0][0] < dist_m - self.window_m or len(self._q) > self.MAX_ENTRIES):
            d0, r0, w0 = self._q.popleft()
            self._s -= (r0, r0 * r0, w0)

    def sigma_mgal(self, floor_mgal: float) -> float:
        """sqrt of the learnt misfit variance (scaled up by the GM variance a window does not see), at least floor;
        the floor until the window is full."""
        n = len(self._q)
        if n < 10 or self._q[-1][0] - self._q[0][0] < 0.95 * self.window_m:
            return float(floor_mgal)
        mean = self._s[0] / n
        var = max(self._s[1] / n - mean * mean, 0.0) - self._s[2] / n
        x = self.corr_length_m / self.window_m  # expected sample variance of a GM process over a window: sigma^2 f(x)
        var /= max(1.0 - 2.0 * x + 2.0 * x * x * (1.0 - np.exp(-1.0 / x)), 0.25)
        return float(np.sqrt(max(var, floor_mgal**2)))


# ---- back-ends -----------------------------------------------------------------------------------------
class _Mpf:
    """Marginalised particle filter with a covariance shared by all particles' Kalman filters."""

    def __init__(self, cfg: SeqGravConfig, rng: np.random.Generator):
        self.cfg, self.rng = cfg, rng
        self.n = int(cfg.n_particles)

    def init(self, P: np.ndarray, mean_xn=None, b_mean=None, b_var=None) -> None:
        """Particles from the joint Gaussian N(0, P): xn ~ N(0, Pnn), xl | xn its conditional mean, Pl the
        conditional covariance; optionally keep a map-misfit estimate (mean, variance)."""
        Pnn, Pln, Pll = P[:N_NL, :N_NL], P[N_NL:, :N_NL], P[N_NL:, N_NL:]
        xn = self.rng.standard_normal((self.n, N_NL)) @ _chol_psd(Pnn).T
        G = Pln @ np.linalg.inv(Pnn)
        self.xl = xn @ G.T
        self.Pl = Pll - G @ Pln.T
        self.xn = xn + (0.0 if mean_xn is None else np.asarray(mean_xn))
        if b_mean is not None:
            self.xl[:, IB] = b_mean
            self.Pl[IB, :] = 0.0
            self.Pl[:, IB] = 0.0
            self.Pl[IB, IB] = b_var
        self.w = np.full(self.n, 1.0 / self.n)

    def predict(self, Phi: np.ndarray, Qd: np.ndarray, qn: float) -> None:
        """Schoen 2005 eqs. 23-24, 25b with Qln = 0 (position noise enters through dv)."""
        Ann, Anl = Phi[:N_NL, :N_NL], Phi[:N_NL, N_NL:]
        Aln, All = Phi[N_NL:, :N_NL], Phi[N_NL:, N_NL:]
        Ql = Qd[N_NL:, N_NL:]
        Pl = self.Pl
        M = Anl @ Pl @ Anl.T + qn * np.eye(N_NL)  # eq. 23c
        L = All @ Pl @ Anl.T @ np.linalg.inv(M)  # eq. 23d
        self.Pl = All @ Pl @ All.T + Ql - L @ M @ L.T  # eq. 23b
        self.Pl = 0.5 * (self.Pl + self.Pl.T)
        xn_old, xl_old = self.xn, self.xl
        drift = xn_old @ Ann.T + xl_old @ Anl.T
        xn_new = drift + self.rng.standard_normal((self.n, N_NL)) @ _chol_psd(M).T  # eq. 25b
        z = xn_new - xn_old @ Ann.T  # eq. 24a
        self.xl = xn_old @ Aln.T + xl_old @ All.T + (z - xl_old @ Anl.T) @ L.T  # eq. 23a
        self.xn = xn_new

    def positions(self) -> np.ndarray:
        return self.xn

    def update(self, tile: MapTile, ref_ne: np.ndarray, y: float, H: np.ndarray, R: float, R_raw: float):
        """Eqs. 22, 25a with the inflated white variance R. Returns (NIS with the per-reading variance R_raw, best
        |residual| in sigma, mean map value, mean gradient) or None when every particle is off the map."""
        f = tile(ref_ne[0] - self.xn[:, 0], ref_ne[1] - self.xn[:, 1])
        h = f[:, 0]
        ok = np.isfinite(h)
        if not ok.any():
            return None
        HPH = float(H @ self.Pl @ H)
        V = HPH + R
        yhat_i = np.where(ok, h, 0.0) + self.xl @ H
        e = y - yhat_i
        w0 = np.where(ok, self.w, 0.0)
        w0 = w0 / w0.sum()
        yhat = float(w0 @ yhat_i)
        nis = (y - yhat) ** 2 / (float(w0 @ (yhat_i - yhat) ** 2) + HPH + R_raw)
        r2 = np.where(ok, e * e / V, np.inf)
        best = float(np.sqrt(r2.min()))
        lw = np.log(np.maximum(self.w, 1e-300)) - 0.5 * r2
        lw -= lw.max()
        w = np.exp(lw)
        self.w = w / w.sum()
        K = self.Pl @ H / V  # eq. 22d
        self.xl = self.xl + np.outer(np.where(ok, e, 0.0), K)  # eq. 22a
        self.Pl = self.Pl - np.outer(K, K) * V  # eq. 22b
        self.Pl = 0.5 * (self.Pl + self.Pl.T)
        hm = float(self.w @ np.where(ok, h, 0.0))
        grad = self.w @ np.where(ok[:, None], f[:, 1:], 0.0)
        return nis, best, hm, grad

    def moments(self):
        m, cov, bc = _weighted_moments(self.xn, self.w)
        return m, cov, bc, 1.0 / float(np.sum(self.w**2)), float(self.w @ self.xl[:, IB]), float(self.Pl[IB, IB])

    def velocity_moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance of the horizontal velocity error: the shared Kalman covariance plus the spread of the
        particles' conditional means (the law of total covariance)."""
        v = self.xl[:, IV:IV + 2]
        m = self.w @ v
        d = v - m
        return m, self.Pl[IV:IV + 2, IV:IV + 2] + (self.w[:, None] * d).T @ d

    def resample_if_needed(self) -> bool:
        n_eff = 1.0 / float(np.sum(self.w**2))
        if n_eff >= self.cfg.resample_frac * self.n:
            return False
        u = (self.rng.random() + np.arange(self.n)) / self.n  # systematic
        idx = np.minimum(np.searchsorted(np.cumsum(self.w), u), self.n - 1)
        xn, xl = self.xn[idx], self.xl[idx]
        h = rpf_bandwidth(self.n, N_NL) if self.cfg.roughen is None else float(self.cfg.roughen)
        if h > 0:  # regularisation of the positions only (velocity diversity comes from eq. 23a)
            C = np.cov(xn, rowvar=False)
            if h > self.cfg.roughen_multimodal and _weighted_moments(xn, np.full(self.n, 1.0 / self.n))[2] > \
                    self.cfg.multimodal_bc:  # a kernel of the global spread would smear the modes together
                h = self.cfg.roughen_multimodal
            jitter = self.rng.standard_normal(xn.shape) @ _chol_psd(C).T * h
            if self.cfg.roughen_shrink:  # Liu & West 2001: shrink to the mean so the kernel keeps mean and covariance
                a = np.sqrt(max(1.0 - h * h, 0.0))
                xn = a * xn + (1.0 - a) * xn.mean(axis=0) + jitter
            else:
                xn = xn + jitter
        self.xn, self.xl = xn, xl
        self.w = np.full(self.n, 1.0 / self.n)
        return True

    def shift_errors(self, d_pos_ne_m, d_vel_ne_mps) -> None:
        """Every particle's position error changes by d_pos_ne_m and its velocity error by d_vel_ne_mps."""
        self.xn = self.xn + np.asarray(d_pos_ne_m, float)
        self.xl[:, IV:IV + 2] += np.asarray(d_vel_ne_mps, float)

    def add_velocity_cov(self, Q: np.ndarray) -> None:
        """The velocity error's covariance grows by Q (2x2) in every particle's Kalman filter."""
        self.Pl[IV:IV + 2, IV:IV + 2] += Q


class _Pmf:
    """Point-mass filter on a moving n x n grid over the position error, map misfit per point (shared variance)."""

    def __init__(self, cfg: SeqGravConfig, rng: np.random.Generator):
        self.cfg, self.rng = cfg, rng
        self.k = int(cfg.pmf_grid)
        self.q_acc = np.zeros((2, 2))  # position process covariance not yet convolved

    def _grid(self, centre, spacing):
        ax = (np.arange(self.k) - 0.5 * (self.k - 1)) * spacing
        self.centre = np.asarray(centre, float).copy()
        self.spacing = float(spacing)
        self.axis = ax
        N, E = np.meshgrid(ax + centre[0], ax + centre[1], indexing="ij")
        self.pts = np.column_stack([N.ravel(), E.ravel()])

    def _spacing_for(self, cov):
        return max(2.0 * self.cfg.pmf_span_sigma * float(np.sqrt(np.max(np.linalg.eigvalsh(cov)))) / (self.k - 1), 1.0)

    def init(self, P: np.ndarray, mean_xn=None, b_mean=None, b_var=None) -> None:
        c = np.zeros(2) if mean_xn is None else np.asarray(mean_xn, float)
        cov = P[:2, :2]
        self._grid(c, self._spacing_for(cov))
        d = self.pts - c
        iC = np.linalg.inv(cov)
        lw = -0.5 * np.einsum("ij,jk,ik->i", d, iC, d)
        w = np.exp(lw - lw.max())
        self.w = w / w.sum()
        self.b = np.full(self.pts.shape[0], 0.0 if b_mean is None else float(b_mean))
        self.Pb = float(P[N_NL + IB, N_NL + IB] if b_var is None else b_var)
        self.q_acc = np.zeros((2, 2))

    def predict(self, Phi, Qd, qn, dP_pos=None, phi_b=1.0, q_b=0.0) -> None:
        self.b *= phi_b
        self.Pb = phi_b**2 * self.Pb + q_b
        if dP_pos is not None:
            self.q_acc = self.q_acc + dP_pos
        self.q_acc = self.q_acc + qn * np.eye(2)
        # convolve once the accumulated process noise is a useful fraction of the spacing
        if max(self.q_acc[0, 0], self.q_acc[1, 1]) >= (0.25 * self.spacing) ** 2:
            self._convolve(self.q_acc)
            self.q_acc = np.zeros((2, 2))

    def _kernel(self, var):
        sig = np.sqrt(max(var, 0.0)) / self.spacing
        i = np.arange(self.k)
        if sig < 0.5:  # variance-preserving 3-tap kernel
            a = 0.5 * sig**2
            K = np.eye(self.k) * (1 - 2 * a) + np.eye(self.k, k=1) * a + np.eye(self.k, k=-1) * a
        else:
            K = np.exp(-0.5 * ((i[:, None] - i[None, :]) / sig) ** 2)
        return K / K.sum(axis=0, keepdims=True)

    def _convolve(self, Q):
        Kn, Ke = self._kernel(Q[0, 0]), self._kernel(Q[1, 1])  # separable (cross term dropped)
        W = self.w.reshape(self.k, self.k)
        WB = (self.w * self.b).reshape(self.k, self.k)
        W2 = Kn @ W @ Ke.T
        WB2 = Kn @ WB @ Ke.T
        self.b = np.where(W2 > 1e-300, WB2 / np.maximum(W2, 1e-300), 0.0).ravel()
        self.w = W2.ravel() / W2.sum()

    def positions(self) -> np.ndarray:
        return self.pts

    def update(self, tile, ref_ne, y, H, R, R_raw):
        f = tile(ref_ne[0] - self.pts[:, 0], ref_ne[1] - self.pts[:, 1])
        h = f[:, 0]
        ok = np.isfinite(h)
        if not ok.any():
            return None
        V = self.Pb + R
        yhat_i = np.where(ok, h, 0.0) + self.b
        e = y - yhat_i
        w0 = np.where(ok, self.w, 0.0)
        w0 = w0 / max(w0.sum(), 1e-300)
        yhat = float(w0 @ yhat_i)
        nis = (y - yhat) ** 2 / (float(w0 @ (yhat_i - yhat) ** 2) + self.Pb + R_raw)
        r2 = np.where(ok, e * e / V, np.inf)
        best = float(np.sqrt(r2[self.w > 0].min())) if np.any(self.w > 0) else np.inf
        lw = np.log(np.maximum(self.w, 1e-300)) - 0.5 * r2
        w = np.exp(lw - lw.max())
        self.w = w / w.sum()
        K = self.Pb / V
        self.b = self.b + K * np.where(ok, e, 0.0)
        self.Pb = self.Pb * (1 - K)
        hm = float(self.w @ np.where(ok, h, 0.0))
        grad = self.w @ np.where(ok[:, None], f[:, 1:], 0.0)
        return nis, best, hm, grad

    def moments(self):
        m, cov, bc = _weighted_moments(self.pts, self.w)
        cov = cov + np.eye(2) * self.spacing**2 / 12.0 + self.q_acc  # cell quantisation, pending process noise
        return m, cov, bc, 1.0 / float(np.sum(self.w**2)), float(self.w @ self.b), self.Pb

    def velocity_moments(self) -> None:
        return None  # no velocity states

    def resample_if_needed(self) -> bool:
        """Re-grid when the distribution moved or its spread changed by more than 30 %."""
        m, cov, _ = _weighted_moments(self.pts, self.w)
        cov = cov + np.eye(2) * self.spacing**2 / 12.0
        want = self._spacing_for(cov)
        if abs(np.log(want / self.spacing)) < np.log(1.3) and np.all(np.abs(m - self.centre) < 0.15 * self.k * self.spacing):
            return False
        old_axis_n, old_axis_e = self.axis + self.centre[0], self.axis + self.centre[1]
        W = self.w.reshape(self.k, self.k) / self.spacing**2  # density
        B = self.b.reshape(self.k, self.k)
        self._grid(m, want)
        from companion.gravity.maps import bilinear

        dens = np.nan_to_num(bilinear(old_axis_e, old_axis_n, W, self.pts[:, 1], self.pts[:, 0]), nan=0.0)
        bb = bilinear(old_axis_e, old_axis_n, B, self.pts[:, 1], self.pts[:, 0])
        if dens.sum() <= 0:
            dens = np.ones_like(dens)
        self.w = dens / dens.sum()
        self.b = np.where(np.isfinite(bb), bb, float(np.nansum(B * W) / max(np.sum(W), 1e-300)))
        return True

    def shift_errors(self, d_pos_ne_m, d_vel_ne_mps) -> None:
        """The grid moves by d_pos_ne_m (the point-mass filter has no velocity states)."""
        d = np.asarray(d_pos_ne_m, float)
        self.pts = self.pts + d
        self.centre = self.centre + d

    def add_velocity_cov(self, Q: np.ndarray) -> None:
        """No velocity states: the INS-alone covariance the front-end carries takes it."""
