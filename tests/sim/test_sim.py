"""Simulator: trajectory consistency, sensor models, MAVLink/tlog output and the shipped sample log."""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from companion import units
from companion.sim.flight import (
    CANBERRA_FIELD,
    SAMPLE_BOOT_EPOCH_US,
    SAMPLE_OUTAGE_S,
    SimConfig,
    sample_flight,
    sample_profile,
    simulate_flight,
)
from companion.sim.make_sample import flight_tlog_bytes, truth_csv_text
from companion.sim.sensors import GnssModel, ImuModel, simulate_imu
from companion.sim.motion import G_NED_MPS2
from companion.sim.trajectory import Climb, FlightProfile, Hold, Land, Speed, Straight, Turn
from companion.sim.waypoints import legs_through_waypoints

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "logs" / "sample_flight.tlog"
SAMPLE_TRUTH = REPO / "logs" / "sample_flight_truth.csv"


@pytest.fixture(scope="module")
def flight():
    return sample_flight()


@pytest.fixture(scope="module")
def sample_messages():
    """Every message of the shipped sample, read back with pymavlink's own tlog reader."""
    log = mavutil.mavlink_connection(str(SAMPLE))
    msgs = []
    while True:
        m = log.recv_msg()
        if m is None:
            break
        msgs.append(m)
    return msgs


# -- trajectory -----------------------------------------------------------------------------------
def test_trajectory_derivatives_are_consistent():
    """Velocity, acceleration, Euler rates and body rates equal the numerical derivatives of the
    quantity below them; the accelerometer sees thrust only (body x/y specific force zero)."""
    tr = sample_profile().sample_rate(200.0)
    dt = 1.0 / 200.0
    inner = slice(2, -2)
    for lower, upper, tol in (
        (tr.pos_ned_m, tr.vel_ned_mps, 1e-4),
        (tr.vel_ned_mps, tr.acc_ned_mps2, 1e-3),
        (np.unwrap(tr.euler_rad, axis=0), tr.euler_rate_radps, 1e-3),
    ):
        num = np.gradient(lower, dt, axis=0)
        assert np.max(np.abs(num - upper)[inner]) < tol
    c = tr.c_nb
    w_skew = np.einsum("nji,njk->nik", c, np.gradient(c, dt, axis=0))  # C^T dC/dt = [w]x
    w = np.stack([w_skew[:, 2, 1], w_skew[:, 0, 2], w_skew[:, 1, 0]], axis=-1)
    assert np.max(np.abs(w - tr.rate_frd_radps)[inner]) < 1e-3
    f = tr.specific_force_frd_mps2
    assert np.max(np.abs(f[:, :2])) < 1e-9
    f_ned = np.einsum("nij,nj->ni", c, f)
    assert np.allclose(f_ned, tr.acc_ned_mps2 - G_NED_MPS2, atol=1e-9)
    assert np.allclose(f[0], (0.0, 0.0, -9.80665))  # level on the ground


def test_sample_profile_shape():
    p = sample_profile()
    tr = p.sample_rate(10.0)
    speed = np.hypot(tr.vel_ned_mps[:, 0], tr.vel_ned_mps[:, 1])
    height = -tr.pos_ned_m[:, 2]
    assert 170.0 < p.duration_s < 190.0
    assert 7.9 < speed.max() <= 8.0 + 1e-9
    assert height.max() == pytest.approx(35.0, abs=1e-6)
    assert height[0] == 0.0 and abs(height[-1]) < 1e-9  # takes off from and lands on the ground
    assert np.degrees(np.abs(tr.euler_rad[:, :2]).max()) < 25.0
    t0, t1 = SAMPLE_OUTAGE_S
    during = (tr.t_s >= t0) & (tr.t_s < t1)
    assert height[during].min() > 15.0 and speed[during].min() > 5.0  # the outage is in the air, moving


