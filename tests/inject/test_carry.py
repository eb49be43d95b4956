"""Carrying a final navigator state to the epoch the autopilot assumes: velocity and position on a known trajectory."""

from __future__ import annotations

import math

import pytest

from companion.events import ImuSample, SystemTime
from companion.inject import InjectConfig, Injector
from companion.inject.carry import AccelerationTracker, carry
from companion.nav.outputs import NavigatorReset
from tests.inject.test_inject import state

A_N, A_E = 2.5, -1.0  # a vehicle speeding up out of a turn (m/s^2)
V0_N, V0_E = 1.0, 3.0


def truth(t_s):
    """North/east position (m) and velocity (m/s) under constant acceleration from t = 0."""
    return (V0_N * t_s + A_N * t_s**2 / 2, V0_E * t_s + A_E * t_s**2 / 2), (V0_N + A_N * t_s, V0_E + A_E * t_s)


def truth_state(t_s, **kw):
    (pn, pe), (vn, ve) = truth(t_s)
    return state(t_s=t_s, north_m=pn, east_m=pe, vel_n_mps=vn, vel_e_mps=ve, vel_d_mps=0.0, **kw)


def test_tracker_finds_a_constant_acceleration_and_forgets_it_at_a_reset():
    acc = AccelerationTracker()
    for k in range(40):  # 50 Hz
        a = acc.observe(truth_state(k * 0.02))
    assert a == pytest.approx((A_N, A_E, 0.0), abs=1e-9)
    acc.reset()
    assert acc.observe(truth_state(1.0)) == (0.0, 0.0, 0.0)  # (one sample: no span yet)


def test_tracker_refuses_a_jump_no_vehicle_makes():
    acc = AccelerationTracker()
    acc.observe(state(t_s=0.0, vel_n_mps=0.0))
    assert acc.observe(state(t_s=0.2, vel_n_mps=40.0)) == (0.0, 0.0, 0.0)  # 200 m/s^2: a reset, not a motion


def test_carry_with_acceleration_gives_the_velocity_and_position_at_the_new_epoch():
    s = truth_state(3.0)
    c = carry(s, 3.08, (A_N, A_E, 0.0))
    (pn, pe), (vn, ve) = truth(3.08)
    assert (c.vel_n_mps, c.vel_e_mps) == pytest.approx((vn, ve), abs=1e-9)
    assert (c.north_m, c.east_m) == pytest.approx((pn, pe), abs=1e-9)
    flat = carry(s, 3.08)  # at constant velocity the velocity sent lags the vehicle's by the whole gap
    assert math.hypot(flat.vel_n_mps - vn, flat.vel_e_mps - ve) == pytest.approx(0.08 * math.hypot(A_N, A_E))


def test_injector_sends_the_velocity_of_the_epoch_it_claims_while_the_vehicle_accelerates():
    """The navigator's state is final 0.25 s behind the newest sample; the message describes newest - 0.2 s."""
    sent = []
    inj = Injector(InjectConfig(mode="shadow", activate="always", rate_hz=10.0))
    inj.process(SystemTime(t_s=0.0, unix_time_s=1.7e9))
    for k in range(1, 200):
        t = k * 0.02
        inj.process(ImuSample(t_s=t + 0.25, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0,) * 3, imu_index=0))
        sent += [r for r in inj.process(truth_state(t)) if hasattr(r, "fix_type")]
    assert len(sent) > 20
    for r in sent[5:]:
        (pn, pe), (vn, ve) = truth(r.t_s)
        assert r.extrapolated_s == pytest.approx(0.05)
        assert math.hypot(r.vel_n_mps - vn, r.vel_e_mps - ve) < 1e-6  # (before: 0.05 s x 2.7 m/s^2 = 0.13 m/s)
    inj.process(NavigatorReset(t_s=4.0, kind="reinit", reason="test", filter="ins", jump_pos_m=0.0, jump_vel_mps=0.0))
    assert inj.accel.accel_ned_mps2 == (0.0, 0.0, 0.0)
