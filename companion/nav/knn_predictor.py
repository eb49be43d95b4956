"""KNN GNSS predictor (Aziez et al. 2021, Electronics 10:1513, section 2.1).

What the paper specifies, and this module follows:

* Every new point is 0.1 s after the previous one and is predicted from the **four preceding points**,
  measured or already predicted (e.g. t = 5.7, 5.8, 5.9, 6.0 s give t = 6.1 s). The recursion continues
  through a GNSS blockage for as long as points are asked for.
* Neighbours are found by the Euclidean distance over the X, Y and Z sequences of those points (eq. 1).
* The prediction is the weighted mean of the neighbours' continuations, ``y = sum_j w_j y_j`` (eq. 3),
  with ``w_j = j / n`` (eq. 4). Equation (2), the plain mean, is available as ``weights="uniform"``.

Where the paper is vague, the choices (all in :class:`KnnConfig`):

* **Frame of X/Y/Z**: local NED metres (the caller converts geodetic fixes with
  :class:`companion.nav.frame.LocalFrame`); Z is down.
* **Training database**: built online from this flight's own real GNSS fixes (never predictions), interpolated onto
  a 0.1 s grid (cubic Hermite with the receiver's NED velocity, so a turn's 1 Hz history follows the arc rather than
  its chords; else linear). Each run of ``window + 1`` grid points of one contiguous segment (no gap over
  ``max_gap_s``) is one entry: key, then continuation. A ring buffer of ``max_entries`` (bounded memory) indexed
  by a cKDTree rebuilt every ``rebuild_every`` entries, newer entries searched by brute force (an exact search).
* **Translation invariance** (``pattern="relative"``, the default): keys are the window's points minus its
  newest point and the continuation is the next displacement, so a manoeuvre learnt at one place predicts
  the same manoeuvre elsewhere. ``pattern="absolute"`` matches raw coordinates, as eq. (1) reads
  literally; it only finds neighbours where the vehicle has already been.
* **Weights** (eq. 4): ``w_j = j / n`` with the k neighbours ranked by **time** (j = 1 oldest, j = k most
  recent, the paper's "correlation between times") and ``n = k(k+1)/2`` so that the weights sum to one (the
  paper's n is "the number of training data", which would not give a mean). ``weights="distance"`` ranks by
  distance instead (nearest gets k/n).
* **k** = 5 (the paper does not give it).
* **Cold start**: until the database has ``k`` entries the predictor extrapolates the window at
  constant velocity (``method="cv"``).
* **Uncertainty**: 1-sigma grows with the age tau since the last real fix:
  ``sigma^2 = sigma_fix^2 + (sigma_vel * tau)^2 + (0.5 * sigma_acc * tau^2)^2 + spread``, ``spread`` the square of
  the neighbours' weighted continuation spreads summed along the recursion (a wrong step repeats, so it adds
  linearly): noisy fixes make it dominate and tell the filter to distrust the predictor.

Pure: no I/O, no clocks. Positions in, positions out.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class KnnConfig:
    """Predictor settings; see the module docstring for why each default was chosen."""

    k: int = 5
    window: int = 4  # paper: four preceding points
    step_s: float = 0.1  # paper: 10 Hz output
    pattern: str = "relative"  # "relative" | "absolute"
    weights: str = "temporal"  # "temporal" | "distance" (eq. 4 rankings) | "uniform" (eq. 2)
    max_entries: int = 6000  # ring buffer: 10 min of 0.1 s steps
    rebuild_every: int = 100  # new entries between k-d tree rebuilds
    max_gap_s: float = 2.5  # fixes further apart than this start a new database segment
    max_horizon_s: float = 60.0  # no predictions further than this after the last real fix
    history_fixes: int = 64  # real fixes kept for building the query window
    sigma_fix_h_m: float = 1.0  # used when a fix carries no accuracy
    sigma_fix_v_m: float = 1.5
    sigma_vel_h_mps: float = 0.3
    sigma_vel_v_mps: float = 0.2
    sigma_acc_h_mps2: float = 1.0
    sigma_acc_v_mps2: float = 0.4

    def __post_init__(self) -> None:
        if self.k < 1 or self.window < 2:
            raise ValueError("k must be >= 1 and window >= 2")
        if self.step_s <= 0:
            raise ValueError("step_s must be positive")
        if self.pattern not in ("relative", "absolute"):
            raise ValueError(f"pattern must be 'relative' or 'absolute', not {self.pattern!r}")
        if self.weights not in ("temporal", "distance", "uniform"):
            raise ValueError(f"weights must be 'temporal', 'distance' or 'uniform', not {self.weights!r}")
        if self.max_entries < self.k:
            raise ValueError("max_entries must be >= k")


@dataclass(frozen=True, slots=True)
class Prediction:
    t_s: float
    ned_m: tuple[float, float, float]
    sigma_h_m: float
    sigma_v_m: float
    age_s: float
    method: str


@functools.lru_cache(maxsize=16)
def eq4_weights(k: int) -> np.ndarray:
    """Eq. (4): w_j = j / n for j = 1..k, with n = k(k+1)/2 so that the weights sum to one (read-only: cached)."""
    j = np.arange(1, k + 1, dtype=float)
    w = j / j.sum()
    w.flags.writeable = False
    return w


def _interp_pair(a, b, t: float) -> np.ndarray:
    """Position at t between fixes a and b (t, p, v|None): cubic Hermite with velocities, else linear."""
    ta, pa, va = a
    tb, pb, vb = b
    h = tb - ta
    s = (t - ta) / h
    if va is None or vb is None or not 0.0 <= s <= 1.0:
        return pa + s * (pb - pa)
    s2, s3 = s * s, s * s * s
    return (2 * s3 - 3 * s2 + 1) * pa + (s3 - 2 * s2 + s) * h * va + (-2 * s3 + 3 * s2) * pb + (s3 - s2) * h * vb


class KnnPredictor:
    """Online KNN predictor: feed real fixes with :meth:`add_fix`, ask for points with :meth:`predict`."""

    def __init__(self, config: KnnConfig | None = None) -> None:
        self.config = config or KnnConfig()
        c = self.config
        self._key_dim = 3 * (c.window - 1) if c.pattern == "relative" else 3 * c.window
        self._keys = np.zeros((c.max_entries, self._key_dim))
        self._conts = np.zeros((c.max_entries, 3))
        self._entry_t = np.zeros(c.max_entries)
        self._n_added = 0  # total entries ever added (ring position = n_added % max_entries)
        self._tree = None  # scipy.spatial.cKDTree, imported at the first build (1 s of the live start-up)
        self._tree_n_added = 0  # n_added when the tree was built
        self._tree_rows: np.ndarray | None = None  # ring rows the tree indexes
        self._fixes: deque[tuple[float, np.ndarray, np.ndarray | None]] = deque(maxlen=c.history_fixes)
        self._seg: deque[np.ndarray] = deque(maxlen=c.window + 1)  # newest grid points of the segment
        self._seg_last_idx: int | None = None  # grid index of the newest segment point
        # recursion state
        self._anchor_t: float | None = None
        self._anchor_sigma = (c.sigma_fix_h_m, c.sigma_fix_v_m)
        self._steps: list[np.ndarray] = []  # points at anchor + i*step, i = 0.. (i=0 is the fix)
        self._window_pts: deque[np.ndarray] = deque(maxlen=c.window)
        self._spread = [0.0]  # summed neighbour std (m, horizontal) up to each step
        self._methods: list[str] = ["fix"]

    # ------------------------------------------------------------------ database
    @property
    def n_entries(self) -> int:
        return min(self._n_added, self.config.max_entries)

    @property
    def last_fix_t_s(self) -> float | None:
        return self._anchor_t

    def _add_entry(self, pts: list[np.ndarray], t_s: float) -> None:
        c = self.config
        win = np.array(pts[: c.window])
        nxt = pts[c.window]
        row = self._n_added % c.max_entries
        if c.pattern == "relative":
            self._keys[row] = (win[:-1] - win[-1]).ravel()
            self._conts[row] = nxt - win[-1]
        else:
            self._keys[row] = win.ravel()
            self._conts[row] = nxt
        self._entry_t[row] = t_s
        self._n_added += 1

    def _maybe_rebuild(self) -> None:
        c = self.config
        if self._n_added - self._tree_n_added >= c.rebuild_every or (
            self._tree is None and self._n_added >= c.k
        ):
            n = self.n_entries
            self._tree_rows = np.arange(n)
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self._keys[:n].copy())
            self._tree_n_added = self._n_added

    def _fresh(self, rows: np.ndarray, overwritten: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(rows, mask of those not overwritten since the tree was built; None: all)."""
        if not overwritten:
            return rows, None
        c = self.config
        return rows, (rows - self._tree_n_added % c.max_entries) % c.max_entries >= overwritten

    def _query(self, key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact k nearest entries (ring rows, distances) by eq. (1): tree part plus brute-force tail."""
        c = self.config
        k = min(c.k, self.n_entries)
        rows_list, d_list = [], []
        valid_tree_rows = None
        if self._tree is not None:
            # rows overwritten since the build are stale in the tree; they are re-searched in the tail
            overwritten = self._n_added - self._tree_n_added
            kk = min(k + overwritten, len(self._tree_rows))
            d = None
            if kk > k + 1:  # a narrow query first; it decides when k fresh rows lie strictly inside its radius
                d, i = self._tree.query(key, k=k + 1)
                rows, fresh = self._fresh(self._tree_rows[i], overwritten)
                inside = fresh & (d < d[-1])
                if np.count_nonzero(inside) >= k:  # the wide query's k nearest fresh rows are exactly these
                    rows, d = rows[inside], d[inside]
                else:
                    d = None
            if d is None:
                d, i = self._tree.query(key, k=kk)
                d, i = np.atleast_1d(d), np.atleast_1d(i)
                rows, fresh = self._fresh(self._tree_rows[i], overwritten)
                if fresh is not None:
                    rows, d = rows[fresh], d[fresh]
            rows_list.append(rows)
            d_list.append(d)
            valid_tree_rows = True
        tail_from = self._tree_n_added if valid_tree_rows else max(0, self._n_added - c.max_entries)
        if self._n_added > tail_from:
            tail = np.arange(tail_from, self._n_added) % c.max_entries
            dt = np.sqrt(((self._keys[tail] - key) ** 2).sum(axis=1))
            rows_list.append(tail)
            d_list.append(dt)
        rows = np.concatenate(rows_list)
        d = np.concatenate(d_list)
        order = np.lexsort((rows, d))[:k]  # ties broken by row for determinism
        return rows[order], d[order]

    # ------------------------------------------------------------------ input
    def add_fix(
        self,
        t_s: float,
        ned_m,
        sigma_h_m: float | None = None,
        sigma_v_m: float | None = None,
        vel_ned_mps=None,
    ) -> None:
        """Add a real GNSS fix (local NED metres, optional NED velocity). Older-than-last fixes are ignored."""
        c = self.config
        p = np.asarray(ned_m, dtype=float).reshape(3)
        if not np.all(np.isfinite(p)):
            raise ValueError("fix position must be finite")
        v = None
        if vel_ned_mps is not None:
            v = np.asarray(vel_ned_mps, dtype=float).reshape(3)
            if not np.all(np.isfinite(v)):
                v = None
        if self._fixes and t_s <= self._fixes[-1][0]:
            return
        if self._fixes and t_s - self._fixes[-1][0] > c.max_gap_s:
            self._seg.clear()
            self._seg_last_idx = None
            self._fixes.clear()
        prev = self._fixes[-1] if self._fixes else None
        self._fixes.append((t_s, p, v))
        # extend the 0.1 s grid of this segment and learn new entries
        idx_hi = math.floor(t_s / c.step_s + 1e-9)
        if prev is None:
            if abs(idx_hi * c.step_s - t_s) < 1e-9:
                self._push_grid(idx_hi, p)
        else:
            idx_lo = math.floor(prev[0] / c.step_s + 1e-9) + 1
            for g in range(idx_lo, idx_hi + 1):
                self._push_grid(g, _interp_pair(prev, self._fixes[-1], g * c.step_s))
        self._maybe_rebuild()
        # restart the recursion at this fix (paper: e.g. 5.7..6.0 s predict 6.1 s)
        self._anchor_t = t_s
        self._anchor_sigma = (
            sigma_h_m if sigma_h_m is not None and sigma_h_m > 0 else c.sigma_fix_h_m,
            sigma_v_m if sigma_v_m is not None and sigma_v_m > 0 else c.sigma_fix_v_m,
        )
        self._window_pts.clear()
        for j in range(c.window - 1, -1, -1):
            self._window_pts.append(self._interp_fixes(t_s - j * c.step_s))
        self._steps = [p]
        self._spread = [0.0]
        self._methods = ["fix"]

    def _push_grid(self, g: int, p: np.ndarray) -> None:
        if self._seg_last_idx is not None and g != self._seg_last_idx + 1:
            self._seg.clear()
        self._seg.append(p)
        self._seg_last_idx = g
        if len(self._seg) == self.config.window + 1:
            self._add_entry(list(self._seg), g * self.config.step_s)

    def _interp_fixes(self, t: float) -> np.ndarray:
        f = self._fixes
        if len(f) == 1:
            p, v = f[0][1], f[0][2]
            return p + (t - f[0][0]) * v if v is not None else p.copy()
        if t <= f[0][0]:  # before the first fix of the segment: extrapolate its first interval
            return _interp_pair(f[0], f[1], t)
        for i in range(len(f) - 1, 0, -1):
            if f[i - 1][0] <= t:
                return _interp_pair(f[i - 1], f[i], t)
        return f[0][1].copy()

    # ------------------------------------------------------------------ prediction
    def _step(self) -> None:
        """One recursion step: predict anchor + (len(steps)) * step from the last `window` points."""
        c = self.config
        win = np.array(self._window_pts)
        last = win[-1]
        if self.n_entries < c.k:
            nxt = last + (win[-1] - win[-2])
            var = 0.0
            method = "cv"
        else:
            key = (win[:-1] - last).ravel() if c.pattern == "relative" else win.ravel()
            rows, _d = self._query(key)
            conts = self._conts[rows]
            if c.weights == "uniform":
                w = np.full(len(rows), 1.0 / len(rows))  # eq. (2)
            else:
                w = eq4_weights(len(rows))  # eq. (4), rank 1..k
                if c.weights == "temporal":
                    order = np.argsort(self._entry_t[rows], kind="stable")  # oldest first -> weight 1/n
                else:
                    order = np.arange(len(rows))[::-1]  # farthest first -> nearest gets k/n
                conts = conts[order]
            y = w @ conts  # eq. (3)
            nxt = last + y if c.pattern == "relative" else y
            dev = conts - y
            var = float(w @ (dev[:, 0] ** 2 + dev[:, 1] ** 2))
            method = "knn"
        self._window_pts.append(nxt)
        self._steps.append(nxt)
        self._spread.append(self._spread[-1] + math.sqrt(var))
        self._methods.append(method)

    def _sigmas(self, age: float, spread: float) -> tuple[float, float]:
        c = self.config
        sh0, sv0 = self._anchor_sigma
        sh = math.sqrt(
            sh0**2 + (c.sigma_vel_h_mps * age) ** 2 + (0.5 * c.sigma_acc_h_mps2 * age**2) ** 2 + spread**2
        )
        sv = math.sqrt(sv0**2 + (c.sigma_vel_v_mps * age) ** 2 + (0.5 * c.sigma_acc_v_mps2 * age**2) ** 2)
        return sh, sv

    def predict(self, t_s: float) -> Prediction | None:
        """Predicted position at ``t_s`` (after the last real fix), or None if there is nothing to predict.

        Times on the recursion grid (last fix + i * step) return the recursion's point; other times are
        interpolated linearly between the two neighbouring steps.
        """
        c = self.config
        if self._anchor_t is None:
            return None
        age = t_s - self._anchor_t
        if age < 0 or age > c.max_horizon_s:
            return None
        x = age / c.step_s
        i_hi = math.ceil(x - 1e-9)
        while len(self._steps) <= i_hi:
            self._step()
        i_lo = max(0, math.floor(x + 1e-9))
        if i_lo >= i_hi:
            p = self._steps[i_hi]
            spread = self._spread[i_hi]
            method = self._methods[i_hi]
        else:
            a = x - i_lo
            p = (1 - a) * self._steps[i_lo] + a * self._steps[i_hi]
            spread = (1 - a) * self._spread[i_lo] + a * self._spread[i_hi]
            method = self._methods[i_hi]
        sh, sv = self._sigmas(age, spread)
        return Prediction(t_s, (float(p[0]), float(p[1]), float(p[2])), sh, sv, age, method)

    def predict_steps(self, n: int) -> list[Prediction]:
        """The next ``n`` recursion points after the last fix (paper: n = 9 between 1 Hz fixes)."""
        if self._anchor_t is None:
            return []
        return [self.predict(self._anchor_t + i * self.config.step_s) for i in range(1, n + 1)]  # type: ignore[misc]
