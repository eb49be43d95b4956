"""Strapdown inertial navigation in NED (local-level, wander-free), for IMU samples in body FRD.

State: geodetic position (lat, lon in rad; height in m, the datum of the initialising altitude), NED
velocity, attitude quaternion body->NED, accelerometer and gyro bias estimates (body FRD).

Per sample (dt = time since the previous sample), following the standard local-level mechanisation
(e.g. Groves 2013, ch. 5.4):

* attitude: q <- q_n(-w_in^n dt) * q * q_b(w_ib^b dt), with w_in = w_ie + w_en (Earth rate and transport
  rate; Earth rate is 0.004 deg/s, below a MEMS gyro's bias but cheap to keep);
* velocity: v += (C_b^n f^b + g^n - (2 w_ie + w_en) x v) dt, with C_b^n at mid-interval and g the WGS84
  normal gravity with free-air correction (:func:`companion.nav.frame.normal_gravity_mps2`);
* position: lat += v_N/(R_M+h) dt, lon += v_E/((R_N+h) cos lat) dt, h -= v_D dt (trapezoidal).

The per-sample path uses plain Python floats: at 50-400 Hz numpy call overhead would dominate.
Pure: no I/O, no clocks.
"""

from __future__ import annotations

import math

import numpy as np

from companion.nav.frame import EARTH_RATE_RADPS, WGS84_A_M, WGS84_E2


