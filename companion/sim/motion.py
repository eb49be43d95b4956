"""Rigid-body kinematics of the simulated vehicle: ZYX Euler angles, the attitude a multirotor needs for an
acceleration, and what an IMU on a rotating WGS84 Earth senses. Pure numpy."""

from __future__ import annotations

import numpy as np

from companion.constants import G0_MPS2
from companion.nav.frame import EARTH_RATE_RADPS, normal_gravity_mps2, radii_m

GRAVITY_MPS2 = G0_MPS2
G_NED_MPS2 = np.array([0.0, 0.0, GRAVITY_MPS2])


def dcm_from_euler(euler_rad) -> np.ndarray:
    """C_nb (body FRD -> NED) from ZYX Euler angles (roll, pitch, yaw); shape (..., 3, 3)."""
    e = np.asarray(euler_rad, dtype=float)
    cr, sr = np.cos(e[..., 0]), np.sin(e[..., 0])
    cp, sp = np.cos(e[..., 1]), np.sin(e[..., 1])
    cy, sy = np.cos(e[..., 2]), np.sin(e[..., 2])
    c = np.empty(e.shape[:-1] + (3, 3))
    c[..., 0, 0] = cp * cy
    c[..., 0, 1] = sr * sp * cy - cr * sy
    c[..., 0, 2] = cr * sp * cy + sr * sy
    c[..., 1, 0] = cp * sy
    c[..., 1, 1] = sr * sp * sy + cr * cy
    c[..., 1, 2] = cr * sp * sy - sr * cy
    c[..., 2, 0] = -sp
    c[..., 2, 1] = sr * cp
    c[..., 2, 2] = cr * cp
    return c


def wrap_pi(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def attitude_from_motion(acc_ned, jerk_ned, yaw, yaw_rate):
    """Multirotor attitude and body rates from acceleration, jerk, yaw and yaw rate (all NED).

    Body z (down) is aligned with -f / |f|, f = a - g. Returns (euler (N,3), euler rates (N,3),
    body rates FRD (N,3), specific force FRD (N,3)).
    """
    f = np.asarray(acc_ned) - G_NED_MPS2
    fd = np.asarray(jerk_ned)
    fn = np.linalg.norm(f, axis=-1)
    if np.any(fn < 0.5):
        raise ValueError("commanded acceleration leaves almost no thrust (free fall); fly gentler legs")
    z = -f / fn[:, None]
    zd = -(fd / fn[:, None] - f * (np.sum(f * fd, axis=-1) / fn**3)[:, None])
    c, s = np.cos(yaw), np.sin(yaw)
    # z in the yaw-rotated frame: q = Rz(-yaw) z = (sin(pitch) cos(roll), -sin(roll), cos(pitch) cos(roll))
    qx = c * z[:, 0] + s * z[:, 1]
    qy = -s * z[:, 0] + c * z[:, 1]
    qz = z[:, 2]
    dqx = c * zd[:, 0] + s * zd[:, 1] + yaw_rate * (-s * z[:, 0] + c * z[:, 1])
    dqy = -s * zd[:, 0] + c * zd[:, 1] + yaw_rate * (-c * z[:, 0] - s * z[:, 1])
    dqz = zd[:, 2]
    h2 = qx * qx + qz * qz
    h = np.sqrt(h2)
    pitch = np.arctan2(qx, qz)
    roll = np.arctan2(-qy, h)
    pitch_d = (qz * dqx - qx * dqz) / h2
    h_d = (qx * dqx + qz * dqz) / h
    roll_d = (-h * dqy + qy * h_d) / (qy * qy + h2)
    yaw_w = wrap_pi(yaw)
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    p = roll_d - yaw_rate * sp
    q = pitch_d * cr + yaw_rate * sr * cp
    r = -pitch_d * sr + yaw_rate * cr * cp
    euler = np.stack([roll, pitch, yaw_w], axis=-1)
    euler_rate = np.stack([roll_d, pitch_d, yaw_rate * np.ones_like(roll)], axis=-1)
    rate = np.stack([p, q, r], axis=-1)
    f_frd = np.einsum("nji,nj->ni", dcm_from_euler(euler), f)  # C_bn f = C_nb^T f
    return euler, euler_rate, rate, f_frd


def earth_rates_ned_radps(lat_rad, height_m, vel_ned_mps) -> tuple[np.ndarray, np.ndarray]:
    """(w_ie^n, w_en^n), shape (N, 3) each: Earth rate and transport rate in NED (Groves 2013, eqs. 2.123, 5.44)."""
    lat = np.asarray(lat_rad, dtype=float)
    v = np.asarray(vel_ned_mps, dtype=float)
    rm, rn = radii_m(lat)
    cl, sl = np.cos(lat), np.sin(lat)
    w_ie = EARTH_RATE_RADPS * np.stack([cl, np.zeros_like(lat), -sl], axis=-1)
    rnh = rn + height_m
    w_en = np.stack([v[:, 1] / rnh, -v[:, 0] / (rm + height_m), -v[:, 1] * sl / cl / rnh], axis=-1)
    return w_ie, w_en


def rotating_earth_imu(euler_rad, rate_nb_frd_radps, vel_ned_mps, acc_ned_mps2, lat_rad, height_m):
    """(specific force FRD, inertial angular rate FRD) on the rotating WGS84 Earth for a given attitude and motion.

    f^n = a^n - g^n(lat, h) + (2 w_ie + w_en) x v^n (Groves 2013, eq. 5.54 solved for f) with normal gravity
    (:func:`companion.nav.frame.normal_gravity_mps2`, as the INS uses), and w_ib^b = w_nb^b + C_bn (w_ie + w_en).
    """
    c_nb = dcm_from_euler(euler_rad)
    v = np.asarray(vel_ned_mps, dtype=float)
    w_ie, w_en = earth_rates_ned_radps(lat_rad, height_m, v)
    f_ned = np.asarray(acc_ned_mps2, dtype=float) + np.cross(2.0 * w_ie + w_en, v)
    f_ned[:, 2] -= normal_gravity_mps2(lat_rad, height_m)
    f_frd = np.einsum("nji,nj->ni", c_nb, f_ned)
    rate_ib = np.asarray(rate_nb_frd_radps, dtype=float) + np.einsum("nji,nj->ni", c_nb, w_ie + w_en)
    return f_frd, rate_ib


# ---------------------------------------------------------------------------------------------
