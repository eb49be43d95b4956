"""Sequential gravity filter (companion/gravity/sequential.py): convergence on a synthetic map with zero noise from a
5 km initial error, streaming == batch, no-signal and divergence detection, covariance honesty (NEES) on a small
Monte Carlo. Truth is known in every test; accuracy targets live in the benchmark (replay.gravity.marine)."""

import numpy as np
import pytest

from companion.gravity.sequential import (SeqGravConfig, SequentialGravityFilter, error_dynamics,
                                          eotvos_jacobian_mgal_per_mps, run_batch)
from companion.gravity.maps import GravityMap, LocalGravityMap
from companion.gravity.eotvos import eotvos_from_ne_mgal
from companion.sim.gravity_scenario import InsErrorModel, Segment, make_trajectory, simulate_ins, turn


def _synthetic_map(seed=11, half_m=70_000.0, cell_m=500.0, flat_east_of_m=None) -> LocalGravityMap:
    """Sum of Gaussian bumps (1.5-5 km wide, ~20 mGal); optionally constant east of ``flat_east_of_m``."""
    rng = np.random.default_rng(seed)
    ax = np.arange(-half_m, half_m + 1, cell_m)
    N, E = np.meshgrid(ax, ax, indexing="ij")
    g = np.zeros_like(N)
    for _ in range(500):
        c = rng.uniform(-half_m, half_m, 2)
        w = rng.uniform(1500, 5000)
        g += rng.normal(0, 20) * np.exp(-((N - c[0]) ** 2 + (E - c[1]) ** 2) / (2 * w**2))
    if flat_east_of_m is not None:
        g = np.where(E > flat_east_of_m, 10.0, g)
    return LocalGravityMap(GravityMap(g, ax, ax, "local_m"))


MAP = _synthetic_map()


def _track(hours=1.0, speed=8.0, heading=45.0, start=(-15_000.0, -15_000.0)):
    segs = [Segment(0.4 * hours * 3600), turn(90.0, 800.0, speed)]
    segs.append(Segment(hours * 3600 - sum(s.duration_s for s in segs)))
    return make_trajectory(speed, segs, dt_s=1.0, heading0_deg=heading, start_ne_m=start)


def test_eotvos_jacobian_matches_finite_difference():
    v = np.array([3.0, -6.0])
    J = eotvos_jacobian_mgal_per_mps(v, 40.0)
    for i in range(2):
        d = np.zeros(2)
        d[i] = 1e-4
        fd = (eotvos_from_ne_mgal(v + d, 40.0) - eotvos_from_ne_mgal(v - d, 40.0)) / 2e-4
        assert J[i] == pytest.approx(float(fd), rel=1e-6)


def test_error_dynamics_schuler_period():
    """The velocity/position block oscillates at the Schuler frequency sqrt(g/R) (84.4 min)."""
    A = error_dynamics(np.radians(45.0), (0.0, 0.0), (0.0, 0.0), 0.0, 1e9)
    sub = A[np.ix_([2, 4], [2, 4])]  # dsN, dvN
    w = np.abs(np.linalg.eigvals(sub).imag).max()
    assert 2 * np.pi / w / 60.0 == pytest.approx(84.4, abs=0.2)


@pytest.mark.parametrize("rng", [3, 4, 5])
def test_converges_from_5km_with_zero_noise(rng):
    """INS off by a constant (4000, -3000) m, prior 5 km per axis, readings exactly the map (the filter's default
    misfit model): the error falls to a few hundred metres, the reported accuracy shrinks with it and covers it.
    Over the last 10 minutes the mean error is below 400 m for each particle draw (the largest single error there
    depends on the draw: 240-439 m over these three, 120-545 m with the earlier 8 mGal / 50 km misfit model)."""
    tr = _track(hours=1.0)
    g = MAP.interp_ne(tr.pos_ne_m[:, 0], tr.pos_ne_m[:, 1])
    ins = tr.pos_ne_m + np.array([4000.0, -3000.0])
    cov0 = np.full((len(tr), 2, 2), np.nan)
    cov0[0] = np.eye(2) * 5000.0**2
    out = run_batch(MAP, tr.t_s, g, ins, tr.vel_ne_mps, 0.5, ref_cov_ne_m2=cov0, rng=rng)
    err = np.hypot(*(out.pos_ne_m - tr.pos_ne_m[out.index]).T)
    assert err[0] > 1500.0 and out.h_acc_m[0] > 5000.0
    last = out.t_s >= out.t_s[-1] - 600.0
    assert err[last].mean() < 400.0 and err[last].max() < 1000.0
    assert out.h_acc_m[last].max() < 1500.0
    assert np.all(err[last] <= 3.0 * out.h_acc_m[last])
    assert out.reinit_count[-1] == 0


