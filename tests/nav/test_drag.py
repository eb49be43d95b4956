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
