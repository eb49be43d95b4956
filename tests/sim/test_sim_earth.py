"""The simulator's rotating-ellipsoid Earth (FlightProfile(earth="ellipsoid")): truth geometry, IMU physics, and a
free strapdown INS fed by the simulated IMU staying on the truth -- which the flat-Earth IMU does not allow."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.nav.ins import StrapdownIns
from companion.nav.frame import EARTH_RATE_RADPS, LocalFrame, normal_gravity_mps2, radii_m
from companion.sim.cruise import cruise_profile
from companion.sim.flight import SimConfig, simulate_flight
from companion.sim.sensors import GnssModel, ImuModel, simulate_imu
from companion.sim.trajectory import FlightProfile, Hold, Speed, Straight

ORIGIN = LocalFrame(-40.5, 155.6, 120.0)


@pytest.fixture(scope="module")
def cruises():
    """The same 25 min survey (150 m/s, 40 km lines 10 km apart: 8 fly-by turns) on both Earth models."""
    kw = dict(hours=25.0 / 60.0, speed_mps=150.0, line_km=40.0, spacing_km=10.0, heading_deg=30.0)
    return {e: cruise_profile(ORIGIN, earth=e, **kw) for e in ("flat", "ellipsoid")}


def _free_ins_errors(profile, minutes, rate_hz=100.0):
    """Free INS from the truth at t = 0 on a perfect IMU; (horizontal, down) error in m at each whole minute.

    IMU samples are taken at mid-interval and held over the interval, like an integrating IMU (tests/nav/test_ins.py)."""
    n = int(round(minutes * 60.0 * rate_hz))
    t = np.arange(1, n + 1) / rate_hz
    imu = simulate_imu(profile.sample(t - 0.5 / rate_hz), ImuModel.perfect(), np.random.default_rng(0))
    tr0 = profile.sample(0.0)
    ins = StrapdownIns(0.0, tr0.lat_deg[0], tr0.lon_deg[0], tr0.alt_msl_m[0], tr0.vel_ned_mps[0], *tr0.euler_rad[0])
    every = int(round(60.0 * rate_hz))
    truth = profile.sample(t[every - 1::every])
    acc, gyr = imu.accel_frd_mps2.tolist(), imu.gyro_frd_radps.tolist()
    out = []
    for i in range(n):
        ins.step(float(t[i]), acc[i], gyr[i])
        if (i + 1) % every == 0:
            j = len(out)
            d = LocalFrame(truth.lat_deg[j], truth.lon_deg[j], truth.alt_msl_m[j]).to_ned_m(ins.lat_deg, ins.lon_deg, ins.h_m)
            out.append((math.hypot(d[0], d[1]), d[2]))
    return np.array(out)


def test_free_ins_on_the_simulated_imu_stays_on_the_ellipsoid_truth(cruises):
    """Decisive: the INS integrates exactly the simulated physics, so with a perfect IMU it stays within
    its own discretisation error (measured 0.37 m horizontal, 0.09 m vertical after 20 min at 100 Hz); the
    flat-Earth IMU (no Earth rate, no Coriolis, constant g) sends the same INS off by kilometres in minutes."""
    ell = _free_ins_errors(cruises["ellipsoid"], 20.0)
    assert ell[:, 0].max() < 2.0, ell[:, 0]
    assert np.abs(ell[:, 1]).max() < 1.0, ell[:, 1]  # vertical: unstable by physics, but the physics agree
    flat = _free_ins_errors(cruises["flat"], 5.0)
    assert flat[-1, 0] > 1000.0, flat[:, 0]  # measured 2.8 km after 5 min
    assert flat[-1, 0] > 500.0 * ell[:, 0].max()


def test_truth_lat_lon_follow_the_ellipsoid_not_the_tangent_plane():
    """A 150 km leg due north covers the meridian arc of that length; one due east keeps its latitude (a rhumb line
    in the local level) and gains distance / ((R_N + h) cos lat) of longitude. Independent of the grid integration."""
    legs = [Hold(1.0), Speed(150.0, 2.0), Straight(150_000.0), Speed(0.0, 2.0), Hold(1.0)]
    h = ORIGIN.ref_alt_m
    north = FlightProfile(legs, ORIGIN, start_heading_deg=0.0, internal_rate_hz=25.0, earth="ellipsoid")
    end = north.sample(north.duration_s)
    dist = float(end.pos_ned_m[0, 0])
    lat = np.radians(np.linspace(ORIGIN.ref_lat_deg, end.lat_deg[0], 20001))
    rm, _ = radii_m(lat)
    arc = float(np.trapezoid(rm + h, lat))  # meridian arc from the origin to the truth latitude
    assert arc == pytest.approx(dist, abs=1e-3)
    assert end.lon_deg[0] == pytest.approx(ORIGIN.ref_lon_deg, abs=1e-12)
    # the tangent-plane mapping is off by metres here (R_M changes by 0.03 % over 1.35 deg)
    flat_lat = ORIGIN.to_geodetic(end.pos_ned_m[0])[0]
    assert abs(float(flat_lat) - end.lat_deg[0]) * 111_000.0 > 5.0

    east = FlightProfile(legs, ORIGIN, start_heading_deg=90.0, internal_rate_hz=25.0, earth="ellipsoid")
    tr = east.sample_rate(1.0)
    assert np.abs(tr.lat_deg - ORIGIN.ref_lat_deg).max() < 1e-12
    lat0 = math.radians(ORIGIN.ref_lat_deg)
    _, rn = radii_m(lat0)
    dlon = np.degrees(tr.pos_ned_m[:, 1] / ((float(rn) + h) * math.cos(lat0)))
    assert np.abs(tr.lon_deg - (ORIGIN.ref_lon_deg + dlon)).max() * 111_000.0 < 1e-3


def test_coarse_grid_truth_lat_lon_match_the_fine_one():
    kw = dict(hours=0.1, speed_mps=150.0, line_km=30.0, spacing_km=10.0)
    coarse = cruise_profile(ORIGIN, internal_rate_hz=25.0, **kw)
    fine = cruise_profile(ORIGIN, internal_rate_hz=2000.0, **kw)
    t = np.linspace(0.0, coarse.duration_s, 3001)
    a, b = coarse.sample(t), fine.sample(t)
    assert np.abs(a.lat_deg - b.lat_deg).max() * 111_000.0 < 1e-3
    assert np.abs(a.lon_deg - b.lon_deg).max() * 111_000.0 * math.cos(math.radians(ORIGIN.ref_lat_deg)) < 1e-3
    np.testing.assert_array_equal(a.alt_msl_m, b.alt_msl_m)


def test_imu_at_rest_reads_normal_gravity_and_earth_rate_and_flat_stays_flat(cruises):
    ell = cruises["ellipsoid"].sample([1.0, 3.0])  # on the ground, level, nose along the first line
    lat = math.radians(ORIGIN.ref_lat_deg)
    c_bn = ell.c_nb[0].T
    np.testing.assert_allclose(ell.specific_force_frd_mps2[0], [0.0, 0.0, -float(normal_gravity_mps2(lat, 120.0))], atol=1e-12)
    w_ie = EARTH_RATE_RADPS * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    np.testing.assert_allclose(ell.gyro_truth_frd_radps[0], c_bn @ w_ie, atol=1e-15)
    np.testing.assert_array_equal(ell.rate_frd_radps, 0.0)  # relative to NED: not rotating
    flat = cruises["flat"].sample([1.0])
    assert flat.rate_ib_frd_radps is None and flat.earth == "flat"
    np.testing.assert_allclose(flat.specific_force_frd_mps2[0], [0.0, 0.0, -9.80665], atol=1e-12)
    np.testing.assert_array_equal(flat.gyro_truth_frd_radps, 0.0)
    # slicing keeps the Earth model and the inertial rates
    s = ell.slice(slice(1, 2))
    assert s.earth == "ellipsoid" and s.rate_ib_frd_radps.shape == (1, 3)


def test_simulated_flight_uses_the_ellipsoid_truth_everywhere():
    """GNSS, IMU and ATTITUDE of a simulated ellipsoid cruise: GNSS lat/lon are the truth moved by the simulated error,
    the IMU reads the rotating-Earth truth, ATTITUDE keeps the rates relative to NED."""
    p = cruise_profile(ORIGIN, hours=0.1, speed_mps=150.0, line_km=30.0, spacing_km=10.0)
    assert p.earth == "ellipsoid"
    f = simulate_flight(p, 5, SimConfig(imu_rate_hz=10.0, gnss_rate_hz=1.0, imu=ImuModel.perfect(), imu2=None))
    g, tr = f.gnss, f.truth_gnss
    d = np.stack([LocalFrame(la, lo, al).to_ned_m(g.lat_deg[k], g.lon_deg[k], g.alt_msl_m[k])
                  for k, (la, lo, al) in enumerate(zip(tr.lat_deg, tr.lon_deg, tr.alt_msl_m))])
    assert np.abs(d - g.pos_error_ned_m).max() < 1e-3
    assert np.abs(g.pos_error_ned_m[:, :2]).max() > 0.5  # the error is there
    np.testing.assert_array_equal(f.imu.accel_frd_mps2, f.truth_imu.specific_force_frd_mps2)
    np.testing.assert_array_equal(f.imu.gyro_frd_radps, f.truth_imu.rate_ib_frd_radps)
    assert np.abs(f.imu.gyro_frd_radps - f.truth_imu.rate_frd_radps).max() > 4e-5  # Earth rate (+ transport)
    rate_err = f.attitude_rates_radps - f.truth_attitude.rate_frd_radps
    assert np.abs(rate_err).max() < 6 * f.config.attitude.rate_noise_radps
    perfect = simulate_flight(p, 5, SimConfig(imu_rate_hz=10.0, gnss_rate_hz=1.0, gnss=GnssModel.perfect(), imu2=None))
    np.testing.assert_allclose(perfect.gnss.lat_deg, perfect.truth_gnss.lat_deg, rtol=0, atol=1e-12)
    np.testing.assert_allclose(perfect.gnss.lon_deg, perfect.truth_gnss.lon_deg, rtol=0, atol=1e-12)


def test_unknown_earth_model_is_an_error():
    with pytest.raises(ValueError, match="earth"):
        FlightProfile([Hold(1.0)], ORIGIN, earth="round")
