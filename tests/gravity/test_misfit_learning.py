"""Learnt map-misfit sigma (companion.gravity.sequential_backends.MisfitVarianceLearner and the filter's
MapErrorSpec.learn_window_m): against a known misfit injected on synthetic series and a synthetic map."""

from dataclasses import replace

import numpy as np
import pytest

from companion.gravity.sequential import MapErrorSpec, SeqGravConfig, SequentialGravityFilter
from companion.gravity.sequential_backends import MisfitVarianceLearner
from companion.sim.gravity_scenario import Segment, make_trajectory
from tests.gravity.test_sequential_gravity import MAP


def _gauss_markov(rng, dist_m, sigma, corr_m):
    """First-order Gauss-Markov process in distance, stationary from its first sample."""
    out = np.empty(dist_m.size)
    out[0] = rng.normal(0.0, sigma)
    a = np.exp(-np.diff(dist_m) / corr_m)
    n = rng.standard_normal(dist_m.size - 1)
    for k in range(1, dist_m.size):
        out[k] = a[k - 1] * out[k - 1] + np.sqrt(1.0 - a[k - 1] ** 2) * sigma * n[k - 1]
    return out


@pytest.mark.parametrize("sigma", [2.0, 6.0, 12.0])
def test_learner_recovers_an_injected_gauss_markov_sigma(sigma):
    """r = GM misfit (L 5 km) + 1 mGal white every 100 m over a 1000 km window: the learnt sigma is the injected one
    (the window's own sampling error is ~ sqrt(2L/W) ~ 10 % in variance), never below the floor."""
    rng = np.random.default_rng(int(sigma * 10))
    d = np.arange(0.0, 1_200_000.0, 100.0)
    r = _gauss_markov(rng, d, sigma, 5_000.0) + rng.normal(0.0, 1.0, d.size) + 30.0  # a level the window removes
    lr = MisfitVarianceLearner(1_000_000.0, 5_000.0)
    assert lr.sigma_mgal(1.5) == 1.5  # empty: the floor
    for dk, rk in zip(d, r):
        lr.add(float(dk), float(rk), 1.0)
    assert lr.sigma_mgal(1.5) == pytest.approx(sigma, rel=0.12)
    assert lr.sigma_mgal(20.0) == 20.0  # the floor wins when the data show less
    assert len(lr._q) <= 10_001  # bounded by the window


def test_learner_waits_for_a_full_window():
    lr = MisfitVarianceLearner(50_000.0, 2_000.0)
    rng = np.random.default_rng(0)
    for dk in np.arange(0.0, 40_000.0, 100.0):
        lr.add(float(dk), float(rng.normal(0.0, 10.0)), 1.0)
    assert lr.sigma_mgal(3.0) == 3.0  # 40 of 50 km: the floor
    for dk in np.arange(40_000.0, 60_000.0, 100.0):
        lr.add(float(dk), float(rng.normal(0.0, 10.0)), 1.0)
    assert lr.sigma_mgal(3.0) == pytest.approx(10.0, rel=0.1)  # white: no GM correction needed beyond L / W


def _anchored_misfit_sigma(seed, injected_sigma, learn_window_m=60_000.0):
    """The filter pinned to the truth by a 2 m reference (as while GNSS is on) on the synthetic map, readings = map +
    a GM misfit (1.5 km) of injected_sigma + 1 mGal white; returns the filter's learnt sigma at the end (floor 3)."""
    rng = np.random.default_rng(seed)
    tr = make_trajectory(20.0, [Segment(3600.0)], dt_s=1.0, heading0_deg=45.0, start_ne_m=(-28_000.0, -28_000.0))
    g = MAP.interp_ne(tr.pos_ne_m[:, 0], tr.pos_ne_m[:, 1])
    g = g + _gauss_markov(rng, tr.distance_m(), injected_sigma, 1_500.0) + rng.normal(0.0, 1.0, len(tr))
    cfg = replace(SeqGravConfig(), map_error=MapErrorSpec(sigma_mgal=3.0, corr_length_m=1_500.0,
                                                          learn_window_m=learn_window_m))
    f = SequentialGravityFilter(MAP, cfg, rng=seed)
    cov = np.eye(2) * 4.0
    for k in range(len(tr)):
        f.feed(tr.t_s[k], g[k], tr.pos_ne_m[k] + rng.normal(0.0, 2.0, 2), tr.vel_ne_mps[k], 1.0, ref_cov_ne_m2=cov)
    return f.misfit.sigma_mgal(cfg.map_error.sigma_mgal)


def test_filter_learns_the_injected_misfit_sigma_on_a_synthetic_map():
    """Over 72 km of track (60 km window, 40 correlation lengths: ~16 % sampling error in sigma per run) the mean of
    three runs recovers an injected 8 mGal misfit within 15 %; with no misfit injected the floor (3 mGal) stays."""
    learnt = [_anchored_misfit_sigma(s, 8.0) for s in (1, 2, 3)]
    assert np.mean(learnt) == pytest.approx(8.0, rel=0.15)
    assert _anchored_misfit_sigma(4, 0.0) == 3.0



def test_a_track_shorter_than_the_window_runs_exactly_as_without_learning():
    """The learnt sigma is the floor until the window is full: a 14 km track gives the same output, bit for bit."""
    from tests.gravity.test_sequential_gravity import _track
    from companion.gravity.sequential import run_batch

    tr = _track(hours=0.5)
    rng = np.random.default_rng(5)
    g = MAP.interp_ne(tr.pos_ne_m[:, 0], tr.pos_ne_m[:, 1]) + rng.normal(0.0, 3.0, len(tr))
    ins = tr.pos_ne_m + np.array([800.0, -600.0])
    cov0 = np.full((len(tr), 2, 2), np.nan)
    cov0[0] = np.eye(2) * 1000.0**2
    on = SeqGravConfig()
    assert on.map_error.learn_window_m > 20_000.0
    off = replace(on, map_error=replace(on.map_error, learn_window_m=0.0))
    a = run_batch(MAP, tr.t_s, g, ins, tr.vel_ne_mps, 1.0, ref_cov_ne_m2=cov0, cfg=on, rng=3)
    b = run_batch(MAP, tr.t_s, g, ins, tr.vel_ne_mps, 1.0, ref_cov_ne_m2=cov0, cfg=off, rng=3)
    np.testing.assert_array_equal(a.pos_ne_m, b.pos_ne_m)
    np.testing.assert_array_equal(a.h_acc_m, b.h_acc_m)


def test_learner_memory_is_bounded_for_a_vehicle_that_does_not_move(monkeypatch):
    """Readings at one place for ever (a moored ship, a hover): the window never spans its distance, the entries stop
    at MAX_ENTRIES and the floor stays in force."""
    monkeypatch.setattr(MisfitVarianceLearner, "MAX_ENTRIES", 500)
    lr = MisfitVarianceLearner(50_000.0, 2_000.0)
    rng = np.random.default_rng(0)
    for r in rng.normal(0.0, 20.0, 2000):
        lr.add(1234.0, float(r), 1.0)
    assert len(lr._q) == 500
    assert lr.sigma_mgal(5.3) == 5.3
    kept = np.array([e[1] for e in lr._q])
    assert np.allclose(lr._s, (kept.sum(), (kept**2).sum(), 500.0))  # the running sums follow what is kept
