"""IMU increments accumulated between strapdown steps: a fast IMU (200-400 Hz) integrated at the filter's rate.

Per sample only multiply-adds, no trigonometry. The rotation: the delta angles ``da_k`` summed into ``a`` with the
coning term ``b = 1/2 sum a_(k-1) x da_k``, the step's rotation vector ``a + b`` (Savage 1998, Strapdown inertial
navigation integration algorithm design, part 1; Groves 2013 sec. 5.5.4). The velocity: each increment ``dv_k``
resolved in the body frame at the interval's start with the rotation to the sample's middle, ``m = a_(k-1) +
da_k / 2``, to second order: ``dv_k + m x dv_k + 1/2 m x (m x dv_k)``; this carries the sculling (the rotation of
the specific force within the interval) without the first-order algorithm's bias under fast vibration (at 3.8 rad/s
of 23 Hz roll vibration, 3 mm/s^2 along gravity; tests/nav/test_imu_accumulator.py). Pure: no I/O, no clocks.
"""

from __future__ import annotations


class ImuAccumulator:
    """Sums of the samples since the last :meth:`take`; ``dt_s`` is the time they span."""

    __slots__ = ("dt_s", "t_s", "n", "_a", "_v", "_b")

    def __init__(self) -> None:
        self.t_s = 0.0  # time of the last sample added
        self.reset()

    def reset(self) -> None:
        self.dt_s = 0.0
        self.n = 0
        self._a = [0.0, 0.0, 0.0]
        self._v = [0.0, 0.0, 0.0]
        self._b = [0.0, 0.0, 0.0]

    def add(self, t_s: float, dt_s: float, accel_frd_mps2, gyro_frd_radps) -> None:
        """One sample held over ``dt_s`` (already bias-corrected)."""
        dax, day, daz = gyro_frd_radps[0] * dt_s, gyro_frd_radps[1] * dt_s, gyro_frd_radps[2] * dt_s
        dvx, dvy, dvz = accel_frd_mps2[0] * dt_s, accel_frd_mps2[1] * dt_s, accel_frd_mps2[2] * dt_s
        a, v, b = self._a, self._v, self._b
        ax, ay, az = a
        b[0] += 0.5 * (ay * daz - az * day)
        b[1] += 0.5 * (az * dax - ax * daz)
        b[2] += 0.5 * (ax * day - ay * dax)
        mx, my, mz = ax + 0.5 * dax, ay + 0.5 * day, az + 0.5 * daz  # the rotation to the sample's middle
        cx, cy, cz = my * dvz - mz * dvy, mz * dvx - mx * dvz, mx * dvy - my * dvx  # m x dv
        v[0] += dvx + cx + 0.5 * (my * cz - mz * cy)
        v[1] += dvy + cy + 0.5 * (mz * cx - mx * cz)
        v[2] += dvz + cz + 0.5 * (mx * cy - my * cx)
        a[0], a[1], a[2] = ax + dax, ay + day, az + daz
        self.dt_s += dt_s
        self.t_s = t_s
        self.n += 1

    def take(self) -> tuple[float, tuple[float, float, float], tuple[float, float, float]]:
        """(dt_s, rotation vector rad, velocity increment m/s in the body frame at the start) of the samples summed;
        then starts again."""
        a, v, b = self._a, self._v, self._b
        rot = (a[0] + b[0], a[1] + b[1], a[2] + b[2])
        dv = (v[0], v[1], v[2])
        dt = self.dt_s
        self.reset()
        return dt, rot, dv
