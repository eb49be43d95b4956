"""Viterbi map matching (Li 2022): exact DP equals brute force; alpha = 0 equals no pruning; recovery."""

import numpy as np
import pytest

from companion.gravity import GravityMap, LocalGravityMap, MatchWindow
from companion.gravity.matchers.li_viterbi import (CellMap, ViterbiConfig, ViterbiMatcher, _step_sigma_m, brute_force_path,
                                        build_layers, greedy_paths, viterbi_lattice, viterbi_path)


def _rough_cells(seed=0, shape=(60, 60), cell_m=500.0):
    rng = np.random.default_rng(seed)
    return CellMap.from_array(rng.normal(0, 20, shape), cell_m)


def _window(cmap, rng, start_rc=(30.3, 29.8), T=4, vel=(80.0, 60.0), dt=10.0, ins_off=(700.0, -400.0), sigma_z=0.0):
    t = np.arange(T) * dt
    true = cmap.centre(np.asarray(start_rc)) + np.outer(t, vel)
    g = cmap.value(cmap.cell_of(true)) + rng.normal(0, sigma_z, T) if sigma_z else cmap.value(cmap.cell_of(true))
    return MatchWindow.of(t, true + np.asarray(ins_off), np.tile(vel, (T, 1)), g), true


def _layers_and_steps(cmap, win, cfg):
    layers = build_layers(cmap, win, cfg)
    dt = np.diff(win.t_s)
    disp = win.ins_vel_ne_mps[:-1] * dt[:, None]
    sig = np.array([_step_sigma_m(cfg, d, cmap.cell_m / cfg.o) for d in dt])
    return layers, disp, sig


@pytest.mark.parametrize("seed,o,alpha,T", [(0, 1, 0.0, 4), (1, 1, 0.0, 5), (2, 2, 0.0, 3), (3, 1, 0.3, 4)])
def test_viterbi_equals_brute_force(seed, o, alpha, T):
    rng = np.random.default_rng(seed)
    cmap = _rough_cells(seed, (20, 20), 500.0)
    cfg = ViterbiConfig(n=3, o=o, alpha=alpha, T=T, sigma_z_mgal=3.0, sigma_v_mps=5.0)
    win, _ = _window(cmap, rng, start_rc=(10.2, 9.7), T=T, sigma_z=2.0, ins_off=(300.0, -200.0))
    layers, disp, sig = _layers_and_steps(cmap, win, cfg)
    assert sum(layer.pos.shape[0] for layer in layers) > T * 2  # not trivially pruned
    path, score, _ = viterbi_path(layers, disp, sig)
    bf_path, bf_score = brute_force_path(layers, disp, sig)
    np.testing.assert_array_equal(path, bf_path)
    assert score == pytest.approx(bf_score, rel=1e-12, abs=1e-9)
    # the separable lattice recursion (the matcher's default) gives the same path and score
    lpath, lscore, _ = viterbi_lattice(layers, disp, sig, cmap.cell_m / o)
    np.testing.assert_array_equal(lpath, bf_path)
    assert lscore == pytest.approx(bf_score, rel=1e-12, abs=1e-9)
    # tiny blocks give the same answer as one block
    path2, score2, _ = viterbi_path(layers, disp, sig, max_pairs=3)
    np.testing.assert_array_equal(path2, path)
    # the paper's greedy search never beats the MAP path
    gp, gs, _ = greedy_paths(layers, disp, sig)
    assert gs <= score + 1e-9


def test_alpha_zero_equals_unpruned_and_pruning_shrinks_states():
    rng = np.random.default_rng(5)
    cmap = _rough_cells(5)
    win, _ = _window(cmap, rng, T=6, sigma_z=1.0)
    base = dict(n=9, o=1, T=6, sigma_z_mgal=1.0, sigma_v_mps=2.0)
    r0 = ViterbiMatcher(None, ViterbiConfig(alpha=0.0, **base), cell_map=cmap).match(win)
    # tiniest positive alpha prunes nothing on these values; with underflow-free log-likelihoods it is VBMP
    r_tiny = ViterbiMatcher(None, ViterbiConfig(alpha=1e-300, **base), cell_map=cmap).match(win)
    layers0 = build_layers(cmap, win, ViterbiConfig(alpha=0.0, **base))
    assert all(layer.pos.shape[0] == 81 for layer in layers0)  # A_t holds every cell of B_t
    assert r0.extra["n_states"] == 6 * 81
    np.testing.assert_array_equal(r0.track_ne_m, r_tiny.track_ne_m)
    r_pruned = ViterbiMatcher(None, ViterbiConfig(alpha=0.1, **base), cell_map=cmap).match(win)
    assert r_pruned.extra["n_states"] < r0.extra["n_states"]