def test_waypoint_legs_fly_by_and_stop_at_last():
    wps = [(100.0, 0.0), (100.0, 80.0), (0.0, 80.0)]
    legs = [Climb(10.0)] + legs_through_waypoints(wps, (0.0, 0.0), 0.0, 7.0, 15.0) + [Land()]
    tr = FlightProfile(legs, CANBERRA_FIELD).sample_rate(50.0)
    ne = tr.pos_ned_m[:, :2]
    assert np.allclose(ne[-1], wps[-1], atol=1e-3)
    for wp in wps[:-1]:  # corners are cut by a fly-by turn: passes within the radius, not through
        d = np.min(np.linalg.norm(ne - wp, axis=1))
        assert 0.5 < d < 15.0
    turn_accel = np.linalg.norm(tr.acc_ned_mps2[:, :2], axis=1).max()
    assert turn_accel == pytest.approx(7.0**2 / 15.0, rel=1e-3)


def test_waypoint_reversal_and_short_legs_are_rejected():
    with pytest.raises(ValueError, match="reversal"):
        legs_through_waypoints([(100.0, 0.0), (0.0, 0.0)], (-50.0, 0.0), 0.0, 5.0, 10.0)
    with pytest.raises(ValueError, match="too short"):
        legs_through_waypoints([(10.0, 0.0), (10.0, 10.0)], (0.0, 0.0), 0.0, 8.0, 20.0)


@pytest.mark.parametrize(
    "legs, why",
    [
        ([Straight(10.0)], "zero speed"),
        ([Climb(5.0), Turn(90.0, 10.0)], "zero speed"),
        ([Land()], "on the ground"),
        ([Climb(5.0), Speed(5.0)], "end stopped"),
    ],
)
def test_bad_plans_are_rejected(legs, why):
    with pytest.raises(ValueError, match=why):
        FlightProfile(legs, CANBERRA_FIELD)


# -- sensors --------------------------------------------------------------------------------------
def _rodrigues(phi: np.ndarray) -> np.ndarray:
    a = np.linalg.norm(phi)
    k = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if a < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + math.sin(a) / a * k + (1.0 - math.cos(a)) / a**2 * (k @ k)


def _strapdown_error_m(tr, accel, gyro, k0: int, n: int) -> float:
    """NED strapdown (trapezoidal, flat earth, constant g as the simulator) from the true state at k0."""
    dt = tr.t_s[1] - tr.t_s[0]
    c, v, p = tr.c_nb[k0], tr.vel_ned_mps[k0].copy(), tr.pos_ned_m[k0].copy()
    a_n = c @ accel[k0] + G_NED_MPS2
    for k in range(k0, k0 + n):
        c = c @ _rodrigues(0.5 * (gyro[k] + gyro[k + 1]) * dt)
        a_n1 = c @ accel[k + 1] + G_NED_MPS2
        v1 = v + 0.5 * (a_n + a_n1) * dt
        p = p + 0.5 * (v + v1) * dt
        v, a_n = v1, a_n1
    return float(np.linalg.norm(p - tr.pos_ned_m[k0 + n]))


@pytest.mark.parametrize("t0_s", [24.0, 44.0, 95.0, 116.0])  # accelerating, fly-by turn, circle, climb
def test_noise_free_imu_integrates_to_truth(t0_s):
    """10 s of 50 Hz strapdown from the true state stays within 5 cm of the true position.

    The measured discretisation error of this second-order integrator is below 5 mm. 5 cm is far below
    what any inconsistency between the IMU and the trajectory would give over 10 s: a 1 mG (0.01 m/s^2)
    specific-force error drifts 0.5 m, a 0.001 rad/s rate error (tilt error -> g leaks into the horizontal)
    about 1.6 m, a wrong rate sign or frame hundreds of metres (checked below).
    """
    tr = sample_profile().sample_rate(50.0)
    imu = simulate_imu(tr, ImuModel.perfect(), np.random.default_rng(0))
    k0 = int(round(t0_s * 50))
    assert _strapdown_error_m(tr, imu.accel_frd_mps2, imu.gyro_frd_radps, k0, 500) < 0.05
    # the check has teeth: a sign error in the gyro, or a 1 mG accel bias, fails it
    assert _strapdown_error_m(tr, imu.accel_frd_mps2, -imu.gyro_frd_radps, k0, 500) > 1.0
    assert _strapdown_error_m(tr, imu.accel_frd_mps2 + [0.0098, 0.0, 0.0], imu.gyro_frd_radps, k0, 500) > 0.1


