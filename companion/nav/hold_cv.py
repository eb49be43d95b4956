"""Hold / constant-velocity model mixing for the navigator's kinematic filter: an interacting multiple model (IMM).

Without a usable IMU the kinematic filter only knows the fixes. A constant-velocity (CV) model extrapolates the last
velocity through a blockage; a multicopter that hovers or loiters goes nowhere, and its small, noisy velocity carried
forward is worse than holding the last fix. Two 6-state models ``[p_ned, v_ned]`` run side by side (Blom &
Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan 2001, sec. 11.6.6):

* **hold**: the velocity is zero; the position wanders by at most ``hold_speed_mps`` x dt between epochs (process
  noise ``(hold_speed_mps dt)^2`` on the position);
* **CV**: white-noise acceleration of ``accel_sigma_mps2`` (the kinematic filter's own model).

Each step mixes the models by a Markov switch with mean dwell ``dwell_s`` (switch probability 1 - exp(-dt/dwell_s)),
each model predicts and updates with the same measurement, and a measurement of the vehicle (``evidence``: GNSS, a
position fix) updates the mode probabilities with each model's innovation likelihood N(y; 0, S). Pseudo-measurements
extrapolated from past fixes (the KNN predictor, zero velocity) update the states but are no evidence for a model.
The output is the moment-matched mixture: mean sum mu_j x_j, covariance sum mu_j (P_j + (x_j - x)(x_j - x)').

Pure: no I/O, no clocks; O(1) per step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.nav.kalman import KalmanFilter
from companion.nav.linalg import small_inverse


@dataclass(frozen=True)
class HoldCvConfig:
    # a hover's wander: chosen on simulated tracks (tests/nav/test_hold_cv.py) so that the models are equally likely
    # at ~0.9 m/s, just above the hover detector's 0.7 m/s bound (companion.nav.hover)
    hold_speed_mps: float = 0.3
    dwell_s: float = 30.0  # mean time the vehicle stays in one motion mode (a hover, a leg of a mission)
    min_prob: float = 1e-3  # neither model's probability falls below this (it can always come back)

    def __post_init__(self) -> None:
        if self.hold_speed_mps <= 0 or self.dwell_s <= 0 or not 0 < self.min_prob < 0.5:
            raise ValueError("HoldCvConfig: need hold_speed_mps > 0, dwell_s > 0, 0 < min_prob < 0.5")


HOLD, CV = 0, 1


# the flat indices of the diagonals of a 6 x 6 matrix's 3 x 3 blocks: (0:3, 0:3), (0:3, 3:6), (3:6, 0:3), (3:6, 3:6)
_D00, _D01, _D10, _D11 = ([6 * i + i + off for i in range(3)] for off in (0, 3, 18, 21))


def cv_model(dt: float, accel_sigma_mps2: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of the constant-velocity model over dt: white-noise acceleration of ``accel_sigma_mps2``. (Each block is
    a multiple of I; its diagonal is set from the scalar product, the same operations in the same order as I x dt^4 /
    4 x s2, so the same bits.)"""
    F = np.eye(6)
    F.flat[_D01] = dt
    s2 = accel_sigma_mps2**2
    Q = np.zeros((6, 6))
    Q.flat[_D00] = dt**4 / 4 * s2
    Q.flat[_D01] = Q.flat[_D10] = dt**3 / 2 * s2
    Q.flat[_D11] = dt**2 * s2
    return F, Q


def _det(S: np.ndarray) -> float:
    """det(S), in Python floats for a 1-3 x 3 matrix."""
    if S.shape[0] > 3:
        return float(np.linalg.det(S))
    if S.shape[0] == 1:
        return float(S[0, 0])
    if S.shape[0] == 2:
        (a, b), (c, d) = S.tolist()
        return a * d - b * c
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    return a * (e * i - f * h) + b * (f * g - d * i) + c * (d * h - e * g)


def _hold_F() -> np.ndarray:
    F = np.eye(6)
    F[3:6, 3:6] = 0.0
    F.flags.writeable = False
    return F


_HOLD_F = _hold_F()  # the hold model: position kept, velocity zero (read-only: shared)


def _mix(w0: float, a: tuple, w1: float, b: tuple, D: np.ndarray) -> np.ndarray:
    """w0 (P_a + (x_a - x)(x_a - x)') + w1 (P_b + ...), x = w0 x_a + w1 x_b, w0 + w1 = 1: the moment-matched
    covariance of two Gaussians, as w0 P_a + w1 P_b + w0 w1 D with D = (x_a - x_b)(x_a - x_b)' (x_a - x = w1 (x_a -
    x_b), x_b - x = -w0 (x_a - x_b): one outer product for every mixture of the pair)."""
    P = w0 * a[1]
    P += w1 * b[1]
    P += (w0 * w1) * D
    return P


def _spread(a: tuple, b: tuple) -> np.ndarray:
    d = a[0] - b[0]
    return d @ d.T


def reset_position(kf: KalmanFilter, z, R) -> None:
    """The position set to z with covariance R, uncorrelated with the velocity (a reset to GNSS)."""
    kf.x[0:3, 0] = np.asarray(z, dtype=float)
    kf.P[0:3, 0:3] = np.asarray(R, dtype=float)
    kf.P[0:3, 3:6] = kf.P[3:6, 0:3] = 0.0


