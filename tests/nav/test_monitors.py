"""The autopilot heading check alone (companion.nav.monitors): on a level vehicle accelerating in every horizontal
direction, whose autopilot heading is off by a known angle, it measures that angle from GNSS velocity changes and
the autopilot-resolved specific force, flags an offset beyond its bound, and inflates the tilt variance by the error
such a heading induces."""

import math

import pytest

from companion.events import Attitude
from companion.nav.config import NavigatorConfig
from companion.nav.monitors import AhrsHeadingCheck

G = 9.80665
A_MPS2 = 2.0  # horizontal acceleration, turning at 0.2 rad/s


def _run(offset_deg: float, duration_s: float = 60.0, config=None) -> AhrsHeadingCheck:
    """The vehicle's true heading is 0; the autopilot reports -offset, so GNSS heading minus autopilot = +offset."""
    chk = AhrsHeadingCheck(config or NavigatorConfig())
    assert chk.add_imu(0.02, (0.0, 0.0, -G)) is None  # no attitude yet: nothing resolved
    chk.add_attitude(Attitude(0.0, 0.0, 0.0, -math.radians(offset_deg)))
    dt, v, t = 0.02, [0.0, 0.0], 0.0
    for k in range(int(duration_s / dt)):
        t = (k + 1) * dt
        tm = t - 0.5 * dt
        a = (A_MPS2 * math.cos(0.2 * tm), A_MPS2 * math.sin(0.2 * tm))
        v = [v[0] + a[0] * dt, v[1] + a[1] * dt]
        chk.add_imu(dt, (a[0], a[1], -G))  # body = NED (level, true heading 0)
        if k % 50 == 49:  # 1 Hz GNSS velocity
            chk.check(round(t, 9), (v[0], v[1], 0.0))
    return chk


def test_finds_a_small_offset_and_keeps_the_autopilot():
    chk = _run(10.0)
    assert math.degrees(chk.offset_rad) == pytest.approx(10.0, abs=0.5)
    assert chk.consistent and chk.fuse_heading() and chk.heading_target_rad(0.3) is None
    assert chk.tilt_var_rad2() == pytest.approx(NavigatorConfig().att_sigma_tilt_rad ** 2)


def test_flags_a_90_degree_offset_and_widens_its_tilt():
    c = NavigatorConfig()
    chk = _run(90.0)
    assert math.degrees(chk.offset_rad) == pytest.approx(90.0, abs=0.5)
    assert not chk.consistent and not chk.fuse_heading()
    assert chk.heading_target_rad(0.3) == pytest.approx(0.3 + chk.offset_rad)
    # tilt error of an AHRS levelling on an acceleration rotated by d: 2 sin(d/2) a_rms / g, a_rms ~ A
    extra = (2.0 * math.sin(math.radians(45.0)) * A_MPS2 / 9.8) ** 2
    assert chk.tilt_var_rad2() == pytest.approx(c.att_sigma_tilt_rad ** 2 + extra, rel=0.02)


def test_no_estimate_without_manoeuvres():
    chk = AhrsHeadingCheck(NavigatorConfig())
    chk.add_attitude(Attitude(0.0, 0.0, 0.0, 1.0))
    for k in range(1, 120):
        chk.add_imu(1.0, (0.0, 0.0, -G))
        assert not chk.check(float(k), (5.0, 0.0, 0.0))  # constant velocity: nothing to compare
    assert math.isnan(chk.offset_rad) and chk.consistent and not chk.fuse_heading()


def test_tilt_consistency_measures_a_tilted_autopilot():
    """An autopilot 10 deg off in pitch on a vehicle at rest: each 1 s interval's GNSS-minus-autopilot velocity change
    is g sin(10 deg), whose excess over the GNSS and accelerometer noise, in units of the tilt variance fused, is the
    factor the tilt variance must grow by (companion.nav.monitors._tilt_residual)."""
    c = NavigatorConfig(att_consistency=True)
    chk = AhrsHeadingCheck(c)
    tilt = math.radians(10.0)
    chk.add_attitude(Attitude(0.0, 0.0, 0.0, 0.0))
    for k in range(1, 60):
        chk.add_imu(1.0, (G * math.sin(tilt), 0.0, -G * math.cos(tilt)))  # resolved as a north acceleration
        chk.check(float(k), (0.0, 0.0, 0.0))
    other = 2 * c.gnss_vel_sigma_mps ** 2 + c.accel_noise_mps2_rthz ** 2 * 1.0
    expect = (0.5 * (G * math.sin(tilt)) ** 2 - other) / (G * c.att_sigma_tilt_rad) ** 2
    assert chk.tilt_nis.inflation() == pytest.approx(expect, rel=1e-6)
    assert chk.tilt_var_rad2() == pytest.approx(c.att_sigma_tilt_rad ** 2 * expect, rel=1e-6)
