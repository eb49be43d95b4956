"""The 2-D gravity scenario model: tracks, INS error model, gravimeter, Eotvos."""

from dataclasses import replace

import numpy as np
import pytest

from companion.nav.frame import EARTH_RATE_RADPS, WGS84_A_M
from companion.gravity import GravityMap, LocalGravityMap
from tests.conftest import SHARED_GRAVITY, require
from companion.gravity.eotvos import MPS_PER_KNOT, correct_eotvos_mgal, eotvos_from_ne_mgal, eotvos_mgal
from companion.sim.gravity_scenario import (GravimeterModel, InsErrorModel, Segment, make_trajectory, record_by_distance,
                                simulate_ins, simulate_run, turn)

NO_ERRORS = InsErrorModel(gyro_bias_degph=0, accel_bias_ug=0, gyro_arw_deg_rthr=0, accel_vrw_ug_rthz=0,
                          init_tilt_sigma_rad=0, init_heading_sigma_rad=0)


def _geo_map():
    lon = np.linspace(-146, -142, 121)
    lat = np.linspace(55, 57, 61)
    g = 20 * np.sin(np.radians(lon * 40))[None, :] + 15 * np.cos(np.radians(lat * 55))[:, None]
    return LocalGravityMap.around(GravityMap(g, lon, lat, "geographic_deg"), 56.0, -144.0)


def test_eotvos_worked_value():
    # 10 kn due east on the equator: 7.5 * 10 + 0.004 * 100 = 75.4 mGal (eq. 5)
    assert eotvos_mgal(10 * MPS_PER_KNOT, np.pi / 2, 0.0) == pytest.approx(75.4, abs=1e-9)
    # and it agrees with the physics 2 Omega v_E cos(lat) + v^2 / R to 0.1 mGal
    v = 10 * MPS_PER_KNOT
    exact = (2 * EARTH_RATE_RADPS * v + v**2 / WGS84_A_M) * 1e5
    assert eotvos_mgal(v, np.pi / 2, 0.0) == pytest.approx(exact, abs=0.1)
    # heading north at 60 deg: only the v^2 term; westward halves with cos(60)
    assert eotvos_mgal(v, 0.0, 60.0) == pytest.approx(0.4)
    assert eotvos_mgal(v, -np.pi / 2, 60.0) == pytest.approx(-37.5 + 0.4)
    assert eotvos_from_ne_mgal(np.array([0.0, v]), 0.0) == pytest.approx(75.4)
    assert correct_eotvos_mgal(100.0, np.array([0.0, v]), 0.0) == pytest.approx(24.6)  # eq. 6


def test_trajectory_curvature_and_turns():
    r = 2000.0
    tr = make_trajectory(5.0, [Segment(2 * np.pi * r / 5.0, 1.0 / r)], dt_s=0.5, heading0_deg=0.0)
    centre = np.array([0.0, r])  # right turn from heading north
    np.testing.assert_allclose(np.hypot(*(tr.pos_ne_m - centre).T), r, rtol=1e-4)
    np.testing.assert_allclose(np.hypot(*tr.vel_ne_mps.T), 5.0)
    np.testing.assert_allclose(np.hypot(*tr.acc_ne_mps2.T), 25.0 / r, rtol=1e-9)
    tr2 = make_trajectory(200.0, [Segment(60), turn(90.0, 5000.0, 200.0), Segment(60)], heading0_deg=0.0)
    assert np.degrees(tr2.heading_rad[-1]) == pytest.approx(90.0, abs=0.5)
    idx = record_by_distance(tr2.distance_m(), 1000.0)
    assert np.allclose(np.diff(tr2.distance_m()[idx]), 1000.0, atol=200.0)


def test_ins_drift_is_realistic():
    tr = make_trajectory(5.0, [Segment(4 * 3600.0)], dt_s=2.0, heading0_deg=45.0)
    # no error sources: no drift
    out = simulate_ins(tr, 30.0, NO_ERRORS, np.random.default_rng(0))
    assert np.abs(out.pos_err_ne_m).max() < 1e-9
    # accelerometer bias only: Schuler-bounded, peak error ~ 2 b R / g
    acc = InsErrorModel(gyro_bias_degph=0, accel_bias_ug=100, gyro_arw_deg_rthr=0, accel_vrw_ug_rthz=0,
                        init_tilt_sigma_rad=0, init_heading_sigma_rad=0)
    out = simulate_ins(tr, 30.0, acc, np.random.default_rng(1))
    b = np.hypot(*out.accel_bias_mps2[:2])
    peak = np.hypot(*out.pos_err_ne_m.T).max()
    assert 0.5 * 2 * b * WGS84_A_M / 9.8 < peak < 1.5 * 2 * b * WGS84_A_M / 9.8
    # paper-grade gyro (0.01 deg/h): km-level drift after hours, not metres, not hundreds of km
    drifts = [np.hypot(*simulate_ins(tr, 30.0, InsErrorModel(), np.random.default_rng(s)).pos_err_ne_m[-1]) for s in range(5)]
    assert 300 < np.median(drifts) < 20_000