def reset_velocity(kf: KalmanFilter, v, var: float) -> None:
    """Each finite velocity component set to v with variance var, uncorrelated with the rest (a reset to GNSS)."""
    for i, vi in enumerate(v):
        if math.isfinite(vi):
            kf.x[3 + i, 0] = float(vi)
            kf.P[3 + i, :] = kf.P[:, 3 + i] = 0.0
            kf.P[3 + i, 3 + i] = var


class CvFilter:
    """The constant-velocity model alone (``kinematic_hold_cv`` off), with HoldCvFilter's interface."""

    def __init__(self, x0, P0, accel_sigma_mps2: float) -> None:
        self.accel_sigma_mps2 = float(accel_sigma_mps2)
        self.kf = KalmanFilter(dim_x=6, dim_z=3)
        self.kf.x, self.kf.P = x0, P0

    @property
    def x(self) -> np.ndarray:
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    def predict(self, dt: float) -> None:
        if dt > 0:
            self.kf.predict(*cv_model(dt, self.accel_sigma_mps2))

    def update(self, z: np.ndarray, R: np.ndarray, H: np.ndarray, evidence: bool = True) -> None:
        self.kf.update(z, R=R, H=H)  # one model: nothing to weigh the evidence against

    def reset_position(self, z, R) -> None:
        reset_position(self.kf, z, R)

    def reset_velocity(self, v, var: float) -> None:
        reset_velocity(self.kf, v, var)


class HoldCvFilter:
    """The kinematic filter as an IMM of hold and CV. ``x`` (6 x 1) and ``P`` are the mixture's; ``mu`` the mode
    probabilities (hold, CV)."""

    def __init__(self, x0, P0, accel_sigma_mps2: float, config: HoldCvConfig | None = None) -> None:
        self.config = config or HoldCvConfig()
        self.accel_sigma_mps2 = float(accel_sigma_mps2)
        self.models = [KalmanFilter(dim_x=6, dim_z=3), KalmanFilter(dim_x=6, dim_z=3)]
        x0 = np.asarray(x0, dtype=float).reshape(6, 1)
        P0 = np.asarray(P0, dtype=float)
        hold = self.models[HOLD]
        hold.x = x0.copy()
        hold.x[3:6, 0] = 0.0
        hold.P = P0.copy()
        hold.P[3:6, :] = 0.0
        hold.P[:, 3:6] = 0.0
        hold.P[3:6, 3:6] = np.eye(3) * 1e-4
        self.models[CV].x, self.models[CV].P = x0.copy(), P0.copy()
        self.mu = np.array([0.5, 0.5])
        self._combine()

    # ------------------------------------------------------------------ steps
    def predict(self, dt: float) -> None:
        """Mode interaction over dt, then each model's prediction."""
        if dt <= 0:
            return
        p = 1.0 - math.exp(-dt / self.config.dwell_s)
        M = np.array([[1.0 - p, p], [p, 1.0 - p]])  # M[i, j]: from model i to model j
        c = M.T @ self.mu
        a, b = ((m.x, m.P) for m in self.models)
        D = _spread(a, b)
        mu0, mu1 = self.mu.tolist()
        for j, m in enumerate(self.models):
            w0, w1 = M[0, j] * mu0 / c[j], M[1, j] * mu1 / c[j]
            m.x, m.P = w0 * a[0] + w1 * b[0], _mix(w0, a, w1, b, D)
        self.mu = c
        hold, cv = self.models
        # the hold model: position kept (its wander as noise), velocity zero
        x = hold.x.copy()
        x[3:6] = 0.0
        P = hold.P.copy()
        P[3:6] = 0.0
        P[:, 3:6] = 0.0
        P.flat[_D00] += (self.config.hold_speed_mps * dt) ** 2
        P.flat[_D11] += 1e-4
        hold.x, hold.P = x, P
        cv.predict(*cv_model(dt, self.accel_sigma_mps2))
        self._combine()

    def update(self, z: np.ndarray, R: np.ndarray, H: np.ndarray, evidence: bool = True) -> None:
        """Both models updated with z = H x + v, v ~ N(0, R); with ``evidence`` the mode probabilities too."""
        like = np.empty(2)
        for j, m in enumerate(self.models):
            if evidence:  # (a pseudo-measurement's likelihood is not used)
                y = z - H @ m.x
                S = H @ m.P @ H.T + R
                Si = small_inverse(S)
                det = _det(S)
                like[j] = math.exp(-0.5 * (y.T @ Si @ y).item()) / math.sqrt(max((2 * math.pi) ** S.shape[0] * det, 1e-300))
            m.update(z, R=R, H=H)
        if evidence:
            mu = self.mu * like
            s = mu.sum()
            if s > 0 and math.isfinite(s):
                self.mu = mu / s
            lo = self.config.min_prob
            self.mu = np.clip(self.mu, lo, 1.0 - lo)
            self.mu /= self.mu.sum()
        self._combine()

    def reset_position(self, z, R) -> None:
        """Both models' position set to z with covariance R, uncorrelated with the velocity (a reset to GNSS)."""
        for m in self.models:
            reset_position(m, z, R)
        self._combine()

    def reset_velocity(self, v, var: float) -> None:
        """The CV model's velocity set to the fix's (the hold model's stays zero)."""
        reset_velocity(self.models[CV], v, var)
        self._combine()

    def _combine(self) -> None:
        a, b = ((m.x, m.P) for m in self.models)
        mu0, mu1 = self.mu.tolist()
        self.x = mu0 * a[0] + mu1 * b[0]
        self.P = _mix(mu0, a, mu1, b, _spread(a, b))
