"""SITL's truth in place of one input of the air-data reference (replay.live.sitl_gravity_truth): the true wind from
the truth's displacement and the recorded airspeed, a dead reckoning that takes the true heading and wind, and a
perfect gravimeter's reading, on scripted flights with a known wind."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.gravity.air_data import AirDataReckoner, radii_m
from companion.gravity.eotvos import eotvos_from_ne_mgal
from companion.gravity.maps import LocalGravityMap, load_grid
from replay.live import sitl_gravity_truth as tru
from tests.conftest import AK_MAP, require

LAT0_DEG, LON0_DEG = 56.2, -143.0
TAS_MPS = 22.0


def _wind_ne_mps(t_s: float, turn_s: float) -> np.ndarray:
    return np.array([3.0, -4.0]) if t_s < turn_s else np.array([-1.0, 5.0])


def _flight(duration_s: float = 1800.0, turn_s: float = 900.0, dt_s: float = 0.2, legs: bool = True):
    """Legs of 300 s turning by 90 deg (or one straight line), weaving by 30 deg, TAS 22 m/s along the yaw, a wind
    that steps at ``turn_s``: (t, lat, lon, yaw)."""
    t = np.arange(0.0, duration_s, dt_s)
    yaw = np.radians(20.0 + 90.0 * np.floor(t / 300.0) * legs + 30.0 * np.sin(t / 40.0))
    lat, lon = [LAT0_DEG], [LON0_DEG]
    for k in range(1, len(t)):
        air = 0.5 * TAS_MPS * np.array([math.cos(yaw[k - 1]) + math.cos(yaw[k]), math.sin(yaw[k - 1]) + math.sin(yaw[k])])
        v = air + _wind_ne_mps(t[k - 1], turn_s)
        rm, rn = radii_m(lat[-1])
        lat.append(lat[-1] + math.degrees(v[0] * dt_s / rm))
        lon.append(lon[-1] + math.degrees(v[1] * dt_s / (rn * math.cos(math.radians(lat[-1])))))
    return t, np.array(lat), np.array(lon), yaw


def _track(t, lat, lon, yaw) -> tru.TruthTrack:
    wrapped = (yaw + math.pi) % (2 * math.pi) - math.pi  # SIMSTATE's yaw is wrapped
    return tru.TruthTrack(list(zip(t, lat, lon)), list(zip(t, wrapped)))


def test_truth_yaw_interpolates_across_the_wrap():
    tr = tru.TruthTrack([(0.0, 0.0, 0.0), (1.0, 0.0, 1e-5)], [(0.0, math.radians(179.0)), (1.0, math.radians(-179.0))])
    assert abs(math.degrees(tr.yaw_rad(0.5))) == pytest.approx(180.0, abs=1e-6)
    assert math.degrees(tr.yaw_rad(0.25)) == pytest.approx(179.5, abs=1e-6)


def test_true_wind_is_the_displacement_minus_the_airspeed_along_the_true_yaw():
    t, lat, lon, yaw = _flight()
    wind = tru.TruthWind(_track(t, lat, lon, yaw), t, np.full(t.size, TAS_MPS), window_s=60.0)
    for at_s, want in ((450.0, (3.0, -4.0)), (750.0, (3.0, -4.0)), (1050.0, (-1.0, 5.0)), (1650.0, (-1.0, 5.0))):
        assert wind.at(at_s) == pytest.approx(want, abs=0.02)
    # across the step the window's mean: half of each wind at the step
    assert wind.at(900.0) == pytest.approx((1.0, 0.5), abs=0.1)
    # an airspeed 2 % high (a scale error) leaves its along-yaw part in the wind the reference sees
    scaled = tru.TruthWind(_track(t, lat, lon, yaw), t, np.full(t.size, 1.02 * TAS_MPS), window_s=60.0)
    y = yaw[np.searchsorted(t, 450.0)]
    assert scaled.at(450.0) == pytest.approx(np.array([3.0, -4.0]) - 0.02 * TAS_MPS * np.array([math.cos(y), math.sin(y)]),
                                             abs=0.05)


def _reckon(rk: AirDataReckoner, t, lat, lon, yaw, gnss_until_s: float, heading_err_rad: float = 0.0):
    """GNSS (with velocity) until ``gnss_until_s``, then dead reckoning; the heading given is yaw + heading_err_rad.
    Returns the horizontal error (m) at the end."""
    for k in range(1, len(t)):
        ts = t[k]
        rk.airspeed(ts, TAS_MPS)
        rk.heading(ts, yaw[k] + heading_err_rad)
        if ts <= gnss_until_s:
            dt = t[k] - t[k - 1]
            rm, rn = radii_m(lat[k])
            v = (math.radians(lat[k] - lat[k - 1]) * rm / dt,
                 math.radians(lon[k] - lon[k - 1]) * rn * math.cos(math.radians(lat[k])) / dt)
            rk.gnss(ts, lat[k], lon[k], v)
        else:
            rk.advance(ts)
    rm, rn = radii_m(lat[-1])
    return math.hypot(math.radians(rk.lat - lat[-1]) * rm,
                      math.radians(rk.lon - lon[-1]) * rn * math.cos(math.radians(lat[-1])))


def test_dead_reckoning_with_the_true_wind_and_heading_follows_the_truth():
    t, lat, lon, yaw = _flight(legs=False)  # one direction: a heading error does not cancel over the legs
    track = _track(t, lat, lon, yaw)
    wind = tru.TruthWind(track, t, np.full(t.size, TAS_MPS), window_s=60.0)
    held = _reckon(AirDataReckoner(), t, lat, lon, yaw, gnss_until_s=600.0)
    assert held > 5000.0  # the wind stepped by 10.8 m/s for 900 s
    # the true wind: only the step's smoothing over the window is left (the window is centred: it cancels)
    assert _reckon(tru.TruthReckoner(wind=wind), t, lat, lon, yaw, gnss_until_s=600.0) < 30.0
    # a 5 deg heading error: 22 m/s x 0.087 rad over 1200 s is some 2.3 km; the true heading takes it away (the held
    # wind, learnt along the true heading, still has the step)
    off = math.radians(5.0)
    assert _reckon(tru.TruthReckoner(wind=wind), t, lat, lon, yaw, 600.0, heading_err_rad=off) > 1500.0
    both = _reckon(tru.TruthReckoner(yaw=track, wind=wind), t, lat, lon, yaw, 600.0, heading_err_rad=off)
    assert both < 30.0
    assert _reckon(tru.TruthReckoner(yaw=track), t, lat, lon, yaw, 600.0, heading_err_rad=off) == pytest.approx(held, rel=0.02)


def test_a_perfect_reading_is_the_mean_map_over_its_window_plus_the_true_eotvos_term():
    lmap = LocalGravityMap.around(load_grid(require(AK_MAP)))
    t = np.arange(0.0, 120.0, 0.2)  # due east at 22 m/s along the latitude
    rm, rn = radii_m(LAT0_DEG)
    lon = LON0_DEG + np.degrees(TAS_MPS * t / (rn * math.cos(math.radians(LAT0_DEG))))
    lat = np.full(t.size, LAT0_DEG)
    track = tru.TruthTrack(list(zip(t, lat, lon)), list(zip(t, np.full(t.size, math.pi / 2))))
    sel = (t > 60.0) & (t <= 90.0)
    n, e = lmap.xy_to_ne(lon[sel], lat[sel])
    want = float(np.mean(lmap.interp_ne(n, e))) + float(eotvos_from_ne_mgal(np.array([0.0, TAS_MPS]), LAT0_DEG))
    assert tru.perfect_reading_mgal(track, lmap, 90.0, window_s=30.0) == pytest.approx(want, abs=0.01)
    assert float(eotvos_from_ne_mgal(np.array([0.0, TAS_MPS]), LAT0_DEG)) > 50.0  # the Eotvos term is in it
    assert math.isnan(tru.perfect_reading_mgal(track, lmap, 10.0, window_s=30.0))  # no truth before its window


def test_the_filter_trace_puts_the_estimates_beside_the_truth_and_skips_anchored_readings():
    from types import SimpleNamespace

    t, lat, lon, yaw = _flight(duration_s=400.0)
    track = _track(t, lat, lon, yaw)
    wind = tru.TruthWind(track, t, np.full(t.size, TAS_MPS), window_s=60.0)
    lmap = SimpleNamespace(xy_to_ne=lambda x, y: (np.asarray(y) * 1e5, np.asarray(x) * 1e5))  # any map frame
    nis = []

    def feed(t_s, g, ref, vel, sigma, **kw):
        nis.append((t_s, 0.5))
        return SimpleNamespace(err_ne_m=np.array([30.0, -40.0]), h_acc_m=100.0, vel_err_ne_mps=np.array([0.5, 0.0]),
                               vel_cov_ne_m2ps2=np.eye(2) * 0.04, status="ok", nis_mean=0.5, reinit_count=0,
                               bimodality=0.3, signal_ratio=2.0)

    stage = SimpleNamespace(lmap=lmap, filter=SimpleNamespace(feed=feed, _nis=nis, be=None,
                                                               unaided_cov_ne_m2=lambda: np.diag([160.0**2, 120.0**2])),
                            dr=SimpleNamespace(wind_held=np.array([4.0, -4.0]), _yaw=(200.0, float(track.yaw_rad(200.0)) + 0.1)),
                            cfg=SimpleNamespace(ins=SimpleNamespace(air_heading=False)))
    tr = tru.FilterTrace(stage, track, wind)
    la, lo = track.lat_lon_deg(200.0)
    truth_ne = np.array([float(la) * 1e5, float(lo) * 1e5])
    stage.filter.feed(100.0, 1.0, truth_ne, np.zeros(2), 1.0, anchor=True)  # pinned to GNSS: not traced
    stage.filter.feed(200.0, 1.0, truth_ne + np.array([50.0, -30.0]), np.zeros(2), 1.0, anchor=False)
    assert len(tr.rows) == 1
    r = tr.rows[0]
    assert r["ref_err_ne_m"] == pytest.approx([50.0, -30.0], abs=1e-6)  # reference - truth
    assert r["wind_err_ne_mps"] == pytest.approx(np.array([4.0, -4.0]) - wind.at(200.0))  # held - true
    assert r["wind_err_ne_mps"] == pytest.approx([1.0, 0.0], abs=0.05)
    assert r["heading_err_rad"] == pytest.approx(0.1, abs=1e-9)
    lines = tr.lines(100.0, [100.0 / 60.0])
    assert len(lines) == 2 and "| ok | 0.500" in lines[1]
    own = math.hypot(30.0 - 50.0, -40.0 + 30.0)  # the filter's position error: estimated minus true reference error
    assert f"{own:6.0f} /   100 /   200 |" in lines[1]  # stated, and what it would state without readings
