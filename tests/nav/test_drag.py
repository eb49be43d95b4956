"""Rotor drag (companion.nav.drag): the fit recovers a multicopter's drag coefficient, wind and accelerometer bias, says
nothing without drag, and its measurement holds the INS through a 30 s blockage on a simulated multicopter whose
accelerometers read its drag (companion.sim.trajectory with drag_per_s)."""

import math

import numpy as np
import pytest

from companion.nav.drag import DragConfig, DragInterval, RotorDrag, drag_rows
from companion.nav.ins import dcm_from_quat, quat_from_euler
from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import FusedState, MeasurementUpdate
from companion.sim.flight import CANBERRA_FIELD, SimConfig, simulate_flight
from companion.sim.sensors import AttitudeEstimateModel, ImuModel
from companion.sim.trajectory import Climb, FlightProfile, Hold, Speed, Straight, Turn
from tests.helpers import flight_events

K, WIND, BIAS = 0.3, (2.0, -1.0), (-0.05, 0.02)


def _intervals(rng, n, k=K, noise=0.15):
    """Synthetic interval means: random headings, speeds and small tilts; f = -k (C^T (v - w))_xy + b + noise."""
    out = []
    for i in range(n):
        C = dcm_from_quat(quat_from_euler(*rng.normal(0, 0.05, 2), rng.uniform(-math.pi, math.pi)))
        v = np.array([*rng.normal(0, 4.0, 2), rng.normal(0, 0.5)])
        rows = drag_rows(C, v)
        vb = C.T @ (v - np.array([*WIND, 0.0]))
        f = -k * vb[:2] + np.array(BIAS) + rng.normal(0, noise, 2)
        out.append(DragInterval(float(i), (float(f[0]), float(f[1])), rows, rows))
    return out


def test_fit_recovers_coefficient_wind_and_bias():
    drag = RotorDrag()
    for iv in _intervals(np.random.default_rng(1), 200):
        drag.learn(iv)
    th, cov, s2 = drag.model()
    assert th[0] == pytest.approx(K, rel=0.03)
    assert th[1] / th[0] == pytest.approx(WIND[0], abs=0.15) and th[2] / th[0] == pytest.approx(WIND[1], abs=0.15)
    assert th[3] == pytest.approx(BIAS[0], abs=0.03) and th[4] == pytest.approx(BIAS[1], abs=0.03)
    assert np.sqrt(s2) == pytest.approx([0.15, 0.15], rel=0.2)  # the residual scatter is the noise
    assert math.sqrt(cov[0, 0]) < 0.02  # and the coefficient's standard error is honest-sized


def test_no_model_without_drag_or_before_enough_rows():
    drag = RotorDrag()
    rows = _intervals(np.random.default_rng(2), 200, k=0.0)
    for iv in rows[:10]:
        drag.learn(iv)
    assert drag.model() is None  # 20 rows < min_rows
    for iv in rows[10:]:
        drag.learn(iv)
    assert drag.model() is None  # k ~ 0: the accelerometers say nothing about the velocity
    with pytest.raises(ValueError):
        DragConfig(min_rows=1.0)


def _drag_flight():
    """A multicopter flying laps at 2.5-7 m/s through a 2.2 m/s wind (drag 0.3 /s); a noisy MEMS IMU and an autopilot
    whose tilt is off by ~1.5 deg (30 s correlation), the INS's usual problem in a blockage."""
    lap = []
    for v in (4.0, 7.0, 2.5, 5.5):
        lap += [Speed(v, max_accel_mps2=1.5), Straight(40.0), Turn(90.0, 6.0)]
    legs = [Hold(5.0), Climb(15.0, rate_mps=2.5), Hold(3.0), *lap * 3, Speed(0.0), Hold(5.0)]
    profile = FlightProfile(legs, CANBERRA_FIELD, drag_per_s=K, wind_ned_mps=(*WIND, 0.0))
    cfg = SimConfig(imu=ImuModel(accel_noise_mps2=0.3, gyro_noise_radps=0.005, accel_bias_sigma_mps2=0.05), imu2=None,
                    attitude=AttitudeEstimateModel(roll_pitch_sigma_rad=math.radians(1.5), tau_s=30.0))
    return simulate_flight(profile, seed=2, config=cfg)


