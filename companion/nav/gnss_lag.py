"""Online estimate of the GNSS latency: how long before its time stamp a fix describes the vehicle.

A receiver reports the vehicle as it was some tens of milliseconds before the fix reaches the autopilot (ArduPilot
models 0.12 s for a u-blox M8, 0.22 s for older ones; its SITL u-blox lags 0.1 s by default). An integrating filter
that takes the fix as current explains the lag with its other states: at 8 m/s a 0.1 s lag is a 0.8 m position
offset that turns with every manoeuvre, and the error-state KF absorbs it into tilt and accelerometer bias. Those
wrong states cost nothing while fixes arrive and drive the drift once they stop: on a simulated noise-free square
an unmodelled 0.1 s lag makes 30 m after 30 s of dead reckoning instead of 2 m (tests/nav/test_gnss_lag.py).
A lag modelled 0.02 s off still costs 5-8 m, so it is measured rather than assumed.

Method: the horizontal velocity change between two consecutive GNSS velocities, ``v(t2) - v(t1)``, is compared
with the integral of the IMU specific force resolved in NED over the same interval shifted by a candidate lag tau,
``V(t2 - tau) - V(t1 - tau)`` (gravity and Coriolis have next to no horizontal part). It is resolved with the
autopilot's attitude interpolated to each sample's time, which does not depend on the lag (the INS's own attitude
does: it absorbs a mis-modelled lag into tilt). A heading error of the attitude rotates the IMU's velocity changes,
and in a steady turn a rotation is indistinguishable from a lag (0.8 deg at 0.4 rad/s looks like 0.035 s), so each
candidate is scored after the best common rotation: with forgotten sums (``tau_s``) C = sum dv_g conj(dv_i), E_g,
E_i of the velocity changes as complex N + iE numbers, the residual is E_g + E_i - 2 |C| (the rotation is arg C;
cf. the navigator's autopilot heading check). Candidates are on a grid (``step_s``); the estimate is the grid
minimum refined by a parabola through its neighbours. It is valid once the forgotten sum of squared GNSS velocity
changes exceeds ``min_dv_mps``^2 (a hover does not observe a lag) over at least ``min_pairs`` pairs, the minimum is
inside the grid and its standard error is within ``max_sigma_s``.

The IMU integral is held the way the strapdown INS integrates (each sample over the interval before it), so the
estimate is the lag the INS itself needs. Pure: no I/O, no clocks.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GnssLagConfig:
    max_lag_s: float = 0.4  # candidates 0 .. max_lag_s
    step_s: float = 0.01
    tau_s: float = 120.0  # forgetting time constant of the residual sums
    min_dv_mps: float = 2.0  # excitation: sqrt of the forgotten sum of |dv_gnss|^2 before the estimate is used
    min_pairs: int = 20
    max_pair_dt_s: float = 1.1  # consecutive GNSS velocities further apart than this are not paired
    max_sigma_s: float = 0.01  # the estimate is used only while its standard error is within this
    relearn_s: float = 0.01  # the navigator re-learns tilt and accelerometer bias when the lag in use moves further

    def __post_init__(self) -> None:
        if not (0 < self.step_s <= self.max_lag_s and self.tau_s > 0 and self.min_dv_mps >= 0
                and self.min_pairs >= 1 and self.max_pair_dt_s > 0 and self.max_sigma_s > 0 and self.relearn_s >= 0):
            raise ValueError("GnssLagConfig: need 0 < step_s <= max_lag_s, tau_s > 0, min_dv_mps >= 0, "
                             "min_pairs >= 1, max_pair_dt_s > 0, max_sigma_s > 0, relearn_s >= 0")


class GnssLagEstimator:
    """Feed :meth:`add_imu` for every IMU sample, :meth:`add_attitude` for every autopilot attitude and
    :meth:`add_gnss_velocity` for every GNSS velocity, each stream in time order; :attr:`lag_s` is the estimate
    (None until it is observable).

    A sample is resolved in NED once attitudes bracket it, with the attitude interpolated linearly to its time (the
    10 Hz ATTITUDE is up to 0.1 s older than the newest sample: resolved with the last one as it is, a turn rotates
    the force like a lag and biased the estimate by -0.04 s on the simulated square); a GNSS pair is compared once
    the resolved integral reaches its later time."""

    def __init__(self, config: GnssLagConfig | None = None) -> None:
        self.config = c = config or GnssLagConfig()
        self.taus_s = np.arange(0.0, c.max_lag_s + 0.5 * c.step_s, c.step_s)
        self._cross = np.zeros(len(self.taus_s), dtype=complex)  # forgotten sums of dv_gnss conj(dv_imu(tau))
        self._ei = np.zeros(len(self.taus_s))  # ... of |dv_imu(tau)|^2
        self._excitation = 0.0
        self._n_w = 0.0  # forgotten number of pairs
        self._pairs = 0
        self._t_sum: float | None = None  # time of the last residual added (forgetting)
        self._hist: deque[tuple[float, float, float]] = deque()  # (t, integral N, integral E) of the specific force
        self._vn = 0.0
        self._ve = 0.0
        self._imu: deque[tuple[float, float, float, float, float]] = deque()  # unresolved (t, dt, ax, ay, az)
        self._att: tuple[float, tuple[float, ...]] | None = None  # last attitude: t, first two rows of C_b^n
        self._pending: deque[tuple[float, float, float, float, float, float]] = deque()  # GNSS pairs to compare
        self._prev_fix: tuple[float, float, float] | None = None

    def add_imu(self, t_s: float, dt_s: float, accel_frd_mps2) -> None:
        """One IMU sample (specific force in body FRD), held over the ``dt_s`` before it (as the INS integrates)."""
        if dt_s > 0 and all(math.isfinite(v) for v in accel_frd_mps2):
            self._imu.append((t_s, dt_s, *accel_frd_mps2))
            while self._imu[0][0] < t_s - 2.0:  # no attitude for that long: those samples are not resolvable
                self._imu.popleft()

    def add_attitude(self, t_s: float, c_rows) -> None:
        """An autopilot attitude: the first two rows of its C_b^n (6 numbers, row-major)."""
        prev, self._att = self._att, (t_s, tuple(c_rows))
        if prev is None:
            while self._imu and self._imu[0][0] <= t_s:
                self._imu.popleft()  # no attitude before it: not resolvable
            return
        t0, c0 = prev
        c1 = self._att[1]
        span = t_s - t0
        while self._imu and self._imu[0][0] - 0.5 * self._imu[0][1] <= t_s:
            ts, dt, ax, ay, az = self._imu.popleft()
            w = (ts - 0.5 * dt - t0) / span if span > 0 else 1.0  # mid-interval, as the INS resolves it
            c = [a + w * (b - a) for a, b in zip(c0, c1)]
            self._integrate(ts, dt, c[0] * ax + c[1] * ay + c[2] * az, c[3] * ax + c[4] * ay + c[5] * az)
        self._compare()

    def _integrate(self, t_s: float, dt_s: float, f_n: float, f_e: float) -> None:
        if not self._hist:
            self._hist.append((t_s - dt_s, 0.0, 0.0))
        self._vn += f_n * dt_s
        self._ve += f_e * dt_s
        self._hist.append((t_s, self._vn, self._ve))
        keep = self.config.max_lag_s + self.config.max_pair_dt_s + 1.0
        while self._hist[0][0] < t_s - keep:
            self._hist.popleft()

    def reset_imu(self) -> None:
        """The IMU stream had a gap: the integral does not bridge it."""
        self._hist.clear()
        self._imu.clear()
        self._pending.clear()
        self._prev_fix = None

    def add_gnss_velocity(self, t_s: float, vn_mps: float, ve_mps: float) -> None:
        prev, self._prev_fix = self._prev_fix, (t_s, vn_mps, ve_mps)
        if prev is not None and 0 < t_s - prev[0] <= self.config.max_pair_dt_s:
            self._pending.append((prev[0], prev[1], prev[2], t_s, vn_mps, ve_mps))
            self._compare()

    def _compare(self) -> None:
        c = self.config
        while self._pending and self._hist and self._pending[0][3] <= self._hist[-1][0]:
            t1, vn1, ve1, t2, vn2, ve2 = self._pending.popleft()
            h = np.asarray(self._hist)
            if t1 - self.taus_s[-1] < h[0, 0]:
                continue  # the integral does not reach back to every candidate
            a, b = t1 - self.taus_s, t2 - self.taus_s
            dvn_i = np.interp(b, h[:, 0], h[:, 1]) - np.interp(a, h[:, 0], h[:, 1])
            dve_i = np.interp(b, h[:, 0], h[:, 2]) - np.interp(a, h[:, 0], h[:, 2])
            zg = complex(vn2 - vn1, ve2 - ve1)
            zi = dvn_i + 1j * dve_i
            w = 1.0 if self._t_sum is None else math.exp(-max(0.0, t2 - self._t_sum) / c.tau_s)
            self._t_sum = t2
            self._cross = self._cross * w + zg * np.conj(zi)
            self._ei = self._ei * w + np.abs(zi) ** 2
            self._excitation = self._excitation * w + abs(zg) ** 2
            self._n_w = self._n_w * w + 1.0
            self._pairs += 1

    @property
    def observable(self) -> bool:
        c = self.config
        return self._pairs >= c.min_pairs and self._excitation >= c.min_dv_mps**2

    @property
    def lag_s(self) -> float | None:
        """The lag with the least forgotten squared residual (parabolic refinement), or None: not yet observable,
        its standard error (:meth:`sigma_s`) above ``max_sigma_s``, or the minimum at the grid's upper end (the lag
        is beyond it); at its lower end the lag is 0."""
        est = self._estimate()
        return None if est is None or not est[1] <= self.config.max_sigma_s else est[0]

    def sigma_s(self) -> float | None:
        """Standard error of the estimate: least squares in tau, sigma^2 = 2 s2 / a with s2 the residual variance
        per pair (minimum sum / forgotten count) and a the curvature of the residual sum over +-0.05 s. A flat
        curve (noise above the signal: the bundled sample's noisy 5 Hz velocities on its gentle legs) is large."""
        est = self._estimate()
        return None if est is None else est[1]

    def _estimate(self) -> tuple[float, float] | None:
        if not self.observable:
            return None
        s = self._sse()
        n = len(s)
        k = int(np.argmin(s))
        if k == n - 1:
            return None
        step = self.config.step_s
        if k == 0:
            lag = 0.0
        else:
            den = s[k - 1] - 2.0 * s[k] + s[k + 1]
            off = 0.5 * (s[k - 1] - s[k + 1]) / den if den > 0 else 0.0
            lag = float(self.taus_s[k] + max(-0.5, min(0.5, off)) * step)
        h = max(1, int(round(0.05 / step)))
        lo, hi = max(0, k - h), min(n - 1, k + h)
        if k - lo == hi - k:
            a = (s[lo] + s[hi] - 2.0 * s[k]) / ((hi - k) * step) ** 2
        else:
            j = hi if hi - k >= k - lo else lo
            a = 2.0 * (s[j] - s[k]) / ((j - k) * step) ** 2
        if not a > 0:
            return lag, math.inf
        s2 = s[k] / max(self._n_w - 1.0, 1.0)
        return lag, math.sqrt(2.0 * s2 / a)

    def _sse(self) -> np.ndarray:
        """Per candidate lag, the forgotten sum of squared residuals after the best common heading rotation."""
        return np.maximum(0.0, self._excitation + self._ei - 2.0 * np.abs(self._cross))

    def heading_offset_rad(self) -> float | None:
        """The rotation from the IMU's velocity changes to the GNSS's at the estimated lag (the attitude's heading
        error), or None."""
        lag = self.lag_s
        if lag is None:
            return None
        return float(np.angle(self._cross[int(round(lag / self.config.step_s))]))

    def residual_curve(self) -> tuple[np.ndarray, np.ndarray]:
        """(candidate lags, forgotten sum of squared residuals): for diagnostics and tests."""
        return self.taus_s.copy(), self._sse()


class GnssLatency:
    """The GNSS latency the navigator's filters model: the online estimate once it is observable (``estimator``, None
    when not measured), else the configured delays of the position and, before it, of the velocity."""

    def __init__(self, delay_s: float, vel_delay_s: float, estimator: GnssLagEstimator | None = None) -> None:
        self.configured_s = delay_s
        self.configured_vel_s = vel_delay_s
        self.estimator = estimator

    def delay_s(self) -> float:
        """How long before its time stamp a fix describes the vehicle."""
        est = self.estimator
        lag = est.lag_s if est is not None else None
        return self.configured_s if lag is None else lag

    def vel_delay_s(self) -> float:
        """The same for the fix's velocity: the measured lag (measured from the velocity), else the position's plus
        the velocity's own."""
        est = self.estimator
        lag = est.lag_s if est is not None else None
        return self.configured_s + self.configured_vel_s if lag is None else lag

    def history_s(self) -> float | None:
        """How far back the INS must keep its states to compare a fix with the epoch it describes (None: never)."""
        est = self.estimator
        if not (self.configured_s > 0 or self.configured_vel_s > 0 or est is not None):
            return None
        return max(self.configured_s + self.configured_vel_s, est.config.max_lag_s if est is not None else 0.0)

    def describe(self) -> str:
        """The latency in use, for the recording's metadata: the measured one with its sigma, or the configured."""
        est = self.estimator
        sig = est.sigma_s() if est is not None else None
        return f"{self.delay_s():.3f}" + (
            f" (measured, sigma {sig:.3f})" if est is not None and est.lag_s is not None else " (configured)")
