"""KNN predictor (Aziez 2021 eqs. 1, 3-4) on synthetic trajectories with known truth."""

import numpy as np
import pytest

from companion.nav.knn_predictor import KnnConfig, KnnPredictor, eq4_weights


def _feed(pred, traj, t_end, rate_hz, t_start=0.0, with_velocity=False):
    for t in np.arange(t_start, t_end + 1e-9, 1.0 / rate_hz):
        vel = (traj(t + 1e-4) - traj(t - 1e-4)) / 2e-4 if with_velocity else None
        pred.add_fix(round(float(t), 6), traj(t), vel_ned_mps=vel)


def straight(t):
    return np.array([3.0 * t, -1.5 * t, -0.0 * t])


def climb(t):
    return np.array([2.0 * t, 1.0 * t, -1.2 * t])


def turn(t, r=30.0, v=5.0):
    w = v / r
    return np.array([r * np.sin(w * t), r * (1 - np.cos(w * t)), -10.0])


def _cv_extrapolate(traj, t0, dt):
    # constant velocity from the last two 1 Hz fixes (what a naive gap filler does)
    v = traj(t0) - traj(t0 - 1.0)
    return traj(t0) + v * dt


@pytest.mark.parametrize("traj", [straight, climb], ids=["straight", "climb"])
def test_linear_trajectories_are_exact_inbetween_and_through_blockage(traj):
    p = KnnPredictor()
    _feed(p, traj, 60.0, 1.0)
    steps = p.predict_steps(9)  # the paper's nine in-between points
    for i, s in enumerate(steps, start=1):
        assert s.t_s == pytest.approx(60.0 + 0.1 * i)
        assert np.allclose(s.ned_m, traj(s.t_s), atol=1e-6)
        assert s.method == "knn"
    for tau in (1.0, 4.0, 8.0):  # the paper's blockages
        q = p.predict(60.0 + tau)
        assert np.allclose(q.ned_m, traj(60.0 + tau), atol=1e-5)


@pytest.mark.parametrize("with_velocity,inbetween_max_m", [(False, 0.8), (True, 0.05)])
def test_constant_turn_follows_arc_far_better_than_cv(with_velocity, inbetween_max_m):
    # 5 m/s on a 30 m circle: one lap is 37.7 s; three laps of 1 Hz history, then block 8 s
    p = KnnPredictor()
    t0 = 113.0
    _feed(p, turn, t0, 1.0, with_velocity=with_velocity)
    inbetween = [np.linalg.norm(np.array(s.ned_m) - turn(s.t_s)) for s in p.predict_steps(9)]
    # linear 1 Hz history is chords, so the in-between points follow the last chord (0.71 m at 0.9 s);
    # with receiver velocity the Hermite grid follows the arc
    assert max(inbetween) < inbetween_max_m
    for tau in (1.0, 4.0, 8.0):
        err = np.linalg.norm(np.array(p.predict(t0 + tau).ned_m) - turn(t0 + tau))
        err_cv = np.linalg.norm(_cv_extrapolate(turn, t0, tau) - turn(t0 + tau))
        if with_velocity:  # the curved grid lets the neighbours carry the turn through the blockage
            assert err < 0.25 * err_cv + 0.2, (tau, err, err_cv)
        else:  # chords only ever match chords: no better than straight-line extrapolation
            assert err < err_cv + 1e-6
    if with_velocity:
        assert np.linalg.norm(np.array(p.predict(t0 + 8.0).ned_m) - turn(t0 + 8.0)) < 1.5


def _brute_force_reference(db_pts, window_pts, k):
    """Independent eq. (1), (3), (4) over all relative patterns of a 0.1 s series (temporal weights)."""
    keys, conts = [], []
    for i in range(len(db_pts) - 4):
        w = db_pts[i : i + 4]
        keys.append((w[:-1] - w[-1]).ravel())
        conts.append(db_pts[i + 4] - w[-1])
    keys, conts = np.array(keys), np.array(conts)
    q = (window_pts[:-1] - window_pts[-1]).ravel()
    d = np.sqrt(((keys - q) ** 2).sum(axis=1))  # eq. (1)
    nn = np.lexsort((np.arange(len(d)), d))[:k]
    nn_time_order = np.sort(nn)  # entries were added in time order
    w = np.arange(1, k + 1) / (k * (k + 1) / 2)  # eq. (4)
    return window_pts[-1] + w @ conts[nn_time_order]  # eq. (3)


