"""The vehicle's own motion as a second opinion during a blockage: hold and constant velocity, mixed by what they have
been worth on this flight (the "model mixing" of the navigator's output).

During a GNSS blockage the INS error grows without bound (t^2 .. t^3 from tilt and accelerometer errors), while a
loitering multicopter stays near where it was and a cruising one keeps its velocity. Two motion models predict the
position ``tau`` seconds after the last fix: hold (``p0``) and constant velocity (``p0 + v0 tau``). Their errors are
learnt causally, per axis, from the accepted fixes: for every fix and every whole-second lag up to ``max_lag_s``, the
errors both models would have made from the fix that lag earlier, as exponentially forgotten second moments
(``tau_s``) -- the 2 x 2 covariance ``S(tau)`` of (hold error, constant-velocity error). A fix at which the vehicle
was stationary (the navigator's hover detector: standing on the ground, or a still hover) starts no pair: minutes
on the ground before take-off would otherwise teach that the vehicle never moves.

At an age ``tau`` of the last fix, the best linear unbiased mix of the two models (hold weight
``w = (S22 - S12) / (S11 + S22 - 2 S12)`` clipped to [0, 1]; the last fix's own variance is common to both) is the
motion prior, its variance that of the mix times ``variance_scale`` (the forgotten statistics of a short, changing
flight underestimate the next blockage's).
At a lag with fewer than ``min_pairs`` (forgotten) pairs, the statistics of the longest lag that has them are
extrapolated ballistically (x (tau / lag)^2: an upper bound for a vehicle whose velocity persists).

:func:`blend` multiplies the navigator's own Gaussian (the INS/KF estimate and its covariance, which is calibrated to
its blockage error on the shared logs) with the prior's, per axis: each is weighted by the inverse of its variance, so
the output leans on the motion prior only as far as the filter's own drift exceeds what the vehicle's motion allows.
Where the two disagree by more than ``consistency_sigma`` combined sigmas, the vehicle has left its recent pattern
(the INS sees it accelerate away) and the prior's variance is widened until they agree at that level. Output only:
the filter's state is not changed, so aiding resumes from the INS. Pure: no I/O, no clocks; O(max_lag_s) per fix.

``select`` (kinematic mode only): an online, per-flight model selection instead of the product. The filter's own
dead reckoning from each fix (its position plus velocity x lag: ``ins`` of :meth:`MotionPrior.add_fix`) is scored
against the later fixes like hold and CV, and :meth:`MotionPrior.select` mixes hold, CV and the filter's estimate
with the non-negative weights that minimise the variance of the mix under the learnt 3 x 3 error moments at this
age. It needs the filter's dead reckoning to stand for its blockage output: true of the kinematic filter (its output
in a blockage is that extrapolation, plus the predictor's points), not of the INS filter, whose blockage output owes
much to its aids (autopilot attitude, rotor drag, the predictor), which the free-INS record leaves out. So in INS
mode the product with the filter's claimed variance is used, from ``blend_min_age_s`` on (after the aided INS's own
short-age accuracy). Why these forms and ages: docs/decisions/0007-motion-prior.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


_MAX_FIXES = 4096  # fixes kept for pairing at most (60 s of 50 Hz GNSS)


@dataclass(frozen=True)
class MotionPriorConfig:
    max_lag_s: int = 60
    tau_s: float = 120.0  # forgetting time constant of the error statistics
    min_pairs: float = 10.0  # forgotten number of fix pairs a lag needs before its statistics are used
    min_age_s: float = 1.5  # the prior is applied from this age of the last fix on (select, kinematic mode)
    blend_min_age_s: float = 6.0  # ... and the product with the INS filter (INS mode) from this one
    variance_scale: float = 2.0  # the prior's variance x this (docs/decisions/0007)
    consistency_sigma: float = 2.0
    # per-horizon selection (kinematic mode only): mix hold, CV and the filter's own output by the errors each would
    # have made from this flight's past fixes at this age (MotionPrior.select) instead of the product with the
    # filter's claimed variance (blend)
    select: bool = True

    def __post_init__(self) -> None:
        if (self.max_lag_s < 1 or self.tau_s <= 0 or self.min_pairs < 2 or self.min_age_s < 0
                or self.blend_min_age_s < 0 or self.variance_scale <= 0 or self.consistency_sigma <= 0):
            raise ValueError("MotionPriorConfig: need max_lag_s >= 1, tau_s > 0, min_pairs >= 2, min_age_s >= 0, "
                             "blend_min_age_s >= 0, variance_scale > 0, consistency_sigma > 0")


class MotionPrior:
    """Feed :meth:`add_fix` with every accepted fix (local NED, its velocity or None, its variance per axis, whether
    the vehicle is stationary); :meth:`predict` gives the prior's mean and variance per axis at a later time."""

    def __init__(self, config: MotionPriorConfig | None = None) -> None:
        self.config = c = config or MotionPriorConfig()
        n = c.max_lag_s + 1
        self._hh = np.zeros((n, 3))  # forgotten sums per lag and axis: hold error^2, CV error^2, their product
        self._cc = np.zeros((n, 3))
        self._hc = np.zeros((n, 3))
        self._w = np.zeros(n)  # forgotten number of pairs per lag
        self._lags = np.arange(1, n)
        self._t_sum: float | None = None
        self._n = 0  # recent fixes (the first _n rows): time, position, velocity, stationary
        self._ht = np.empty(256)
        self._hp = np.empty((256, 3))
        self._hv = np.empty((256, 3))
        self._hs = np.zeros(256, dtype=bool)
        self._hi = np.empty((256, 12))  # the INS at the fix: position, velocity, free position, free velocity
        self._he = np.full(256, -1)  # ... and its epoch (-1: no INS)
        self._ii = np.zeros((c.max_lag_s + 1, 3))  # forgotten sums per lag and axis: INS dead-reckoning error^2
        self._wi = np.zeros(c.max_lag_s + 1)
        # on the same pairs as _ii: hold^2, CV^2, hold x CV, INS x hold, INS x CV (for select)
        self._sel = [np.zeros((c.max_lag_s + 1, 3)) for _ in range(5)]
        self._last: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None  # t, p, v, variance

    def reset(self) -> None:
        """Forget the fix history (after a stream gap): the statistics stay, the next fix starts a new track."""
        self._n = 0
        self._last = None

    def add_fix(self, t: float, p_ned, v_ned, var_ned, stationary: bool = False, ins=None, ins_epoch: int = -1) -> None:
        """``ins``: the INS at the fix (after its update) as (position, velocity, free position, free velocity), the
        free ones without any correction since ``ins_epoch`` began (companion.nav.ins_filter): a pair of fixes then
        also gives the error of the INS dead reckoning from the first over the lag."""
        c = self.config
        n = self._n
        tt = self._ht[:n]
        if n and t <= tt[-1]:
            return
        p = np.asarray(p_ned, dtype=float)
        if v_ned is not None and all(math.isfinite(x) for x in v_ned):
            v = np.asarray(v_ned, dtype=float)
        elif n:  # no receiver velocity: the last two fixes' finite difference
            v = (p - self._hp[n - 1]) / (t - tt[-1])
        else:
            v = np.zeros(3)
        if self._t_sum is not None:
            f = math.exp(-(t - self._t_sum) / c.tau_s)
            for s in (self._hh, self._cc, self._hc, self._w, self._ii, self._wi, *self._sel):
                s *= f
        self._t_sum = t
        if n:  # the fix each lag pairs with: the first within +-0.5 s of t - lag, if it was not stationary
            lags = self._lags
            idx = np.minimum(np.searchsorted(tt, t - lags - 0.5), n - 1)
            ok = (tt[idx] >= t - lags - 0.5) & (tt[idx] <= t - lags + 0.5) & ~self._hs[idx]
            if ok.any():
                lag, i = lags[ok], idx[ok]
                eh = p - self._hp[i]
                ec = eh - self._hv[i] * (t - tt[i])[:, None]
                self._hh[lag] += eh * eh
                self._cc[lag] += ec * ec
                self._hc[lag] += eh * ec
                self._w[lag] += 1.0
                if ins is not None:
                    m = self._he[i] == ins_epoch
                    if m.any():
                        lag, i, dt = lag[m], i[m], (t - tt[i[m]])[:, None]
                        a = self._hi[i]
                        pred = a[:, 0:3] + a[:, 3:6] * dt + (np.asarray(ins[2]) - a[:, 6:9] - a[:, 9:12] * dt)
                        ei = p - pred
                        self._ii[lag] += ei * ei
                        self._wi[lag] += 1.0
                        if c.select:
                            sh_, sc_ = eh[m], ec[m]
                            for acc, x in zip(self._sel, (sh_ * sh_, sc_ * sc_, sh_ * sc_, ei * sh_, ei * sc_)):
                                acc[lag] += x
        if n == len(self._ht):  # full: drop what no lag reaches any more, grow if that is not enough
            k = int(np.searchsorted(tt, t - c.max_lag_s - 1.0))
            if n - k > _MAX_FIXES // 2:  # bounded whatever the fix rate: keep the newest half
                k = n - _MAX_FIXES // 2
            keep = slice(k, n)
            grow = 2 if n - k > n // 2 and n < _MAX_FIXES else 1
            self._ht = np.concatenate([self._ht[keep], np.empty(len(self._ht) * grow - (n - k))])
            self._hp = np.concatenate([self._hp[keep], np.empty((len(self._hp) * grow - (n - k), 3))])
            self._hv = np.concatenate([self._hv[keep], np.empty((len(self._hv) * grow - (n - k), 3))])
            self._hs = np.concatenate([self._hs[keep], np.zeros(len(self._hs) * grow - (n - k), dtype=bool)])
            self._hi = np.concatenate([self._hi[keep], np.empty((len(self._hi) * grow - (n - k), 12))])
            self._he = np.concatenate([self._he[keep], np.full(len(self._he) * grow - (n - k), -1)])
            n -= k
        self._ht[n], self._hp[n], self._hv[n], self._hs[n] = t, p, v, bool(stationary)
        if ins is not None:
            self._hi[n] = np.concatenate([np.asarray(x, dtype=float) for x in ins])
        self._he[n] = ins_epoch if ins is not None else -1
        self._n = n + 1
        self._last = (t, p, v, np.asarray(var_ned, dtype=float))

    def _moments(self, sums, w, age: float, power: float = 2.0):
        """Second moments per axis at this age from per-lag sums and pair weights, or None; beyond the longest lag
        with enough pairs, extrapolated as (age / lag)^power."""
        c = self.config
        ok = w >= c.min_pairs
        ok[0] = False
        lo = min(int(math.floor(age)), c.max_lag_s)
        hi = min(lo + 1, c.max_lag_s)
        if lo >= 1 and ok[lo] and ok[hi]:
            f = min(max(age - lo, 0.0), 1.0) if hi > lo else 0.0
            return tuple((1 - f) * s[lo] / w[lo] + f * s[hi] / w[hi] for s in sums)
        good = np.nonzero(ok[: lo + 1])[0]
        if len(good) == 0:
            return None
        g = int(good[-1])
        k = (age / g) ** power
        return tuple(s[g] / w[g] * k for s in sums)

    def _since_last(self, t: float, min_age_s: float):
        """(age, position, velocity, variance) of the last fix at time t; None before any fix or before min_age_s."""
        if self._last is None:
            return None
        t0, p, v, var = self._last
        age = t - t0
        return None if age < min_age_s else (age, p, v, var)

    def predict(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
        """Mean and variance per NED axis of the motion prior at time t, and the INS dead-reckoning error variance
        learnt for this age (None without it); None before ``blend_min_age_s`` or with nothing learnt."""
        last = self._since_last(t, self.config.blend_min_age_s)
        if last is None:
            return None
        age, p, v, var = last
        st = self._moments((self._hh, self._cc, self._hc), self._w, age)
        if st is None:
            return None
        mean = np.empty(3)
        out_var = np.empty(3)
        for a in range(3):
            s11, s22, s12 = st[0][a] + var[a], st[1][a] + var[a], st[2][a] + var[a]
            den = s11 + s22 - 2.0 * s12
            w = min(max((s22 - s12) / den, 0.0), 1.0) if den > 1e-12 else (1.0 if s11 <= s22 else 0.0)
            mean[a] = p[a] + (1.0 - w) * v[a] * age
            out_var[a] = max(w * w * s11 + (1 - w) ** 2 * s22 + 2 * w * (1 - w) * s12, 1e-6) * self.config.variance_scale
        ins = self._moments((self._ii,), self._wi, age, power=3.0)  # an INS drifts t^2 .. t^3
        return mean, out_var, (None if ins is None else ins[0] + var)

    def select(self, t: float, ned) -> tuple[list[float], list[float]] | None:
        """Online per-flight model selection (``select``): the output at time t as the best linear unbiased mix of
        hold, constant velocity and the filter's own estimate ``ned``, per axis, with weights >= 0 from the 3 x 3
        second moments of the errors each would have made at this age from this flight's past fixes (the filter's
        by its dead reckoning from the fix, see :meth:`add_fix`); variance that of the mix x ``variance_scale``.
        None before ``min_age_s`` or with nothing learnt."""
        last = self._since_last(t, self.config.min_age_s)
        if last is None:
            return None
        age, p, v, var = last
        hc = self._moments(tuple(self._sel[:3]), self._wi, age, power=2.0)
        ii = self._moments((self._ii,), self._wi, age, power=3.0)
        ix = self._moments(tuple(self._sel[3:]), self._wi, age, power=2.5)
        if hc is None or ii is None or ix is None:
            return None
        out, out_var = [], []
        for a in range(3):
            S = np.array([[hc[0][a], hc[2][a], ix[0][a]], [hc[2][a], hc[1][a], ix[1][a]],
                          [ix[0][a], ix[1][a], ii[0][a]]]) + var[a]
            w = _nonneg_blue(S)
            out.append(w[0] * p[a] + w[1] * (p[a] + v[a] * age) + w[2] * ned[a])
            out_var.append(max(float(w @ S @ w), 1e-6) * self.config.variance_scale)
        return out, out_var

    def output(self, t: float, ned, P: np.ndarray, ins_mode: bool, ins_error_learnt: bool):
        """The navigator's output position at t (local NED) and its covariance ``P`` after the prior: the selection in
        kinematic mode (``select``), else the product with the filter's claimed variance (:func:`blend`), bounded by
        the learnt INS dead-reckoning error only when ``ins_error_learnt`` (that of an attitude-aided INS). Returns
        (ned, P, applied); P is a new array when applied."""
        if self.config.select and not ins_mode:
            sel = self.select(t, ned)
            if sel is None:
                return ned, P, False
            P = P.copy()
            P[0, 0], P[1, 1], P[2, 2] = sel[1]
            return tuple(sel[0]), P, True
        prior = self.predict(t)
        if prior is None:
            return ned, P, False
        if not (ins_mode and ins_error_learnt):
            prior = (prior[0], prior[1], None)
        ned, var = blend(ned, (P[0, 0], P[1, 1], P[2, 2]), prior, self.config.consistency_sigma)
        P = P.copy()
        P[0, 0], P[1, 1], P[2, 2] = var
        return ned, P, True


def _nonneg_blue(S: np.ndarray) -> np.ndarray:
    """Weights w >= 0, sum 1, minimising w' S w: the unconstrained optimum on every subset of the models, the best
    admissible one."""
    n = len(S)
    best, best_v = None, math.inf
    for mask in range(1, 1 << n):
        idx = [i for i in range(n) if mask >> i & 1]
        sub = S[np.ix_(idx, idx)]
        try:
            x = np.linalg.solve(sub, np.ones(len(idx)))
        except np.linalg.LinAlgError:
            continue
        if x.sum() <= 0 or (x < 0).any():
            continue
        w = np.zeros(n)
        w[idx] = x / x.sum()
        val = float(w @ S @ w)
        if val < best_v:
            best, best_v = w, val
    if best is None:
        best = np.zeros(n)
        best[int(np.argmin(np.diag(S)))] = 1.0
    return best


def blend(ned, var, prior, consistency_sigma: float):
    """The product of the filter's Gaussian (``ned``, per-axis ``var``) with the motion prior's, per axis; the filter's
    variance bounded by the INS dead-reckoning error learnt on this flight (a clean IMU drifts far less than a
    filter tuned for vibrating ones claims), the prior widened where the two disagree by more than
    ``consistency_sigma`` combined sigmas. Returns (ned, var); the variance is that of the two estimates mixed with
    the product's weights (as an IMM combines its models' covariances), never below the product's."""
    mean, pv, ins_var = prior
    g = consistency_sigma * consistency_sigma
    out, out_var = [], []
    for i in range(3):
        p = var[i] if ins_var is None else min(var[i], ins_var[i])
        d = pv[i]
        r2 = (mean[i] - ned[i]) ** 2
        if r2 > g * (p + d):
            d = r2 / g - p
        k = p / (p + d)
        out.append(ned[i] + k * (mean[i] - ned[i]))
        # claimed as a mixture of the two (each with its own variance, and their disagreement), not as the product's
        # (p d / (p + d)): the product is only as honest as the prior's tails, which a changing flight makes heavy
        out_var.append((1.0 - k) * var[i] + k * d + k * (1.0 - k) * r2)
    return out, out_var
