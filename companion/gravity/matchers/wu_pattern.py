"""Gravity pattern (image) matching: RPCM (Wu et al. 2015, J. Navigation) and classic TERCOM.

The map is resampled once to a regular NE grid (cell_m). A pattern image S (eq. 2's S_{m*n}) holds the
measurements at grid cells, cells without a measurement are invalid and skipped. COEFS over every
placement of S in the map P is MAD (eq. 3) or MSD (eq. 4) over the valid cells; the minimum (eq. 5)
gives the match.
  * RPCM lays measurements at INS *relative* positions (eq. 1): x_j - x_i ~ x_j^INS - x_i^INS, so the
    pattern keeps the trajectory's shape, curves and turns included.
  * TERCOM (classic, Golden 1980, as described in Wu sec. 1) assumes straight, constant-speed motion
    over the update period: measurements are laid at constant spacing on the straight line between
    the first and last absolute INS positions. Its pattern therefore loses the shape of curved tracks.
MSD uses FFT correlation (three correlations per pattern); MAD sums |S - P| per pattern cell over all
placements (vectorised over placements).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.fft as sfft
from scipy.signal import fftconvolve

from companion.gravity.matchers.base import MatchFailure, Matcher, MatchResult, MatchWindow
from companion.gravity.maps import LocalGravityMap


@dataclass(frozen=True)
class PatternConfig:
    cell_m: float = 2.0 * 1852.0  # Wu: 2 nm/grid
    metric: Literal["mad", "msd"] = "msd"
    min_len: int = 10
    window_len: int = 300  # Wu's pattern is 300 x 15 cells
    region_ne_m: tuple[float, float, float, float] | None = None  # (n0, n1, e0, e1) searched; None = whole map
    max_ins_error_m: float = 50_000.0  # INS points farther than this outside the searched region -> failure
    subcell: bool = True  # parabolic refinement of the COEFS minimum (not in Wu; else fixes snap to cells)


class RegularMetricMap:
    """Map resampled to a regular NE grid with FFT-ready masked arrays."""

    def __init__(self, lmap: LocalGravityMap, cell_m: float, region_ne_m=None):
        n0, n1, e0, e1 = region_ne_m if region_ne_m is not None else lmap.bounds_ne()
        g, self.north_m, self.east_m = lmap.regular_ne(cell_m, (n0, n1), (e0, e1))
        self.cell_m = float(cell_m)
        self.valid = np.isfinite(g)
        if not self.valid.any():
            raise ValueError("no valid map cells in the region")
        self.g = np.where(self.valid, g, 0.0)
        self.g2 = self.g**2
        self.v = self.valid.astype(float)
        self.g32 = self.g.astype(np.float32)
        self.g32[~self.valid] = np.nan  # MAD: NaN placements are rejected by the coverage test
        self._spec: dict = {}

    def spectra(self, pad: tuple[int, int]):
        """rfft2 of (g, g^2, valid) zero-padded to pad, cached per pad shape."""
        if pad not in self._spec:
            self._spec[pad] = tuple(sfft.rfft2(a.astype(np.float32), pad) for a in (self.g, self.g2, self.v))
        return self._spec[pad]

    def correlate_msd(self, s: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sum W (S - P)^2, coverage count) over all valid placements of the pattern (eq. 4 expanded:
        sum W S^2 - 2 corr(P, W S) + corr(P^2, W)), by FFT with the map spectra cached."""
        from scipy.fft import next_fast_len

        M, N = self.g.shape
        m, n = s.shape
        bucket = lambda k: 32 * int(np.ceil(k / 32))  # noqa: E731  reuse spectra across similar patterns
        pad = (next_fast_len(M + bucket(m)), next_fast_len(N + bucket(n)))
        G, G2, V = self.spectra(pad)
        # float32 transforms: ~2x faster; SSD errors ~1e-7 of sum(P^2), far below the noise floor of COEFS
        kws = sfft.rfft2((w * s)[::-1, ::-1].astype(np.float32), pad)
        kw = sfft.rfft2(w[::-1, ::-1].astype(np.float32), pad)
        full = sfft.irfft2(G2 * kw - 2.0 * G * kws, pad)
        cover = sfft.irfft2(V * kw, pad)
        sl = (slice(m - 1, M), slice(n - 1, N))
        return np.sum(w * s * s) + full[sl].astype(float), cover[sl].astype(float)

    @property
    def shape(self):
        return self.g.shape


def _corr_valid(big: np.ndarray, kern: np.ndarray) -> np.ndarray:
    """Cross-correlation sum_{u,v} kern[u,v] big[x+u, y+v] for all valid placements."""
    return fftconvolve(big, kern[::-1, ::-1], mode="valid")


def _parabolic_offset(c_minus: float, c0: float, c_plus: float) -> float:
    """Vertex of the parabola through three equally spaced costs, in cells, clipped to +-0.5."""
    den = c_minus - 2 * c0 + c_plus
    if not np.isfinite(den) or den <= 0:
        return 0.0
    return float(np.clip(0.5 * (c_minus - c_plus) / den, -0.5, 0.5))