@pytest.mark.parametrize("o", [1, 5])
@pytest.mark.parametrize("search", ["viterbi", "paper"])
def test_recovers_true_path_with_zero_noise(o, search):
    rng = np.random.default_rng(7)
    cmap = _rough_cells(7)
    cfg = ViterbiConfig(n=7, o=o, alpha=0.1, T=6, sigma_z_mgal=1.0, sigma_v_mps=0.5, search=search,
                        representation_error=False)  # measurements are the cell values here
    win, true = _window(cmap, rng, T=6, ins_off=(900.0, -1100.0))
    res = ViterbiMatcher(None, cfg, cell_map=cmap).match(win)
    assert res.ok, res.reason
    err = np.hypot(*(res.track_ne_m - true).T)
    # INS was ~1.4 km off; the path must land within a cell (quantisation only)
    assert np.all(err < cmap.cell_m * 0.75), err
    assert res.sigma_m >= cmap.cell_m / o / np.sqrt(12) - 1e-9


def test_subcells_refine_position_on_a_real_style_map():
    """RVBMP-2 (o=5) localises sub-cell offsets that RVBMP (cell centres only) cannot."""
    ax = np.arange(0, 40_001, 1000.0)
    E, N = np.meshgrid(ax, ax)
    g = 30 * np.sin(E / 3000.0) * np.cos(N / 4000.0) + 10 * np.sin((E + N) / 1700.0)
    lmap = LocalGravityMap(GravityMap(g, ax, ax, "local_m"))
    T, dt, vel = 6, 10.0, np.array([130.0, 170.0])
    true = np.array([12_340.0, 9_870.0]) + np.outer(np.arange(T) * dt, vel)
    win = MatchWindow.of(np.arange(T) * dt, true + [1500.0, 800.0], np.tile(vel, (T, 1)),
                         lmap.interp_ne(true[:, 0], true[:, 1]))
    errs = {}
    for o in (1, 5):
        cfg = ViterbiConfig(n=9, o=o, alpha=0.0, T=T, sigma_z_mgal=2.0, sigma_v_mps=0.2)
        res = ViterbiMatcher(lmap, cfg, cell_m=1000.0).match(win)
        errs[o] = float(np.mean(np.hypot(*(res.track_ne_m - true).T)))
    assert errs[5] < 700.0 and errs[1] < 1500.0


def test_bad_config_and_offmap_failure():
    with pytest.raises(ValueError):
        ViterbiConfig(n=4)
    with pytest.raises(ValueError):
        ViterbiConfig(alpha=1.5)
    cmap = _rough_cells(1, (20, 20))
    win = MatchWindow.of(np.arange(6.0), np.full((6, 2), 1e7), np.zeros((6, 2)), np.zeros(6))
    res = ViterbiMatcher(None, ViterbiConfig(n=3), cell_map=cmap).match(win)
    assert not res.ok and "no valid map cell" in res.reason


def test_interp_subcells_and_prior_variants_run_and_name():
    rng = np.random.default_rng(2)
    cmap = _rough_cells(2)
    win, true = _window(cmap, rng, T=6, sigma_z=0.0, ins_off=(300.0, 200.0))
    cfg = ViterbiConfig(n=7, o=3, alpha=0.0, T=6, subcell_values="interp", prior_sigma_m=5000.0, representation_error=False)
    assert cfg.name == "RVBMP-2i+prior"
    res = ViterbiMatcher(None, cfg, cell_map=cmap).match(win)
    assert res.ok and res.track_ne_m.shape == (6, 2)
    # a tight prior pins the first state to the cell around the INS position
    tight = ViterbiMatcher(None, ViterbiConfig(n=7, o=1, alpha=0.0, T=6, prior_sigma_m=1.0, sigma_v_mps=1e4,
                                               representation_error=False), cell_map=cmap).match(win)
    assert np.hypot(*(tight.track_ne_m[0] - win.ins_ne_m[0])) <= cmap.cell_m * 0.75