def test_imu_noise_and_bias_statistics():
    tr = sample_profile().sample_rate(50.0)
    model = ImuModel()
    imu = simulate_imu(tr, model, np.random.default_rng(7))
    acc_err = imu.accel_frd_mps2 - tr.specific_force_frd_mps2 - imu.accel_bias_frd_mps2
    gyr_err = imu.gyro_frd_radps - tr.rate_frd_radps - imu.gyro_bias_frd_radps
    assert np.std(acc_err) == pytest.approx(model.accel_noise_mps2, rel=0.03)
    assert np.std(gyr_err) == pytest.approx(model.gyro_noise_radps, rel=0.03)
    assert np.abs(np.mean(acc_err, axis=0)).max() < 5 * model.accel_noise_mps2 / math.sqrt(len(tr))


def test_gnss_error_is_bounded_random_walk(flight):
    g = flight.gnss
    fix = g.has_fix
    err = flight.profile.frame.to_ned_m(g.lat_deg[fix], g.lon_deg[fix], g.alt_msl_m[fix]) - flight.truth_gnss.pos_ned_m[fix]
    assert np.allclose(err, g.pos_error_ned_m[fix], atol=1e-6)  # the reported position = truth + the modelled error
    horiz = np.linalg.norm(err[:, :2], axis=1)
    assert 0.2 < np.sqrt(np.mean(horiz**2)) < 3.0
    # correlated, not white: consecutive 0.2 s errors differ by far less than the error itself
    assert np.std(np.diff(err[:, 0])) < 0.3 * np.std(err[:, 0])


# -- MAVLink / tlog -------------------------------------------------------------------------------
def test_sample_regenerates_byte_identical(flight):
    data, _ = flight_tlog_bytes(flight)
    assert data == SAMPLE.read_bytes(), "logs/sample_flight.tlog is stale: run python -m companion.sim.make_sample"
    assert truth_csv_text(flight) == SAMPLE_TRUTH.read_text()
    assert SAMPLE.stat().st_size < 1_500_000 and SAMPLE_TRUTH.stat().st_size < 1_000_000


