"""companion.nav.linalg against np.linalg: the same bits, and the same errors."""

import numpy as np
import pytest

from companion.nav.linalg import inverse, solve


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
