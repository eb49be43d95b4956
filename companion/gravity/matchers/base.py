"""One interface for every gravity matcher: batch (`match(window)`) and online (`feed(...)`).

All positions are metres (north, east) in the frame of a `LocalGravityMap`; gravity measurements are
Eotvos-corrected anomalies in mGal (see companion.gravity.eotvos).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from companion.gravity.maps import LocalGravityMap


@dataclass(frozen=True)
class MatchWindow:
    """A window of INS samples and gravity measurements, oldest first."""

    t_s: np.ndarray  # (n,)
    ins_ne_m: np.ndarray  # (n, 2) INS-indicated north, east
    ins_vel_ne_mps: np.ndarray  # (n, 2)
    gravity_mgal: np.ndarray  # (n,) measured anomaly, Eotvos-corrected

    @classmethod
    def of(cls, t_s, ins_ne_m, ins_vel_ne_mps, gravity_mgal) -> "MatchWindow":
        return cls(np.asarray(t_s, float).reshape(-1), np.asarray(ins_ne_m, float).reshape(-1, 2),
                   np.asarray(ins_vel_ne_mps, float).reshape(-1, 2), np.asarray(gravity_mgal, float).reshape(-1))

    def __len__(self) -> int:
        return int(self.t_s.size)

    def problem(self, min_len: int) -> str | None:
        """Reason the window cannot be matched, or None."""
        n = self.t_s.size
        if n == 0:
            return "empty window"
        if self.ins_ne_m.shape != (n, 2) or self.ins_vel_ne_mps.shape != (n, 2) or self.gravity_mgal.shape != (n,):
            return "window arrays have inconsistent shapes"
        if n < min_len:
            return f"window has {n} samples, need {min_len}"
        if not np.all(np.isfinite(self.gravity_mgal)):
            return f"{int((~np.isfinite(self.gravity_mgal)).sum())} non-finite gravity measurements"
        if not (np.all(np.isfinite(self.ins_ne_m)) and np.all(np.isfinite(self.ins_vel_ne_mps)) and np.all(np.isfinite(self.t_s))):
            return "non-finite INS samples or times"
        if np.any(np.diff(self.t_s) <= 0):
            return "times not strictly increasing"
        return None

    def tail(self, n: int) -> "MatchWindow":
        return MatchWindow(self.t_s[-n:], self.ins_ne_m[-n:], self.ins_vel_ne_mps[-n:], self.gravity_mgal[-n:])


@dataclass
class MatchResult:
    """Outcome of one match. position_ne_m is the estimate at the window's last sample."""

    ok: bool
    method: str
    t_s: float
    position_ne_m: np.ndarray  # (2,), NaN if not ok
    sigma_m: float = float("nan")  # 1-sigma horizontal uncertainty
    quality: float = float("nan")  # method score (distance / cost of the chosen solution, lower is better)
    track_ne_m: np.ndarray | None = None  # (n, 2) estimated positions of the window samples
    reason: str = ""
    compute_time_s: float = 0.0
    extra: dict = field(default_factory=dict)

    @classmethod
    def failed(cls, method: str, t_s: float, reason: str, compute_time_s: float = 0.0) -> "MatchResult":
        return cls(False, method, t_s, np.full(2, np.nan), reason=reason, compute_time_s=compute_time_s)


class MatchFailure(Exception):
    """Raised inside a matcher to produce a failed MatchResult with this reason."""


@dataclass(frozen=True)
class SpeedConstraint:
    """Continuous matching with the speed constraint, Gao et al. 2022 eqs. 12-13."""

    speed_accuracy_mps: float = 0.5  # delta_V in eq. 12
    weight_n: int | None = None  # N in eq. 13; None = window length

    def apply(self, prev_pos_ne_m, prev_ins_ne_m, dt_s, pos_ne_m, ins_ne_m, n_window) -> tuple[np.ndarray, bool]:
        """Return (output position, constraint satisfied)."""
        d_ins = np.asarray(ins_ne_m) - np.asarray(prev_ins_ne_m)  # integral of INS velocity over [T, T+1]
        d = np.asarray(pos_ne_m) - np.asarray(prev_pos_ne_m)
        tol = self.speed_accuracy_mps * dt_s
        if np.all(np.abs(d - d_ins) <= tol):  # eq. 12, north and east separately
            return np.asarray(pos_ne_m, float), True
        n = self.weight_n or n_window
        return ((np.asarray(prev_pos_ne_m) + d_ins) * n + np.asarray(pos_ne_m)) / (n + 1), False  # eq. 13


