"""KNN gravity matching (Gao, Cai, Fang 2022, Sensors 22:4454) and its MSD baseline.

Both use the paper's sample set (sec. 2.1): grid labels P within radius R of the current INS position,
each carrying the INS sequence translated to P and rotated by dtheta (+ i * dtheta0 progressively),
eqs. 1-2. Positions are metres in the LocalGravityMap frame; R and the label step are given in degrees
as in the paper and converted with the map's metres-per-degree of latitude (a circle on the ground).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.gravity.matchers.base import MatchFailure, Matcher, MatchResult, MatchWindow, SpeedConstraint
from companion.gravity.maps import LocalGravityMap


@dataclass(frozen=True)
class SequenceSearchConfig:
    search_radius_deg: float = 0.055  # R (paper sec. 3.1)
    step_deg: float = 0.003  # label / interpolation step
    min_len: int = 10  # initial matching sequence length
    window_len: int = 20  # sliding window width in continuous matching
    dtheta_deg: tuple[float, ...] = (-2.0, -1.0, 0.0, 1.0, 2.0)  # whole-sequence rotations (eq. 2, A_dtheta)
    dtheta0_deg: tuple[float, ...] = (-0.1, 0.0, 0.1)  # per-point progressive rotation (eq. 2, A_{i dtheta0})


class SampleSet:
    """Labels and their transformed INS sequences with interpolated map gravity (eqs. 1-4)."""

    def __init__(self, lmap: LocalGravityMap, cfg: SequenceSearchConfig, window: MatchWindow):
        m_per_deg_n, _ = lmap.metres_per_deg()
        radius_m = cfg.search_radius_deg * m_per_deg_n
        step_m = cfg.step_deg * m_per_deg_n
        k = int(np.floor(radius_m / step_m))
        off = np.arange(-k, k + 1) * step_m
        dn, de = np.meshgrid(off, off, indexing="ij")
        inside = dn**2 + de**2 <= radius_m**2 + 1e-6
        centre = window.ins_ne_m[-1]
        # labels as complex e + i n (rotation = complex multiply)
        self.labels = (centre[1] + de[inside]) + 1j * (centre[0] + dn[inside])  # (L,)
        ins = window.ins_ne_m[:, 1] + 1j * window.ins_ne_m[:, 0]
        d = ins - ins[-1]  # INS_i - INS_N (eq. 1; the label is the newest point)
        n = d.size
        back = np.arange(n - 1, -1, -1)  # number of steps back from the newest point
        th = np.radians(np.asarray(cfg.dtheta_deg))[:, None, None]
        th0 = np.radians(np.asarray(cfg.dtheta0_deg))[None, :, None]
        rot = np.exp(1j * (th + back[None, None, :] * th0)).reshape(-1, n)  # (m, n), eq. 2
        self.rotations = rot
        pts = self.labels[:, None, None] + rot[None, :, :] * d[None, None, :]  # (L, m, n), eq. 1
        self.points = pts
        self.g_map = lmap.interp_ne(pts.imag, pts.real)  # eq. 3
        self.valid = np.all(np.isfinite(self.g_map), axis=-1)  # (L, m)
        self.step_m = step_m
        self.radius_m = radius_m

    def label_ne(self, flat_idx: np.ndarray) -> np.ndarray:
        m = self.rotations.shape[0]
        lab = self.labels[np.asarray(flat_idx) // m]
        return np.column_stack([lab.imag, lab.real])

    def track_ne(self, flat_idx: int) -> np.ndarray:
        L, m, n = self.points.shape
        p = self.points[flat_idx // m, flat_idx % m]
        return np.column_stack([p.imag, p.real])


class _SequenceMatcher(Matcher):
    def __init__(self, lmap: LocalGravityMap, cfg: SequenceSearchConfig | None = None,
                 speed_constraint: SpeedConstraint | None = SpeedConstraint(), fix_every: int = 1):
        self.cfg = cfg or SequenceSearchConfig()
        super().__init__(lmap, min_len=self.cfg.min_len, window_len=self.cfg.window_len, fix_every=fix_every,
                         speed_constraint=speed_constraint)

    def _samples(self, window: MatchWindow) -> SampleSet:
        s = SampleSet(self.lmap, self.cfg, window)
        if not np.any(s.valid):
            raise MatchFailure("track leaves the map (no label has all sequence points on valid map cells)")
        return s


class KnnMatcher(_SequenceMatcher):
    """Gao et al. 2022: differential features (eqs. 4, 7), Euclidean distance (eq. 8), K nearest,
    outlier removal and reciprocal-distance weighting about the label centroid (eqs. 9-11)."""

    name = "KNN"

    def __init__(self, lmap, cfg=None, k: int = 17, speed_constraint=SpeedConstraint(), fix_every: int = 1):
        super().__init__(lmap, cfg, speed_constraint, fix_every)
        if k < 2:
            raise ValueError("K must be >= 2")
        self.k = k

    def _match(self, window: MatchWindow) -> MatchResult:
        s = self._samples(window)
        feat = s.g_map[..., 1:] - s.g_map[..., :1]  # eq. 4
        meas = window.gravity_mgal[1:] - window.gravity_mgal[0]  # eq. 7
        dist = np.sqrt(np.sum((feat - meas) ** 2, axis=-1))  # eq. 8, p = 2
        dist = np.where(s.valid, dist, np.inf).ravel()
        n_ok = int(np.isfinite(dist).sum())
        if n_ok < self.k:
            raise MatchFailure(f"only {n_ok} valid samples on the map, need K={self.k}")
        idx = np.argpartition(dist, self.k - 1)[: self.k]
        lab = s.label_ne(idx)  # (K, 2)
        centre = lab.mean(axis=0)  # eq. 9
        r = np.hypot(*(lab - centre).T)
        eta = 1.0 / np.maximum(r, 1e-3 * s.step_m)  # eq. 10
        keep = np.ones(self.k, bool)
        keep[np.argmin(eta)] = False  # remove the farthest label
        w = eta[keep]
        pos = (w[:, None] * lab[keep]).sum(axis=0) / w.sum()  # eq. 11
        sigma = float(np.sqrt((w * np.sum((lab[keep] - pos) ** 2, axis=1)).sum() / w.sum()))
        track = window.ins_ne_m - window.ins_ne_m[-1] + pos
        return MatchResult(True, self.name, float(window.t_s[-1]), pos, sigma_m=max(sigma, s.step_m / np.sqrt(12)),
                           quality=float(np.min(dist)), track_ne_m=track,
                           extra={"n_samples": n_ok})


class MsdSequenceMatcher(_SequenceMatcher):
    """Maximum-correlation (minimum mean square difference) baseline on the same sample set (Gao sec. 3.1)."""

    name = "MSD"

    def _match(self, window: MatchWindow) -> MatchResult:
        s = self._samples(window)
        msd = np.mean((s.g_map - window.gravity_mgal) ** 2, axis=-1)
        msd = np.where(s.valid, msd, np.inf).ravel()
        best = int(np.argmin(msd))
        pos = s.label_ne(np.array([best]))[0]
        # spread of the 17 best samples as an uncertainty indicator
        kk = min(17, int(np.isfinite(msd).sum()))
        top = s.label_ne(np.argpartition(msd, kk - 1)[:kk])
        sigma = float(np.sqrt(np.mean(np.sum((top - pos) ** 2, axis=1))))
        return MatchResult(True, self.name, float(window.t_s[-1]), pos, sigma_m=max(sigma, s.step_m / np.sqrt(12)),
                           quality=float(msd[best]), track_ne_m=s.track_ne(best))