def _noisy_run(seed, hours=0.5, lmap=MAP, speed=8.0):
    rng = np.random.default_rng(seed)
    tr = _track(hours=hours, speed=speed, heading=float(rng.uniform(0, 360)),
                start=tuple(rng.uniform(-25_000.0, 25_000.0, 2)))
    ins = simulate_ins(tr, 45.0, InsErrorModel(), rng)  # 0.01 deg/h, 100 ug class
    g = lmap.interp_ne(tr.pos_ne_m[:, 0], tr.pos_ne_m[:, 1]) + rng.normal(0.0, 1.0, len(tr))
    g = g + eotvos_from_ne_mgal(tr.vel_ne_mps, 45.0) - eotvos_from_ne_mgal(ins.vel_ne_mps, 45.0)
    return tr, ins, g


def test_streaming_equals_batch():
    tr, ins, g = _noisy_run(5, hours=0.25)
    cov = np.full((len(tr), 2, 2), np.nan)
    cov[:120] = np.eye(2) * 4.0  # anchored (GNSS) for two minutes, then free
    for method in ("mpf", "pmf"):
        cfg = SeqGravConfig(method=method, n_particles=300, pmf_grid=24)
        batch = run_batch(MAP, tr.t_s, g, ins.pos_ne_m, ins.vel_ne_mps, 1.0, ref_cov_ne_m2=cov, cfg=cfg, rng=9)
        f = SequentialGravityFilter(MAP, cfg, np.random.default_rng(9))
        stream = []
        for k in range(len(tr)):
            rc = cov[k] if np.all(np.isfinite(cov[k])) else None
            stream.append(f.feed(tr.t_s[k], g[k], ins.pos_ne_m[k], ins.vel_ne_mps[k], 1.0, ref_cov_ne_m2=rc))
        assert all(e is not None for e in stream)
        np.testing.assert_array_equal(batch.pos_ne_m, [e.pos_ne_m for e in stream])
        np.testing.assert_array_equal(batch.cov_ne_m2, [e.cov_ne_m2 for e in stream])
        np.testing.assert_array_equal(batch.status, [e.status for e in stream])
        np.testing.assert_array_equal(batch.n_eff, [e.n_eff for e in stream])
        assert batch.status[0] == "anchored" and batch.status[-1] != "anchored"


def test_rejects_unusable_readings():
    f = SequentialGravityFilter(MAP, SeqGravConfig(n_particles=100), 0)
    assert f.feed(0.0, np.nan, (0.0, 0.0), (5.0, 0.0), 1.0) is None
    assert f.feed(0.0, 1.0, (0.0, 0.0), (5.0, 0.0), 1.0) is not None
    assert f.feed(0.0, 1.0, (5.0, 0.0), (5.0, 0.0), 1.0) is None  # not after the previous reading
    assert f.feed(1.0, 1.0, (5.0, 0.0), (5.0, 0.0), 0.0) is None  # no noise level
    assert f.feed(1.0, 1.0, (5.0, 0.0), (5.0, 0.0), 1.0) is not None


def test_flat_region_reports_no_signal_and_keeps_honest_spread():
    """Map constant east of 0 m: once in the flat part the filter says no_signal, never ok, and its spread keeps
    growing (north like the INS alone; east a little slower: the Eotvos error of the INS velocity still tells the
    east velocity error) and covers the error."""
    flat = _synthetic_map(flat_east_of_m=0.0)
    tr = make_trajectory(8.0, [Segment(3600.0)], dt_s=1.0, heading0_deg=90.0, start_ne_m=(0.0, 5_000.0))
    rng = np.random.default_rng(2)
    ins = simulate_ins(tr, 45.0, InsErrorModel(), rng)
    g = flat.interp_ne(tr.pos_ne_m[:, 0], tr.pos_ne_m[:, 1]) + rng.normal(0.0, 1.0, len(tr))
    g = g + eotvos_from_ne_mgal(tr.vel_ne_mps, 45.0) - eotvos_from_ne_mgal(ins.vel_ne_mps, 45.0)
    cov = np.full((len(tr), 2, 2), np.nan)
    cov[0] = np.eye(2) * 25.0
    out = run_batch(flat, tr.t_s, g, ins.pos_ne_m, ins.vel_ne_mps, 1.0, ref_cov_ne_m2=cov,
                    cfg=SeqGravConfig(n_particles=500), rng=4)
    after = out.t_s > 900.0  # the signal window (6 km) is full of flat map
    assert set(out.status[after]) == {"no_signal"}
    assert np.all(out.signal_ratio[after] < 0.5)
    assert out.h_acc_m[-1] > out.h_acc_m[np.searchsorted(out.t_s, 900.0)]
    assert np.sqrt(out.cov_ne_m2[-1, 0, 0]) >= 0.5 * out.ins_h_sigma_m[-1] / np.sqrt(2.0)  # north: no map information
    err = np.hypot(*(out.pos_ne_m - tr.pos_ne_m[out.index]).T)
    assert np.mean(err[after] <= 2.0 * out.h_acc_m[after]) >= 0.9


