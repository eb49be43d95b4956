"""Gap-filling baselines the KNN + INS + Kalman navigator is measured against.

* **hold last fix**: GNSS without a predictor; the position stays at the last real fix.
* **constant velocity**: the last fix extrapolated with the receiver's velocity at that fix (finite
  difference of the last two fixes when the receiver gives none).
* **INS alone**: the strapdown INS coasting from the filter's state at the start of the gap with no aiding
  at all: run :class:`companion.nav.navigator.Navigator` with ``fuse_predictor=False`` on the
  events from :func:`withhold_aiding` (GNSS *and* attitude removed inside the gaps).
* **KNN alone**: the predictor's points (:class:`companion.nav.outputs.PredictorPoint`), see
  :func:`series_at` to sample them at truth times.

Pure functions on arrays and event lists.
"""

from __future__ import annotations

import numpy as np

from companion.events import Attitude, Event, GnssFix

#: the baselines a full filter is compared with (replay.gap_filling's method keys)
BASELINES = ("hold", "cv", "knn", "ins_alone")


def _last_index(fix_t_s: np.ndarray, query_t_s: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(fix_t_s, query_t_s, side="right") - 1
    if np.any(idx < 0):
        raise ValueError("a query time precedes the first available fix")
    return idx


def hold_last_fix(fix_t_s, fix_ned_m, query_t_s) -> np.ndarray:
    """Position of the last available fix at or before each query time; shape (n, 3)."""
    fix_t_s = np.asarray(fix_t_s, dtype=float)
    return np.asarray(fix_ned_m, dtype=float)[_last_index(fix_t_s, np.asarray(query_t_s, dtype=float))]


def constant_velocity(fix_t_s, fix_ned_m, fix_vel_ned_mps, query_t_s) -> np.ndarray:
    """Last fix + velocity * elapsed time. NaN rows of ``fix_vel_ned_mps`` use the last two fixes instead."""
    t = np.asarray(fix_t_s, dtype=float)
    p = np.asarray(fix_ned_m, dtype=float)
    q = np.asarray(query_t_s, dtype=float)
    i = _last_index(t, q)
    v = np.array(fix_vel_ned_mps, dtype=float) if fix_vel_ned_mps is not None else np.full(p.shape, np.nan)
    fd = np.zeros_like(p)
    fd[1:] = (p[1:] - p[:-1]) / np.maximum(np.diff(t), 1e-3)[:, None]
    v = np.where(np.isfinite(v), v, fd)
    return p[i] + v[i] * (q - t[i])[:, None]


def series_at(t_s, values, query_t_s) -> np.ndarray:
    """Linear interpolation of an output series (n, m) at query times (values outside -> nearest end)."""
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(values, dtype=float)
    q = np.asarray(query_t_s, dtype=float)
    return np.stack([np.interp(q, t, v[:, j]) for j in range(v.shape[1])], axis=1)


def withhold_gnss(events: list[Event], windows: list[tuple[float, float]]) -> list[Event]:
    """Drop GNSS fixes with time in any [start, end) window (an injected blockage)."""
    return [e for e in events if not (isinstance(e, GnssFix) and _inside(e.t_s, windows))]


def withhold_aiding(events: list[Event], windows: list[tuple[float, float]]) -> list[Event]:
    """Drop GNSS fixes and attitude inside the windows: what the INS-alone baseline may see."""
    return [e for e in events if not (isinstance(e, (GnssFix, Attitude)) and _inside(e.t_s, windows))]


def _inside(t: float, windows: list[tuple[float, float]]) -> bool:
    for a, b in windows:
        if a <= t < b:
            return True
    return False
