"""Sensor models for the simulator: IMU, magnetometer, GNSS (with outages), attitude estimate.

Every random draw comes from the ``numpy.random.Generator`` passed in. Outputs are SI floats; the
MAVLink scaling happens in :mod:`companion.sim.mavlink_out`.

Default noise levels (per sample, 1 sigma) and why:

* Accelerometer: white 0.03 m/s^2 at 50 Hz; constant bias ~ N(0, 0.04 m/s^2) per axis (about 4 mG).
  An MPU6000/ICM2060x-class MEMS has ~150-300 ug/sqrt(Hz) noise density; through ArduPilot's 20 Hz
  accel filter that is ~0.01-0.02 m/s^2, and frame vibration on a small quad adds about as much again.
  The bias is what remains after a level calibration (a few mG).
* Gyroscope: white 0.002 rad/s (0.11 deg/s); constant bias ~ N(0, 0.001 rad/s) per axis (0.06 deg/s),
  i.e. what remains after ArduPilot's gyro calibration at boot plus temperature drift.
* Magnetometer: Earth field at Canberra (IGRF approx.: declination +12.5 deg, inclination -66 deg,
  57 uT, i.e. N 22.8, E 5.1, D -52.5 uT), white 3 mGauss.
* GNSS (u-blox M8 class, open sky): the position error is a first-order Gauss-Markov process per
  axis (steady sigma 0.6 m per horizontal axis, i.e. 0.85 m horizontal RMS, 1.2 m vertical,
  correlation time 60 s), so it wanders
  like a random walk over a minute but stays bounded, plus 0.05 m white noise; velocity has 0.08 m/s
  white noise per axis. HDOP drifts around 0.8 (VDOP 1.3), 13 to 15 satellites.
* During an outage window the receiver keeps reporting at its rate with fix_type = 1 (NO_FIX),
  lat = lon = 0, 0 satellites, unknown accuracy, as ArduPilot logs a lost fix. The error processes keep
  running underneath, so the fix resumes with a realistic (not reset) error.
* Attitude estimate (what the autopilot's EKF reports in ATTITUDE): truth plus Gauss-Markov error,
  0.2 deg roll/pitch, 0.8 deg yaw, 20 s correlation time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.nav.frame import LocalFrame, radii_m
from companion.sim.trajectory import Trajectory

#: Earth magnetic field near Canberra, NED, in milligauss (1 uT = 10 mGauss).
MAG_FIELD_CANBERRA_NED_MGAUSS = (228.0, 51.0, -525.0)


@dataclass(frozen=True)
class ImuModel:
    accel_noise_mps2: float = 0.03
    gyro_noise_radps: float = 0.002
    accel_bias_sigma_mps2: float = 0.04
    gyro_bias_sigma_radps: float = 0.001
    mag_field_ned_mgauss: tuple[float, float, float] = MAG_FIELD_CANBERRA_NED_MGAUSS
    mag_noise_mgauss: float = 3.0
    temperature_c: float = 38.0

    @classmethod
    def perfect(cls) -> ImuModel:
        """No noise and no bias: the IMU reads the truth exactly."""
        return cls(0.0, 0.0, 0.0, 0.0, mag_noise_mgauss=0.0)


@dataclass
class ImuData:
    t_s: np.ndarray
    accel_frd_mps2: np.ndarray
    gyro_frd_radps: np.ndarray
    mag_frd_mgauss: np.ndarray
    accel_bias_frd_mps2: np.ndarray  # (3,) constant bias that was applied
    gyro_bias_frd_radps: np.ndarray
    temperature_c: float


def simulate_imu(traj: Trajectory, model: ImuModel, rng: np.random.Generator) -> ImuData:
    """IMU samples at the trajectory's times: truth + constant bias + white noise.

    The truth is the trajectory's specific force and inertial rate (with the Earth's rotation, transport rate,
    Coriolis and normal gravity for an ``earth="ellipsoid"`` profile); the magnetometer sees the attitude in NED.
    """
    n = len(traj)
    acc_bias = rng.normal(0.0, model.accel_bias_sigma_mps2, 3)
    gyr_bias = rng.normal(0.0, model.gyro_bias_sigma_radps, 3)
    acc = traj.specific_force_frd_mps2 + acc_bias + rng.normal(0.0, 1.0, (n, 3)) * model.accel_noise_mps2
    gyr = traj.gyro_truth_frd_radps + gyr_bias + rng.normal(0.0, 1.0, (n, 3)) * model.gyro_noise_radps
    field_ned = np.asarray(model.mag_field_ned_mgauss, dtype=float)
    mag = np.einsum("nji,j->ni", traj.c_nb, field_ned) + rng.normal(0.0, 1.0, (n, 3)) * model.mag_noise_mgauss
    return ImuData(traj.t_s, acc, gyr, mag, acc_bias, gyr_bias, model.temperature_c)


def gauss_markov(n: int, dt_s: float, sigma: float, tau_s: float, rng: np.random.Generator, dims: int = 1) -> np.ndarray:
    """First-order Gauss-Markov sequence with steady-state ``sigma`` and correlation time ``tau_s``."""
    phi = np.exp(-dt_s / tau_s)
    drive = sigma * np.sqrt(1.0 - phi * phi)
    w = rng.normal(0.0, 1.0, (n, dims))
    x = np.empty((n, dims))
    x[0] = sigma * w[0]
    for k in range(1, n):
        x[k] = phi * x[k - 1] + drive * w[k]
    return x


@dataclass(frozen=True)
class GnssModel:
    horiz_sigma_m: float = 0.6
    vert_sigma_m: float = 1.2
    tau_s: float = 60.0
    white_m: float = 0.05
    vel_sigma_mps: float = 0.08
    hdop_mean: float = 0.8
    vdop_mean: float = 1.3
    sats_range: tuple[int, int] = (13, 15)
    #: geoid height (ellipsoid - MSL) at the site, for alt_ellipsoid; EGM96 near Canberra is about +19.6 m
    geoid_height_m: float = 19.6
    #: (start_s, end_s) windows in which the receiver has no fix
    outages_s: tuple[tuple[float, float], ...] = ()

    @classmethod
    def perfect(cls, outages_s: tuple[tuple[float, float], ...] = ()) -> GnssModel:
        return cls(0.0, 0.0, 60.0, 0.0, 0.0, outages_s=outages_s)


@dataclass
class GnssData:
    t_s: np.ndarray
    fix_type: np.ndarray  # int, 3 with a fix, 1 during outages
    lat_deg: np.ndarray  # 0 during outages (as ArduPilot sends)
    lon_deg: np.ndarray
    alt_msl_m: np.ndarray
    vel_ned_mps: np.ndarray
    hdop: np.ndarray  # nan during outages
    vdop: np.ndarray
    h_acc_m: np.ndarray
    v_acc_m: np.ndarray
    speed_acc_mps: np.ndarray
    satellites: np.ndarray
    alt_ellipsoid_m: np.ndarray
    pos_error_ned_m: np.ndarray  # the simulated error (for evaluation)

    @property
    def has_fix(self) -> np.ndarray:
        return self.fix_type >= 3


def simulate_gnss(traj: Trajectory, frame: LocalFrame, model: GnssModel, rng: np.random.Generator) -> GnssData:
    """GNSS solutions at the trajectory's (uniform) times.

    The position error (metres NED) is added to the truth: through ``frame``'s tangent-plane mapping for a flat-Earth
    trajectory, to the truth lat/lon/alt with the ellipsoid's local radii for an ``earth="ellipsoid"`` one.
    """
    n = len(traj)
    dt = float(traj.t_s[1] - traj.t_s[0]) if n > 1 else 1.0
    err = np.empty((n, 3))
    err[:, :2] = gauss_markov(n, dt, model.horiz_sigma_m, model.tau_s, rng, 2)
    err[:, 2:] = gauss_markov(n, dt, model.vert_sigma_m, model.tau_s, rng, 1)
    err += rng.normal(0.0, 1.0, (n, 3)) * model.white_m
    if traj.earth == "ellipsoid":
        lat, lon, alt = offset_geodetic(traj.lat_deg, traj.lon_deg, traj.alt_msl_m, err)
    else:
        lat, lon, alt = frame.to_geodetic(traj.pos_ned_m + err)
    vel = traj.vel_ned_mps + rng.normal(0.0, 1.0, (n, 3)) * model.vel_sigma_mps
    dop_wander = gauss_markov(n, dt, 0.08, 40.0, rng, 1)[:, 0]
    hdop = np.round(model.hdop_mean + dop_wander, 2)
    vdop = np.round(model.vdop_mean + 1.5 * dop_wander, 2)
    lo, hi = model.sats_range
    # satellite count changes now and then (a step every ~20 s on average)
    steps = rng.random(n) < dt / 20.0
    sats = np.clip(lo + 1 + np.cumsum(np.where(steps, rng.choice([-1, 1], n), 0)), lo, hi).astype(int)
    fix = np.full(n, 3, dtype=int)
    h_acc = np.full(n, np.hypot(model.horiz_sigma_m, model.white_m) * 1.5) * hdop / model.hdop_mean
    v_acc = np.full(n, np.hypot(model.vert_sigma_m, model.white_m) * 1.5) * vdop / model.vdop_mean
    s_acc = np.full(n, max(model.vel_sigma_mps, 0.01) * 2.0)
    lat, lon, alt = np.array(lat, dtype=float), np.array(lon, dtype=float), np.array(alt, dtype=float)
    out = np.zeros(n, dtype=bool)
    for t0, t1 in model.outages_s:
        out |= (traj.t_s >= t0) & (traj.t_s < t1)
    fix[out] = 1
    lat[out] = lon[out] = alt[out] = 0.0
    vel[out] = 0.0
    for a in (hdop, vdop, h_acc, v_acc, s_acc):
        a[out] = np.nan
    sats[out] = 0
    alt_ell = np.where(out, 0.0, alt + model.geoid_height_m)
    return GnssData(traj.t_s, fix, lat, lon, alt, vel, hdop, vdop, h_acc, v_acc, s_acc, sats, alt_ell, err)


def offset_geodetic(lat_deg, lon_deg, alt_m, d_ned_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Geodetic points moved by small NED offsets (metres), with the WGS84 radii at each point."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    alt = np.asarray(alt_m, dtype=float)
    d = np.asarray(d_ned_m, dtype=float)
    rm, rn = radii_m(lat)
    lat_out = np.degrees(lat + d[..., 0] / (rm + alt))
    lon_out = np.asarray(lon_deg, dtype=float) + np.degrees(d[..., 1] / ((rn + alt) * np.cos(lat)))
    return lat_out, (lon_out + 180.0) % 360.0 - 180.0, alt - d[..., 2]


@dataclass(frozen=True)
class AttitudeEstimateModel:
    roll_pitch_sigma_rad: float = math.radians(0.2)
    yaw_sigma_rad: float = math.radians(0.8)
    tau_s: float = 20.0
    rate_noise_radps: float = 0.001


def simulate_attitude_estimate(traj: Trajectory, model: AttitudeEstimateModel, rng: np.random.Generator):
    """(euler_rad (N,3), body rates (N,3)): the autopilot's estimate = truth + slowly varying error.

    Attitude and rates relative to the local NED frame (as ATTITUDE reports them), on either Earth model."""
    n = len(traj)
    dt = float(traj.t_s[1] - traj.t_s[0]) if n > 1 else 1.0
    err = np.concatenate(
        [
            gauss_markov(n, dt, model.roll_pitch_sigma_rad, model.tau_s, rng, 2),
            gauss_markov(n, dt, model.yaw_sigma_rad, model.tau_s, rng, 1),
        ],
        axis=1,
    )
    euler = traj.euler_rad + err
    euler[:, 2] = (euler[:, 2] + np.pi) % (2 * np.pi) - np.pi
    rates = traj.rate_frd_radps + rng.normal(0.0, 1.0, (n, 3)) * model.rate_noise_radps
    return euler, rates