def test_sim_accelerometer_reads_the_drag():
    sim = _drag_flight()
    from companion.sim.motion import dcm_from_euler

    tr = sim.truth_imu
    vb = np.einsum("nji,nj->ni", dcm_from_euler(tr.euler_rad), tr.vel_ned_mps - np.array([*WIND, 0.0]))
    assert np.allclose(tr.specific_force_frd_mps2[:, :2], -K * vb[:, :2], atol=1e-9)


def test_drag_holds_the_ins_through_a_30_s_blockage():
    sim = _drag_flight()
    deny = (150.0, 180.0)
    events = flight_events(sim, gnss_every=5, deny_s=deny)  # 1 Hz fixes, none for 30 s
    errs = {}
    for on in (True, False):
        # the simulated receiver has no latency; the motion prior off: the INS and its aids alone
        cfg = NavigatorConfig(gnss_vel_delay_s=0.0, motion_prior=False, rotor_drag=on)
        out = run_navigator(events, cfg)
        fs = [o for o in out if isinstance(o, FusedState) and deny[0] <= o.t_s < deny[1]]
        ned = CANBERRA_FIELD.to_ned_m(np.array([o.lat_deg for o in fs]), np.array([o.lon_deg for o in fs]),
                                      np.array([o.alt_msl_m for o in fs]))
        tr = sim.profile.sample(np.array([o.t_s for o in fs]))
        truth = CANBERRA_FIELD.to_ned_m(tr.lat_deg, tr.lon_deg, tr.alt_msl_m)
        errs[on] = float(np.sqrt(np.mean(np.sum((ned[:, :2] - truth[:, :2]) ** 2, axis=1))))
        if on:
            ups = [u for u in out if isinstance(u, MeasurementUpdate) and u.kind == "rotor_drag"]
            assert ups and all(deny[0] < u.t_s < deny[1] + 1.0 for u in ups)  # fused in the blockage only
            assert np.mean([u.accepted for u in ups]) > 0.9
            assert any("rotor_drag" in o.measurement.split("+") for o in fs)
    assert errs[False] > 15.0, errs  # the tilt error drives the free INS away ...
    assert errs[True] < 0.2 * errs[False], errs  # ... the drag measurement holds its velocity


def test_measurement_learns_while_gnss_aids_and_is_given_once_it_is_gone():
    """At 1 s intervals of the output ticks: learnt while a fix is recent and the vehicle moves, a DragMeasurement
    carrying the fit's coefficient, wind and bias once no fix has come for min_fix_age_s."""
    rng = np.random.default_rng(4)
    drag = RotorDrag()
    t, learnt = 0.0, 0
    for k in range(400):
        C = dcm_from_quat(quat_from_euler(0.0, 0.0, rng.uniform(-math.pi, math.pi)))
        v = np.array([*rng.normal(0, 4.0, 2), 0.0])
        f = -K * (C.T @ (v - np.array([*WIND, 0.0])))[:2] + np.array(BIAS)
        for j in range(10):  # ten IMU samples and ticks per interval, the same state throughout
            drag.add_accel((float(f[0]), float(f[1]), -9.8))
            t = round(t + 0.1, 9)
            assert drag.measurement(t, C, tuple(v), 0.5) is None  # a fresh fix: learning, no measurement
        learnt += drag.model() is not None
    th = drag.model()[0]
    assert learnt > 300 and th[0] == pytest.approx(K, rel=0.01)
    assert drag.measurement(t + 0.1, C, tuple(v), None) is None  # no fix ever: nothing
    m = None
    for j in range(12):
        drag.add_accel((float(f[0]), float(f[1]), -9.8))
        m = m or drag.measurement(round(t + 0.2 + 0.1 * j, 9), C, tuple(v), 2.0 + 0.1 * j)
    assert m is not None and m.kind == "rotor_drag"
    assert m.k_per_s == pytest.approx(K, rel=0.01) and m.wind_ne_mps == pytest.approx(WIND, abs=0.05)


