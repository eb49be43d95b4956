"""Small dense linear algebra for the filters: the LAPACK calls np.linalg makes, without its Python wrapper.

For a 3x3 innovation covariance np.linalg.inv / solve spend two thirds of their time in argument checks, type
promotion and error-state set-up around one LAPACK call. These call the same gufuncs (numpy.linalg._umath_linalg),
so the results are the same bits; anything unusual (another dtype, a singular matrix, a numpy without that module)
goes to np.linalg itself, which raises as before. tests/nav/test_kalman.py checks the filter against filterpy bit for
bit; tests/nav/test_linalg.py these against np.linalg.
"""

from __future__ import annotations

import math

import numpy as np

try:
    from numpy.linalg._umath_linalg import inv as _inv, solve1 as _solve1
except ImportError:  # another numpy layout: the public functions
    _inv = _solve1 = None


def inverse(S: np.ndarray) -> np.ndarray:
    """np.linalg.inv(S)."""
    if _inv is not None and S.dtype == np.float64:
        with np.errstate(all="ignore"):  # (a singular S: no warning here, np.linalg.inv below raises)
            Si = _inv(S, signature="d->d")
        if np.isfinite(Si).all():
            return Si
    return np.linalg.inv(S)


def solve(S: np.ndarray, y: np.ndarray) -> np.ndarray:
    """np.linalg.solve(S, y) for a vector y."""
    if _solve1 is not None and S.dtype == np.float64 and y.dtype == np.float64 and y.ndim == 1:
        with np.errstate(all="ignore"):
            x = _solve1(S, y, signature="dd->d")
        if np.isfinite(x).all():
            return x
    return np.linalg.solve(S, y)


def small_inverse(S: np.ndarray) -> np.ndarray:
    """The inverse of a 1 x 1, 2 x 2 or 3 x 3 float matrix by its adjugate in Python floats (a third of the time of
    one LAPACK call with its error handling, for the measurement updates' innovation covariances); other sizes, a
    singular or non-finite one go to :func:`inverse` (which raises as np.linalg.inv does). Equal to np.linalg.inv to
    rounding (tests/nav/test_linalg.py)."""
    n = S.shape[0]
    if n == 3:
        (a, b, c), (d, e, f), (g, h, i) = S.tolist()
        A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
        det = a * A + b * B + c * C
        if det != 0.0 and math.isfinite(det):
            r = 1.0 / det
            return np.array([[A * r, (c * h - b * i) * r, (b * f - c * e) * r],
                             [B * r, (a * i - c * g) * r, (c * d - a * f) * r],
                             [C * r, (b * g - a * h) * r, (a * e - b * d) * r]])
    elif n == 2:
        (a, b), (c, d) = S.tolist()
        det = a * d - b * c
        if det != 0.0 and math.isfinite(det):
            r = 1.0 / det
            return np.array([[d * r, -b * r], [-c * r, a * r]])
    elif n == 1:
        s = float(S[0, 0])
        if s != 0.0 and math.isfinite(s):
            return np.array([[1.0 / s]])
    return inverse(S)