def test_sample_reads_cleanly_with_expected_counts_and_rates(flight, sample_messages):
    counts = Counter(m.get_type() for m in sample_messages)
    assert counts["BAD_DATA"] == 0
    dur = flight.duration_s
    n_imu = math.floor(dur * 50.0) + 1
    assert counts["RAW_IMU"] == n_imu
    assert counts["SCALED_IMU2"] == n_imu
    assert counts["ATTITUDE"] == math.floor(dur * 10.0) + 1
    assert counts["GPS_RAW_INT"] == math.floor((dur - 0.1) * 5.0) + 1  # first fix at 0.1 s
    assert counts["SYSTEM_TIME"] == math.floor(dur) + 1
    assert counts["HEARTBEAT"] == 2 * (math.floor(dur) + 1)  # autopilot + ground station
    assert counts["STATUSTEXT"] == len(flight.statustexts)
    assert set(counts) == {"RAW_IMU", "SCALED_IMU2", "ATTITUDE", "GPS_RAW_INT", "SYSTEM_TIME", "HEARTBEAT", "STATUSTEXT"}

    # every frame is MAVLink 2 from the autopilot (1/1) except the GCS heartbeats (255/190)
    for m in sample_messages:
        assert m.get_msgbuf()[0] == 0xFD
        src = (m.get_srcSystem(), m.get_srcComponent())
        assert src == ((255, 190) if m.get_type() == "HEARTBEAT" and m.autopilot == 8 else (1, 1))

    # per-type boot-time spacing is exactly the intended rate
    boot_us = defaultdict(list)
    for m in sample_messages:
        t = m.get_type()
        if t == "RAW_IMU":
            boot_us[t].append(m.time_usec)
        elif t == "GPS_RAW_INT":
            boot_us[t].append(m.time_usec)
        elif t in ("SCALED_IMU2", "ATTITUDE", "SYSTEM_TIME"):
            boot_us[t].append(m.time_boot_ms * 1000)
    for t, period_us in (("RAW_IMU", 20_000), ("SCALED_IMU2", 20_000), ("ATTITUDE", 100_000), ("GPS_RAW_INT", 200_000), ("SYSTEM_TIME", 1_000_000)):
        assert set(np.diff(boot_us[t])) == {period_us}, t

    # receive stamps: never decrease, a little after send time (epoch + boot time), no wall clock
    recv = np.array([m._timestamp for m in sample_messages])
    assert np.all(np.diff(recv) >= 0)
    for m in sample_messages:
        if m.get_type() == "RAW_IMU":
            lag_s = m._timestamp - (SAMPLE_BOOT_EPOCH_US + m.time_usec) * 1e-6
            assert 0.0 < lag_s < 0.005
    st = [m for m in sample_messages if m.get_type() == "SYSTEM_TIME"]
    assert all(m.time_unix_usec == SAMPLE_BOOT_EPOCH_US + m.time_boot_ms * 1000 for m in st)

    # heartbeats: quadrotor / ArduPilot, armed exactly inside the armed window
    hb = [m for m in sample_messages if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1]
    assert all(m.type == 2 and m.autopilot == 3 for m in hb)
    for m in hb:
        t_boot = m._timestamp - SAMPLE_BOOT_EPOCH_US * 1e-6 - 0.001
        armed = bool(m.base_mode & 128)
        assert armed == (flight.armed_s[0] <= round(t_boot) < flight.armed_s[1])
    assert {m.custom_mode for m in hb} == {0, 3, 9}  # STABILIZE, AUTO, LAND


def test_imu_scaling_round_trip(flight, sample_messages):
    """RAW_IMU integers decode (units.py) to the simulated IMU within half an LSB."""
    raw = [m for m in sample_messages if m.get_type() == "RAW_IMU"]
    acc = np.array([[units.mps2_from_mG(v) for v in (m.xacc, m.yacc, m.zacc)] for m in raw])
    gyr = np.array([[units.radps_from_mradps(v) for v in (m.xgyro, m.ygyro, m.zgyro)] for m in raw])
    assert np.max(np.abs(acc - flight.imu.accel_frd_mps2)) <= 0.5e-3 * units.STANDARD_GRAVITY_MPS2 + 1e-12
    assert np.max(np.abs(gyr - flight.imu.gyro_frd_radps)) <= 0.5e-3 + 1e-12
    assert np.median(acc[:200, 2]) == pytest.approx(-9.81, abs=0.1)  # on the ground, level


def test_gps_lat_lon_round_trip(flight, sample_messages):
    """Decoded GPS_RAW_INT lat/lon match the simulated receiver output within 1e-7 deg (degE7 LSB/2)."""
    gps = [m for m in sample_messages if m.get_type() == "GPS_RAW_INT"]
    g = flight.gnss
    assert len(gps) == len(g.t_s)
    fix = g.has_fix
    lat = np.array([units.deg_from_degE7(m.lat) for m in gps])
    lon = np.array([units.deg_from_degE7(m.lon) for m in gps])
    alt = np.array([units.m_from_mm(m.alt) for m in gps])
    assert np.max(np.abs(lat[fix] - g.lat_deg[fix])) <= 0.5e-7 + 1e-12
    assert np.max(np.abs(lon[fix] - g.lon_deg[fix])) <= 0.5e-7 + 1e-12
    assert np.max(np.abs(alt[fix] - g.alt_msl_m[fix])) <= 0.5e-3 + 1e-9
    times = np.array([units.s_from_us(m.time_usec) for m in gps])
    assert np.allclose(times, g.t_s, atol=1e-9)
    speed = np.array([units.m_from_cm(m.vel) for m in gps])
    assert np.allclose(speed[fix], np.hypot(g.vel_ned_mps[fix, 0], g.vel_ned_mps[fix, 1]), atol=0.005 + 1e-9)


