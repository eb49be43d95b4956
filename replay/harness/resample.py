"""How far a benchmark figure rests on single blockages: leave one window out, and a bootstrap over windows.

A blockage benchmark pools the errors of a handful of windows (two or three per log at 4 and 8 s on the shared
logs). Its figure -- an RMSE, or the ratio of the full filter's RMSE to the best baseline's -- is then a statistic of
those few windows. :func:`spread` recomputes it with each window left out in turn (the range says whether one window
decides it) and on ``n_boot`` resamples of the windows drawn with replacement (percentile interval; with n windows
there are only C(2n - 1, n) distinct resamples, 10 for three, so the interval is coarse, but it is what the data
support). Windows, not points, are resampled: the points of one window share its trajectory and are not
independent. Pure: the caller passes a seeded ``numpy.random.Generator``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from replay.harness.baselines import BASELINES


Window = dict[str, np.ndarray]  # method -> errors (n, 3) NED at the truth fixes of one window


def h_rmse(windows: Sequence[Window], method: str) -> float:
    """Horizontal RMSE of one method over the points of these windows (pooled by point, as the benchmark's tables)."""
    e = np.concatenate([w[method] for w in windows])
    return float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))


def best_baseline(windows: Sequence[Window], baselines: Sequence[str] = BASELINES) -> tuple[str, float]:
    """The baseline with the lowest H RMSE on these windows, and that RMSE."""
    present = [m for m in baselines if m in windows[0]]
    if not present:
        raise ValueError("no baseline in the windows")
    return min(((m, h_rmse(windows, m)) for m in present), key=lambda mr: mr[1])


def ratio_to_best(windows: Sequence[Window], full: str = "knn_ins_kf", baselines: Sequence[str] = BASELINES) -> float:
    """The full filter's H RMSE over the best baseline's on the same windows (the best chosen on these windows)."""
    return h_rmse(windows, full) / best_baseline(windows, baselines)[1]


@dataclass(frozen=True)
class Spread:
    value: float  # the statistic on all windows
    loo_min: float  # ... with one window left out, the smallest and largest (nan with one window)
    loo_max: float
    lo: float  # percentile interval of the bootstrap over windows
    hi: float
    samples: np.ndarray  # the bootstrap values

    def share_at_most(self, x: float) -> float:
        """Share of the bootstrap resamples whose statistic is <= x."""
        return float(np.mean(self.samples <= x))


def spread(windows: Sequence[Window], stat: Callable[[Sequence[Window]], float], rng: np.random.Generator,
           n_boot: int = 2000, level: float = 0.9) -> Spread:
    """``stat`` on the windows, on each leave-one-out subset, and on ``n_boot`` resamples with replacement."""
    n = len(windows)
    if n == 0:
        raise ValueError("spread of no windows")
    if n_boot < 1 or not 0 < level < 1:
        raise ValueError("n_boot must be >= 1 and level in (0, 1)")
    value = stat(windows)
    loo = [stat([w for j, w in enumerate(windows) if j != i]) for i in range(n)] if n > 1 else [float("nan")]
    idx = rng.integers(0, n, size=(n_boot, n))
    samples = np.array([stat([windows[i] for i in row]) for row in idx])
    a = (1 - level) / 2
    lo, hi = np.quantile(samples, [a, 1 - a])
    return Spread(value, min(loo), max(loo), float(lo), float(hi), samples)