def test_four_point_recursion_matches_brute_force_reference():
    rng = np.random.default_rng(7)
    t = np.arange(0, 40.0 + 1e-9, 0.1)
    # a wiggly trajectory sampled at 10 Hz so that the grid equals the fixes
    pts = np.stack([5 * np.sin(0.3 * t) + 0.1 * rng.standard_normal(len(t)),
                    3 * np.cos(0.2 * t), 0.5 * np.sin(0.7 * t)], axis=1)
    cfg = KnnConfig(k=5, max_entries=100000, rebuild_every=37)
    p = KnnPredictor(cfg)
    for ti, pi in zip(t, pts):
        p.add_fix(round(float(ti), 6), pi)
    window = list(pts[-4:])  # t = 39.7, 39.8, 39.9, 40.0 predict 40.1 (paper's example, shifted)
    for i in range(1, 6):
        ref = _brute_force_reference(pts, np.array(window[-4:]), 5)
        got = p.predict(40.0 + 0.1 * i)
        assert np.allclose(got.ned_m, ref, atol=1e-9), i
        window.append(np.array(got.ned_m))  # recursion: predicted points feed the next step


def test_ring_buffer_tree_plus_tail_is_exact_search():
    rng = np.random.default_rng(3)
    t = np.arange(0, 30.0 + 1e-9, 0.1)
    pts = np.cumsum(rng.standard_normal((len(t), 3)) * 0.2, axis=0)
    cfg = KnnConfig(k=4, max_entries=120, rebuild_every=13)
    p = KnnPredictor(cfg)
    for ti, pi in zip(t, pts):
        p.add_fix(round(float(ti), 6), pi)
    assert p.n_entries == 120  # bounded memory
    ref = _brute_force_reference(pts[-(120 + 4):], pts[-4:], 4)
    assert np.allclose(p.predict(30.1).ned_m, ref, atol=1e-9)


def _wide_query(p, key):
    """The search as it was before the narrow first query: k + (entries since the build) from the tree, stale rows
    dropped, plus the brute-force tail."""
    c, k = p.config, min(p.config.k, p.n_entries)
    overwritten = p._n_added - p._tree_n_added
    d, i = p._tree.query(key, k=min(k + overwritten, len(p._tree_rows)))
    rows, d = p._tree_rows[np.atleast_1d(i)], np.atleast_1d(d)
    stale = (rows - p._tree_n_added % c.max_entries) % c.max_entries < overwritten
    tail = np.arange(p._tree_n_added, p._n_added) % c.max_entries
    rows = np.concatenate([rows[~stale], tail])
    d = np.concatenate([d[~stale], np.sqrt(((p._keys[tail] - key) ** 2).sum(axis=1))])
    order = np.lexsort((rows, d))[:k]
    return rows[order], d[order]


@pytest.mark.parametrize("hover", [False, True], ids=["moving", "hover-ties"])
def test_narrow_first_query_equals_the_wide_one(hover):
    # the narrow (k + 1) query decides only when it can: same rows and distances as the wide one, before and after
    # the ring wraps, and with many exactly equal keys (a hover repeats one fix: all-zero relative keys)
    rng = np.random.default_rng(5)
    cfg = KnnConfig(k=5, max_entries=300, rebuild_every=40)
    p = KnnPredictor(cfg)
    pos = np.zeros(3)
    checked = 0
    for j, t in enumerate(np.arange(0, 80.0, 0.1)):
        if not (hover and (j // 50) % 2):
            pos = pos + rng.standard_normal(3) * 0.3
        p.add_fix(round(float(t), 6), pos.copy())
        if p._tree is not None and j % 3 == 0:
            for key in (np.zeros(p._key_dim), rng.standard_normal(p._key_dim), p._keys[j % p.n_entries]):
                got, ref = p._query(key), _wide_query(p, key)
                assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
                checked += 1
    assert checked > 500 and p._n_added > cfg.max_entries


def test_uncertainty_grows_with_age_and_resets_at_fix():
    p = KnnPredictor()
    _feed(p, turn, 60.0, 1.0)
    s = [p.predict(60.0 + tau).sigma_h_m for tau in (0.1, 1.0, 4.0, 8.0, 15.0)]
    assert all(b > a for a, b in zip(s, s[1:]))
    p.add_fix(61.0, turn(61.0), sigma_h_m=0.7)
    assert p.predict(61.1).sigma_h_m < 1.0
    assert p.predict(61.1).age_s == pytest.approx(0.1)


def test_cold_start_uses_constant_velocity_and_weights_sum_to_one():
    p = KnnPredictor()
    p.add_fix(0.0, [0, 0, 0])
    p.add_fix(0.2, [0.2, 0, 0])  # three grid points: no database entry yet
    q = p.predict(0.7)
    assert p.n_entries == 0 and q.method == "cv"
    assert np.allclose(q.ned_m, [0.7, 0, 0])
    assert eq4_weights(5).sum() == pytest.approx(1.0)
    assert np.allclose(eq4_weights(4), [0.1, 0.2, 0.3, 0.4])


def test_bad_config_and_input_raise():
    with pytest.raises(ValueError):
        KnnConfig(pattern="polar")
    with pytest.raises(ValueError):
        KnnPredictor().add_fix(0.0, [np.nan, 0, 0])
