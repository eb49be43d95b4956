"""Small helpers shared by tests (fixtures and shared-data paths are in tests/conftest.py)."""

from __future__ import annotations


class Collect:
    """A pipeline sink keeping everything written, in order."""

    def __init__(self) -> None:
        self.items: list = []

    def write(self, item, topic=None) -> None:
        self.items.append(item)

    def write_location(self, *a, **k) -> None:
        pass

    def write_log(self, *a, **k) -> None:
        pass


def subclasses(cls) -> set[type]:
    """Every subclass of a class, at any depth."""
    out: set[type] = set()
    for sub in cls.__subclasses__():
        out |= {sub} | subclasses(sub)
    return out


def bumpy_map(seed: int, half_m: float, cell_m: float, n_bumps: int, width_m: tuple[float, float]):
    """A local metric gravity map (north/east axes -half..half) of Gaussian bumps of 20 mGal (1-sigma amplitude)."""
    import numpy as np

    from companion.gravity import GravityMap, LocalGravityMap

    rng = np.random.default_rng(seed)
    ax = np.arange(-half_m, half_m + 1, cell_m)
    N, E = np.meshgrid(ax, ax, indexing="ij")
    g = np.zeros_like(N)
    for _ in range(n_bumps):
        c = rng.uniform(-half_m, half_m, 2)
        w = rng.uniform(*width_m)
        g += rng.normal(0, 20) * np.exp(-((N - c[0]) ** 2 + (E - c[1]) ** 2) / (2 * w * w))
    return LocalGravityMap(GravityMap(g, ax, ax, "local_m"))


def flight_events(sim, gnss_every: int = 1, deny_s=None) -> list:
    """A simulated flight (companion.sim.flight) as navigator events: every IMU sample, the autopilot's attitude
    estimate, and every ``gnss_every``-th receiver fix (none inside ``deny_s``), sorted as a replay sorts them."""
    from companion.events import Attitude, GnssFix, ImuSample

    ev = []
    for k, t in enumerate(sim.imu.t_s):
        ev.append(ImuSample(round(float(t), 6), tuple(map(float, sim.imu.accel_frd_mps2[k])),
                            tuple(map(float, sim.imu.gyro_frd_radps[k])), 0))
    for k, t in enumerate(sim.truth_attitude.t_s):
        ev.append(Attitude(round(float(t), 6), *map(float, sim.attitude_euler_rad[k])))
    g = sim.gnss
    for k in range(0, len(g.t_s), gnss_every):
        t = float(g.t_s[k])
        if not g.has_fix[k] or (deny_s is not None and deny_s[0] <= t < deny_s[1]):
            continue
        v = g.vel_ned_mps[k]
        ev.append(GnssFix(round(t, 6), 3, float(g.lat_deg[k]), float(g.lon_deg[k]), float(g.alt_msl_m[k]),
                          float(v[0]), float(v[1]), float(v[2]), None, None, int(g.satellites[k]), float(g.hdop[k]),
                          float(g.vdop[k]), float(g.h_acc_m[k]), float(g.v_acc_m[k]), float(g.speed_acc_mps[k]),
                          None, None))
    ev.sort(key=lambda e: (e.t_s, {ImuSample: 0, Attitude: 1}.get(type(e), 2)))
    return ev


def tilted_in_ned(e, angle_rad: float):
    """An Attitude event with its level reference rotated by angle_rad about north (a tilt error fixed in the
    navigation frame, e.g. levelled on a wrong acceleration): observable as the vehicle turns."""
    import dataclasses
    import math

    import numpy as np

    from companion.nav.ins import dcm_from_quat, quat_from_euler

    c, s = math.cos(angle_rad), math.sin(angle_rad)
    cm = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]) @ dcm_from_quat(quat_from_euler(e.roll_rad, e.pitch_rad,
                                                                                                e.yaw_rad))
    return dataclasses.replace(e, roll_rad=math.atan2(cm[2, 1], cm[2, 2]), pitch_rad=-math.asin(cm[2, 0]),
                               yaw_rad=math.atan2(cm[1, 0], cm[0, 0]))
