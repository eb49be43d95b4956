"""The navigator's linear Kalman filter: known posteriors, and filterpy's KalmanFilter bit for bit."""

import numpy as np
import pytest

from companion.nav.kalman import KalmanFilter


def test_scalar_update_matches_the_closed_form():
    kf = KalmanFilter(dim_x=1, dim_z=1)
    kf.x[:] = 2.0
    kf.P[:] = 4.0
    kf.update(np.array([[5.0]]), R=np.array([[1.0]]), H=np.eye(1))
    gain = 4.0 / (4.0 + 1.0)
    assert kf.x[0, 0] == pytest.approx(2.0 + gain * 3.0, rel=1e-15)
    assert kf.P[0, 0] == pytest.approx(4.0 * 1.0 / 5.0, rel=1e-15)


def test_predict_propagates_a_constant_velocity_state():
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.x = np.array([[1.0], [2.0]])
    kf.P = np.diag([1.0, 0.5])
    F = np.array([[1.0, 3.0], [0.0, 1.0]])
    kf.predict(F=F, Q=np.diag([0.1, 0.2]))
    assert kf.x.ravel().tolist() == [7.0, 2.0]
    np.testing.assert_allclose(kf.P, [[1.0 + 9 * 0.5 + 0.1, 1.5], [1.5, 0.7]], rtol=1e-15)


def test_bit_identical_to_filterpy_over_a_random_run():
    fp = pytest.importorskip("filterpy.kalman")
    rng = np.random.default_rng(7)
    ours, ref = KalmanFilter(dim_x=15, dim_z=3), fp.KalmanFilter(dim_x=15, dim_z=3)
    P0 = np.diag(rng.uniform(0.1, 10.0, 15))
    ours.P, ref.P = P0.copy(), P0.copy()
    for _ in range(200):
        F = np.eye(15) + 0.01 * rng.standard_normal((15, 15))
        Q = np.diag(rng.uniform(1e-6, 1e-2, 15))
        ours.predict(F=F, Q=Q)
        ref.predict(F=F, Q=Q)
        H = np.zeros((3, 15))
        H[:, rng.choice(15, 3, replace=False)] = np.eye(3)
        R = np.diag(rng.uniform(0.1, 4.0, 3))
        z = rng.standard_normal((3, 1))
        ours.update(z, R=R, H=H)
        ref.update(z, R=R, H=H)
    assert np.array_equal(ours.x, ref.x) and np.array_equal(ours.P, ref.P)
    assert np.allclose(ours.P, ours.P.T) and np.all(np.linalg.eigvalsh(ours.P) > 0)


def test_rejects_empty_dimensions():
    with pytest.raises(ValueError):
        KalmanFilter(dim_x=0, dim_z=1)


def test_a_singular_innovation_covariance_still_raises():
    kf = KalmanFilter(dim_x=2, dim_z=2)
    kf.P = np.zeros((2, 2))
    with pytest.raises(np.linalg.LinAlgError):
        kf.update(np.ones((2, 1)), R=np.zeros((2, 2)), H=np.eye(2))


def test_a_restricted_gain_corrects_only_its_states_and_keeps_an_honest_covariance():
    """gain_rows (a Schmidt update): the other states keep their estimates, and P is the covariance of the error
    the restricted gain leaves (checked on 40000 draws from the prior)."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(4, 4))
    P0 = A @ A.T + np.eye(4)  # position-velocity-like correlations
    H = np.array([[1.0, 0.0, 0.0, 0.0]])
    R = np.array([[0.5]])
    rows = np.array([True, False, True, False])
    kf = KalmanFilter(dim_x=4, dim_z=1)
    kf.P = P0.copy()
    kf.update(np.array([[2.0]]), R=R, H=H, gain_rows=rows)
    assert kf.x[1, 0] == 0.0 and kf.x[3, 0] == 0.0 and kf.x[0, 0] != 0.0 and kf.x[2, 0] != 0.0
    # the same gain applied to many truths drawn from the prior: the error covariance is kf.P
    K = (P0 @ H.T / (H @ P0 @ H.T + R)[0, 0]) * rows.reshape(-1, 1)
    truth = rng.multivariate_normal(np.zeros(4), P0, size=40000)
    z = truth @ H.T + rng.normal(0.0, np.sqrt(R[0, 0]), size=(40000, 1))
    err = truth - z @ K.T
    np.testing.assert_allclose(np.cov(err.T), kf.P, rtol=0.05, atol=0.02 * np.abs(P0).max())
    # every row allowed: the ordinary update, bit for bit
    a, b = KalmanFilter(dim_x=4, dim_z=1), KalmanFilter(dim_x=4, dim_z=1)
    a.P, b.P = P0.copy(), P0.copy()
    a.update(np.array([[2.0]]), R=R, H=H)
    b.update(np.array([[2.0]]), R=R, H=H, gain_rows=np.ones(4, dtype=bool))
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
