"""FFT gravity-gradient tensor: Laplace, and agreement with the analytic field of a buried point mass."""

import numpy as np
import pytest

from companion.gravity import GravityMap, LocalGravityMap
from companion.gravity.gradient import COMPONENTS, GradientMap, gradient_tensor_fft

G_SI = 6.674e-11
E_PER_SI = 1e9


def _point_mass(depth_m=6000.0, mass_kg=5e13, n=256, cell_m=400.0):
    ax = (np.arange(n) - n / 2) * cell_m
    X, Y = np.meshgrid(ax, ax, indexing="ij")  # X north (rows), Y east (cols)
    h = depth_m
    r = np.sqrt(X**2 + Y**2 + h**2)
    gm = G_SI * mass_kg
    dg_mgal = gm * h / r**3 * 1e5  # z down, mass at z = +h
    analytic = {
        "xx": gm * (3 * X**2 / r**5 - 1 / r**3),
        "yy": gm * (3 * Y**2 / r**5 - 1 / r**3),
        "zz": gm * (3 * h**2 / r**5 - 1 / r**3),
        "xy": gm * 3 * X * Y / r**5,
        "xz": -gm * 3 * X * h / r**5,
        "yz": -gm * 3 * Y * h / r**5,
    }
    return dg_mgal, {k: v * E_PER_SI for k, v in analytic.items()}, cell_m


def test_point_mass_matches_analytic_tensor():
    dg, ana, cell = _point_mass()
    num = gradient_tensor_fft(dg, cell, cell)
    c = slice(64, 192)  # central half: away from the periodic edges
    scale = max(np.abs(ana[k][c, c]).max() for k in COMPONENTS)
    assert scale > 10  # a meaningful signal (Eotvos)
    for k in COMPONENTS:
        err = np.abs(num[k][c, c] - ana[k][c, c]).max()
        assert err < 0.03 * scale, (k, err, scale)
    # signs: directly above the mass the vertical gradient is positive, horizontal ones negative
    assert num["zz"][128, 128] > 0 and num["xx"][128, 128] < 0 and num["yy"][128, 128] < 0


def test_laplace_on_real_style_random_field():
    rng = np.random.default_rng(0)
    g = rng.normal(0, 10, (90, 120)).cumsum(axis=0).cumsum(axis=1) * 0.01
    t = gradient_tensor_fft(g, 1000.0, 1500.0, height_m=300.0)
    trace = t["xx"] + t["yy"] + t["zz"]
    assert np.abs(trace).max() < 1e-9 * max(np.abs(t["zz"]).max(), 1.0)
    assert np.abs(t["zz"]).max() > 0.1


def test_upward_continuation_attenuates_and_bad_input():
    dg, _, cell = _point_mass(n=128)
    t0 = gradient_tensor_fft(dg, cell, cell)
    t1 = gradient_tensor_fft(dg, cell, cell, height_m=2000.0)
    assert np.abs(t1["zz"]).max() < np.abs(t0["zz"]).max()
    with pytest.raises(ValueError):
        gradient_tensor_fft(np.full((10, 10), np.nan), 1.0, 1.0)


def test_gradient_map_from_local_map_and_subsample():
    dg, ana, cell = _point_mass(n=128, cell_m=500.0)
    ax = (np.arange(128) - 64) * 500.0
    lmap = LocalGravityMap(GravityMap(dg, ax, ax, "local_m"))
    gm = GradientMap.from_local_map(lmap, 500.0, (-30_000.0, 30_000.0, -30_000.0, 30_000.0))
    v = gm.interp_ne(np.array([0.0]), np.array([0.0]))
    assert v.shape == (1, 5)
    # at the centre xy, xz, yz vanish by symmetry; xx = yy
    assert abs(v[0, 1]) < 1e-3 * abs(v[0, 0]) + 1e-6 and abs(v[0, 2]) < 0.02 * abs(v[0, 0])
    sub = gm.subsample(2)
    assert sub.comps["xx"].shape[0] == (gm.comps["xx"].shape[0] + 1) // 2
    stats = gm.statistics()
    assert set(stats) == {"xx", "xy", "xz", "yy", "yz"}
