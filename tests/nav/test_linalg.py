"""companion.nav.linalg against np.linalg: the same bits (the closed-form small inverse: to rounding), and the same
errors."""

import numpy as np
import pytest

from companion.nav.linalg import inverse, small_inverse, solve


def test_same_bits_as_numpy_over_random_covariances():
    rng = np.random.default_rng(3)
    for n in (2, 3, 6, 15):
        for _ in range(200):
            A = rng.standard_normal((n, n))
            S = A @ A.T + rng.uniform(1e-6, 1.0) * np.eye(n)
            y = rng.standard_normal(n)
            assert np.array_equal(inverse(S), np.linalg.inv(S))
            assert np.array_equal(solve(S, y), np.linalg.solve(S, y))


def test_singular_raises_like_numpy_and_other_types_take_numpys_path():
    with pytest.raises(np.linalg.LinAlgError):
        inverse(np.zeros((3, 3)))
    with pytest.raises(np.linalg.LinAlgError):
        solve(np.zeros((3, 3)), np.ones(3))
    S = np.array([[2, 1], [1, 3]])  # integers: promoted by np.linalg itself
    assert np.array_equal(inverse(S), np.linalg.inv(S)) and np.array_equal(solve(S, np.ones(2)), np.linalg.solve(S, np.ones(2)))


def test_small_inverse_equals_numpys_to_rounding():
    """The adjugate inverse of 1-3 x 3 matrices (the measurement updates' S) against np.linalg.inv, on covariances
    with a condition number up to 1e10 (the attitude's 1e6 rad^2 yaw beside 1e-4 rad^2 tilt): the error is rounding
    times the condition number, as LAPACK's; a singular one raises; larger ones are np.linalg.inv's."""
    rng = np.random.default_rng(5)
    for n in (1, 2, 3):
        for i in range(500):
            A = rng.standard_normal((n, n))
            d = rng.uniform(1e-4, 1.0, n)
            if i % 2 and n > 1:
                d[-1] = 1e6
            S = A @ A.T * rng.uniform(1e-3, 1.0) + np.diag(d)
            ref = np.linalg.inv(S)
            tol = 1e-15 * np.linalg.cond(S) * 8
            np.testing.assert_allclose(small_inverse(S), ref, rtol=tol, atol=tol * np.abs(ref).max())
    with pytest.raises(np.linalg.LinAlgError):
        small_inverse(np.zeros((3, 3)))
    with pytest.raises(np.linalg.LinAlgError):
        small_inverse(np.array([[1.0, 2.0], [2.0, 4.0]]))
    S = np.eye(6) * 2.0
    assert np.array_equal(small_inverse(S), np.linalg.inv(S))
