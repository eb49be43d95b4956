"""Rotor drag: what a multicopter's horizontal accelerometers say about its velocity through the air.

A multicopter's thrust is along its body z axis, so the horizontal body components of the specific force carry no
gravity and no manoeuvre: they are the aerodynamic drag of the rotors (blade flapping and induced drag), linear in
the air-relative velocity (Leishman, Macdonald, Beard, McLain 2014, "Quadrotors and accelerometers: state estimation
with an improved dynamic model", IEEE Control Systems 34(1), eqs. 3-5):

    f_xy = -k (C^T (v - w))_xy + b

with ``C`` the body-to-NED attitude, ``v`` the NED velocity, ``w`` the (horizontal) wind, ``k`` the drag coefficient
per second and ``b`` the accelerometers' horizontal bias. This is a velocity measurement that does not depend on the
tilt: a tilt error, which makes a free INS drift t^2, changes nothing in it. ArduPilot's EKF3 (EK3_DRAG_*) and PX4's
EKF2 fuse the same model for wind estimation and dead reckoning without GNSS.

:class:`RotorDrag` learns ``theta = (k, k w_n, k w_e, b_x, b_y)`` by exponentially forgotten least squares (the model
is linear in theta) from interval means while GNSS aids the navigator and the vehicle moves (a vehicle on the
ground is not held by its rotors: its accelerometers read the slope it stands on), and during a blockage hands out
one :class:`companion.nav.measurements.DragMeasurement` per interval. The accelerometer is averaged over the interval
(``interval_s``; at 50 Hz a vibrating airframe's sample noise is ~1 m/s^2); the INS velocity and attitude are
sampled at the navigator's output ticks. Its noise is the fit's residual scatter (with the parameter uncertainty)
times ``sigma_scale`` (the residuals are correlated over seconds). Pure: no I/O, no clocks, O(1) per sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.nav.measurements import DragMeasurement

_PRIOR_INFO = np.eye(5) * 1e-4  # a weak prior on theta (sigma 100) keeps the fit defined before it is observable


@dataclass(frozen=True)
class DragConfig:
    interval_s: float = 1.0  # accelerometer mean and one learning row pair / one measurement per interval
    tau_s: float = 300.0  # forgetting of the fit
    learn_min_speed_mps: float = 1.0  # rows are learnt only while the aided INS moves at least this fast
    learn_max_fix_age_s: float = 1.5  # ... and a GNSS fix was accepted within this
    min_rows: float = 40.0  # forgotten number of rows (two per interval) before the model is used
    min_k_per_s: float = 0.05  # a smaller drag coefficient says nothing (or the vehicle is not a multicopter)
    max_rel_sigma_k: float = 0.2  # the coefficient's standard error must be within this fraction of it
    sigma_scale: float = 2.0  # measurement sigma = residual scatter x this
    min_fix_age_s: float = 1.5  # fused only once no GNSS fix has come for this long
    # the model's lack of fit at the current air speed (SpeedMisfit): bins of misfit_bin_mps; in a bin with fewer
    # than misfit_min_rows forgotten intervals learnt the model is an extrapolation, its error taken as its whole claim
    # (docs/decisions/0001, "What ended the 60 s takeovers")
    misfit_bin_mps: float = 1.0
    misfit_min_rows: float = 5.0

    def __post_init__(self) -> None:
        if not (self.interval_s > 0 and self.tau_s > 0 and self.min_rows >= 5 and self.min_k_per_s > 0
                and self.max_rel_sigma_k > 0 and self.sigma_scale > 0 and self.misfit_bin_mps > 0
                and self.misfit_min_rows >= 0):
            raise ValueError("DragConfig: need interval_s, tau_s, min_k_per_s, max_rel_sigma_k, sigma_scale > 0 and "
                             "min_rows >= 5")


@dataclass(frozen=True)
class DragInterval:
    """One interval's means: accelerometer x, y (FRD), the drag regressors of the model and the ones at its end."""

    t_s: float
    f_xy: tuple[float, float]
    rows: np.ndarray  # (2, 5): the model's regressors, interval mean
    rows_end: np.ndarray  # (2, 5): at the end of the interval (the state the measurement is compared with)
    air_speed_mps: float = math.nan  # horizontal body air speed, interval mean ...
    air_speed_end_mps: float = math.nan  # ... and at its end


