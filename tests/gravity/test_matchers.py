"""Gravity matchers: known-offset recovery on a synthetic map (the contract all share: tests/contract)."""

import numpy as np
import pytest

from companion.gravity import (GravityMap, IccpMatcher, KnnMatcher, LocalGravityMap, MatchWindow,
                                MsdSequenceMatcher, PatternConfig, RpcmMatcher, SpeedConstraint, TercomMatcher)
from companion.gravity.matchers.gao_iccp import rigid_fit_2d
from companion.gravity.maps import METRES_PER_ARCMIN

STEP_M = 0.003 * 60 * METRES_PER_ARCMIN  # the paper's 0.003 deg label step on a local map


def _synthetic_map(seed=3, size_m=120_000.0, spacing_m=500.0) -> LocalGravityMap:
    """Sum of random Gaussian bumps (seamount-like, 2-8 km wide) on a local metric grid."""
    rng = np.random.default_rng(seed)
    ax = np.arange(-size_m / 2, size_m / 2 + 1, spacing_m)
    E, N = np.meshgrid(ax, ax)
    g = np.zeros_like(E)
    for _ in range(400):
        c = rng.uniform(-size_m / 2, size_m / 2, 2)
        w = rng.uniform(2000, 8000)
        g += rng.normal(0, 25) * np.exp(-((N - c[0]) ** 2 + (E - c[1]) ** 2) / (2 * w**2))
    return LocalGravityMap(GravityMap(g, ax, ax, "local_m", name="synthetic"))


LMAP = _synthetic_map()


def _window(lmap, offset_ne, n=20, spacing_m=1500.0, heading_deg=60.0, curvature_per_m=0.0, start=(-12_000, -15_000)):
    h = np.radians(heading_deg) + curvature_per_m * spacing_m * np.arange(n)
    steps = spacing_m * np.column_stack([np.cos(h), np.sin(h)])
    true = np.asarray(start, float) + np.r_[np.zeros((1, 2)), np.cumsum(steps[:-1], axis=0)]
    t = np.arange(n) * spacing_m / 5.0
    vel = 5.0 * np.column_stack([np.cos(h), np.sin(h)])
    g = lmap.interp_ne(true[:, 0], true[:, 1])
    return MatchWindow.of(t, true + np.asarray(offset_ne), vel, g), true


def test_knn_recovers_offset_zero_noise():
    off = np.array([3 * STEP_M, -5 * STEP_M])  # on the label lattice
    win, true = _window(LMAP, off)
    r = KnnMatcher(LMAP).match(win)
    assert r.ok, r.reason
    assert np.linalg.norm(r.position_ne_m - true[-1]) < STEP_M
    assert np.linalg.norm(win.ins_ne_m[-1] - true[-1]) > 1500  # the INS was far off


def test_msd_recovers_offset_exactly_zero_noise():
    off = np.array([-7 * STEP_M, 4 * STEP_M])
    win, true = _window(LMAP, off)
    r = MsdSequenceMatcher(LMAP).match(win)
    assert r.ok and np.linalg.norm(r.position_ne_m - true[-1]) < 1.0


def test_iccp_recovers_small_offset_zero_noise():
    # ICCP is a local method; its fix is limited by the contour lattice (0.003 deg) and the band width
    win, true = _window(LMAP, (1000.0, 800.0))
    r = IccpMatcher(LMAP, equivalence_mgal=(-0.2, 0.2)).match(win)
    assert r.ok
    assert np.linalg.norm(win.ins_ne_m[-1] - true[-1]) > 1200
    assert np.linalg.norm(r.position_ne_m - true[-1]) < 200.0


@pytest.mark.parametrize("cls", [RpcmMatcher, TercomMatcher])
@pytest.mark.parametrize("metric", ["mad", "msd"])
def test_pattern_matchers_recover_offset_on_straight_track(cls, metric):
    win, true = _window(LMAP, (6000.0, -4500.0), n=40, spacing_m=500.0)
    r = cls(LMAP, PatternConfig(cell_m=500.0, metric=metric, window_len=60)).match(win)
    assert r.ok, r.reason
    assert np.linalg.norm(r.position_ne_m - true[-1]) < 500.0


def test_rpcm_keeps_curved_shape_tercom_does_not():
    win, true = _window(LMAP, (5000.0, 3000.0), n=60, spacing_m=500.0, curvature_per_m=2e-4 / 500 * 500 / 10)
    cfg = PatternConfig(cell_m=500.0, metric="msd", window_len=60)
    rp = RpcmMatcher(LMAP, cfg).match(win)
    te = TercomMatcher(LMAP, cfg).match(win)
    err_rp = np.linalg.norm(rp.track_ne_m - true, axis=1).mean()
    err_te = np.linalg.norm(te.track_ne_m - true, axis=1).mean()
    assert err_rp < 500.0 and err_te > 2 * err_rp


def test_speed_constraint_eqs_12_13():
    sc = SpeedConstraint(speed_accuracy_mps=0.5)
    prev, prev_ins, ins = np.array([0.0, 0.0]), np.array([10.0, 10.0]), np.array([110.0, 10.0])
    out, ok = sc.apply(prev, prev_ins, 100.0, np.array([120.0, -20.0]), ins, 20)  # within +-50 m of (100, 0)
    assert ok and np.allclose(out, [120.0, -20.0])
    out, ok = sc.apply(prev, prev_ins, 100.0, np.array([400.0, 0.0]), ins, 20)
    assert not ok and np.allclose(out, ((np.array([100.0, 0.0])) * 20 + [400.0, 0.0]) / 21)


def test_rigid_fit_recovers_rotation_translation():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(15, 2))
    a = 0.3
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    rr, t = rigid_fit_2d(src, src @ r.T + [5.0, -2.0])
    np.testing.assert_allclose(rr, r, atol=1e-12)
    np.testing.assert_allclose(t, [5.0, -2.0], atol=1e-12)
