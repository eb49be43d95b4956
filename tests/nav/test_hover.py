"""Low-dynamics detection (companion.nav.hover) on simulated flights, and the zero-velocity pseudo-measurement keeping
the navigator no worse than hold-last-fix on a hover."""

import numpy as np

from companion.events import Attitude, GnssFix, ImuSample
from companion.nav.hover import HoverDetector
from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import FusedState, MeasurementUpdate
from companion.sim.flight import CANBERRA_FIELD, SimConfig, simulate_flight
from companion.sim.motion import dcm_from_euler
from companion.sim.trajectory import Climb, FlightProfile, Hold, Speed, Straight


def _hover_share(legs, t_from_s, t_to_s=np.inf):
    sim = simulate_flight(FlightProfile(legs, CANBERRA_FIELD), seed=3, config=SimConfig())
    det = HoverDetector()
    imu, gnss = sim.imu, sim.gnss
    j = 0
    flags = []
    for k, t in enumerate(imu.t_s):
        while j < len(gnss.t_s) and gnss.t_s[j] <= t:
            det.add_speed(gnss.t_s[j], float(np.hypot(*gnss.vel_ned_mps[j, :2])))
            j += 1
        det.add_imu(float(t), imu.accel_frd_mps2[k], imu.gyro_frd_radps[k])
        if t_from_s <= t < t_to_s:
            flags.append(det.hover(float(t)))
    return float(np.mean(flags))


def test_hover_detected_on_a_simulated_hover():
    assert _hover_share([Hold(2.0), Climb(10.0, rate_mps=2.0), Hold(60.0)], t_from_s=20.0) > 0.95


def test_hover_not_detected_on_a_simulated_slow_flight():
    legs = [Hold(2.0), Climb(10.0, rate_mps=2.0), Speed(2.0, max_accel_mps2=0.5), Straight(120.0), Speed(0.0)]
    assert _hover_share(legs, t_from_s=20.0, t_to_s=70.0) < 0.02


def _hover_events(duration_s, rng, wander_m=0.3):
    """A hovering multicopter: level, vibrating IMU (1 m/s^2, 0.03 rad/s per sample at 50 Hz), GNSS at 1 Hz around a
    point with a slow wander, autopilot attitude at 10 Hz."""
    lat0, lon0, alt0 = -35.3632, 149.1652, 600.0
    ev = []
    for k in range(int(duration_s * 50)):
        t = 100.0 + k / 50.0
        ev.append(ImuSample(round(t, 6), tuple(map(float, rng.normal(0, 1.0, 3) + [0.0, 0.0, -9.7965])),
                            tuple(map(float, rng.normal(0, 0.03, 3))), 0))
    for k in range(int(duration_s * 10)):
        t = 100.0 + k / 10.0
        ev.append(Attitude(round(t, 6), *map(float, rng.normal(0, 0.005, 3))))
    for k in range(int(duration_s)):
        t = 100.0 + k + 0.05
        n, e = wander_m * np.sin(2 * np.pi * t / 40.0), wander_m * np.cos(2 * np.pi * t / 55.0)
        vn, ve = wander_m * 2 * np.pi / 40.0 * np.cos(2 * np.pi * t / 40.0), 0.0
        ev.append(GnssFix(round(t, 6), 3, lat0 + n / 111_000.0, lon0 + e / 90_800.0, alt0, vn, ve, 0.0, None, None,
                          12, 0.8, 1.2, 0.8, 1.2, 0.3, None, None))
    ev.sort(key=lambda x: x.t_s)
    return ev, (lat0, lon0)


def test_zero_velocity_keeps_a_hover_near_hold_last_fix():
    ev, (lat0, lon0) = _hover_events(120.0, np.random.default_rng(1))
    t0, t1 = 170.0, 185.0  # a 15 s blockage
    blocked = [e for e in ev if not (isinstance(e, GnssFix) and t0 <= e.t_s < t1)]
    errs = {}
    for on in (True, False):
        out = run_navigator(blocked, NavigatorConfig(zero_velocity=on))
        fs = [o for o in out if isinstance(o, FusedState) and t0 <= o.t_s < t1]
        errs[on] = max(np.hypot((o.lat_deg - lat0) * 111_000.0, (o.lon_deg - lon0) * 90_800.0) for o in fs)
        if on:
            assert any(isinstance(u, MeasurementUpdate) and u.kind == "zero_velocity" and u.accepted for u in out)
    assert errs[True] < 1.5  # hold-last-fix: within ~0.6 m (the wander)
    assert errs[True] <= errs[False]


def _hover_share_blocked(legs, block_from_s, t_from_s, t_to_s):
    """As _hover_share, with no GNSS speed from ``block_from_s`` on (a blockage)."""
    sim = simulate_flight(FlightProfile(legs, CANBERRA_FIELD), seed=3, config=SimConfig())
    det = HoverDetector()
    imu, gnss = sim.imu, sim.gnss
    j = 0
    flags = []
    for k, t in enumerate(imu.t_s):
        while j < len(gnss.t_s) and gnss.t_s[j] <= t:
            if gnss.t_s[j] < block_from_s:
                det.add_speed(gnss.t_s[j], float(np.hypot(*gnss.vel_ned_mps[j, :2])))
            j += 1
        det.add_imu(float(t), imu.accel_frd_mps2[k], imu.gyro_frd_radps[k])
        if k:  # the specific force resolved with the true attitude (the navigator uses the autopilot's)
            f_ned = dcm_from_euler(sim.truth_imu.euler_rad[k]) @ imu.accel_frd_mps2[k]
            det.add_horizontal_dv(*(f_ned[:2] * (t - imu.t_s[k - 1])))
        if t_from_s <= t < t_to_s:
            flags.append(det.hover(float(t)))
    return float(np.mean(flags))


def test_no_hover_while_cruising_away_from_a_stop_in_a_blockage():
    """GNSS last saw the vehicle still; it then accelerates to 8 m/s and cruises: the IMU is as quiet as in a hover
    once the acceleration ends, but the vehicle is moving."""
    legs = [Hold(2.0), Climb(10.0, rate_mps=2.0), Hold(20.0), Speed(8.0, max_accel_mps2=2.0), Straight(300.0),
            Speed(0.0)]
    tr = FlightProfile(legs, CANBERRA_FIELD).sample(np.arange(0.0, 60.0, 0.05))
    speed = np.hypot(tr.vel_ned_mps[:, 0], tr.vel_ned_mps[:, 1])
    leave_s = float(tr.t_s[np.argmax(speed > 0.01)])
    block_s = leave_s - 0.5  # GNSS stops just before the vehicle leaves the hover
    moving_s = float(tr.t_s[np.argmax(speed > 1.5)])  # 1.5 s later at 2 m/s^2
    assert _hover_share_blocked(legs, block_s, t_from_s=moving_s, t_to_s=block_s + 30.0) == 0.0
    # the hover before it is still found with GNSS up to the blockage
    assert _hover_share_blocked(legs, block_s, t_from_s=15.0, t_to_s=block_s) > 0.9
