"""The jump guard (companion.gravity.jump_guard): quiet on a consistent filter, a jump beyond the stated covariance
(at once or over many readings) added to what is stated, bounded, cleared by GNSS."""

from __future__ import annotations

import numpy as np
import pytest

from companion.gravity.jump_guard import CHI2_2_99, JumpGuard


def consistent_filter(seed: int, n: int = 3600, r_m: float = 2000.0, q_mps_rts: float = 0.1):
    """A Kalman filter that is right about itself: a 2-D position error with a velocity error that walks, its position
    measured once a second with noise r_m. Yields (t, estimated error, P_pos, velocity, P_vel) after each update."""
    rng = np.random.default_rng(seed)
    F = np.eye(4)
    F[0, 2] = F[1, 3] = 1.0
    Q = np.zeros((4, 4))
    Q[2:, 2:] = np.eye(2) * q_mps_rts**2
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    R = np.eye(2) * r_m**2
    P = np.diag([3000.0**2, 3000.0**2, 1.0, 1.0])
    x_true = rng.multivariate_normal(np.zeros(4), P)
    x = np.zeros(4)
    for k in range(n):
        x_true = F @ x_true + np.concatenate([np.zeros(2), rng.normal(0.0, q_mps_rts, 2)])
        x, P = F @ x, F @ P @ F.T + Q
        z = H @ x_true + rng.normal(0.0, r_m, 2)
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ (z - H @ x)
        P = (np.eye(4) - K @ H) @ P
        yield float(k + 1), x[:2].copy(), P[:2, :2].copy(), x[2:].copy(), P[2:, 2:].copy()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_quiet_on_a_consistent_filter(seed):
    g = JumpGuard(vel_walk_mps_rts=0.1)  # the filter's own process noise
    fired = [g.observe(*est) for est in consistent_filter(seed)]
    assert sum(j is not None for j in fired) == 0
    assert np.all(g.cov_ne_m2 == 0.0)


def steady(t0: float, n: int, m=(0.0, 0.0), sigma_m: float = 1600.0, step_ne_m=(0.0, 0.0)):
    """n estimates a second apart, each stating sigma_m per axis and no velocity error, moving by step_ne_m a second."""
    for k in range(n):
        yield t0 + k, np.asarray(m, float) + k * np.asarray(step_ne_m, float), np.eye(2) * sigma_m**2, np.zeros(2), \
            np.eye(2) * 0.01


def test_a_jump_at_once_is_added_to_what_is_stated():
    g = JumpGuard()
    for est in steady(0.0, 60):
        assert g.observe(*est) is None
    j = g.observe(60.0, np.array([10_000.0, 0.0]), np.eye(2) * 1600.0**2, np.zeros(2), np.eye(2) * 0.01)
    assert j is not None and j.shift_m == pytest.approx(10_000.0) and j.d2 > CHI2_2_99
    assert np.sqrt(np.trace(g.cov_ne_m2)) == pytest.approx(10_000.0)
    # the shift counts once: the estimates after it stay put and add nothing
    for est in steady(61.0, 120, m=(10_000.0, 0.0)):
        assert g.observe(*est) is None
    assert np.sqrt(np.trace(g.cov_ne_m2)) == pytest.approx(10_000.0)


def test_a_jump_over_many_readings_is_seen_over_the_window():
    g = JumpGuard()
    list(map(lambda e: g.observe(*e), steady(0.0, 60)))
    # 10 km in 100 s: 100 m a second, each step a sixteenth of the stated sigma
    fired = [g.observe(*e) for e in steady(60.0, 101, step_ne_m=(0.0, 100.0))]
    assert any(j is not None for j in fired)
    assert np.sqrt(np.trace(g.cov_ne_m2)) > 4000.0  # the part of the slide the test saw before it fired
    quiet = JumpGuard(window_s=0.0)  # the one-reading test alone misses it
    assert all(quiet.observe(*e) is None for e in steady(0.0, 161, step_ne_m=(0.0, 100.0)))


def test_a_motion_its_velocity_error_explains_is_no_jump():
    g = JumpGuard()
    v = np.array([5.0, -3.0])
    for k in range(900):
        assert g.observe(float(k), v * k, np.eye(2) * 500.0**2, v, np.eye(2) * 0.04) is None


def test_reset_restart_off_and_bad_input():
    g = JumpGuard()
    list(map(lambda e: g.observe(*e), steady(0.0, 10)))
    assert g.observe(10.0, np.array([9000.0, 0.0]), np.eye(2) * 1e6) is not None
    g.reset()
    assert np.all(g.cov_ne_m2 == 0.0)
    assert g.observe(11.0, np.array([0.0, 0.0]), np.eye(2) * 1e6) is None  # nothing before it to be a shift of
    g.restart()  # a re-initialised filter: its next estimate is not compared with the earlier ones
    assert g.observe(12.0, np.array([50_000.0, 0.0]), np.eye(2) * 1e6) is None
    assert g.observe(12.0, np.array([0.0, 0.0]), np.eye(2) * 1e6) is None  # not after the last: ignored
    assert g.observe(13.0, np.array([np.nan, 0.0]), np.eye(2) * 1e6) is None
    assert g._prev.t_s == 12.0 and len(g._kept) == 1  # refused: not kept to compare with
    off = JumpGuard(chi2=0.0)
    assert off.observe(0.0, np.zeros(2), np.eye(2)) is None and off.observe(1.0, np.full(2, 1e6), np.eye(2)) is None
    with pytest.raises(ValueError):
        JumpGuard(chi2=-1.0)


def test_memory_is_bounded_whatever_the_time_stamps():
    g = JumpGuard(window_s=600.0, spacing_s=30.0)
    rng = np.random.default_rng(0)
    t = 0.0
    for _ in range(20_000):
        t += float(rng.choice([1e-3, 1.0, 31.0, 1e5]))
        g.observe(t, rng.normal(0, 1e3, 2), np.eye(2) * 1e6)
        assert len(g._kept) <= 600.0 / 30.0 + 1
    assert len(g.jumps) <= 100
