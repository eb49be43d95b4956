"""An analytic circling multicopter flight with exact IMU, GNSS and attitude events, for tests with known truth
(the full flight simulator with legs, sensors and MAVLink is companion.sim.flight).

The trajectory is analytic (NED about a reference point): a level circle with a weave in height, yaw
along the track and small roll/pitch oscillations. The IMU is derived exactly (specific force including
normal gravity, Coriolis and transport rate; angular rate including Earth and transport rate), sampled
at mid-interval, then noise is added from a seeded generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.events import Attitude, Event, GnssFix, ImuSample
from companion.nav.frame import EARTH_RATE_RADPS, LocalFrame, normal_gravity_mps2, radii_m
from companion.sim.motion import dcm_from_euler  # one ZYX Euler -> C_nb for simulator and tests

REF = (47.4992, 19.1977, 150.0)  # the paper's airfield (Matyasfold), altitude MSL


@dataclass(frozen=True)
class SimNoise:
    accel_std_mps2: float = 1.0  # per sample
    gyro_std_radps: float = 0.03
    accel_bias_mps2: tuple[float, float, float] = (0.05, -0.04, 0.08)
    gyro_bias_radps: tuple[float, float, float] = (0.002, -0.001, 0.0015)
    gnss_std_h_m: float = 1.5
    gnss_std_v_m: float = 2.5
    gnss_corr_tau_s: float = 30.0  # > 0: first-order Gauss-Markov fix error (a receiver's error wanders);
    # 0: white fix error (what the KF's "accuracy" GNSS model assumes)
    gnss_white_m: float = 0.05  # white part added to a correlated error
    gnss_vel_std_mps: float = 0.3
    att_std_tilt_rad: float = 0.03
    att_std_yaw_rad: float = 0.1


def circle_trajectory(t):
    """Position, velocity, acceleration (NED), Euler angles and their rates at times t (arrays)."""
    t = np.asarray(t, dtype=float)
    w, r = 0.15, 40.0
    ramp = np.clip(t / 10.0, 0.0, 1.0)  # speed ramps up over the first 10 s
    # phase phi(t) with phi' = w * ramp
    phi = np.where(t < 10.0, w * t**2 / 20.0, w * (t - 5.0))
    dphi = w * ramp
    ddphi = np.where(t < 10.0, w / 10.0, 0.0)
    pos = np.stack([r * np.sin(phi), r * (1 - np.cos(phi)), -20.0 - 3.0 * np.sin(0.2 * t)], axis=-1)
    vel = np.stack([r * np.cos(phi) * dphi, r * np.sin(phi) * dphi, -0.6 * np.cos(0.2 * t)], axis=-1)
    acc = np.stack([
        r * (-np.sin(phi) * dphi**2 + np.cos(phi) * ddphi),
        r * (np.cos(phi) * dphi**2 + np.sin(phi) * ddphi),
        0.12 * np.sin(0.2 * t),
    ], axis=-1)
    roll = 0.12 * ramp + 0.05 * np.sin(1.3 * t)
    pitch = -0.08 * ramp + 0.04 * np.cos(0.9 * t)
    yaw = phi
    droll = np.where(t < 10.0, 0.012, 0.0) + 0.065 * np.cos(1.3 * t)
    dpitch = np.where(t < 10.0, -0.008, 0.0) - 0.036 * np.sin(0.9 * t)
    dyaw = dphi
    return pos, vel, acc, np.stack([roll, pitch, yaw], -1), np.stack([droll, dpitch, dyaw], -1)


def exact_imu(t, frame: LocalFrame):
    """Exact specific force and angular rate in body FRD at times t."""
    pos, vel, acc, eul, deul = circle_trajectory(t)
    lat_deg, _lon, h = frame.to_geodetic(pos)
    lat = np.radians(lat_deg)
    rm, rn = radii_m(lat)
    w_ie = EARTH_RATE_RADPS * np.stack([np.cos(lat), np.zeros_like(lat), -np.sin(lat)], -1)
    w_en = np.stack([vel[:, 1] / (rn + h), -vel[:, 0] / (rm + h), -vel[:, 1] * np.tan(lat) / (rn + h)], -1)
    g = np.stack([np.zeros_like(lat), np.zeros_like(lat), normal_gravity_mps2(lat, h)], -1)
    c_bn = dcm_from_euler(eul)
    f_n = acc - g + np.cross(2 * w_ie + w_en, vel)
    f_b = np.einsum("nji,nj->ni", c_bn, f_n)
    r, p = eul[:, 0], eul[:, 1]
    dr, dp, dy = deul[:, 0], deul[:, 1], deul[:, 2]
    w_nb = np.stack([dr - dy * np.sin(p), dp * np.cos(r) + dy * np.sin(r) * np.cos(p),
                     -dp * np.sin(r) + dy * np.cos(r) * np.cos(p)], -1)
    w_ib = w_nb + np.einsum("nji,nj->ni", c_bn, w_ie + w_en)
    return f_b, w_ib


@dataclass
class CircleFlight:
    events: list[Event]
    frame: LocalFrame
    truth_t_s: np.ndarray  # 100 Hz truth
    truth_pos_ned_m: np.ndarray
    truth_vel_ned_mps: np.ndarray


def simulate_circle_flight(
    duration_s: float = 60.0,
    rng: np.random.Generator | None = None,
    imu_rate_hz: float = 50.0,
    gnss_rate_hz: float = 5.0,
    att_rate_hz: float = 10.0,
    noise: SimNoise | None = None,
    t0_s: float = 100.0,
    with_imu: bool = True,
) -> CircleFlight:
    """Events (IMU0, GNSS, attitude) of the synthetic flight, starting at vehicle time ``t0_s``."""
    rng = rng if rng is not None else np.random.default_rng(0)
    nz = noise or SimNoise()
    frame = LocalFrame(*REF)
    events: list[Event] = []
    if with_imu:
        n = int(round(duration_s * imu_rate_hz))
        ti = np.arange(1, n + 1) / imu_rate_hz
        f_b, w_b = exact_imu(ti - 0.5 / imu_rate_hz, frame)
        f_b = f_b + np.array(nz.accel_bias_mps2) + nz.accel_std_mps2 * rng.standard_normal(f_b.shape)
        w_b = w_b + np.array(nz.gyro_bias_radps) + nz.gyro_std_radps * rng.standard_normal(w_b.shape)
        for k in range(n):
            events.append(ImuSample(round(t0_s + ti[k], 6), tuple(map(float, f_b[k])), tuple(map(float, w_b[k])), 0))
    ta = np.arange(0, int(duration_s * att_rate_hz) + 1) / att_rate_hz
    _p, _v, _a, eul, _d = circle_trajectory(ta)
    eul = eul + rng.standard_normal(eul.shape) * np.array([nz.att_std_tilt_rad] * 2 + [nz.att_std_yaw_rad])
    for k in range(len(ta)):
        y = (eul[k, 2] + math.pi) % (2 * math.pi) - math.pi
        events.append(Attitude(round(t0_s + ta[k], 6), float(eul[k, 0]), float(eul[k, 1]), float(y)))
    tg = np.arange(0, int(duration_s * gnss_rate_hz) + 1) / gnss_rate_hz
    pos, vel, *_ = circle_trajectory(tg)
    std = np.array([nz.gnss_std_h_m] * 2 + [nz.gnss_std_v_m])
    if nz.gnss_corr_tau_s > 0:
        a = math.exp(-1.0 / (gnss_rate_hz * nz.gnss_corr_tau_s))
        err = np.empty(pos.shape)
        err[0] = rng.standard_normal(3) * std
        for k in range(1, len(tg)):
            err[k] = a * err[k - 1] + math.sqrt(1 - a * a) * std * rng.standard_normal(3)
        pos_m = pos + err + nz.gnss_white_m * rng.standard_normal(pos.shape)
    else:
        pos_m = pos + rng.standard_normal(pos.shape) * std
    vel_m = vel + rng.standard_normal(vel.shape) * nz.gnss_vel_std_mps
    lat, lon, alt = frame.to_geodetic(pos_m)
    for k in range(len(tg)):
        events.append(GnssFix(
            round(t0_s + tg[k], 6), 3, float(lat[k]), float(lon[k]), float(alt[k]),
            float(vel_m[k, 0]), float(vel_m[k, 1]), float(vel_m[k, 2]),
            float(math.hypot(vel_m[k, 0], vel_m[k, 1])), None, 12, nz.gnss_std_h_m / 1.5,
            nz.gnss_std_v_m / 2.5, None, None, None, None, None,
        ))
    events.sort(key=lambda e: e.t_s)
    tt = np.arange(0, int(duration_s * 100) + 1) / 100.0
    p, v, *_ = circle_trajectory(tt)
    return CircleFlight(events, frame, t0_s + tt, p, v)
