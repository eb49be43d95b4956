"""The INS filter alone (companion.nav.ins_filter): on a level vehicle flying north at a known speed, its delay history
gives the state of a past epoch, follows every correction, its free trajectory is the uncorrected INS's, and its
updates, resets and alignment move the state and covariance as their equations say."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from companion.events import Attitude
from companion.nav.config import NavigatorConfig
from companion.nav.frame import LocalFrame
from companion.nav.gnss_lag import GnssLagConfig, GnssLatency
from companion.nav.ins import StrapdownIns
from companion.nav.ins_filter import InsFilter
from companion.nav.measurements import PositionMeasurement
from companion.nav.outputs import MeasurementUpdate

FRAME = LocalFrame(-35.3, 149.1, 600.0)
OMEGA = 7.292115e-5


def _filter(speed_n_mps=10.0, yaw_rad=0.0, delay_s=0.0, vel_delay_s=0.15, config=None):
    out = []
    c = config or NavigatorConfig(gnss_delay_s=delay_s, gnss_vel_delay_s=vel_delay_s)
    f = InsFilter(c, FRAME, GnssLatency(c.gnss_delay_s, c.gnss_vel_delay_s), out.append, 0.0, (0.0, 0.0, 0.0),
                  (speed_n_mps, 0.0, 0.0), Attitude(0.0, 0.0, 0.0, yaw_rad), epoch=1)
    return f, out


def _level_imu(ins: StrapdownIns):
    """Specific force and rate of a level, unaccelerated vehicle heading north (body = NED), as the INS expects."""
    lat = ins.lat_rad
    return (0.0, 0.0, -ins.gravity()), (OMEGA * math.cos(lat), 0.0, -OMEGA * math.sin(lat))


def _fly(f: InsFilter, t0: float, t1: float, dt=0.02, twin: StrapdownIns | None = None) -> float:
    t = t0
    while t < t1 - 1e-9:
        t = round(t + dt, 9)
        acc, gyr = _level_imu(f.strapdown)
        f.step_imu(t, acc, gyr)
        if twin is not None:
            twin.step(t, acc, gyr)
    return t


def test_history_gives_the_state_of_a_past_epoch_and_follows_corrections():
    f, _ = _filter(delay_s=0.2)
    t = _fly(f, 0.0, 2.0)
    p_now = f.position_ned()
    assert p_now[0] == pytest.approx(20.0, abs=0.02)  # 10 m/s north for 2 s
    p, v = f.state_at(t)  # the GNSS latency of this filter: 0.2 s (+ the velocity's 0.15 s of history kept)
    assert p[0] == pytest.approx(p_now[0] - 2.0, abs=0.02) and v[0] == pytest.approx(10.0, abs=1e-3)
    p1, _ = f.state_at(t, delay_s=0.1)  # between two IMU steps: interpolated
    assert p1[0] == pytest.approx(p_now[0] - 1.0, abs=0.02)
    f.correct((1.0, -2.0, 0.5), (0.0, 0.0, 0.0), (0, 0, 0), (0, 0, 0), (0, 0, 0))
    q, _ = f.state_at(t)
    assert q - p == pytest.approx([1.0, -2.0, 0.5], abs=1e-9)  # the past epoch moved with the correction
    ahead, _ = f.state_at(t + 0.5, delay_s=0.0)  # ahead of the INS: extrapolated at its velocity
    assert ahead[0] == pytest.approx(f.position_ned()[0] + f.strapdown.vn * 0.5, abs=1e-9)


def test_no_history_without_a_latency_to_model():
    f, _ = _filter(delay_s=0.0, vel_delay_s=0.0)
    t = _fly(f, 0.0, 1.0)
    p, _ = f.state_at(t, delay_s=0.3)  # nothing kept: the current state carried back at constant velocity
    assert p[0] == pytest.approx(f.position_ned()[0] - f.strapdown.vn * 0.3, abs=1e-9)


def test_free_trajectory_is_the_uncorrected_ins():
    f, _ = _filter()
    twin = StrapdownIns(0.0, *FRAME.geodetic_tuple(0.0, 0.0, 0.0), (10.0, 0.0, 0.0))
    _fly(f, 0.0, 1.0, twin=twin)
    f.correct((3.0, -1.0, 0.2), (0.5, -0.2, 0.0), (0, 0, 0), (0, 0, 0), (0, 0, 0))
    t = _fly(f, 1.0, 3.0, twin=twin)
    p, v, p_free, v_free = f.trajectory_record()
    assert p[0] == pytest.approx(30.0 + 3.0 + 0.5 * 2.0, abs=0.02)  # the corrected INS
    assert p_free == pytest.approx(FRAME.ned_tuple(twin.lat_deg, twin.lon_deg, twin.h_m), abs=0.01)
    assert v_free == pytest.approx(twin.vel_ned, abs=1e-3) and t == 3.0


def test_update_pulls_towards_a_fix_and_the_gate_refuses_an_outlier():
    f, out = _filter(speed_n_mps=0.0)
    t = _fly(f, 0.0, 1.0)
    ok, y = f.apply(PositionMeasurement(t, "gnss_pos", (2.0, 0.0, 0.0), 0.5, 0.5, gate_chi2=16.27))
    assert ok and y[0] == pytest.approx(2.0, abs=0.01)
    # position variance ~9 m^2 against 0.25: the gain is ~0.97, the error estimate is fed back and zeroed
    assert f.position_ned()[0] == pytest.approx(2.0 * 9.0 / 9.25, abs=0.05) and not f.kf.x.any()
    n_before = f.position_ned()
    ok, _ = f.apply(PositionMeasurement(t, "gnss_pos", (1000.0, 0.0, 0.0), 0.5, 0.5, gate_chi2=16.27))
    assert not ok and f.position_ned() == n_before
    assert [type(o) for o in out] == [MeasurementUpdate, MeasurementUpdate]
    assert out[0].accepted and not out[1].accepted and out[1].innovation[0] == pytest.approx(1000.0 - n_before[0])


def test_reset_to_fix_takes_each_velocity_component_the_fix_has():
    c = NavigatorConfig()
    f, _ = _filter(speed_n_mps=0.0)
    t = _fly(f, 0.0, 0.5)
    p0 = f.position_ned()
    dv = f.reset_to_fix(t, np.array([5.0, 0.0, 0.0]), (1.0, 2.0, math.nan), 1.0, 2.0)
    assert dv == pytest.approx([1.0, 2.0, 0.0], abs=1e-6)
    assert f.strapdown.vel_ned == pytest.approx((1.0, 2.0, 0.0), abs=1e-6)
    assert f.position_ned()[0] == pytest.approx(p0[0] + 5.0, abs=1e-6)
    P, s = f.kf.P, c.reset_cov_scale
    assert P[0, 0] == pytest.approx(s) and P[2, 2] == pytest.approx(4.0 * s)
    assert P[3, 3] == pytest.approx(c.gnss_vel_sigma_mps**2 * s) and P[5, 5] == pytest.approx(P[3, 3] + 1.0)
    assert not P[0:6, 6:].any()  # position and velocity start uncorrelated with the rest


def test_yaw_alignment_rotates_to_the_target_only_when_far():
    c = NavigatorConfig()
    f, _ = _filter(speed_n_mps=0.0, yaw_rad=0.0)
    assert f.align_yaw(0.0, math.radians(10.0)) is None  # within yaw_align_min_deg (15)
    d = f.align_yaw(0.0, math.radians(-100.0))
    assert d == pytest.approx(math.radians(-100.0))
    assert f.strapdown.euler()[2] == pytest.approx(math.radians(-100.0), abs=1e-9)
    assert f.kf.P[8, 8] == pytest.approx(c.yaw_align_sigma_rad**2) and not f.kf.P[8, :8].any()


def test_tilt_reset_rotates_the_tilt_and_widens_it():
    c = NavigatorConfig()
    f, _ = _filter(speed_n_mps=0.0)
    f.reset_tilt(0.02, -0.01)
    roll, pitch, _ = f.strapdown.euler()
    assert (roll, pitch) == pytest.approx((0.02, -0.01), abs=1e-4)  # psi about N is roll, about E pitch, at yaw 0
    assert f.kf.P[6, 6] == pytest.approx(c.init_sigma_att_rad**2 * c.reset_cov_scale)


def test_a_stall_is_coasted_over_and_widens_the_covariance():
    f, _ = _filter(speed_n_mps=4.0)
    t = _fly(f, 0.0, 1.0)
    var_v = f.kf.P[3, 3]
    acc, gyr = _level_imu(f.strapdown)
    f.step_imu(t + 2.0, acc, gyr)  # 2 s without a sample
    assert f.position_ned()[0] == pytest.approx(12.0, abs=0.05)  # coasted at 4 m/s, not integrated
    assert f.kf.P[3, 3] > var_v + (2.0 * 2.0) ** 2 * 0.99  # (kinematic_accel_sigma x dt)^2 added


def test_a_moved_latency_widens_tilt_and_accelerometer_bias_once():
    c = NavigatorConfig(gnss_delay_estimate=True)
    est = SimpleNamespace(lag_s=None, config=GnssLagConfig())
    lat = GnssLatency(c.gnss_delay_s, c.gnss_vel_delay_s, est)
    f = InsFilter(c, FRAME, lat, [].append, 0.0, (0.0, 0.0, 0.0), None, Attitude(0.0, 0.0, 0.0, 0.0), 1)
    f.kf.P[6, 6] = f.kf.P[9, 9] = 1e-8
    f.relearn_if_latency_moved()  # unchanged (the configured latency): nothing
    assert f.kf.P[6, 6] == 1e-8
    est.lag_s = 0.1  # measured: 0.1 s off what the filter learnt with
    f.relearn_if_latency_moved()
    assert f.kf.P[6, 6] == pytest.approx(c.init_sigma_att_rad**2)
    assert f.kf.P[9, 9] == pytest.approx(c.accel_bias_sigma_mps2**2)
    f.kf.P[6, 6] = 1e-8
    f.relearn_if_latency_moved()  # re-learnt at 0.1 s: nothing more
    assert f.kf.P[6, 6] == 1e-8
