"""The stated accuracy after a jump the gravity filter's own covariance did not allow.

A consistent filter moves its estimate at one update by a shift whose covariance is what the update takes off its
covariance (P_prior - P_post, never more than P_prior). A shift u of the estimated error with

    d^2 = u' P_prior^-1 u  >  chi2_2(0.99) = 9.21

is one a consistent filter makes once in a hundred updates at most: the covariance it stated before the update was too
small by about that shift. That happens when the model misses something (a wind step taken as position, a heading
error it did not allow for) and the particles jump to another mode of the map. Its estimate after the jump is no more
trustworthy than the jump says, so the guard adds the shift's outer product u u' to every covariance stated for the
rest of the outage (jumps add up); GNSS back clears it. It only ever adds covariance: it can make a stated accuracy
larger, never smaller.

A jump can also be made over many readings, each within the covariance: the same test runs against the estimates of
the last ``window_s`` (one kept every ``spacing_s``), each carried to now by its velocity error, the shift since then
against a bound of what a consistent filter could have moved by (``_prior``: its factor 2 keeps the many tests quiet
on a consistent filter, tests/gravity/test_jump_guard.py). The largest shift that fails adds once, and the test
restarts from the estimate after it. Measured in docs/decisions/0018-jump-guard.md. Pure: vehicle time only, bounded
work and memory per reading (window_s / spacing_s estimates).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

#: chi-square with 2 degrees of freedom at 0.99
CHI2_2_99 = 9.21


@dataclass(frozen=True, slots=True)
class Jump:
    t_s: float
    shift_m: float  # |u|
    d2: float  # its Mahalanobis distance squared under the prior


@dataclass(frozen=True, slots=True)
class _Est:
    t_s: float
    m: np.ndarray  # estimated error (m)
    P: np.ndarray  # its covariance
    v: np.ndarray  # velocity error (m/s)
    Pv: np.ndarray  # its covariance


class JumpGuard:
    """``observe`` each estimate of the outage (error, covariance, velocity error and its covariance); ``cov_ne_m2``
    is what to add to the stated covariance. ``chi2`` 0 turns it off."""

    def __init__(self, chi2: float = CHI2_2_99, window_s: float = 600.0, spacing_s: float = 30.0,
                 vel_walk_mps_rts: float = 0.0, pos_walk_m_rts: float = 0.0):
        if not (chi2 >= 0 and window_s >= 0 and spacing_s > 0 and vel_walk_mps_rts >= 0 and pos_walk_m_rts >= 0):
            raise ValueError(f"jump guard: need chi2 >= 0 (0: off), window_s >= 0, spacing_s > 0, walks >= 0, not "
                             f"{chi2}, {window_s}, {spacing_s}, {vel_walk_mps_rts}, {pos_walk_m_rts}")
        self.chi2 = float(chi2)
        self.window_s, self.spacing_s = float(window_s), float(spacing_s)
        self.vel_walk_mps_rts, self.pos_walk_m_rts = float(vel_walk_mps_rts), float(pos_walk_m_rts)
        self.cov_ne_m2 = np.zeros((2, 2))
        self.jumps: deque[Jump] = deque(maxlen=100)
        self._prev: _Est | None = None
        self._kept: deque[_Est] = deque()

    def set_process_noise(self, vel_walk_mps_rts: float, pos_walk_m_rts: float) -> None:
        """The filter's process noise for this outage (its velocity error's walk, its position's)."""
        self.vel_walk_mps_rts, self.pos_walk_m_rts = max(float(vel_walk_mps_rts), 0.0), max(float(pos_walk_m_rts), 0.0)

    def reset(self) -> None:
        """GNSS back (or a new outage): nothing the filter stated before is in question any more."""
        self.cov_ne_m2 = np.zeros((2, 2))
        self.restart()

    def restart(self) -> None:
        """The filter re-initialised around its reference: its new covariance is the reference's own; the next
        estimate is not a shift of the earlier ones."""
        self._prev = None
        self._kept.clear()

    def _prior(self, e: _Est, dt: float) -> np.ndarray:
        """What a consistent filter's error could have moved by since estimate e: its position and velocity errors
        carried dt on (their cross-covariance unknown: Var(a + b) <= 2 Var(a) + 2 Var(b)) plus the process noise the
        filter adds over dt (the velocity's walk integrated, and the position's own walk)."""
        q = self.vel_walk_mps_rts**2 * dt**3 / 3.0 + self.pos_walk_m_rts**2 * dt
        return 2.0 * (e.P + e.Pv * dt * dt) + np.eye(2) * q

    def observe(self, t_s: float, err_ne_m, cov_ne_m2, vel_err_ne_mps=None, vel_cov_ne_m2ps2=None) -> Jump | None:
        """One estimate; returns the jump it made, if it was one."""
        if self.chi2 <= 0:
            return None
        m = np.asarray(err_ne_m, float).reshape(2)
        P = np.asarray(cov_ne_m2, float).reshape(2, 2)
        v = np.zeros(2) if vel_err_ne_mps is None else np.asarray(vel_err_ne_mps, float).reshape(2)
        Pv = np.zeros((2, 2)) if vel_cov_ne_m2ps2 is None else np.asarray(vel_cov_ne_m2ps2, float).reshape(2, 2)
        if not (np.isfinite(t_s) and np.all(np.isfinite(m)) and np.all(np.isfinite(P)) and np.all(np.isfinite(v))
                and np.all(np.isfinite(Pv))):
            return None
        if self._prev is not None and not t_s > self._prev.t_s:
            return None
        worst = None
        kept = list(self._kept)
        if self._prev is not None and (not kept or kept[-1] is not self._prev):  # the last reading, unless kept
            kept.append(self._prev)
        for e in kept:
            dt = float(t_s) - e.t_s
            u = m - (e.m + e.v * dt)
            try:
                d2 = float(u @ np.linalg.solve(self._prior(e, dt), u))
            except np.linalg.LinAlgError:
                continue
            if d2 > self.chi2 and (worst is None or u @ u > worst[0] @ worst[0]):
                worst = (u, d2)
        cur = _Est(float(t_s), m, P, v, Pv)
        if worst is not None:
            self.restart()
        self._prev = cur
        if not self._kept or t_s - self._kept[-1].t_s >= self.spacing_s:
            self._kept.append(cur)
        while self._kept and self._kept[0].t_s < t_s - self.window_s:
            self._kept.popleft()
        if worst is None:
            return None
        u, d2 = worst
        self.cov_ne_m2 = self.cov_ne_m2 + np.outer(u, u)
        j = Jump(float(t_s), float(np.hypot(*u)), d2)
        self.jumps.append(j)
        return j