class SpeedMisfit:
    """Where a fitted drag model is wrong: its mean residual per band of air speed.

    The model is linear in the air velocity; a real airframe's drag is not (a bluff-body term grows with its square,
    as EKF3's EK3_DRAG_BCOEF_* beside EK3_DRAG_MCOEF). A fit learnt mostly at cruise is then wrong at a hover by a
    constant offset, and fused once a second that offset reads as a velocity the filter believes to centimetres per
    second. Per band the forgotten sums of the regressors and the accelerometer give the band's mean residual under
    the current fit exactly; the measurement's noise takes its square, and in a band the fit has not seen the square
    of the model's whole prediction (an extrapolation may be wrong by all it claims)."""

    def __init__(self, bin_mps: float, n_bins: int = 60) -> None:
        self.bin_mps = bin_mps
        self.rows = np.zeros((n_bins, 2, 5))
        self.f = np.zeros((n_bins, 2))
        self.n = np.zeros(n_bins)

    def band(self, air_speed_mps: float) -> int | None:
        if not math.isfinite(air_speed_mps):
            return None
        return min(int(air_speed_mps / self.bin_mps), len(self.n) - 1)

    def learn(self, lam: float, air_speed_mps: float, rows: np.ndarray, f_xy) -> None:
        self.rows *= lam
        self.f *= lam
        self.n *= lam
        b = self.band(air_speed_mps)
        if b is not None:
            self.rows[b] += rows
            self.f[b] += f_xy
            self.n[b] += 1.0

    def residual(self, air_speed_mps: float, theta: np.ndarray) -> tuple[float, np.ndarray]:
        """(forgotten intervals learnt in the band, the band's mean residual per axis under ``theta``)."""
        b = self.band(air_speed_mps)
        if b is None or self.n[b] <= 0:
            return 0.0, np.zeros(2)
        return float(self.n[b]), (self.f[b] - self.rows[b] @ theta) / self.n[b]


def drag_rows(C: np.ndarray, v_ned) -> np.ndarray:
    """The regressors of f_x and f_y for theta = (k, k w_n, k w_e, b_x, b_y)."""
    vb = C.T @ np.asarray(v_ned, dtype=float)
    return np.array([[-vb[0], C[0, 0], C[1, 0], 1.0, 0.0],
                     [-vb[1], C[0, 1], C[1, 1], 0.0, 1.0]])


