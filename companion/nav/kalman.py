"""A linear Kalman filter: predict and the Joseph-form update, nothing else.

The navigator's filters need only ``x``, ``P``, ``predict(F, Q)`` and ``update(z, R, H)``. This is the arithmetic
of filterpy's ``KalmanFilter`` (the reference the suite checks it against, to rounding), without its import of
``scipy.stats`` (about 1 s of the live process's start-up). The innovation covariance (at most 3 x 3 here) is
inverted in closed form (companion.nav.linalg.small_inverse). When H picks consecutive states (``cols``: H is the
identity's rows ``cols``, as for a position, a velocity or an attitude), P H' is a slice of P and the Joseph form
``(I - K H) P (I - K H)' + K R K'`` is ``A - (A H' - K R) K'`` with ``A = P - K (H P)``: O(n^2 m) instead of
O(n^3), and fewer numpy calls (tests/nav/test_kalman.py: equal to the dense form to 1e-12; what it bought:
docs/decisions/0015-filter-update-numpy-calls.md).
"""

from __future__ import annotations

import numpy as np

from companion.nav.linalg import small_inverse

_EYES: dict[int, np.ndarray] = {}


def _eye(n: int) -> np.ndarray:
    I = _EYES.get(n)
    if I is None:
        I = _EYES[n] = np.eye(n)
        I.flags.writeable = False
    return I


def joseph(P: np.ndarray, K: np.ndarray, H: np.ndarray, R: np.ndarray, cols: slice | None = None) -> np.ndarray:
    """(I - K H) P (I - K H)' + K R K' (symmetric and positive under rounding for any gain K); ``cols``: H is the
    identity's rows ``cols`` (then H is not read)."""
    if cols is not None:
        A = P - K @ P[cols]  # (I - K H) P
        return A - (A[:, cols] - K @ R) @ K.T
    I_KH = _eye(P.shape[0]) - K @ H
    return I_KH @ P @ I_KH.T + K @ R @ K.T


class KalmanFilter:
    """State ``x`` (dim_x x 1) and covariance ``P``; transition and noise given at each step."""

    __slots__ = ("dim_x", "dim_z", "x", "P")

    def __init__(self, dim_x: int, dim_z: int) -> None:
        if dim_x < 1 or dim_z < 1:
            raise ValueError("dim_x and dim_z must be >= 1")
        self.dim_x, self.dim_z = dim_x, dim_z
        self.x = np.zeros((dim_x, 1))
        self.P = np.eye(dim_x)

    def predict(self, F: np.ndarray, Q: np.ndarray) -> None:
        """x = F x; P = F P F' + Q."""
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q

    def update(self, z: np.ndarray, R: np.ndarray, H: np.ndarray, gain_rows: np.ndarray | None = None) -> None:
        """z (m x 1) measured as H x + v, v ~ N(0, R): gain K = P H' S^-1, S = H P H' + R; Joseph-form covariance
        P = (I - K H) P (I - K H)' + K R K' (stays symmetric and positive under rounding, and is the covariance of
        any gain). ``gain_rows`` (boolean, dim_x): only these states are corrected, the others' gain rows are zero
        (a consider or Schmidt-Kalman update: they keep their estimates, their covariance with the corrected ones is
        carried by the Joseph form)."""
        y = z - H @ self.x
        PHT = self.P @ H.T
        K = PHT @ small_inverse(H @ PHT + R)
        if gain_rows is not None:
            K = K * gain_rows.reshape(-1, 1)
        self.x = self.x + K @ y
        self.P = joseph(self.P, K, H, R)

    def update_innovation(self, y: np.ndarray, R: np.ndarray, H: np.ndarray, PHT: np.ndarray, S: np.ndarray,
                          gain_rows: np.ndarray | None = None, cols: slice | None = None,
                          S_inv: np.ndarray | None = None) -> np.ndarray:
        """:meth:`update` given what the caller already has: the innovation ``y = z - H x`` (flat), ``PHT = P H'`` and
        ``S = H P H' + R`` (a gate computed them; ``S_inv`` its inverse, if computed), ``cols`` (see :func:`joseph`);
        the same Joseph-form algebra. Returns the correction ``K y`` (flat)."""
        K = PHT @ (small_inverse(S) if S_inv is None else S_inv)
        if gain_rows is not None:
            K = K * gain_rows.reshape(-1, 1)
        dx = K @ y
        self.x = self.x + dx.reshape(-1, 1)
        self.P = joseph(self.P, K, H, R, cols)
        return dx
