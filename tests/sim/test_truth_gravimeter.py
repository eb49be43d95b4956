"""The SITL gravimeter (companion.sim.truth_gravimeter, companion.sim.sitl_gravimeter_link) against known truth: the
map at the true position, the Eotvos term at the true velocity, its output window, bias and drift, seeding, and the
readings it sends on a scripted SIMSTATE stream."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.gravity.maps import LocalGravityMap, load_grid
from companion.nav.frame import LocalFrame
from companion.sim.gravity_residuals import ship_minus_satellite_mgal
from companion.sim.sitl_gravimeter_link import GravimeterOnLink
from companion.sim.truth_gravimeter import GravimeterSpec, TruthGravimeter
from tests.conftest import AK_MAP, SHARED_GRAVITY, require

QUIET = GravimeterSpec(white_sigma_mgal=0.0, bias_sigma_mgal=0.0, drift_sigma_mgal_per_h=0.0, window_s=0.0,
                       eotvos=False, misfit=False)
LAT0, LON0 = 56.0, -144.0  # the AK grid's seamount area


@pytest.fixture(scope="module")
def ak():
    gmap = load_grid(require(AK_MAP))
    return gmap, LocalGravityMap.around(gmap)


def _track(speed_mps: float, heading_deg: float, seconds: float, dt: float = 0.1):
    """Truth along a straight line from (LAT0, LON0): times, lat, lon."""
    fr = LocalFrame(LAT0, LON0, 0.0)
    t = np.arange(0.0, seconds + 1e-9, dt)
    h = math.radians(heading_deg)
    ned = np.stack([speed_mps * t * math.cos(h), speed_mps * t * math.sin(h), np.zeros_like(t)], axis=1)
    lat, lon, _ = fr.to_geodetic(ned)
    return t, lat, lon


def test_quiet_gravimeter_reads_the_map_at_the_true_position(ak):
    gmap, lmap = ak
    g = TruthGravimeter(lmap, QUIET, np.random.default_rng(0))
    t, lat, lon = _track(25.0, 30.0, 120.0)
    for ti, la, lo in zip(t, lat, lon):
        g.sample(ti, la, lo)
    # the grid's own bilinear value at the last true point, asked directly of the grid
    assert g.read(t[-1]) == pytest.approx(float(gmap.interp(lon[-1], lat[-1])), abs=1e-6)
    assert g.distance_m == pytest.approx(25.0 * 120.0, rel=1e-3)


def test_eotvos_term_at_the_true_velocity(ak):
    _gmap, lmap = ak
    spec = GravimeterSpec(0.0, 0.0, 0.0, 0.0, eotvos=True, misfit=False)
    east = TruthGravimeter(lmap, spec, np.random.default_rng(0))
    west = TruthGravimeter(lmap, spec, np.random.default_rng(0))
    quiet = TruthGravimeter(lmap, QUIET, np.random.default_rng(0))
    for gm, hd in ((east, 90.0), (west, 270.0), (quiet, 90.0)):
        t, lat, lon = _track(10.0, hd, 20.0)
        for ti, la, lo in zip(t, lat, lon):
            gm.sample(ti, la, lo)
    v_kn = 10.0 / (1852.0 / 3600.0)
    want = 7.5 * v_kn * math.cos(math.radians(LAT0)) + 0.004 * v_kn**2  # Gao 2022 eq. 5, heading east
    assert east.read(20.0) - quiet.read(20.0) == pytest.approx(want, abs=0.05)
    # westward the first term changes sign; the map under the two tracks differs, so compare the term alone
    west_map = west.truth_value_mgal(*west._last[1:])
    assert west.read(20.0) - west_map == pytest.approx(-7.5 * v_kn * math.cos(math.radians(LAT0)) + 0.004 * v_kn**2,
                                                       abs=0.05)


def test_output_window_is_the_mean_of_the_map_over_the_window(ak):
    gmap, lmap = ak
    spec = GravimeterSpec(0.0, 0.0, 0.0, window_s=30.0, eotvos=False, misfit=False)
    g = TruthGravimeter(lmap, spec, np.random.default_rng(0))
    t, lat, lon = _track(100.0, 0.0, 90.0, dt=0.5)  # fast, so the map changes within the window
    for ti, la, lo in zip(t, lat, lon):
        g.sample(ti, la, lo)
    inside = (t > t[-1] - 30.0) & (t > 0)
    want = float(np.mean(gmap.interp(lon[inside], lat[inside])))
    assert g.read(t[-1]) == pytest.approx(want, abs=1e-6)
    assert abs(want - float(gmap.interp(lon[-1], lat[-1]))) > 0.1  # the window does change the reading here


def test_bias_drift_and_noise_are_drawn_from_the_seed(ak):
    _gmap, lmap = ak
    spec = GravimeterSpec(white_sigma_mgal=1.0, bias_sigma_mgal=3.0, drift_sigma_mgal_per_h=2.0, window_s=0.0,
                          eotvos=False, misfit=False)
    runs = []
    for seed in (5, 5, 6):
        g = TruthGravimeter(lmap, spec, np.random.default_rng(seed))
        out = []
        for k in range(3600):
            g.sample(float(k), LAT0, LON0, (0.0, 0.0))  # standing still: the map value is constant
            out.append(g.read(float(k)) - g.truth_value_mgal(LAT0, LON0))
        runs.append((g.bias_mgal, g.drift_mgal_per_s, np.array(out)))
    assert np.array_equal(runs[0][2], runs[1][2])
    assert not np.array_equal(runs[0][2], runs[2][2])
    bias, drift, err = runs[0]
    assert bias != 0.0 and drift != 0.0
    k = np.arange(3600.0)
    resid = err - (bias + drift * k)
    assert abs(resid.mean()) < 0.1 and resid.std() == pytest.approx(1.0, rel=0.1)
    # the fitted line over the hour recovers the drawn bias and drift
    slope, icpt = np.polyfit(k, err, 1)
    assert icpt == pytest.approx(bias, abs=0.1) and slope * 3600.0 == pytest.approx(drift * 3600.0, abs=0.2)


def test_misfit_is_the_real_ship_minus_satellite_series_along_distance(ak):
    require(SHARED_GRAVITY / "tracks" / "ship_03.txt")
    _gmap, lmap = ak
    series = ship_minus_satellite_mgal()
    spec = GravimeterSpec(0.0, 0.0, 0.0, 0.0, eotvos=False, misfit=True)
    g = TruthGravimeter(lmap, spec, np.random.default_rng(3), series)
    quiet = TruthGravimeter(lmap, QUIET, np.random.default_rng(3))
    t, lat, lon = _track(33.0, 0.0, 200.0, dt=1.0)  # 33 m per sample: one misfit value every 10 samples
    diffs = []
    for ti, la, lo in zip(t, lat, lon):
        g.sample(ti, la, lo)
        quiet.sample(ti, la, lo)
        if ti > 0:
            diffs.append(g.read(ti) - quiet.read(ti))
    start = g._mis_start
    want = [series[(start + int(d // 330.0)) % series.size] for d in 33.0 * np.arange(1, t.size)]
    assert np.allclose(diffs, want, atol=0.05)  # distance steps are geodesic, not exactly 33 m: allow the odd edge
    assert len(set(np.round(diffs, 6))) >= 15  # it changes along the track (20 misfit samples passed)


def _m(msg, src=(1, 1)):
    msg._header = mav.MAVLink_header(msg.id, srcSystem=src[0], srcComponent=src[1])
    return msg


def test_link_sends_one_reading_per_period_on_the_autopilot_clock(ak):
    _gmap, lmap = ak
    gl = GravimeterOnLink(TruthGravimeter(lmap, QUIET, np.random.default_rng(0)), period_s=1.0)
    t, lat, lon = _track(25.0, 45.0, 10.0, dt=0.1)
    out = []
    for k, (ti, la, lo) in enumerate(zip(t, lat, lon)):
        tb = int(round((100.0 + ti) * 1000))
        assert gl.on_message(_m(mav.MAVLink_attitude_message(tb, 0, 0, 0, 0, 0, 0))) == []
        out += gl.on_message(_m(mav.MAVLink_simstate_message(0, 0, 0, 0, 0, 0, 0, 0, 0, int(round(la * 1e7)),
                                                             int(round(lo * 1e7)))))
    assert [tb for tb, _v in out] == [101000 + 1000 * k for k in range(9)] + [110000]
    assert out[-1][1] == pytest.approx(gl.meter.truth_value_mgal(round(lat[-1] * 1e7) * 1e-7, round(lon[-1] * 1e7) * 1e-7), abs=1e-6)


def test_spec_rejects_negative_sigmas():
    with pytest.raises(ValueError):
        GravimeterSpec(white_sigma_mgal=-1.0)