def test_ins_with_attitude_reference():
    """attitude_tau_s > 0: psi is the reference's stationary Gauss-Markov error (its sigmas, its time constant) and
    there is no Schuler loop, so an accelerometer bias alone grows the position error as b t^2 / 2."""
    tr = make_trajectory(8.0, [Segment(4 * 3600.0)], dt_s=1.0, heading0_deg=30.0)
    tau, tilt, head = 60.0, 3e-4, 9e-4
    held = InsErrorModel(gyro_bias_degph=0.01, accel_bias_ug=0, gyro_arw_deg_rthr=0.001, accel_vrw_ug_rthz=0,
                         attitude_tau_s=tau, attitude_tilt_sigma_rad=tilt, attitude_heading_sigma_rad=head)
    psi = np.concatenate([simulate_ins(tr, 30.0, held, np.random.default_rng(s)).psi_ned_rad for s in range(4)])
    np.testing.assert_allclose(psi.std(axis=0), [tilt, tilt, head], rtol=0.12)  # the gyro errors play no part
    one = psi[: tr.t_s.size]
    lag1 = [np.corrcoef(one[:-1, i], one[1:, i])[0, 1] for i in range(3)]
    np.testing.assert_allclose(lag1, np.exp(-1.0 / tau), atol=0.01)
    bias_only = InsErrorModel(gyro_bias_degph=0, accel_bias_ug=100, gyro_arw_deg_rthr=0, accel_vrw_ug_rthz=0,
                              attitude_tau_s=tau, attitude_tilt_sigma_rad=0.0, attitude_heading_sigma_rad=0.0)
    out = simulate_ins(tr, 30.0, bias_only, np.random.default_rng(1))
    b = np.hypot(*out.accel_bias_mps2[:2])
    t_end = tr.t_s[-1]
    assert np.hypot(*out.pos_err_ne_m[-1]) == pytest.approx(0.5 * b * t_end**2, rel=1e-3)
    # the same bias in a free INS stays Schuler-bounded (~2 b R / g, see test_ins_drift_is_realistic): under 2 % of
    # the held INS's b t^2 / 2
    free = simulate_ins(tr, 30.0, replace(bias_only, attitude_tau_s=0.0), np.random.default_rng(1))
    assert np.hypot(*free.pos_err_ne_m.T).max() < 0.02 * 0.5 * b * t_end**2
    # the attitude mode draws after the free INS's draws, so the same seed gives the same accelerometer bias
    np.testing.assert_array_equal(out.accel_bias_mps2, free.accel_bias_mps2)


def test_measurements_and_eotvos_correction_consistent():
    lm = _geo_map()
    tr = make_trajectory(5.0, [Segment(3000.0), turn(120, 3000, 5.0), Segment(2000.0)], dt_s=5.0, heading0_deg=80.0,
                         start_ne_m=(-20000.0, -30000.0))
    run = simulate_run(lm, tr, NO_ERRORS, GravimeterModel(sigma_mgal=0.0), np.random.default_rng(0))
    np.testing.assert_allclose(run.gravity_mgal, run.map_true_mgal, atol=1e-9)
    assert np.abs(run.gravity_raw_mgal - run.map_true_mgal).max() > 20  # Eotvos was really added
    noisy = simulate_run(lm, tr, NO_ERRORS, GravimeterModel(sigma_mgal=2.0), np.random.default_rng(0))
    assert np.std(noisy.gravity_mgal - noisy.map_true_mgal) == pytest.approx(2.0, rel=0.15)


def test_simulator_deterministic_by_seed():
    lm = _geo_map()
    tr = make_trajectory(5.0, [Segment(5000.0, 1e-5)], dt_s=5.0, heading0_deg=70.0, start_ne_m=(-20000.0, -30000.0))
    model = InsErrorModel(init_pos_sigma_m=2000.0)
    a = simulate_run(lm, tr, model, GravimeterModel(sigma_mgal=3.0), np.random.default_rng(42))
    b = simulate_run(lm, tr, model, GravimeterModel(sigma_mgal=3.0), np.random.default_rng(42))
    c = simulate_run(lm, tr, model, GravimeterModel(sigma_mgal=3.0), np.random.default_rng(43))
    for f in ("ins_ne_m", "ins_vel_ne_mps", "gravity_raw_mgal", "gravity_mgal"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        assert not np.array_equal(getattr(a, f), getattr(c, f))


def test_residual_noise_mode_uses_real_residuals():
    require(SHARED_GRAVITY)
    from companion.sim.gravity_residuals import ship_minus_satellite_mgal

    res = ship_minus_satellite_mgal()
    assert res.size > 1000 and res.mean() == pytest.approx(1.3, abs=0.15) and res.std() == pytest.approx(5.7, abs=0.2)
    lm = _geo_map()
    tr = make_trajectory(5.0, [Segment(6000.0)], dt_s=66.0, heading0_deg=80.0, start_ne_m=(-20000.0, -30000.0))
    run = simulate_run(lm, tr, NO_ERRORS, GravimeterModel(noise="residuals", eotvos=False), np.random.default_rng(5),
                       residuals_mgal=res)
    noise = run.gravity_mgal - run.map_true_mgal
    assert np.all(np.min(np.abs(noise[:, None] - res[None, :]), axis=1) < 1e-9)  # every value is a real residual
    # samples 330 m apart take consecutive residuals (a contiguous block, keeping their correlation)
    from companion.sim.gravity_scenario import gravimeter_noise_mgal

    blk = gravimeter_noise_mgal(GravimeterModel(noise="residuals"), 330.0 * np.arange(6), np.random.default_rng(9), res)
    start = int(np.random.default_rng(9).integers(0, res.size))
    np.testing.assert_array_equal(blk, res[(start + np.arange(6)) % res.size])
