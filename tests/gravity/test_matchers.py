"""Gravity matchers: known-offset recovery on a synthetic map and one interface contract for all."""

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


def _all_matchers(lmap):
    pc = dict(cell_m=500.0, min_len=10, window_len=60)
    return [
        KnnMatcher(lmap),
        MsdSequenceMatcher(lmap),
        IccpMatcher(lmap, equivalence_mgal=(-0.3, 0.3)),
        RpcmMatcher(lmap, PatternConfig(metric="msd", **pc)),
        RpcmMatcher(lmap, PatternConfig(metric="mad", **pc)),
        TercomMatcher(lmap, PatternConfig(metric="msd", **pc)),
        TercomMatcher(lmap, PatternConfig(metric="mad", **pc)),
    ]


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


@pytest.mark.parametrize("matcher", _all_matchers(LMAP), ids=lambda m: m.name)
def test_interface_contract(matcher):
    win, true = _window(LMAP, (300.0, -300.0), n=30, spacing_m=700.0)
    # batch: a good window gives a finite fix with uncertainty and timing
    r = matcher.match(win)
    assert r.ok, r.reason
    assert r.position_ne_m.shape == (2,) and np.all(np.isfinite(r.position_ne_m))
    assert np.isfinite(r.sigma_m) and r.sigma_m > 0 and r.compute_time_s > 0
    assert r.t_s == win.t_s[-1] and r.method == matcher.name
    assert r.track_ne_m is None or r.track_ne_m.shape[1] == 2
    # bad input: failed result with a reason, never an exception
    empty = MatchWindow.of([], np.zeros((0, 2)), np.zeros((0, 2)), [])
    for bad, why in [
        (empty, "empty"),
        (MatchWindow.of(win.t_s, win.ins_ne_m, win.ins_vel_ne_mps, np.where(np.arange(len(win)) == 3, np.nan, win.gravity_mgal)), "non-finite"),
        (MatchWindow.of(win.t_s[:3], win.ins_ne_m[:3], win.ins_vel_ne_mps[:3], win.gravity_mgal[:3]), "need"),
        (MatchWindow.of(win.t_s, win.ins_ne_m + 1e6, win.ins_vel_ne_mps, win.gravity_mgal), "map"),
    ]:
        rb = matcher.match(bad)
        assert not rb.ok and why in rb.reason and np.all(np.isnan(rb.position_ne_m))
    # online: nothing until min_len samples, then a fix per sample
    matcher.reset()
    outs = [matcher.feed(win.t_s[i], win.ins_ne_m[i], win.ins_vel_ne_mps[i], win.gravity_mgal[i]) for i in range(len(win))]
    assert all(o is None for o in outs[: matcher.min_len - 1])
    assert all(o is not None and o.ok for o in outs[matcher.min_len - 1:])
    assert np.linalg.norm(outs[-1].position_ne_m - true[-1]) < 1000.0
    # online bad samples are dropped with a reason and do not poison later fixes
    bad = matcher.feed(win.t_s[-1] + 10.0, win.ins_ne_m[-1], win.ins_vel_ne_mps[-1], float("nan"))
    assert bad is not None and not bad.ok and "non-finite" in bad.reason
    late = matcher.feed(win.t_s[-1], win.ins_ne_m[-1], win.ins_vel_ne_mps[-1], win.gravity_mgal[-1])
    assert late is not None and not late.ok and "time" in late.reason
    nxt = matcher.feed(win.t_s[-1] + 140.0, win.ins_ne_m[-1] + [0.0, 700.0], win.ins_vel_ne_mps[-1],
                       float(LMAP.interp_ne(true[-1, 0], true[-1, 1] + 700.0)))
    assert nxt is not None and nxt.ok


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