def _quadratic_drag_intervals(rng, n, k=0.29, c=0.028):
    """A copter that mostly cruises forward at ~7.5 m/s and sometimes flies slower (1.5-7 m/s), with a drag that is not
    linear: f = -k v_a - c |v_a| v_a per body axis (SITL's multicopter: momentum plus bluff-body drag)."""
    out = []
    for i in range(n):
        C = dcm_from_quat(quat_from_euler(0.0, -0.35, rng.uniform(-math.pi, math.pi)))
        speed = rng.normal(7.5, 0.2) if rng.uniform() < 0.7 else rng.uniform(1.5, 7.0)
        v = C @ np.array([speed, 0.0, 0.0])
        v[2] = 0.0
        vb = C.T @ v
        f = -k * vb[:2] - c * np.abs(vb[:2]) * vb[:2] + rng.normal(0, 0.05, 2)
        rows = drag_rows(C, v)
        sp = float(math.hypot(vb[0], vb[1]))
        out.append((C, v, DragInterval(float(i), (float(f[0]), float(f[1])), rows, rows, sp, sp)))
    return out


def test_the_linear_fit_s_misfit_at_an_air_speed_enters_the_noise_and_unseen_speeds_give_nothing():
    """A linear fit learnt mostly at cruise: at cruise its band residual is small, at 1.5 m/s it is the fit's true
    error there (the noise takes it), and at a hover (a band never learnt) there is no measurement: fused, the fit's
    offset would read as ~1 m/s of velocity the filter believes to a few cm/s."""
    rng = np.random.default_rng(7)
    drag = RotorDrag()
    for _C, _v, iv in _quadratic_drag_intervals(rng, 600):
        drag.learn(iv)
    th = drag.model()[0]
    k, c = 0.29, 0.028

    def model_error(speed):  # the fit's prediction minus the truth along body x, at speed along x
        C = dcm_from_quat(quat_from_euler(0.0, -0.35, 0.3))
        v = C @ np.array([speed, 0.0, 0.0])
        v[2] = 0.0
        vb = C.T @ v
        return float((drag_rows(C, v) @ th)[0] - (-k * vb[0] - c * abs(vb[0]) * vb[0])), float(math.hypot(vb[0], vb[1]))

    err_cruise, s_cruise = model_error(7.5)
    err_slow, s_slow = model_error(1.6)
    n_c, bias_c = drag.misfit.residual(s_cruise, th)
    n_s, bias_s = drag.misfit.residual(s_slow, th)
    assert n_c > 50 and abs(bias_c[0]) < 0.1
    assert abs(err_slow) > 0.08 and abs(err_slow) > 3 * abs(bias_c[0])  # the linear fit is wrong at low speed ...
    # ... and knows it: the band's mean residual (over 1-2 m/s) has the sign and size of the fit's error there
    assert n_s >= DragConfig().misfit_min_rows and bias_s[0] * -err_slow > 0 and 0.5 < bias_s[0] / -err_slow < 1.5
    assert drag.misfit.residual(0.3, th)[0] == 0.0  # a hover: never learnt


def test_at_an_air_speed_the_fit_has_not_seen_the_noise_is_the_whole_prediction():
    """A fit learnt at 1.5-8 m/s, asked at a hover (0.2 m/s): the measurement's sigma covers all the model predicts
    there (its offset, which fused as data reads as ~1 m/s of velocity), far above its sigma at cruise."""
    rng = np.random.default_rng(8)
    drag = RotorDrag()
    t = 0.0
    for C, v, iv in _quadratic_drag_intervals(rng, 300):
        for j in range(10):
            drag.add_accel((iv.f_xy[0], iv.f_xy[1], -9.8))
            t = round(t + 0.1, 9)
            drag.measurement(t, C, tuple(v), 0.5)
    th = drag.model()[0]
    C = dcm_from_quat(quat_from_euler(0.0, -0.35, 0.0))
    got = {}
    for speed in (7.5, 0.2):
        v = C @ np.array([speed, 0.0, 0.0])
        v[2] = 0.0
        m = None
        for j in range(12):
            drag.add_accel((-2.0, 0.0, -9.8))
            t = round(t + 0.1, 9)
            m = m or drag.measurement(t, C, tuple(v), 2.0 + 0.1 * j)
        got[speed] = (m, float((drag_rows(C, v) @ th)[0]))
    (cruise, _), (hover, pred_hover) = got[7.5], got[0.2]
    assert abs(pred_hover) > 0.1  # the linear fit's offset at a standstill
    assert math.sqrt(hover.r_mps4[0]) >= abs(pred_hover)
    assert math.sqrt(hover.r_mps4[0]) > 3 * math.sqrt(cruise.r_mps4[0])
