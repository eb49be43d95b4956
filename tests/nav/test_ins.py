"""Strapdown INS on simulated IMU from known trajectories (error bounds after N seconds)."""

import math

import numpy as np
import pytest

from companion.nav.ins import StrapdownIns, dcm_from_quat, euler_from_quat, quat_from_euler
from companion.nav.frame import EARTH_RATE_RADPS, LocalFrame, normal_gravity_mps2, radii_m

LAT0, LON0, H0 = 47.4992, 19.1977, 150.0  # the paper's airfield


def traj(t):
    """Known manoeuvring flight: 8 m/s circle of radius 40 m, climbing and weaving, yaw along track."""
    w = 0.2
    pos = np.array([40 * np.sin(w * t), 40 * (1 - np.cos(w * t)), -0.5 * t - 2 * np.sin(0.5 * t)])
    vel = np.array([8 * np.cos(w * t), 8 * np.sin(w * t), -0.5 - np.cos(0.5 * t)])
    acc = np.array([-1.6 * np.sin(w * t), 1.6 * np.cos(w * t), 0.5 * np.sin(0.5 * t)])
    roll, pitch, yaw = 0.16 + 0.05 * np.sin(1.3 * t), -0.1 + 0.04 * np.cos(0.9 * t), w * t
    droll, dpitch, dyaw = 0.065 * np.cos(1.3 * t), -0.036 * np.sin(0.9 * t), w
    return pos, vel, acc, (roll, pitch, yaw), (droll, dpitch, dyaw)


def imu_from_traj(t, frame):
    """Exact specific force and angular rate (body FRD) including gravity, Earth rate and transport rate."""
    pos, vel, acc, (r, p, y), (dr, dp, dy) = traj(t)
    lat, _lon, h = frame.to_geodetic(pos)
    lat = math.radians(float(lat))
    rm, rn = (float(x) for x in radii_m(lat))
    w_ie = EARTH_RATE_RADPS * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    w_en = np.array([vel[1] / (rn + h), -vel[0] / (rm + h), -vel[1] * math.tan(lat) / (rn + h)], dtype=float)
    g = np.array([0, 0, float(normal_gravity_mps2(lat, h))])
    c_bn = dcm_from_quat(quat_from_euler(r, p, y))
    f_b = c_bn.T @ (acc - g + np.cross(2 * w_ie + w_en, vel))
    w_nb = np.array([dr - dy * math.sin(p), dp * math.cos(r) + dy * math.sin(r) * math.cos(p),
                     -dp * math.sin(r) + dy * math.cos(r) * math.cos(p)])
    return f_b, w_nb + c_bn.T @ (w_ie + w_en)


def run_ins(duration_s, rate_hz, accel_bias=np.zeros(3)):
    frame = LocalFrame(LAT0, LON0, H0)
    pos, vel, _a, att, _ = traj(0.0)
    lat, lon, h = frame.to_geodetic(pos)
    ins = StrapdownIns(0.0, float(lat), float(lon), float(h), vel, *att)
    dt = 1.0 / rate_hz
    for i in range(1, int(round(duration_s * rate_hz)) + 1):
        f, w = imu_from_traj((i - 0.5) * dt, frame)  # sample at mid-interval, like an integrating IMU
        ins.step(i * dt, f + accel_bias, w)
    pos, vel, _a, att, _ = traj(duration_s)
    est = frame.to_ned_m(ins.lat_deg, ins.lon_deg, ins.h_m)
    datt = (np.array(ins.euler()) - np.array(att) + np.pi) % (2 * np.pi) - np.pi
    return ins, est - pos, np.array(ins.vel_ned) - vel, datt


def test_perfect_imu_tracks_manoeuvring_trajectory_for_60_s():
    _ins, dpos, dvel, datt = run_ins(60.0, 100.0)
    assert np.linalg.norm(dpos) < 0.05, dpos
    assert np.linalg.norm(dvel) < 0.005, dvel
    assert np.max(np.abs(datt)) < 1e-3, datt


def test_stationary_with_earth_rate_and_gravity_stays_put():
    lat = math.radians(LAT0)
    g = float(normal_gravity_mps2(lat, H0))
    ins = StrapdownIns(0.0, LAT0, LON0, H0, (0, 0, 0), 0.0, 0.0, 0.3)
    c_bn = ins.dcm()
    w_ie = EARTH_RATE_RADPS * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    f_b, w_b = c_bn.T @ np.array([0, 0, -g]), c_bn.T @ w_ie
    for i in range(1, 6001):
        ins.step(i * 0.01, f_b, w_b)
    d = LocalFrame(LAT0, LON0, H0).to_ned_m(ins.lat_deg, ins.lon_deg, ins.h_m)
    assert np.linalg.norm(d) < 0.01
    assert euler_from_quat(ins.q)[2] == pytest.approx(0.3, abs=1e-6)


def test_accelerometer_bias_gives_half_b_t_squared():
    # a 0.05 m/s^2 bias along the body x axis (yawed with the vehicle): error must show and be bounded
    _ins, dpos, _dv, _ = run_ins(10.0, 100.0, accel_bias=np.array([0.05, 0.0, 0.0]))
    assert 0.5 * 0.05 * 10**2 * 0.3 < np.linalg.norm(dpos) < 0.5 * 0.05 * 10**2 * 1.05


def test_bias_correction_removes_bias_effect():
    ins, dpos, _dv, _ = run_ins(5.0, 100.0)
    ins2 = StrapdownIns(0.0, LAT0, LON0, H0)
    ins2.correct((1.0, -2.0, 0.5), (0.1, 0, 0), (0, 0, 0.01), (0.01, 0, 0), (0, 0, 0.001))
    d = LocalFrame(LAT0, LON0, H0).to_ned_m(ins2.lat_deg, ins2.lon_deg, ins2.h_m)
    assert np.allclose(d, [1.0, -2.0, 0.5], atol=1e-6)
    assert ins2.euler()[2] == pytest.approx(0.01, abs=1e-9)
    assert ins2.ba[0] == 0.01 and ins2.bg[2] == 0.001