def quat_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float, float, float]:
    """ZYX Euler (body FRD relative to NED) -> quaternion (w, x, y, z) rotating body to NED."""
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(q) -> tuple[float, float, float]:
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def dcm_from_quat(q) -> np.ndarray:
    """C_b^n (body -> NED) from a unit quaternion."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _qrotvec(rx, ry, rz):
    """Quaternion of a rotation vector (rad)."""
    a2 = rx * rx + ry * ry + rz * rz
    if a2 < 1e-12:
        return (1.0 - a2 / 8.0, 0.5 * rx, 0.5 * ry, 0.5 * rz)
    a = math.sqrt(a2)
    s = math.sin(a / 2) / a
    return (math.cos(a / 2), rx * s, ry * s, rz * s)


def _gravity(sin2_lat: float, w: float, h_m: float) -> float:
    """WGS84 normal gravity (Somigliana) with the free-air correction; ``w`` = sqrt(1 - e^2 sin^2 lat)."""
    return 9.7803253359 * (1.0 + 0.00193185265241 * sin2_lat) / w - 3.086e-6 * h_m


def _rot(q, vx, vy, vz):
    """C(q) @ v without building the matrix."""
    w, x, y, z = q
    return (
        (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - w * z) * vy + 2 * (x * z + w * y) * vz,
        2 * (x * y + w * z) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - w * x) * vz,
        2 * (x * z - w * y) * vx + 2 * (y * z + w * x) * vy + (1 - 2 * (x * x + y * y)) * vz,
    )


class StrapdownIns:
    """NED strapdown mechanisation. Call :meth:`step` for every IMU sample in time order."""

    def __init__(
        self,
        t_s: float,
        lat_deg: float,
        lon_deg: float,
        height_m: float,
        vel_ned_mps=(0.0, 0.0, 0.0),
        roll_rad: float = 0.0,
        pitch_rad: float = 0.0,
        yaw_rad: float = 0.0,
        earth_rate: bool = True,
    ) -> None:
        self.t_s = float(t_s)
        self.lat_rad = math.radians(lat_deg)
        self.lon_rad = math.radians(lon_deg)
        self.h_m = float(height_m)
        self.vn, self.ve, self.vd = (float(v) for v in vel_ned_mps)
        self.q = quat_from_euler(roll_rad, pitch_rad, yaw_rad)
        self.ba = [0.0, 0.0, 0.0]
        self.bg = [0.0, 0.0, 0.0]
        self.earth_rate = earth_rate
        self.f_ned = (0.0, 0.0, -9.8)  # last specific force in NED (for the error model)
        self._omega = EARTH_RATE_RADPS if earth_rate else 0.0
        self._dcm_q: tuple | None = None  # the attitude self._dcm was built for
        self._dcm: np.ndarray | None = None
        self._dcm_neg_q: tuple | None = None
        self._dcm_neg: np.ndarray | None = None

    # -- geometry helpers
    def radii(self) -> tuple[float, float]:
        s = math.sin(self.lat_rad)
        w = math.sqrt(1.0 - WGS84_E2 * s * s)
        return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w

    def gravity(self) -> float:
        s2 = math.sin(self.lat_rad) ** 2
        return _gravity(s2, math.sqrt(1.0 - WGS84_E2 * s2), self.h_m)

    @property
    def lat_deg(self) -> float:
        return math.degrees(self.lat_rad)

    @property
    def lon_deg(self) -> float:
        return math.degrees(self.lon_rad)

    @property
    def vel_ned(self) -> tuple[float, float, float]:
        return (self.vn, self.ve, self.vd)

    def euler(self) -> tuple[float, float, float]:
        return euler_from_quat(self.q)

    def dcm(self) -> np.ndarray:
        """C_b^n of the current attitude; built once per attitude (``q`` is replaced, never changed in place, at every
        step or correction), read-only as it is shared."""
        if self.q is not self._dcm_q:
            C = dcm_from_quat(self.q)
            C.flags.writeable = False
            self._dcm, self._dcm_q = C, self.q
        return self._dcm

    def dcm_neg(self) -> np.ndarray:
        """-C_b^n (the error model's bias blocks), built once per attitude like :meth:`dcm`."""
        if self.q is not self._dcm_neg_q:
            C = -self.dcm()
            C.flags.writeable = False
            self._dcm_neg, self._dcm_neg_q = C, self.q
        return self._dcm_neg

    def nav_rates(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(w_ie^n, w_en^n) in rad/s."""
        rm, rn = self.radii()
        lat = self.lat_rad
        om = self._omega
        w_ie = (om * math.cos(lat), 0.0, -om * math.sin(lat))
        w_en = (self.ve / (rn + self.h_m), -self.vn / (rm + self.h_m), -self.ve * math.tan(lat) / (rn + self.h_m))
        return w_ie, w_en

    # -- mechanisation
    def step(self, t_s: float, accel_frd_mps2, gyro_frd_radps) -> float:
        """Advance to ``t_s`` with one sample held over the interval; returns dt (0 if not advancing)."""
        dt = t_s - self.t_s
        if dt <= 0.0:
            return 0.0
        ba, bg = self.ba, self.bg
        f_b = (accel_frd_mps2[0] - ba[0], accel_frd_mps2[1] - ba[1], accel_frd_mps2[2] - ba[2])
        rot = ((gyro_frd_radps[0] - bg[0]) * dt, (gyro_frd_radps[1] - bg[1]) * dt, (gyro_frd_radps[2] - bg[2]) * dt)
        return self._advance(t_s, dt, rot, f_b, None)

    def step_increments(self, t_s: float, rot_frd_rad, dv_frd_mps) -> float:
        """Advance to ``t_s`` by summed increments (companion.nav.imu_accumulator, bias-corrected): the body's rotation
        vector over the interval and the velocity increment in the body frame at its start; returns dt."""
        dt = t_s - self.t_s
        if dt <= 0.0:
            return 0.0
        return self._advance(t_s, dt, rot_frd_rad, None, dv_frd_mps)

    def _advance(self, t_s: float, dt: float, rot, f_b, dv_b) -> float:
        """The mechanisation over dt: body rotation ``rot``; specific force ``f_b`` held over the interval (resolved
        with the mid-interval attitude) or velocity increment ``dv_b`` (resolved with the attitude at its start)."""
        # the Earth's radii, rates and gravity at this latitude (nav_rates(), radii(), gravity() with one sin and cos)
        lat, h = self.lat_rad, self.h_m
        sl, cl = math.sin(lat), math.cos(lat)
        s2 = sl * sl
        w = math.sqrt(1.0 - WGS84_E2 * s2)
        rm, rn = WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w
        om = self._omega
        wie_n, wie_e, wie_d = om * cl, 0.0, -om * sl
        wen_n, wen_e, wen_d = self.ve / (rn + h), -self.vn / (rm + h), -self.ve * (sl / cl) / (rn + h)
        win_n, win_e, win_d = wie_n + wen_n, wie_e + wen_e, wie_d + wen_d
        # attitude: body rotation on the right, navigation-frame rotation on the left
        q_old = self.q
        q = _qmul(q_old, _qrotvec(rot[0], rot[1], rot[2]))
        q = _qmul(_qrotvec(-win_n * dt, -win_e * dt, -win_d * dt), q)
        n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        q = (q[0] / n, q[1] / n, q[2] / n, q[3] / n)
        if dv_b is None:  # specific force resolved with the mid-interval attitude
            qm = (q_old[0] + q[0], q_old[1] + q[1], q_old[2] + q[2], q_old[3] + q[3])
            nm = math.sqrt(qm[0] ** 2 + qm[1] ** 2 + qm[2] ** 2 + qm[3] ** 2)
            qm = (qm[0] / nm, qm[1] / nm, qm[2] / nm, qm[3] / nm)
            fn, fe, fd = _rot(qm, f_b[0], f_b[1], f_b[2])
        else:  # the increment (rotation and sculling compensated) is in the body frame at the start
            fn, fe, fd = _rot(q_old, dv_b[0] / dt, dv_b[1] / dt, dv_b[2] / dt)
        self.f_ned = (fn, fe, fd)
        # Coriolis + transport: (2 w_ie + w_en) x v
        cn, ce, cd = 2 * wie_n + wen_n, 2 * wie_e + wen_e, 2 * wie_d + wen_d
        vn, ve, vd = self.vn, self.ve, self.vd
        an = fn - (ce * vd - cd * ve)
        ae = fe - (cd * vn - cn * vd)
        ad = fd - (cn * ve - ce * vn) + _gravity(s2, w, h)
        nvn, nve, nvd = vn + an * dt, ve + ae * dt, vd + ad * dt
        # position (trapezoidal velocity)
        mvn, mve, mvd = 0.5 * (vn + nvn), 0.5 * (ve + nve), 0.5 * (vd + nvd)
        self.lat_rad += mvn / (rm + self.h_m) * dt
        self.lon_rad += mve / ((rn + self.h_m) * math.cos(self.lat_rad)) * dt
        self.h_m -= mvd * dt
        self.vn, self.ve, self.vd = nvn, nve, nvd
        self.q = q
        self.t_s = t_s
        return dt

    def coast(self, t_s: float) -> None:
        """Advance to ``t_s`` at constant velocity and attitude (bridging a stall in the IMU stream)."""
        dt = t_s - self.t_s
        if dt <= 0:
            return
        rm, rn = self.radii()
        self.lat_rad += self.vn / (rm + self.h_m) * dt
        self.lon_rad += self.ve / ((rn + self.h_m) * math.cos(self.lat_rad)) * dt
        self.h_m -= self.vd * dt
        self.t_s = t_s

    # -- error-state corrections (error = true - estimate; attitude C_true = (I + [psi x]) C_est)
    def correct(self, dpos_ned_m, dvel_ned_mps, psi_ned_rad, dba, dbg) -> None:
        rm, rn = self.radii()
        self.lat_rad += dpos_ned_m[0] / (rm + self.h_m)
        self.lon_rad += dpos_ned_m[1] / ((rn + self.h_m) * math.cos(self.lat_rad))
        self.h_m -= dpos_ned_m[2]
        self.vn += dvel_ned_mps[0]
        self.ve += dvel_ned_mps[1]
        self.vd += dvel_ned_mps[2]
        q = _qmul(_qrotvec(psi_ned_rad[0], psi_ned_rad[1], psi_ned_rad[2]), self.q)
        n = math.sqrt(sum(c * c for c in q))
        self.q = tuple(c / n for c in q)  # type: ignore[assignment]
        for i in range(3):
            self.ba[i] += dba[i]
            self.bg[i] += dbg[i]
