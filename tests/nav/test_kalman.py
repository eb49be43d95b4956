"""The navigator's linear Kalman filter: known posteriors, filterpy's KalmanFilter to rounding, and the Joseph form
on a selection H (P H' a slice of P) equal to the dense one."""

import numpy as np
import pytest

from companion.nav.kalman import KalmanFilter, joseph
from companion.nav.linalg import small_inverse


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


def test_equal_to_filterpy_over_a_random_run():
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
    # (the innovation covariance is inverted in closed form, filterpy calls LAPACK: equal to rounding)
    np.testing.assert_allclose(ours.x, ref.x, rtol=1e-12, atol=1e-12 * np.abs(ref.x).max())
    np.testing.assert_allclose(ours.P, ref.P, rtol=1e-12, atol=1e-12 * np.abs(ref.P).max())
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


def _dense_update(P, y, H, R, gain_rows=None):
    """The textbook update, every matrix dense: K = P H' (H P H' + R)^-1, Joseph form."""
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    if gain_rows is not None:
        K = K * gain_rows.reshape(-1, 1)
    I_KH = np.eye(P.shape[0]) - K @ H
    return K @ y, I_KH @ P @ I_KH.T + K @ R @ K.T


@pytest.mark.parametrize("rows, first", [(3, 0), (2, 0), (3, 3), (2, 3), (3, 6), (1, 2)])
def test_the_update_on_a_selection_equals_the_dense_update(rows, first):
    """update_innovation with ``cols`` (H the identity's rows first..first+rows: P H' a slice, the Joseph form in
    O(n^2 m)) against the dense algebra on random covariances, noises (the attitude's 1e6 rad^2 yaw among them) and
    restricted gains; and chained 300 times, as the filter runs it, against the dense chain."""
    rng = np.random.default_rng(11 + rows + first)
    cols = slice(first, first + rows)
    H = np.zeros((rows, 15))
    H[:, cols] = np.eye(rows)
    P_fast = P_dense = np.eye(15)
    for i in range(300):
        A = rng.standard_normal((15, 15))
        P0 = A @ A.T * rng.uniform(0.01, 10.0) + np.diag(rng.uniform(1e-6, 1.0, 15))
        r = rng.uniform(1e-4, 4.0, rows)
        if rows == 3 and i % 3 == 0:
            r[2] = 1e6
        B = rng.standard_normal((rows, rows)) * 0.1
        R = np.diag(r) + B @ B.T
        y = rng.standard_normal(rows)
        gain_rows = (rng.uniform(size=15) < 0.5) if i % 4 == 1 else None
        kf = KalmanFilter(dim_x=15, dim_z=rows)
        kf.P = P0.copy()
        dx = kf.update_innovation(y, R, H, P0[:, cols], P0[cols, cols] + R, gain_rows, cols)
        dx_ref, P_ref = _dense_update(P0, y, H, R, gain_rows)
        np.testing.assert_allclose(dx, dx_ref, rtol=1e-12, atol=1e-12 * np.abs(dx_ref).max())
        np.testing.assert_allclose(kf.P, P_ref, rtol=1e-12, atol=1e-12 * np.abs(P_ref).max())
        np.testing.assert_allclose(kf.x.ravel(), dx_ref, rtol=1e-12, atol=1e-12 * np.abs(dx_ref).max())
        # the chain: predict with a random transition, update, 300 times
        F = np.eye(15) + 0.05 * rng.standard_normal((15, 15))
        Q = np.diag(rng.uniform(1e-6, 1e-2, 15))
        P_fast, P_dense = F @ P_fast @ F.T + Q, F @ P_dense @ F.T + Q
        K = P_fast[:, cols] @ small_inverse(P_fast[cols, cols] + R)
        P_fast = joseph(P_fast, K, H, R, cols)
        P_dense = _dense_update(P_dense, y, H, R)[1]
    np.testing.assert_allclose(P_fast, P_dense, rtol=1e-10, atol=1e-12 * np.abs(P_dense).max())
    assert np.all(np.linalg.eigvalsh(P_fast) > 0)
