"""The gravity-aided SITL A/B's pure side (replay.live.sitl_gravity_core): the survey's geometry, the schedule, the
cross-track error, and one arm's summary in the summary.json schema from a scripted flight with known errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from companion.gravity.maps import LocalGravityMap, load_grid
from companion.nav.frame import LocalFrame
from replay.live import sitl_core as core
from replay.live import sitl_gravity_core as gc
from replay.live.sitl_gravity_report import table
from tests.conftest import AK_MAP, require


def test_survey_lines_have_the_asked_length_spacing_and_heading():
    s = gc.Survey((56.2, -143.0), line_km=30.0, spacing_km=4.0, lines=4, heading_deg=90.0)
    c = s.corners_ne_m()
    assert np.allclose(c[0], 0.0) and np.allclose(c[-1], 0.0)  # closed: the loop starts over
    legs = np.diff(c, axis=0)
    lengths = np.hypot(*legs.T)
    assert np.allclose(lengths[:-1:2], 30e3, atol=1e-6)  # the lines
    assert np.allclose(lengths[1:-1:2], 4e3, atol=1e-6)  # the cross legs
    assert np.allclose(np.degrees(np.arctan2(legs[0, 1], legs[0, 0])), 90.0)  # first line east
    assert np.all(c[:, 0] <= 1e-6) and c[:, 0].min() == pytest.approx(-12e3)  # the next lines to its right (south)
    assert s.loop_length_m() == pytest.approx(4 * 30e3 + 3 * 4e3 + 12e3)
    # in latitude/longitude: the first corner is the origin, the second 30 km east of it
    (la0, lo0), (la1, lo1) = s.corners_lat_lon()[:2]
    assert (la0, lo0) == pytest.approx((56.2, -143.0))
    n, e, _ = LocalFrame(56.2, -143.0, 0.0).to_ned_m(la1, lo1, 0.0)
    assert (n, e) == pytest.approx((0.0, 30e3), abs=0.01)


def test_map_signal_along_the_survey_tells_features_from_flat_sea():
    lmap = LocalGravityMap.around(load_grid(require(AK_MAP)))
    strong = gc.map_signal(gc.Survey((56.2, -143.0)), lmap)  # the seamount chain (MANIFEST: strong sub-area)
    flat = gc.map_signal(gc.Survey((53.0, -141.0)), lmap)  # the abyssal plain
    assert strong["on_map"] == 1.0 and flat["on_map"] == 1.0
    assert strong["std_mgal"] > 3 * flat["std_mgal"] and strong["grad_mgal_per_km"] > 2 * flat["grad_mgal_per_km"]
    off = gc.map_signal(gc.Survey((40.0, -143.0)), lmap)  # south of the grid
    assert off["on_map"] == 0.0


def test_cross_track_is_the_distance_from_the_nearest_planned_line():
    s = gc.Survey((56.2, -143.0), line_km=30.0, spacing_km=4.0, lines=4)
    fr = LocalFrame(56.2, -143.0, 0.0)
    ne = np.array([[10e3, 100.0], [10e3, 2000.0], [15e3, 3700.0], [31e3, 8e3]])
    lat, lon, _ = fr.to_geodetic(np.column_stack([ne, np.zeros(4)]))
    assert gc.cross_track_m(lat, lon, s) == pytest.approx([100.0, 2000.0, 300.0, 1000.0], abs=0.5)


def test_schedule_denies_turns_the_wind_and_gives_gnss_back():
    ev = gc.Schedule(healthy_min=20, denial_min=60, back_min=5, wind_dir_deg=240, wind_turn_deg=40,
                     wind_turn_min=15).events(100.0)
    t = [x[0] for x in ev]
    assert t == sorted(t)
    assert ev[0] == (100.0 + 1200.0, "deny_on", {"SIM_GPS1_ENABLE": 0.0})
    winds = [(x[0] - 1300.0, x[2]["SIM_WIND_DIR"]) for x in ev if "SIM_WIND_DIR" in x[2]]
    assert winds == [(900.0, 280.0), (1800.0, 320.0), (2700.0, 0.0)]
    assert (ev[-2][0], ev[-2][1]) == (1300.0 + 3600.0, "deny_off") and ev[-1][:2] == (1300.0 + 3600.0 + 300.0, "end")


def test_schedule_turns_a_boats_current_with_the_wind_and_sets_it_only_when_there_is_one():
    sc = gc.Schedule(healthy_min=20, denial_min=60, back_min=5, current_mps=0.5, current_dir_deg=350.0,
                     current_turn_deg=7.5)
    tides = [(x[0] - 1300.0, x[2]["SIM_TIDE_DIR"]) for x in sc.events(100.0) if "SIM_TIDE_DIR" in x[2]]
    assert tides == [(900.0, 357.5), (1800.0, 5.0), (2700.0, 12.5)]
    assert sc.sim_params()["SIM_TIDE_SPEED"] == 0.5 and sc.sim_params()["SIM_TIDE_DIR"] == 350.0
    still = gc.Schedule()
    assert "SIM_TIDE_SPEED" not in still.sim_params() and not any("SIM_TIDE_DIR" in x[2] for x in still.events(0.0))


def _flight(err_fn, deny_on=1300.0, deny_off=4900.0, end=5200.0, route=100.0, dt=0.5):
    """A scripted flight along the survey's first line at 25 m/s, the EKF off to the east of the truth by
    err_fn(t) metres."""
    fr = LocalFrame(56.2, -143.0, 0.0)
    log = core.FlightLog()
    for t in np.arange(0.0, end + dt / 2, dt):
        n = 25.0 * max(0.0, t - route) % 30e3
        lat, lon, _ = fr.to_geodetic(np.array([n, 0.0, 0.0]))
        elat, elon, _ = fr.to_geodetic(np.array([n, err_fn(t), 0.0]))
        log.truth.append((float(t), float(lat), float(lon)))
        log.ekf.append((float(t), float(elat), float(elon), 150.0))
    log.t_boot = end
    log.marks.update({"route": route, "deny_on": deny_on, "deny_off": deny_off, "end": end})
    log.modes = [(0.0, 10, False), (50.0, 10, True), (deny_on + 600.0, 11, True)]  # RTL 10 min into the denial
    log.texts = [(deny_on + 5.0, 4, "GPS 1: no data"), (deny_on + 30.0, 2, "Failsafe. Long event on"),
                 (deny_on + 15.0, 6, "AHRS: DCM active"), (route - 10.0, 6, "AHRS: EKF3 active")]
    return log


def _err(t, on=1300.0, off=4900.0):
    if on <= t < off:
        return 0.5 * (t - on)  # grows 30 m per minute of denial
    if off <= t < off + 20.0:
        return 5.0  # 20 s to settle after GNSS comes back
    return 1.0


def test_arm_summary_measures_the_scripted_errors_in_the_schema():
    s = gc.Survey((56.2, -143.0))
    log = _flight(_err)
    fr = LocalFrame(56.2, -143.0, 0.0)
    # the companion's 3D fixes in the denial: h_acc 100 m, error 50 m for the first half, 300 m for the second
    recs = []
    for t in np.arange(1300.0, 4900.0, 10.0):
        e = 50.0 if t < 3100.0 else 300.0
        tl, tn = core.truth_at(log.truth, [t])
        n, ee, _ = fr.to_ned_m(tl[0], tn[0], 0.0)
        lat, lon, _ = fr.to_geodetic(np.array([n + e, ee, 0.0]))
        vn, ve = core.truth_velocity_ne(log.truth, [t])[0]
        recs.append({"sent": True, "lat_deg": float(lat), "lon_deg": float(lon), "time_boot_us": int(t * 1e6),
                     "fix_type": 3, "h_acc_m": 100.0, "vel_n_mps": vn + 3.0, "vel_e_mps": ve - 4.0,
                     "speed_acc_mps": 50.0})
    out = gc.arm_summary(log, s, gc.PLANE_MODES, True, recs, healthy_level_m=2.0)
    assert list(out["error_m_at_min"]) == [str(m) for m in range(5, 61, 5)]
    for m in range(5, 60, 5):
        assert out["error_m_at_min"][str(m)] == pytest.approx(30.0 * m, rel=0.015)  # (equirectangular error metric)
    assert out["mean_m"] == pytest.approx(0.5 * 3599 / 2, rel=0.01) and out["max_m"] == pytest.approx(1799.5, rel=0.015)
    assert out["healthy_mean_m"] == pytest.approx(1.0, abs=0.05)
    assert out["cross_track_max_m"] < 1.0  # the truth flies the line
    assert [10.0, "mode RTL"] in out["failsafes"] and [0.5, "Failsafe. Long event on"] in out["failsafes"]
    assert out["ahrs"] == [[0.25, "AHRS: DCM active"]]  # the one before the survey is not counted
    assert out["within_2hacc_frac"] == pytest.approx(0.5, abs=0.01) and out["fixes_in_denial"] == 360
    assert out["last_hacc_m"] == 100.0 and out["own_mean_m"] == pytest.approx(175.0, rel=0.015)
    assert out["return_jump_m"] == pytest.approx(1799.5 - 5.0, rel=0.015)  # the step when GNSS came back
    assert out["reconverge_s"] == pytest.approx(20.0, abs=1.0)
    assert out["last_vel_err_mps"] == pytest.approx(5.0, abs=0.01) and out["last_speed_acc_mps"] == 50.0
    summary = {"arms": {"alone": gc.arm_summary(log, s, gc.PLANE_MODES, True), "companion": out}}
    assert gc.validate_summary(json.loads(json.dumps(summary))) == []
    text = table(summary, "plane")
    assert "5.0 m/s off, stated 50.0 m/s" in text
    assert "MISSED" in text and "0.5 min Failsafe. Long event on" in text and "+0.2 min AHRS: DCM active" in text


def test_validate_summary_names_what_is_wrong():
    good = {"error_m_at_min": {"5": 1.0}, "mean_m": 1.0, "max_m": 2.0, "failsafes": [], "kept_up": True}
    assert gc.validate_summary({"arms": {"alone": good}}) == []
    bad = {"arms": {"alone": {**good, "kept_up": "yes", "error_m_at_min": {"7": 1.0}},
                    "companion": {**good, "failsafes": [["x", 1]]}}}
    errs = gc.validate_summary(bad)
    assert any("kept_up" in e for e in errs) and any("'7'" in e for e in errs)
    assert any("failsafes" in e for e in errs) and any("within_2hacc_frac" in e for e in errs)
    assert gc.validate_summary({"arms": []}) != []


def test_reconverge_never_is_nan():
    t = np.arange(0.0, 100.0)
    assert math.isnan(gc.reconverge_s(t, np.full(100, 50.0), 10.0, 5.0))
    assert gc.reconverge_s(t, np.where(t < 40, 50.0, 1.0), 10.0, 5.0) == 30.0


def test_reconverge_reads_a_healthy_error_as_converged_at_once_and_times_a_decay():
    """Healthy noise at 5 Hz is back within its own 95th percentile at once (asking every sample of 10 s to stay under
    it waited minutes); a decaying error with that noise on top is back when the decay has died out."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 600.0, 0.2)
    healthy = 0.27 + 0.02 * rng.standard_normal(len(t))
    level = float(np.percentile(healthy, 95))
    assert gc.reconverge_s(t, healthy, 0.0, level) <= 1.0
    assert gc.healthy_wait_max_s(t, healthy, 0.0, 600.0, level) <= 2.0  # started anywhere, it settles at once
    excursion = np.where((t >= 300.0) & (t < 340.0), 1.0, healthy)  # 40 s at 1 m: started at 300 s, waits to 340 s
    assert gc.healthy_wait_max_s(t, excursion, 0.0, 600.0, level) == pytest.approx(40.0, abs=0.5)
    decay = healthy + 2400.0 * np.exp(-t / 1.5)  # 2.4 km: 0.1 m (5 sigma) at 15.1 s, 0.01 m at 18.6 s
    assert 15.0 <= gc.reconverge_s(t, decay, 0.0, level) <= 18.7