class Matcher(ABC):
    """Base for every gravity matcher.

    Subclasses implement `_match(window) -> MatchResult` and may raise MatchFailure. `match` validates
    input, times the call and never lets numpy errors escape. `feed` is the online path: samples are
    buffered, a fix is computed every `fix_every` samples once `min_len` are held, on the last
    `window_len` samples, and passed through the optional speed constraint (continuous matching).

    ``prior_sigma_m`` (of `match` and `feed`): the caller's own 1-sigma horizontal uncertainty of the window's
    first INS position (the navigator's), for matchers that can use a prior (``supports_prior``; they implement
    `_match(window, prior_sigma_m)`); the others ignore it.
    """

    name = "matcher"
    #: whether `_match` takes the caller's position prior (see the class docstring)
    supports_prior: ClassVar[bool] = False
    #: the matcher's own lattice cell (m), if it has one; its gravimeter noise setting (mGal), if it has one
    cell_m: float | None = None
    sigma_z_mgal: float | None = None

    def __init__(self, lmap: LocalGravityMap, *, min_len: int, window_len: int, fix_every: int = 1,
                 speed_constraint: SpeedConstraint | None = None):
        if min_len < 2 or window_len < min_len or fix_every < 1:
            raise ValueError("need 2 <= min_len <= window_len and fix_every >= 1")
        self.lmap = lmap
        self.min_len = min_len
        self.window_len = window_len
        self.fix_every = fix_every
        self.speed_constraint = speed_constraint
        self.reset()

    def reset(self) -> None:
        self._buf: list[tuple[float, float, float, float, float, float]] = []
        self._since_fix = 0
        self._prev: tuple[np.ndarray, np.ndarray, float] | None = None  # (output pos, INS pos, t)

    def method_name(self, prior_sigma_m: float | None = None) -> str:
        """The name of the method as run with this prior (the results' ``method``)."""
        return self.name

    # ---- batch ----
    def match(self, window: MatchWindow, *, prior_sigma_m: float | None = None) -> MatchResult:
        t0 = time.perf_counter()
        name = self.method_name(prior_sigma_m)
        t_last = float(window.t_s[-1]) if np.size(window.t_s) and np.isfinite(window.t_s[-1]) else float("nan")
        why = window.problem(self.min_len)
        if why:
            return MatchResult.failed(name, t_last, why, time.perf_counter() - t0)
        if len(window) > self.window_len:
            window = window.tail(self.window_len)
        try:
            with np.errstate(all="ignore"):
                res = self._match(window, prior_sigma_m) if self.supports_prior else self._match(window)
        except MatchFailure as exc:
            return MatchResult.failed(name, t_last, str(exc), time.perf_counter() - t0)
        res.compute_time_s = time.perf_counter() - t0
        if res.ok and not np.all(np.isfinite(res.position_ne_m)):
            return MatchResult.failed(name, t_last, "non-finite estimate", res.compute_time_s)
        return res

    @abstractmethod
    def _match(self, window: MatchWindow) -> MatchResult: ...

    # ---- online ----
    def feed(self, t_s: float, ins_ne_m, ins_vel_ne_mps, gravity_mgal: float, *,
             prior_sigma_m: float | None = None) -> MatchResult | None:
        """Add one sample; return a MatchResult when a fix is due, else None. ``prior_sigma_m``: see the class
        docstring (the uncertainty of the first sample of the window this sample completes)."""
        name = self.method_name(prior_sigma_m)
        try:
            n, e = np.asarray(ins_ne_m, float).reshape(2)
            vn, ve = np.asarray(ins_vel_ne_mps, float).reshape(2)
            t_s, gravity_mgal = float(t_s), float(gravity_mgal)
        except (TypeError, ValueError) as exc:
            return MatchResult.failed(name, float("nan"), f"malformed sample dropped ({exc})")
        if not np.all(np.isfinite([t_s, n, e, vn, ve, gravity_mgal])):
            return MatchResult.failed(name, t_s, "non-finite sample dropped")
        if self._buf and t_s <= self._buf[-1][0]:
            return MatchResult.failed(name, t_s, "sample time not after the previous one; dropped")
        self._buf.append((float(t_s), n, e, vn, ve, float(gravity_mgal)))
        if len(self._buf) > self.window_len:
            del self._buf[0]
        self._since_fix += 1
        if len(self._buf) < self.min_len or (self._prev is not None and self._since_fix < self.fix_every):
            return None
        self._since_fix = 0
        a = np.asarray(self._buf)
        win = MatchWindow(a[:, 0], a[:, 1:3], a[:, 3:5], a[:, 5])
        res = self.match(win, prior_sigma_m=prior_sigma_m)
        if not res.ok:
            return res
        if self.speed_constraint is not None and self._prev is not None:
            p_prev, ins_prev, t_prev = self._prev
            raw = res.position_ne_m.copy()
            out, inside = self.speed_constraint.apply(p_prev, ins_prev, res.t_s - t_prev, raw, win.ins_ne_m[-1], len(win))
            res.position_ne_m = out
            if res.track_ne_m is not None:
                res.track_ne_m = res.track_ne_m + (out - raw)
            res.extra["raw_position_ne_m"] = raw
            res.extra["speed_constraint_ok"] = inside
        self._prev = (res.position_ne_m.copy(), win.ins_ne_m[-1].copy(), res.t_s)
        return res