def test_unaided_covariance_is_what_a_filter_without_information_states():
    """``unaided_cov_ne_m2``: the covariance the filter would state without readings. On a flat map with readings
    that carry no velocity error (Eotvos-corrected by the sender) nothing informs the position: the stated covariance
    grows as the unaided one does, random walk included. On the bumpy map the readings shrink it far below."""
    flat = _synthetic_map(flat_east_of_m=-1e9)
    cfg = SeqGravConfig(n_particles=500, pos_noise_m_rts=2.0)
    tr = make_trajectory(8.0, [Segment(1800.0)], dt_s=1.0, heading0_deg=90.0, start_ne_m=(0.0, -20_000.0))
    for lmap, lo, hi in ((flat, 0.8, 1.2), (MAP, 0.0, 0.5)):
        f = SequentialGravityFilter(lmap, cfg, np.random.default_rng(1))
        rng = np.random.default_rng(2)
        e = None
        for i in range(0, len(tr), 5):
            g = float(lmap.interp_ne(tr.pos_ne_m[i:i + 1, 0], tr.pos_ne_m[i:i + 1, 1])[0]) + rng.normal(0.0, 1.0)
            e = f.feed(float(tr.t_s[i]), g, tr.pos_ne_m[i], tr.vel_ne_mps[i], 1.0,
                       ref_cov_ne_m2=np.eye(2) * 25.0 if i == 0 else None, eotvos_from_reference=False)
        un = f.unaided_cov_ne_m2()
        assert np.trace(un) > np.trace(f.ins_alone_cov_ne_m2()) + 2 * 2.0**2 * 1700.0  # the walk is in it
        assert lo <= np.trace(e.cov_ne_m2) / np.trace(un) <= hi


def test_divergence_detected_and_reinitialised():
    """Readings that no position on the map explains (a 40 mGal square wave over a flat map, the filter told
    1 mGal): the windowed innovation test fires and the filter re-initialises around the reference."""
    flat = _synthetic_map(flat_east_of_m=-70_000.0)
    tr = make_trajectory(8.0, [Segment(2400.0)], dt_s=1.0, heading0_deg=0.0, start_ne_m=(0.0, 0.0))
    g = 10.0 + 40.0 * (np.floor(tr.t_s / 300.0) % 2)
    out = run_batch(flat, tr.t_s, g, tr.pos_ne_m, tr.vel_ne_mps, 1.0, cfg=SeqGravConfig(n_particles=300), rng=1)
    assert out.reinit_count[-1] >= 1
    assert "reinit" in set(out.status)
    k = int(np.flatnonzero(out.status == "reinit")[0])
    assert out.nis_mean[k - 1] > SeqGravConfig().nis_max or out.h_acc_m[k] > 0


@pytest.mark.parametrize("method", ["mpf"])
def test_covariance_is_honest_on_a_small_monte_carlo(method):
    """NEES of the 2-D position over 4 seeds (Liu-grade INS, 1 mGal noise, Eotvos from the INS velocity):
    mean within a generous [0.3, 5] around the 2 expected, >= 85 % of errors within 2 x h_acc."""
    nees, cover = [], []
    for seed in range(4):
        tr, ins, g = _noisy_run(100 + seed, hours=0.5)
        cov = np.full((len(tr), 2, 2), np.nan)
        cov[0] = np.eye(2) * 4.0  # the INS starts from a GNSS fix
        out = run_batch(MAP, tr.t_s, g, ins.pos_ne_m, ins.vel_ne_mps, 1.0, ref_cov_ne_m2=cov,
                        cfg=SeqGravConfig(method=method), rng=seed)
        free = out.status != "anchored"
        d = out.pos_ne_m[free] - tr.pos_ne_m[out.index[free]]
        P = out.cov_ne_m2[free]
        nees.append(np.einsum("ni,nij,nj->n", d, np.linalg.inv(P), d))
        cover.append(np.hypot(*d.T) <= 2.0 * out.h_acc_m[free])
    nees = np.concatenate(nees)
    assert 0.3 < float(np.mean(nees)) < 5.0
    assert float(np.mean(np.concatenate(cover))) >= 0.85