class _PatternMatcher(Matcher):
    shape_mode = "relative"

    def __init__(self, lmap: LocalGravityMap, cfg: PatternConfig | None = None, fix_every: int = 1,
                 rmap: RegularMetricMap | None = None):
        self.cfg = cfg or PatternConfig()
        if self.cfg.metric not in ("mad", "msd"):
            raise ValueError("metric must be 'mad' or 'msd'")
        super().__init__(lmap, min_len=self.cfg.min_len, window_len=self.cfg.window_len, fix_every=fix_every)
        self.rmap = rmap or RegularMetricMap(lmap, self.cfg.cell_m, self.cfg.region_ne_m)
        self.name = f"{type(self).__name__.replace('Matcher', '')}-{self.cfg.metric.upper()}"

    def pattern_positions(self, window: MatchWindow) -> np.ndarray:
        """Relative NE positions (m) of the measurements in the pattern, first sample at 0."""
        ins = window.ins_ne_m
        if self.shape_mode == "relative":
            return ins - ins[0]  # eq. 1
        t = window.t_s
        frac = (t - t[0]) / (t[-1] - t[0])
        return frac[:, None] * (ins[-1] - ins[0])[None, :]  # straight line, constant speed

    def _match(self, window: MatchWindow) -> MatchResult:
        rm = self.rmap
        tol = self.cfg.max_ins_error_m
        ins = window.ins_ne_m
        if (np.any(ins[:, 0] < rm.north_m[0] - tol) or np.any(ins[:, 0] > rm.north_m[-1] + tol)
                or np.any(ins[:, 1] < rm.east_m[0] - tol) or np.any(ins[:, 1] > rm.east_m[-1] + tol)):
            raise MatchFailure("INS track leaves the map (beyond max_ins_error_m of the searched region)")
        rel = self.pattern_positions(window)
        c = rm.cell_m
        ij = np.rint(rel / c).astype(np.intp)
        ij0 = ij.min(axis=0)
        ij -= ij0
        m, n = ij.max(axis=0) + 1
        M, N = rm.shape
        if m > M or n > N:
            raise MatchFailure(f"pattern {m}x{n} cells larger than the searched map {M}x{N}")
        # average measurements falling in the same cell
        flat = ij[:, 0] * n + ij[:, 1]
        cnt = np.bincount(flat, minlength=m * n)
        ssum = np.bincount(flat, weights=window.gravity_mgal, minlength=m * n)
        w = (cnt > 0).reshape(m, n).astype(float)
        s = np.where(cnt > 0, ssum / np.maximum(cnt, 1), 0.0).reshape(m, n)
        nv = w.sum()
        if self.cfg.metric == "msd":
            ssd, cover = rm.correlate_msd(s, w)  # eq. 4 (times nv)
            full = cover > nv - 0.5  # every pattern cell on valid map
            cost = ssd / nv
        else:
            ui, vi = np.nonzero(w)
            R, C = M - m + 1, N - n + 1
            cost32 = np.zeros((R, C), np.float32)
            tmp = np.empty((R, C), np.float32)
            for u, v in zip(ui, vi):  # eq. 3, vectorised over all placements
                np.subtract(rm.g32[u:u + R, v:v + C], np.float32(s[u, v]), out=tmp)
                np.abs(tmp, out=tmp)
                cost32 += tmp
            full = np.isfinite(cost32)
            cost = cost32.astype(float) / nv
        if not full.any():
            raise MatchFailure("no placement keeps the whole pattern on valid map cells")
        cost = np.where(full, cost, np.inf)
        a, b = np.unravel_index(int(np.argmin(cost)), cost.shape)  # eq. 5
        da = db = 0.0
        if self.cfg.subcell:
            if 0 < a < cost.shape[0] - 1:
                da = _parabolic_offset(cost[a - 1, b], cost[a, b], cost[a + 1, b])
            if 0 < b < cost.shape[1] - 1:
                db = _parabolic_offset(cost[a, b - 1], cost[a, b], cost[a, b + 1])
        anchor = np.array([rm.north_m[a] + da * c, rm.east_m[b] + db * c])  # map position of pattern cell (0, 0)
        track = anchor + (rel - ij0 * c)
        # uncertainty: spread of the 9 best placements
        k = min(9, int(np.isfinite(cost).sum()))
        best = np.argpartition(cost.ravel(), k - 1)[:k]
        ba, bb = np.unravel_index(best, cost.shape)
        spread = np.hypot((ba - a) * c, (bb - b) * c)
        sigma = float(max(np.sqrt(np.mean(spread**2)), c / np.sqrt(12)))
        return MatchResult(True, self.name, float(window.t_s[-1]), track[-1].copy(), sigma_m=sigma,
                           quality=float(cost[a, b]), track_ne_m=track, extra={"pattern_cells": (int(m), int(n))})


class RpcmMatcher(_PatternMatcher):
    """Relative-positions-constrained pattern matching (Wu et al. 2015)."""

    shape_mode = "relative"


class TercomMatcher(_PatternMatcher):
    """Classic TERCOM: straight-line constant-speed pattern from the absolute INS end points."""

    shape_mode = "straight"
