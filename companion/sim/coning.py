"""A vehicle at rest on a coning, vibrating mount: the IMU samples and the true attitude, the classical test of
strapdown integration (coning, sculling; Savage 1998). The body sweeps a cone (``cone_rad`` half-angle, ``cone_hz``)
and rolls to and fro (``vib_rad``, ``vib_hz``); the velocity is zero throughout. Used by tests/nav/test_imu_accumulator.py
and replay/live/imu_rate.py."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.nav.ins import _qmul, _qrotvec, dcm_from_quat


def rotvec(q) -> np.ndarray:
    """The rotation vector (rad) of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    s = math.sqrt(x * x + y * y + z * z)
    return np.zeros(3) if s < 1e-15 else np.array([x, y, z]) * (2 * math.atan2(s, w) / s)


@dataclass(frozen=True)
class ConingMount:
    cone_rad: float = math.radians(3.0)
    cone_hz: float = 7.0
    vib_rad: float = math.radians(1.5)
    vib_hz: float = 23.0

    def attitude(self, t_s: float):
        """Body-to-NED quaternion at t: yaw(w t) roll(cone) yaw(-w t), then the roll vibration."""
        w = 2 * math.pi * self.cone_hz
        q = _qmul(_qmul(_qrotvec(0, 0, w * t_s), _qrotvec(self.cone_rad, 0, 0)), _qrotvec(0, 0, -w * t_s))
        return _qmul(q, _qrotvec(self.vib_rad * math.sin(2 * math.pi * self.vib_hz * t_s), 0, 0))

    def samples(self, rate_hz: float, duration_s: float, gravity_mps2: float) -> list[tuple[float, tuple, tuple]]:
        """(t, accel FRD, gyro FRD) per sample: the gyro the interval's exact mean rate, the accelerometer gravity's
        reaction resolved in the body at mid-interval."""
        dt = 1.0 / rate_hz
        out = []
        q0 = self.attitude(0.0)
        for k in range(1, int(round(duration_s * rate_hz)) + 1):
            t = k * dt
            q1 = self.attitude(t)
            gyro = rotvec(_qmul((q0[0], -q0[1], -q0[2], -q0[3]), q1)) / dt
            C = dcm_from_quat(self.attitude(t - dt / 2))
            out.append((t, tuple((C.T @ np.array([0.0, 0.0, -gravity_mps2])).tolist()), tuple(gyro.tolist())))
            q0 = q1
        return out

    def errors(self, q, vel_ned, t_s: float) -> tuple[float, float]:
        """(attitude error deg, speed m/s) of an estimate at t against the truth (at rest)."""
        qt = self.attitude(t_s)
        err = rotvec(_qmul((qt[0], -qt[1], -qt[2], -qt[3]), q))
        return math.degrees(float(np.linalg.norm(err))), math.sqrt(sum(v * v for v in vel_ned))