def test_apply_correction_moves_the_error_with_the_reference():
    f = SequentialGravityFilter(MAP, SeqGravConfig(n_particles=200), 0)
    e0 = f.feed(0.0, float(MAP.interp_ne(0.0, 0.0)), (100.0, 0.0), (5.0, 0.0), 1.0, ref_cov_ne_m2=np.eye(2) * 1e4)
    f.apply_correction((-100.0, 0.0))  # the navigator moved its reference 100 m south
    e1 = f.feed(1.0, float(MAP.interp_ne(5.0, 0.0)), (5.0, 0.0), (5.0, 0.0), 1.0)
    assert e1.err_ne_m[0] == pytest.approx(e0.err_ne_m[0] - 100.0, abs=5.0)


def test_attitude_held_by_a_reference_gives_the_velocity_random_walk_of_its_tilt_error():
    """InsErrorSpec.attitude_tau_s > 0 (an AHRS-held attitude): no Schuler loop, psi a Gauss-Markov process, and the
    velocity error variance driven by a tilt error of sigma, tau is the integral of g psi:
    Var(dv)(t) = 2 g^2 sigma^2 tau (t - tau (1 - exp(-t / tau))) from a stationary start."""
    from companion.gravity.sequential import (G0_MPS2, InsErrorSpec, MapErrorSpec, N_NL, IPSI, IV, continuous_noise,
                                              discretise, prior_covariance)

    sig, tau = 3.5e-4, 60.0
    ins = InsErrorSpec(accel_bias_ug=0.0, accel_vrw_ug_rthz=0.0, init_vel_sigma_mps=0.0, attitude_tau_s=tau,
                       attitude_tilt_sigma_rad=sig, attitude_heading_sigma_rad=2 * sig)
    cfg = SeqGravConfig(ins=ins)
    A = error_dynamics(np.radians(45.0), (0.0, 0.0), (0.0, 0.0), 0.0, 1e9, attitude_tau_s=tau)
    assert A[N_NL + IV, N_NL] == 0.0 and A[N_NL + IPSI, N_NL + IPSI] == pytest.approx(-1.0 / tau)
    P = prior_covariance(cfg, np.eye(2))
    P[N_NL + IV:N_NL + IV + 2] = 0.0
    P[:, N_NL + IV:N_NL + IV + 2] = 0.0
    Phi, Qd = discretise(A, continuous_noise(ins, MapErrorSpec(), 1e9), 1.0)
    t_end = 1800
    for _ in range(t_end):
        P = Phi @ P @ Phi.T + Qd
    want = 2 * G0_MPS2**2 * sig**2 * tau * (t_end - tau * (1 - np.exp(-t_end / tau)))
    assert P[N_NL + IV, N_NL + IV] == pytest.approx(want, rel=0.03)
    assert np.sqrt(P[N_NL + IPSI, N_NL + IPSI]) == pytest.approx(sig, rel=0.01)  # stationary


@pytest.mark.parametrize("roughen,shrink,expected", [(None, True, 1.0), (None, False, 1.1), (0.1, False, 1.01)])
def test_resampling_kernel_against_a_known_posterior(roughen, shrink, expected):
    """Regularised resampling against a known posterior: prior N(0, 1000^2 I) particles weighted by a Gaussian
    likelihood N(0, 300^2) per axis (posterior variance s^2 = 1 / (1/1000^2 + 1/300^2)). With roughen=None the
    kernel is the regularised particle filter's optimum for N = 1000, d = 2 (h^2 = 0.1): with Liu-West shrinkage the
    population keeps the posterior's mean and variance (ratio 1), without it every resampling inflates it by
    1 + h^2 (the default 0.1 kernel by 1.01). Averaged over 20 draws; the mean stays at 0."""
    from companion.gravity.sequential_backends import _Mpf, rpf_bandwidth, prior_covariance

    cfg = SeqGravConfig(n_particles=1000, roughen=roughen, roughen_shrink=shrink)
    s2 = 1.0 / (1.0 / 1000.0**2 + 1.0 / 300.0**2)
    assert rpf_bandwidth(1000, 2) ** 2 == pytest.approx(0.1, rel=1e-9)
    ratios, means, distinct = [], [], []
    for seed in range(20):
        be = _Mpf(cfg, np.random.default_rng(seed))
        be.init(prior_covariance(cfg, np.eye(2) * 1000.0**2))
        lw = -0.5 * np.sum(be.xn**2, axis=1) / 300.0**2
        w = np.exp(lw - lw.max())
        be.w = w / w.sum()
        assert be.resample_if_needed()
        ratios.append(np.var(be.xn, axis=0) / s2)
        means.append(be.xn.mean(axis=0))
        distinct.append(np.unique(be.xn[:, 0]).size)
    assert float(np.mean(ratios)) == pytest.approx(expected, abs=0.04)
    assert np.all(np.abs(np.mean(means, axis=0)) < 30.0)
    assert min(distinct) == 1000  # no two particles share a position after the kernel