def test_perfect_gnss_decodes_to_truth(tmp_path):
    """End to end with a noise-free receiver: decoded lat/lon equal the true trajectory within 1e-7 deg."""
    legs = [Hold(1.0), Climb(10.0), Speed(6.0), Turn(90.0, 15.0), Speed(0.0), Land()]
    profile = FlightProfile(legs, CANBERRA_FIELD, start_heading_deg=45.0)
    cfg = SimConfig(gnss=GnssModel.perfect(), imu2=None)
    fl = simulate_flight(profile, seed=1, config=cfg)
    data, _ = flight_tlog_bytes(fl)
    path = tmp_path / "perfect.tlog"
    path.write_bytes(data)
    log = mavutil.mavlink_connection(str(path))
    gps = []
    while (m := log.recv_match(type="GPS_RAW_INT")) is not None:
        gps.append(m)
    assert len(gps) == len(fl.truth_gnss)
    tr = fl.truth_gnss
    lat = np.array([units.deg_from_degE7(m.lat) for m in gps])
    lon = np.array([units.deg_from_degE7(m.lon) for m in gps])
    assert np.max(np.abs(lat - tr.lat_deg)) <= 1e-7
    assert np.max(np.abs(lon - tr.lon_deg)) <= 1e-7


def test_outage_rows(flight, sample_messages):
    gps = [m for m in sample_messages if m.get_type() == "GPS_RAW_INT"]
    t0, t1 = SAMPLE_OUTAGE_S
    inside = [m for m in gps if t0 <= units.s_from_us(m.time_usec) < t1]
    outside = [m for m in gps if not t0 <= units.s_from_us(m.time_usec) < t1]
    assert len(inside) == round((t1 - t0) * 5.0)  # rows keep coming at 5 Hz
    assert all(m.fix_type == 1 and m.lat == 0 and m.lon == 0 and m.satellites_visible == 0 for m in inside)
    assert all(m.eph == 65535 and m.epv == 65535 for m in inside)
    assert all(m.fix_type == 3 and m.lat != 0 and m.lon != 0 for m in outside)
    texts = [m.text for m in sample_messages if m.get_type() == "STATUSTEXT"]
    assert "GPS Glitch" in texts and "GPS Glitch cleared" in texts


def test_project_reader_decodes_sample():
    """The project's own tlog reader takes the sample without dropping autopilot data."""
    from companion.events import GnssFix, ImuSample
    from companion.sources.files import open_reader

    reader = open_reader(SAMPLE)
    events = []
    while batch := reader.read_batch(5000):
        events += batch
    reader.close()
    assert not any("bad" in w or "malformed" in w or "before" in w for w in reader.info.warnings), reader.info.warnings
    fixes = [e for e in events if isinstance(e, GnssFix)]
    lost = [e for e in fixes if not e.has_position]
    assert len(lost) == round((SAMPLE_OUTAGE_S[1] - SAMPLE_OUTAGE_S[0]) * 5.0)
    assert all(SAMPLE_OUTAGE_S[0] <= e.t_s < SAMPLE_OUTAGE_S[1] for e in lost)
    imu_idx = Counter(e.imu_index for e in events if isinstance(e, ImuSample))
    assert set(imu_idx) == {0, 1}


def test_plotted_lines_break_at_gaps():
    from companion.sim.make_sample import _break_gaps

    t = np.array([0.0, 0.1, 0.2, 0.3, 8.5, 8.6, 8.7])
    tt, yy = _break_gaps(t, t * 2)
    assert np.isnan(yy).sum() == 1 and np.isnan(yy[4]) and 0.3 < tt[4] < 8.5  # one break, inside the gap
    assert np.array_equal(tt[~np.isnan(yy)], t)