class RotorDrag:
    """Feed :meth:`add_accel` with every IMU sample and :meth:`tick` at every output tick (INS mode)."""

    def __init__(self, config: DragConfig | None = None) -> None:
        self.config = config or DragConfig()
        self._fx = self._fy = 0.0
        self._nf = 0
        self._rows = np.zeros((2, 5))
        self._nr = 0
        self._t0: float | None = None
        # forgotten least squares per axis: information matrix, vector and sum of squares of the measurements
        self._Ax = np.zeros((5, 5))
        self._Ay = np.zeros((5, 5))
        self._rx = np.zeros(5)
        self._ry = np.zeros(5)
        self._zz = np.zeros(2)
        self._rows_w = 0.0  # forgotten number of rows learnt
        self.theta: np.ndarray | None = None
        self.misfit = SpeedMisfit(self.config.misfit_bin_mps)
        self._speed_sum = 0.0

    def add_accel(self, accel_frd_mps2) -> None:
        self._fx += accel_frd_mps2[0]
        self._fy += accel_frd_mps2[1]
        self._nf += 1

    def reset(self) -> None:
        """Drop the running interval (after a gap in the stream)."""
        self._fx = self._fy = 0.0
        self._nf = self._nr = 0
        self._rows = np.zeros((2, 5))
        self._speed_sum = 0.0
        self._t0 = None

    def tick(self, t: float, C: np.ndarray, v_ned) -> DragInterval | None:
        """Sample the INS at an output tick; returns the interval when one is complete."""
        rows = drag_rows(C, v_ned)
        speed = self._air_speed(C, v_ned)
        if self._t0 is None or t - self._t0 > 2.0 * self.config.interval_s:  # start, or ticks missed: restart
            self.reset()
            self._t0 = t
            return None
        self._rows += rows
        self._speed_sum += speed
        self._nr += 1
        if t - self._t0 < self.config.interval_s - 1e-9:
            return None
        out = None
        if self._nf > 0:
            out = DragInterval(t, (self._fx / self._nf, self._fy / self._nf), self._rows / self._nr, rows,
                               self._speed_sum / self._nr, speed)
        self._t0 = t
        self._fx = self._fy = 0.0
        self._nf = self._nr = 0
        self._rows = np.zeros((2, 5))
        self._speed_sum = 0.0
        return out

    def _air_speed(self, C: np.ndarray, v_ned) -> float:
        """Horizontal body air speed with the fit's wind (none before the coefficient is positive)."""
        th = self.theta
        w = (th[1] / th[0], th[2] / th[0]) if th is not None and th[0] >= self.config.min_k_per_s else (0.0, 0.0)
        va = C.T @ (np.asarray(v_ned, dtype=float) - np.array([w[0], w[1], 0.0]))
        return float(math.hypot(va[0], va[1]))

    def learn(self, iv: DragInterval) -> None:
        """One interval while GNSS aids: a row pair of the forgotten least-squares fit."""
        lam = math.exp(-self.config.interval_s / self.config.tau_s)
        fx, fy = iv.f_xy
        px, py = iv.rows[0], iv.rows[1]
        self._Ax = lam * self._Ax + np.outer(px, px)
        self._Ay = lam * self._Ay + np.outer(py, py)
        self._rx = lam * self._rx + px * fx
        self._ry = lam * self._ry + py * fy
        self._zz = lam * self._zz + np.array([fx * fx, fy * fy])
        self._rows_w = lam * self._rows_w + 2.0
        self.misfit.learn(lam, iv.air_speed_mps, iv.rows, iv.f_xy)
        self.theta = np.linalg.solve(self._Ax + self._Ay + _PRIOR_INFO, self._rx + self._ry)

    def residual_var(self) -> np.ndarray:
        """Weighted residual variance of the current fit per axis (x, y)."""
        th = self.theta
        sx = self._zz[0] - 2.0 * th @ self._rx + th @ self._Ax @ th
        sy = self._zz[1] - 2.0 * th @ self._ry + th @ self._Ay @ th
        dof = max(self._rows_w / 2.0 - 2.5, 1.0)  # 5 parameters over both axes
        return np.maximum(np.array([sx, sy]) / dof, 1e-6)

    def model(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(theta, its covariance, residual variance per axis) once the fit is usable, else None."""
        c = self.config
        th = self.theta
        if th is None or self._rows_w < c.min_rows:
            return None
        s2 = self.residual_var()
        cov = np.linalg.inv(self._Ax / s2[0] + self._Ay / s2[1] + _PRIOR_INFO)
        k = th[0]
        if k < c.min_k_per_s or math.sqrt(max(cov[0, 0], 0.0)) > c.max_rel_sigma_k * k:
            return None
        return th, cov, s2

    def measurement(self, t: float, C: np.ndarray, v_ned, fix_age_s: float | None) -> DragMeasurement | None:
        """At an output tick (INS mode), with the INS attitude and velocity and the age of the last GNSS fix: learn
        the model while GNSS aids and the vehicle moves; once no fix has come for ``min_fix_age_s``, the interval's
        measurement for the INS filter."""
        iv = self.tick(t, C, v_ned)
        if iv is None or fix_age_s is None:
            return None
        c = self.config
        if fix_age_s <= c.learn_max_fix_age_s:
            if math.hypot(v_ned[0], v_ned[1]) >= c.learn_min_speed_mps:
                self.learn(iv)
            return None
        model = self.model() if fix_age_s >= c.min_fix_age_s else None
        if model is None:
            return None
        th, cov, s2 = model
        k = float(th[0])
        n_band, bias = self.misfit.residual(iv.air_speed_end_mps, th)
        if n_band < c.misfit_min_rows:
            # an air speed the fit has not seen: the model is an extrapolation there, its error as large as its claim
            bias = iv.rows_end @ th
        R = np.diag(s2) * c.sigma_scale**2 + iv.rows_end @ cov @ iv.rows_end.T + np.diag(bias**2)
        # the interval mean carried to its end with the model (the innovation is that of the interval means)
        z = np.asarray(iv.f_xy) + (iv.rows_end - iv.rows) @ th
        return DragMeasurement(t, "rotor_drag", (float(z[0]), float(z[1])), k, (float(th[1] / k), float(th[2] / k)),
                               (float(th[3]), float(th[4])), (float(R[0, 0]), float(R[0, 1]), float(R[1, 1])))
