"""Small dense linear algebra for the filters: the LAPACK calls np.linalg makes, without its Python wrapper.

For a 3x3 innovation covariance np.linalg.inv / solve spend two thirds of their time in argument checks, type
promotion and error-state set-up around one LAPACK call. These call the same gufuncs (numpy.linalg._umath_linalg),
so the results are the same bits; anything unusual (another dtype, a singular matrix, a numpy without that module)
goes to np.linalg itself, which raises as before. tests/nav/test_kalman.py checks the filter against filterpy bit for
bit; tests/nav/test_linalg.py these against np.linalg.
"""

from __future__ import annotations

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
