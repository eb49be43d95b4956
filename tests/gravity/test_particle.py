"""Particle filters (GF-PF, PSO-PF, APO-PF; gradient and scalar): convergence from the paper's 2000 m initial
error on a synthetic map with zero measurement noise; the 12-state INS error model; speed-independent checks."""

import numpy as np
import pytest

from companion.gravity.gradient import LIU_COMPONENTS, GradientMap
from companion.gravity.particle import (FieldSampler, GravityParticleFilter, PfConfig, discretise,
                                         ins_error_matrix)
from tests.helpers import bumpy_map


def _synthetic_gradient_map(seed=11, half_m=40_000.0, cell_m=500.0) -> GradientMap:
    lmap = bumpy_map(seed, half_m, cell_m, 250, (1500, 5000))
    r = half_m - 2000
    return GradientMap.from_local_map(lmap, cell_m, (-r, r, -r, r))


GMAP = _synthetic_gradient_map()


def _run(optimizer, names, sigma_obs, seed, steps=50, ins_err=(1318.0, 414.0)):
    sampler = FieldSampler.from_gradient_map(GMAP, names)
    rng = np.random.default_rng(seed)
    cfg = PfConfig(optimizer=optimizer, sigma_obs=sigma_obs)
    pf = GravityParticleFilter(sampler, cfg, rng, t0_s=0.0, lat_rad=np.radians(45.0))
    vel = np.array([3.0, 4.0])
    errs = []
    for k in range(1, steps + 1):
        t = 10.0 * k
        true = np.array([-15_000.0, -12_000.0]) + vel * t
        ins = true + np.asarray(ins_err)
        y = sampler(np.array([true[0]]), np.array([true[1]]))[0]  # zero noise
        est = pf.step(t, ins, vel, y)
        errs.append(np.hypot(*(est.position_ne_m - true)))
    return np.asarray(errs)


@pytest.mark.parametrize("optimizer", ["gf", "pso", "apo"])
def test_gradient_filters_converge_from_2000m_with_zero_noise(optimizer):
    """INS off by (1318, 414) m (Liu's error at the start of aiding), particles spread 2000 m (1 sigma)."""
    errs = _run(optimizer, LIU_COMPONENTS, 1.0, seed=3)
    assert np.median(errs[-10:]) < 150.0, (optimizer, errs[-10:])


@pytest.mark.parametrize("seed", [3, 4])
def test_scalar_gf_pf_converges_with_zero_noise(seed):
    """The scalar-anomaly variant has one observation per period instead of five: slower, looser."""
    errs = _run("gf", ("anomaly",), 0.5, seed=seed, steps=150)
    assert np.median(errs[-10:]) < 0.4 * np.hypot(1318.0, 414.0), errs[-10:]


def test_error_model_is_the_standard_phi_angle_model():
    A = ins_error_matrix(np.radians(30.0), (0.0, 0.0))
    # stationary: Schuler coupling dVN' = g phiE, phiE' = -dVN/R ; biases drive velocity and attitude
    assert A[3, 4] == pytest.approx(9.80665) and A[2, 5] == pytest.approx(-9.80665)
    assert A[4, 3] < 0 and A[5, 2] > 0
    assert A[2, 7] == 1 and A[3, 8] == 1 and A[4, 9] == 1 and A[5, 10] == 1 and A[6, 11] == 1
    # Schuler period ~84.4 min from the eigenvalues of the velocity/tilt loop (rotation terms are small)
    w = np.abs(np.linalg.eigvals(A[np.ix_([3, 4], [3, 4])]).imag).max()
    assert 2 * np.pi / w / 60 == pytest.approx(84.4, abs=0.5)
    Ak, Bk = discretise(A, 10.0)
    np.testing.assert_allclose(Ak, np.eye(12) + 10.0 * A)
    np.testing.assert_allclose(Bk, 10.0 * (np.eye(12) + 5.0 * A))


def test_field_sampler_matches_bilinear_and_is_nan_off_grid():
    s = FieldSampler.from_gradient_map(GMAP, LIU_COMPONENTS)
    n = np.array([0.0, 1234.5, 1e7])
    e = np.array([0.0, -987.6, 0.0])
    a = s(n, e)
    b = GMAP.interp_ne(n, e)
    np.testing.assert_allclose(a[:2], b[:2], rtol=1e-9, atol=1e-9)
    assert np.all(np.isnan(a[2]))


def test_deterministic_given_seed():
    a = _run("gf", LIU_COMPONENTS, 1.0, seed=9, steps=5)
    b = _run("gf", LIU_COMPONENTS, 1.0, seed=9, steps=5)
    np.testing.assert_array_equal(a, b)
