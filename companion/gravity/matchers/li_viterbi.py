"""Viterbi gravity map matching (Li, Cheng, Gu, Wang et al. 2022, arXiv 2204.10492): VBMP, RVBMP, RVBMP-2.

Map cells are the HMM's hidden states. For each of the T measurements of a correction segment, a grid B_t
of n x n cells is centred on the cell holding the INS position (eqs. 3-4); with o > 1 every cell is split
into o x o sub-cells that share the cell's gravity value (RVBMP-2, eqs. 20-21) and differ only in position.

  log p_z(z_t | c)         = -(z_t - g_m(c))^2 / (2 sigma_z^2)                          (eq. 8)
  log p_v(c_t | v, c_t-1)  = -|c_t - c_t-1 - v_t-1 dt|^2 / (2 sigma_step^2)             (eq. 9)
  posterior of a step      = p_z * p_v                                                 (eq. 10)

p_z is the paper's Gaussian; with representation_error (default) its sigma per cell is
sqrt(sigma_z^2 + (|grad g| d / sqrt(12))^2): a measurement taken anywhere in a cell of side d differs from the
cell-centre value by that much (the paper's simulation reads the measurement from the cell value itself, so it
needs no such term; on a continuous field the true cell is otherwise pruned by eq. 25 whenever the field is
steep). The log-likelihood keeps its -log sigma term because sigma varies per cell.

The paper does not give p_v's form; we take a Gaussian on the displacement with
sigma_step^2 = (sigma_v dt)^2 + 2 (d / sqrt(12))^2, the second term being the quantisation of a path that
may only pass through (sub-)cell centres of spacing d.

prior_sigma_m (ours, not the paper's): the paper's first state is uniform over B_1; a Gaussian prior of this
sigma around the INS position keeps the path from jumping to a distant look-alike when the map is smooth.

subcell_values='interp' (ours, not the paper's): sub-cells read the map bilinearly between cell centres at
their own centres instead of sharing the cell value (eq. 20), so the second layer can use the field's
variation inside a cell; pruning (eq. 25) still acts on whole cells.

Pruning (RVBMP, eq. 25): only cells whose p_z / max p_z >= alpha enter A_t; alpha = 0 keeps every valid cell
(VBMP). Search modes:
  * "viterbi" (default): exact max-product dynamic programming over the pruned states, i.e. the MAP path of
    eq. 6 (the HMM the paper sets up, solved by the Viterbi recursion it names).
  * "paper": eqs. 13-19 / 22-24 / 26-28 literally: for each start state j1 the path is continued greedily
    (j_t* = argmax p(c_t | z_t, v_t-1, c_t-1*), eq. 17) and the start with the largest product wins (eq. 18).
    This is cheaper to reason about but not always the MAP path.
Ties (equal scores) go to the path closest to the INS positions, as the paper prescribes.

The estimated cell-centre path resets the INS over the segment (the paper's correction); the fusion module
turns the end point and its spread into a position measurement instead.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from companion.gravity.matchers.base import MatchFailure, Matcher, MatchResult, MatchWindow
from companion.gravity.maps import LocalGravityMap, bilinear


@dataclass(frozen=True)
class ViterbiConfig:
    n: int = 13  # grid B_t is n x n cells (odd)
    o: int = 1  # sub-cells per cell side; 1 = RVBMP, > 1 = RVBMP-2
    alpha: float = 0.1  # eq. 25 pruning threshold; 0 = no pruning (VBMP)
    T: int = 6  # correction rate: measurements per segment
    sigma_z_mgal: float = 1.0  # gravimeter noise in p_z
    sigma_v_mps: float = 1.0  # velocity noise in p_v
    search: Literal["viterbi", "paper"] = "viterbi"
    representation_error: bool = True  # add the within-cell spread of the field to sigma_z (see module doc)
    subcell_values: Literal["cell", "interp"] = "cell"  # 'cell' = eq. 20 (paper); 'interp' = bilinear at sub-cell centres
    prior_sigma_m: float | None = None  # ours: Gaussian prior on the first state around the INS position (None = uniform, paper)
    max_pairs_per_block: int = 4_000_000  # memory bound of one transition block (states_prev x states_next)

    def __post_init__(self):
        if self.n < 1 or self.n % 2 == 0:
            raise ValueError("n must be a positive odd integer")
        if self.o < 1:
            raise ValueError("o must be >= 1")
        if not 0.0 <= self.alpha <= 1.0:
            raise ValueError("alpha must lie in [0, 1]")
        if self.T < 2:
            raise ValueError("T must be >= 2")
        if self.sigma_z_mgal <= 0 or self.sigma_v_mps < 0:
            raise ValueError("sigma_z must be > 0 and sigma_v >= 0")
        if self.search not in ("viterbi", "paper"):
            raise ValueError(f"unknown search {self.search!r}")

    @property
    def name(self) -> str:
        if self.o > 1:
            base = "RVBMP-2" if self.subcell_values == "cell" else "RVBMP-2i"
            return base + ("+prior" if self.prior_sigma_m else "")
        return "VBMP" if self.alpha == 0 else "RVBMP"


class CellMap:
    """The map as cells of a regular NE lattice (cell centres at north0 + i*cell_m, east0 + j*cell_m).

    g_m(c) (the paper's look-up function) is the value at the cell centre; cell values come from bilinear
    interpolation of the source grid at the centres, so cell_m may be the native spacing or a resampling.
    """

    def __init__(self, lmap: LocalGravityMap, cell_m: float, region_ne_m: tuple[float, float, float, float] | None = None):
        if not cell_m > 0:
            raise ValueError("cell_m must be > 0")
        n0, n1, e0, e1 = region_ne_m if region_ne_m is not None else lmap.bounds_ne()
        g, self.north_m, self.east_m = lmap.regular_ne(cell_m, (n0, n1), (e0, e1))
        self.g_mgal = g  # (rows=north, cols=east), NaN off-map/masked
        self.cell_m = float(cell_m)
        self.lmap = lmap
        self._init_spread()

    def _init_spread(self) -> None:
        """RMS difference between the field anywhere in a cell and the cell-centre value: |grad g| cell / sqrt(12)."""
        g = self.g_mgal
        if min(g.shape) >= 2:
            gn, ge = np.gradient(g, self.cell_m)
            self.spread_mgal = np.hypot(gn, ge) * self.cell_m / np.sqrt(12.0)
        else:
            self.spread_mgal = np.zeros_like(g)

    @classmethod
    def from_array(cls, g_mgal: np.ndarray, cell_m: float, north0_m: float = 0.0, east0_m: float = 0.0) -> "CellMap":
        self = cls.__new__(cls)
        self.g_mgal = np.asarray(g_mgal, float)
        self.cell_m = float(cell_m)
        self.north_m = north0_m + cell_m * np.arange(self.g_mgal.shape[0])
        self.east_m = east0_m + cell_m * np.arange(self.g_mgal.shape[1])
        self.lmap = None
        self._init_spread()
        return self

    def cell_of(self, ne_m: np.ndarray) -> np.ndarray:
        """(..., 2) integer (row, col) of the cell containing each point (eq. 3: nearest cell centre)."""
        ne = np.asarray(ne_m, float)
        r = np.rint((ne[..., 0] - self.north_m[0]) / self.cell_m).astype(np.intp)
        c = np.rint((ne[..., 1] - self.east_m[0]) / self.cell_m).astype(np.intp)
        return np.stack([r, c], axis=-1)

    def value(self, rc: np.ndarray, of: str = "g") -> np.ndarray:
        arr = self.g_mgal if of == "g" else self.spread_mgal
        rc = np.asarray(rc, np.intp)
        r, c = rc[..., 0], rc[..., 1]
        ok = (r >= 0) & (r < arr.shape[0]) & (c >= 0) & (c < arr.shape[1])
        out = np.full(r.shape, np.nan)
        out[ok] = arr[r[ok], c[ok]]
        return out

    def centre(self, rc: np.ndarray) -> np.ndarray:
        rc = np.asarray(rc, float)
        return np.stack([self.north_m[0] + rc[..., 0] * self.cell_m, self.east_m[0] + rc[..., 1] * self.cell_m], axis=-1)


@dataclass
class _Layer:
    pos: np.ndarray  # (K, 2) state positions (sub-cell centres), NE metres
    logpz: np.ndarray  # (K,)
    ins_d2: np.ndarray  # (K,) squared distance to the INS position (tie-break)
    ij: np.ndarray | None = None  # (K, 2) indices on the global sub-cell lattice (spacing cell_m / o)


def build_layers(cmap: CellMap, window: MatchWindow, cfg: ViterbiConfig) -> list[_Layer]:
    """Grids B_t (eqs. 3-4), sub-cells (eqs. 20-21) and the pruned sets A_t (eq. 25)."""
    h = cfg.n // 2
    m = np.arange(-h, h + 1)
    d_r, d_c = np.meshgrid(m, m, indexing="ij")
    grid_off = np.column_stack([d_r.ravel(), d_c.ravel()])  # (n^2, 2)
    o = cfg.o
    sub = (np.arange(o) - (o - 1) / 2.0) / o * cmap.cell_m  # sub-cell centre offsets
    s_n, s_e = np.meshgrid(sub, sub, indexing="ij")
    sub_off = np.column_stack([s_n.ravel(), s_e.ravel()])  # (o^2, 2)
    l_n, l_e = np.meshgrid(np.arange(o), np.arange(o), indexing="ij")
    sub_ij = np.column_stack([l_n.ravel(), l_e.ravel()])
    log_alpha = np.log(cfg.alpha) if cfg.alpha > 0 else -np.inf
    centres = cmap.cell_of(window.ins_ne_m)  # (T, 2)
    layers = []
    for t in range(len(window)):
        rc = centres[t] + grid_off
        g = cmap.value(rc)
        ok = np.isfinite(g)
        if not ok.any():
            raise MatchFailure(f"no valid map cell around the INS position at sample {t}")
        sig = np.full(g.shape, cfg.sigma_z_mgal)
        if cfg.representation_error:
            sig = np.sqrt(sig**2 + np.nan_to_num(cmap.value(rc, "spread")) ** 2)
        lpz = -0.5 * ((window.gravity_mgal[t] - g) / sig) ** 2 - np.log(sig)
        keep = ok & (lpz - np.nanmax(np.where(ok, lpz, -np.inf)) >= log_alpha)  # eq. 25
        cpos = cmap.centre(rc[keep])  # (k, 2)
        pos = (cpos[:, None, :] + sub_off[None, :, :]).reshape(-1, 2)
        if cfg.subcell_values == "cell" or o == 1:
            lp = np.repeat(lpz[keep], o * o)  # eq. 21
        else:  # our variant: each sub-cell reads the map (bilinear between cell centres) at its own centre
            gs = bilinear(cmap.east_m, cmap.north_m, cmap.g_mgal, pos[:, 1], pos[:, 0])
            sg = np.full(gs.shape, cfg.sigma_z_mgal)
            if cfg.representation_error:
                sg = np.sqrt(sg**2 + (np.repeat(np.nan_to_num(cmap.value(rc[keep], "spread")), o * o) / o) ** 2)
            lp = np.where(np.isfinite(gs), -0.5 * ((window.gravity_mgal[t] - gs) / sg) ** 2 - np.log(sg), -1e12)
        d2 = ((pos - window.ins_ne_m[t]) ** 2).sum(axis=1)
        ij = (rc[keep][:, None, :] * o + sub_ij[None, :, :]).reshape(-1, 2)
        if t == 0 and cfg.prior_sigma_m:
            lp = lp - 0.5 * d2 / cfg.prior_sigma_m**2
        layers.append(_Layer(pos, lp, d2, ij))
    return layers


def _step_sigma_m(cfg: ViterbiConfig, dt_s: float, spacing_m: float) -> float:
    return float(np.sqrt((cfg.sigma_v_mps * dt_s) ** 2 + 2.0 * spacing_m**2 / 12.0))


def _transition(prev: _Layer, nxt: _Layer, disp_ne_m: np.ndarray, sigma_m: float) -> np.ndarray:
    """log p_v for every (prev state, next state) pair: (K_prev, K_next)."""
    dn = nxt.pos[None, :, 0] - prev.pos[:, None, 0] - disp_ne_m[0]
    de = nxt.pos[None, :, 1] - prev.pos[:, None, 1] - disp_ne_m[1]
    return -0.5 * (dn * dn + de * de) / sigma_m**2


def _blocks(k_prev: int, k_next: int, max_pairs: int):
    step = max(1, max_pairs // max(k_next, 1))
    for a in range(0, k_prev, step):
        yield a, min(k_prev, a + step)


def viterbi_path(layers: list[_Layer], disp_ne_m: np.ndarray, sigmas_m: np.ndarray,
                 max_pairs: int = 4_000_000) -> tuple[np.ndarray, float, np.ndarray]:
    """Exact MAP path (max-product) over the layers. Returns (state index per t, log score, final deltas)."""
    delta = layers[0].logpz.copy()
    tie = layers[0].ins_d2.copy()
    back = []
    for t in range(1, len(layers)):
        prev, nxt = layers[t - 1], layers[t]
        best = np.full(nxt.pos.shape[0], -np.inf)
        arg = np.zeros(nxt.pos.shape[0], np.intp)
        best_tie = np.full(nxt.pos.shape[0], np.inf)
        for a, b in _blocks(prev.pos.shape[0], nxt.pos.shape[0], max_pairs):
            sc = delta[a:b, None] + _transition(_Sub(prev, a, b), nxt, disp_ne_m[t - 1], sigmas_m[t - 1])
            j = np.argmax(sc, axis=0)
            v = sc[j, np.arange(sc.shape[1])]
            tj = tie[a:b][j]
            better = (v > best + 1e-12) | ((np.abs(v - best) <= 1e-12) & (tj < best_tie))
            best = np.where(better, v, best)
            arg = np.where(better, a + j, arg)
            best_tie = np.where(better, tj, best_tie)
        delta = best + nxt.logpz
        tie = best_tie + nxt.ins_d2
        back.append(arg)
    end = _argmax_tie(delta, tie)
    path = [end]
    for arg in reversed(back):
        path.append(int(arg[path[-1]]))
    return np.asarray(path[::-1], np.intp), float(delta[end]), delta


def viterbi_lattice(layers: list[_Layer], disp_ne_m: np.ndarray, sigmas_m: np.ndarray,
                    spacing_m: float) -> tuple[np.ndarray, float, np.ndarray]:
    """Exact MAP path as `viterbi_path`, using the separability of the Gaussian p_v on the sub-cell lattice.

    max_p [delta(p) - |q - p - D|^2 / 2s^2] = max_pn [-(qn - pn - Dn)^2 / 2s^2 + max_pe [delta(pn, pe) - (qe - pe - De)^2 / 2s^2]]
    so each step is two 1-D max-plus products over the bounding boxes of the states (a generalised distance
    transform) instead of one product over all state pairs. Ties are not broken by INS distance here.
    """
    d = spacing_m
    delta = layers[0].logpz.copy()
    backs = []
    for t in range(1, len(layers)):
        prev, nxt = layers[t - 1], layers[t]
        a = 0.5 / sigmas_m[t - 1] ** 2
        p0 = prev.ij.min(axis=0)
        p_shape = prev.ij.max(axis=0) - p0 + 1
        F = np.full(p_shape, -np.inf)
        F[prev.ij[:, 0] - p0[0], prev.ij[:, 1] - p0[1]] = delta
        q0 = nxt.ij.min(axis=0)
        q_shape = nxt.ij.max(axis=0) - q0 + 1
        pe = p0[1] + np.arange(p_shape[1])
        qe = q0[1] + np.arange(q_shape[1])
        ce = -a * ((qe[:, None] - pe[None, :]) * d - disp_ne_m[t - 1, 1]) ** 2  # (Qe, Pe)
        s1 = F[:, None, :] + ce[None, :, :]  # (Pn, Qe, Pe)
        arg1 = np.argmax(s1, axis=2)  # (Pn, Qe)
        G = np.take_along_axis(s1, arg1[:, :, None], axis=2)[:, :, 0]
        pn = p0[0] + np.arange(p_shape[0])
        qn = q0[0] + np.arange(q_shape[0])
        cn = -a * ((qn[:, None] - pn[None, :]) * d - disp_ne_m[t - 1, 0]) ** 2  # (Qn, Pn)
        s2 = G.T[:, None, :] + cn[None, :, :]  # (Qe, Qn, Pn)
        arg2 = np.argmax(s2, axis=2)  # (Qe, Qn)
        H = np.take_along_axis(s2, arg2[:, :, None], axis=2)[:, :, 0]  # (Qe, Qn)
        qi = nxt.ij - q0
        best_pn = arg2[qi[:, 1], qi[:, 0]]
        best_pe = arg1[best_pn, qi[:, 1]]
        # map (pn, pe) box indices back to state indices of prev
        lut = np.full(p_shape, -1, np.intp)
        lut[prev.ij[:, 0] - p0[0], prev.ij[:, 1] - p0[1]] = np.arange(prev.ij.shape[0])
        backs.append(lut[best_pn, best_pe])
        delta = H[qi[:, 1], qi[:, 0]] + nxt.logpz
    end = int(np.argmax(delta))
    path = [end]
    for b in reversed(backs):
        path.append(int(b[path[-1]]))
    return np.asarray(path[::-1], np.intp), float(delta[end]), delta


class _Sub:
    """Rows a:b of a layer (for blocked transitions)."""

    def __init__(self, layer: _Layer, a: int, b: int):
        self.pos = layer.pos[a:b]


def _argmax_tie(score: np.ndarray, tie: np.ndarray) -> int:
    m = np.max(score)
    cand = np.flatnonzero(score >= m - 1e-12)
    return int(cand[np.argmin(tie[cand])])


def greedy_paths(layers: list[_Layer], disp_ne_m: np.ndarray, sigmas_m: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Eqs. 13-19 (22-24, 26-28 with sub-cells and pruning): a greedy forward path from every start state,
    then the start with the largest product (eq. 18). Returns (path, log score, final scores per start)."""
    k1 = layers[0].pos.shape[0]
    cur = np.arange(k1)
    score = layers[0].logpz.copy()
    tie = layers[0].ins_d2.copy()
    paths = [cur]
    for t in range(1, len(layers)):
        prev, nxt = layers[t - 1], layers[t]
        sub = _Layer(prev.pos[cur], prev.logpz[cur], prev.ins_d2[cur])
        step = _transition(sub, nxt, disp_ne_m[t - 1], sigmas_m[t - 1]) + nxt.logpz[None, :]  # (k1, K_t), eq. 10
        j = np.argmax(step, axis=1)  # eq. 17
        score = score + step[np.arange(k1), j]
        tie = tie + nxt.ins_d2[j]
        cur = j
        paths.append(cur)
    best = _argmax_tie(score, tie)  # eq. 18
    return np.asarray([p[best] for p in paths], np.intp), float(score[best]), score


class ViterbiMatcher(Matcher):
    """RVBMP / RVBMP-2 behind the common matcher interface.

    A window of T samples (oldest first) gives the cell-centre path over the segment (track_ne_m) and its end
    point (position_ne_m). sigma_m is the spread of the end state over all surviving paths, weighted by their
    posterior (exp of the final Viterbi scores), floored at the sub-cell quantisation.
    """

    supports_prior = True

    def __init__(self, lmap: LocalGravityMap | None, cfg: ViterbiConfig | None = None, cell_m: float | None = None,
                 cell_map: CellMap | None = None, region_ne_m=None):
        self.cfg = cfg or ViterbiConfig()
        self.name = self.cfg.name
        if cell_map is None:
            if lmap is None:
                raise ValueError("need a LocalGravityMap or a CellMap")
            if cell_m is None:
                cell_m = float(np.mean(lmap.cell_size_m()))
            cell_map = CellMap(lmap, cell_m, region_ne_m)
        self.cells = cell_map
        self.cell_m = float(cell_map.cell_m)
        self.sigma_z_mgal = float(self.cfg.sigma_z_mgal)
        super().__init__(lmap if lmap is not None else cell_map, min_len=self.cfg.T, window_len=self.cfg.T,
                         fix_every=self.cfg.T, speed_constraint=None)

    def _config(self, prior_sigma_m: float | None) -> ViterbiConfig:
        """The configuration of one match: the caller's prior on the first state, if it gives one (else the
        configured one)."""
        return self.cfg if prior_sigma_m is None else replace(self.cfg, prior_sigma_m=float(prior_sigma_m))

    def method_name(self, prior_sigma_m: float | None = None) -> str:
        return self._config(prior_sigma_m).name

    def _match(self, window: MatchWindow, prior_sigma_m: float | None = None) -> MatchResult:
        cfg = self._config(prior_sigma_m)
        layers = build_layers(self.cells, window, cfg)
        dt = np.diff(window.t_s)
        disp = window.ins_vel_ne_mps[:-1] * dt[:, None]  # v_{t-1} dt (eq. 9)
        spacing = self.cells.cell_m / cfg.o
        sig = np.array([_step_sigma_m(cfg, d, spacing) for d in dt])
        if cfg.search == "viterbi":
            idx, logp, final = viterbi_lattice(layers, disp, sig, spacing)
            end_pos = layers[-1].pos
        else:
            idx, logp, final = greedy_paths(layers, disp, sig)
            end_pos = None
        track = np.array([layers[t].pos[i] for t, i in enumerate(idx)])
        w = np.exp(final - final.max())
        w /= w.sum()
        if end_pos is None:  # greedy: final scores are per start path; use their end states
            end_pos = _greedy_end_positions(layers, disp, sig)
        mu = (w[:, None] * end_pos).sum(axis=0)
        spread = float(np.sqrt((w * ((end_pos - mu) ** 2).sum(axis=1)).sum() / 2.0))
        floor = spacing / np.sqrt(12.0)
        n_states = int(sum(layer.pos.shape[0] for layer in layers))
        return MatchResult(True, cfg.name, float(window.t_s[-1]), track[-1].copy(), sigma_m=max(spread, floor),
                           quality=-logp, track_ne_m=track, extra={"n_states": n_states, "log_posterior": logp})


def _greedy_end_positions(layers, disp, sig) -> np.ndarray:
    k1 = layers[0].pos.shape[0]
    cur = np.arange(k1)
    for t in range(1, len(layers)):
        prev, nxt = layers[t - 1], layers[t]
        sub = _Layer(prev.pos[cur], prev.logpz[cur], prev.ins_d2[cur])
        cur = np.argmax(_transition(sub, nxt, disp[t - 1], sig[t - 1]) + nxt.logpz[None, :], axis=1)
    return layers[-1].pos[cur]


def brute_force_path(layers: list[_Layer], disp_ne_m: np.ndarray, sigmas_m: np.ndarray) -> tuple[np.ndarray, float]:
    """Exhaustive enumeration of eq. 6 (for tests on tiny grids only)."""
    import itertools

    best, best_p = -np.inf, None
    for combo in itertools.product(*[range(layer.pos.shape[0]) for layer in layers]):
        s = layers[0].logpz[combo[0]]
        for t in range(1, len(layers)):
            a, b = layers[t - 1].pos[combo[t - 1]], layers[t].pos[combo[t]]
            d = b - a - disp_ne_m[t - 1]
            s += -0.5 * float(d @ d) / sigmas_m[t - 1] ** 2 + layers[t].logpz[combo[t]]
        if s > best:
            best, best_p = s, combo
    return np.asarray(best_p, np.intp), float(best)
