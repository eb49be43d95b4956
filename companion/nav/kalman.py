"""A linear Kalman filter: predict and the Joseph-form update, nothing else.

The navigator's filters need only ``x``, ``P``, ``predict(F, Q)`` and ``update(z, R, H)``. This is the arithmetic
of filterpy's ``KalmanFilter`` (the reference the suite checks it against, operation for operation, so a replay
gives the same bytes), without its import of ``scipy.stats`` (about 1 s of the live process's start-up).
"""

from __future__ import annotations

import numpy as np

from companion.nav.linalg import inverse


class KalmanFilter:
    """State ``x`` (dim_x x 1) and covariance ``P``; transition and noise given at each step."""

    __slots__ = ("dim_x", "dim_z", "x", "P", "_I")

    def __init__(self, dim_x: int, dim_z: int) -> None:
        if dim_x < 1 or dim_z < 1:
            raise ValueError("dim_x and dim_z must be >= 1")
        self.dim_x, self.dim_z = dim_x, dim_z
        self.x = np.zeros((dim_x, 1))
        self.P = np.eye(dim_x)
        self._I = np.eye(dim_x)

    def predict(self, F: np.ndarray, Q: np.ndarray) -> None:
        """x = F x; P = F P F' + Q."""
        self.x = np.dot(F, self.x)
        self.P = np.dot(np.dot(F, self.P), F.T) + Q

    def update(self, z: np.ndarray, R: np.ndarray, H: np.ndarray, gain_rows: np.ndarray | None = None) -> None:
        """z (m x 1) measured as H x + v, v ~ N(0, R): gain K = P H' S^-1, S = H P H' + R; Joseph-form covariance
        P = (I - K H) P (I - K H)' + K R K' (stays symmetric and positive under rounding, and is the covariance of
        any gain). ``gain_rows`` (boolean, dim_x): only these states are corrected, the others' gain rows are zero
        (a consider or Schmidt-Kalman update: they keep their estimates, their covariance with the corrected ones is
        carried by the Joseph form)."""
        y = z - np.dot(H, self.x)
        PHT = np.dot(self.P, H.T)
        S = np.dot(H, PHT) + R
        K = np.dot(PHT, inverse(S))
        if gain_rows is not None:
            K = K * gain_rows.reshape(-1, 1)
        self.x = self.x + np.dot(K, y)
        I_KH = self._I - np.dot(K, H)
        self.P = np.dot(np.dot(I_KH, self.P), I_KH.T) + np.dot(np.dot(K, R), K.T)

    def update_innovation(self, y: np.ndarray, R: np.ndarray, H: np.ndarray, PHT: np.ndarray, S: np.ndarray,
                          gain_rows: np.ndarray | None = None) -> None:
        """:meth:`update` given what the caller already has: the innovation ``y = z - H x`` (flat), ``PHT = P H'`` and
        ``S = H P H' + R`` (a gate computed them); the same Joseph-form algebra."""
        K = np.dot(PHT, inverse(S))
        if gain_rows is not None:
            K = K * gain_rows.reshape(-1, 1)
        self.x = self.x + np.dot(K, y).reshape(-1, 1)
        I_KH = self._I - np.dot(K, H)
        self.P = np.dot(np.dot(I_KH, self.P), I_KH.T) + np.dot(np.dot(K, R), K.T)
