"""ICCP (iterated closest contour point) baseline, as compared in Gao et al. 2022 sec. 3.

Each iteration finds, for every track point, the nearest map point whose anomaly lies in the
equivalence range [G_i + lo, G_i + hi] (the paper sets the range from the measurement noise), then fits
the rigid transform (rotation + translation, least squares) taking the track onto those points.
The map's contour points are taken on a regular NE lattice (step = the paper's 0.003 deg) around the
INS window, expanded by the search radius.
"""

from __future__ import annotations

import numpy as np

from companion.gravity.matchers.base import MatchFailure, Matcher, MatchResult, MatchWindow, SpeedConstraint
from companion.gravity.matchers.gao_knn import SequenceSearchConfig
from companion.gravity.maps import LocalGravityMap


def rigid_fit_2d(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation R and translation t with dst ~ src @ R.T + t (Kabsch, no scaling)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, d]) @ u.T
    return r, cd - cs @ r.T


def equivalence_range_from_noise(sigma_mgal: float, mean_mgal: float = 0.0, k: float = 1.5) -> tuple[float, float]:
    """[mean - k sigma, mean + k sigma]; the paper's -3..5 mGal for mean 1.06, STD 2.94 is k ~ 1.36."""
    return mean_mgal - k * sigma_mgal, mean_mgal + k * sigma_mgal


class IccpMatcher(Matcher):
    name = "ICCP"

    def __init__(self, lmap: LocalGravityMap, cfg: SequenceSearchConfig | None = None,
                 equivalence_mgal: tuple[float, float] = (-3.0, 5.0), iterations: int = 10,
                 contour_step_deg: float | None = None,
                 speed_constraint: SpeedConstraint | None = SpeedConstraint(), fix_every: int = 1):
        self.cfg = cfg or SequenceSearchConfig()
        lo, hi = equivalence_mgal
        if not lo < hi:
            raise ValueError("equivalence range must have lo < hi")
        self.equivalence_mgal = (float(lo), float(hi))
        self.iterations = iterations
        self.contour_step_deg = contour_step_deg or self.cfg.step_deg
        super().__init__(lmap, min_len=self.cfg.min_len, window_len=self.cfg.window_len, fix_every=fix_every,
                         speed_constraint=speed_constraint)

    def _match(self, window: MatchWindow) -> MatchResult:
        m_per_deg_n, _ = self.lmap.metres_per_deg()
        radius = self.cfg.search_radius_deg * m_per_deg_n
        step = self.contour_step_deg * m_per_deg_n
        ins = window.ins_ne_m
        lo_n, lo_e = ins.min(axis=0) - radius
        hi_n, hi_e = ins.max(axis=0) + radius
        gn = np.arange(lo_n, hi_n + step / 2, step)
        ge = np.arange(lo_e, hi_e + step / 2, step)
        N, E = np.meshgrid(gn, ge, indexing="ij")
        gv = self.lmap.interp_ne(N, E).ravel()
        ok = np.isfinite(gv)
        if ok.sum() < 3:
            raise MatchFailure("track leaves the map (no valid contour points around the INS window)")
        grid = np.column_stack([N.ravel()[ok], E.ravel()[ok]])
        gv = gv[ok]
        g = window.gravity_mgal
        lo, hi = self.equivalence_mgal
        diff = gv[None, :] - g[:, None]
        eq = (diff >= lo) & (diff <= hi)  # (n, M) contour membership, fixed over iterations
        has = eq.any(axis=1)
        if has.sum() < 3:
            raise MatchFailure("fewer than 3 measurements have a contour within the search area")
        track = ins.copy()
        closest = track.copy()
        for _ in range(self.iterations):
            d2 = ((track[:, None, 0] - grid[None, :, 0]) ** 2 + (track[:, None, 1] - grid[None, :, 1]) ** 2)
            d2 = np.where(eq, d2, np.inf)
            j = np.argmin(d2, axis=1)
            closest = np.where(has[:, None], grid[j], track)
            r, t = rigid_fit_2d(ins[has], closest[has])
            new = ins @ r.T + t
            if np.allclose(new, track, atol=1e-3):
                track = new
                break
            track = new
        resid = np.hypot(*(track[has] - closest[has]).T)
        rms = float(np.sqrt(np.mean(resid**2)))
        return MatchResult(True, self.name, float(window.t_s[-1]), track[-1].copy(), sigma_m=max(rms, step / np.sqrt(12)),
                           quality=rms, track_ne_m=track)
