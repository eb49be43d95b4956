"""Long survey cruises and the simulated gravimeter on the vehicle simulator's link."""

from __future__ import annotations

import math
import socket
import threading

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.nav.frame import LocalFrame
from companion.gravity import GravityMap, LocalGravityMap
from tests.conftest import TASMAN_MAP, free_port, require
from companion.sim.cruise import SHIP, cruise_profile, survey_waypoints
from companion.sim.flight import CANBERRA_FIELD, SimConfig, sample_profile, simulate_flight
from companion.sim.playback import LazyItems, gravity_readings, playback_from_flight
from companion.sim.vehicle import Faults, VehicleSim

ORIGIN = LocalFrame(-40.5, 155.6, 0.0)


def _along_cross(tr, heading_deg):
    h = math.radians(heading_deg)
    u, c = np.array([math.cos(h), math.sin(h)]), np.array([-math.sin(h), math.cos(h)])
    ne = tr.pos_ned_m[:, :2]
    return ne @ u, ne @ c, tr.vel_ned_mps[:, :2] @ u, tr.vel_ned_mps[:, :2] @ c


def test_cruise_profile_duration_speed_lines_and_box():
    hours, v, line_km, spacing_km, heading = 0.5, 150.0, 60.0, 10.0, 30.0
    p = cruise_profile(ORIGIN, hours=hours, speed_mps=v, line_km=line_km, spacing_km=spacing_km, heading_deg=heading)
    assert p.duration_s == pytest.approx(hours * 3600.0, abs=5.0)
    tr = p.sample_rate(2.0)
    speed = np.hypot(tr.vel_ned_mps[:, 0], tr.vel_ned_mps[:, 1])
    assert speed.max() == pytest.approx(v, abs=0.01)
    assert np.mean(speed > 0.99 * v) > 0.7  # at cruise speed but for ~7 min of climb, 2 x 140 s speed changes, landing
    along, cross, v_along, v_cross = _along_cross(tr, heading)
    # inside the survey box (fly-by turns cut the corners inwards)
    assert along.min() > -1.0 and along.max() < line_km * 1e3 + 1.0
    assert cross.min() > -1.0
    on_line = (np.abs(v_along) > 0.99 * v) & (np.abs(v_cross) < 1e-3)  # straight at speed along the lines
    k = np.round(cross[on_line] / (spacing_km * 1e3))
    assert np.max(np.abs(cross[on_line] - k * spacing_km * 1e3)) < 1.0  # lines exactly spacing apart
    lines = sorted(set(k.astype(int)))
    assert lines == list(range(len(lines))) and len(lines) >= 3
    assert cross.max() < (lines[-1]) * spacing_km * 1e3 + 1.0
    # alternate directions: even lines along the heading, odd lines back
    assert np.all(np.sign(v_along[on_line]) == np.where(k % 2 == 0, 1.0, -1.0))
    # climbs to 300 m, ends stopped on the ground; AUTO for the survey, LAND at the end
    assert tr.alt_msl_m.max() == pytest.approx(300.0, abs=0.01)
    assert tr.alt_msl_m[-1] == pytest.approx(0.0, abs=1e-6) and speed[-1] < 1e-6
    assert p.mode_at(600.0) == "AUTO" and p.mode_at(p.duration_s - 30.0) == "LAND"


def test_ship_cruise_stays_at_sea_level():
    p = cruise_profile(ORIGIN, hours=0.25, **SHIP)
    tr = p.sample_rate(1.0)
    assert p.duration_s == pytest.approx(900.0, abs=5.0)
    assert np.all(tr.alt_msl_m == 0.0)
    assert np.hypot(tr.vel_ned_mps[:, 0], tr.vel_ned_mps[:, 1]).max() == pytest.approx(SHIP["speed_mps"], abs=1e-3)


def test_coarse_integration_grid_matches_the_fine_one():
    """The 4th-order Hermite pre-integration at 25 Hz gives the 2 kHz positions of a cruise to well below 1 mm."""
    kw = dict(hours=0.1, speed_mps=150.0, line_km=30.0, spacing_km=10.0)
    coarse = cruise_profile(ORIGIN, internal_rate_hz=25.0, **kw)
    fine = cruise_profile(ORIGIN, internal_rate_hz=2000.0, **kw)
    t = np.linspace(0.0, coarse.duration_s, 3001)
    d = np.abs(coarse.sample(t).pos_ned_m - fine.sample(t).pos_ned_m)
    assert d.max() < 1e-3


def test_survey_waypoints_turn_back_with_max_lines():
    wps = survey_waypoints(10_000.0, 1000.0, 100.0, 0.0, max_lines=3)
    cross = [e for _, e in wps]
    assert max(cross) == pytest.approx(200.0) and min(cross) >= 0.0
    assert sum(math.dist(a, b) for a, b in zip([(0.0, 0.0)] + wps, wps)) == pytest.approx(10_000.0)


# -- the gravimeter ------------------------------------------------------------------------------
def _map_around(frame: LocalFrame, half_deg: float = 0.3, lat_max: float | None = None) -> LocalGravityMap:
    lon = np.linspace(frame.ref_lon_deg - half_deg, frame.ref_lon_deg + half_deg, 121)
    lat = np.linspace(frame.ref_lat_deg - half_deg, lat_max if lat_max is not None else frame.ref_lat_deg + half_deg, 91)
    g = 30 * np.sin(np.radians(lon * 900))[None, :] + 20 * np.cos(np.radians(lat * 700))[:, None]
    return LocalGravityMap.around(GravityMap(g, lon, lat, "geographic_deg"))


@pytest.fixture(scope="module")
def small_flight():
    return simulate_flight(sample_profile(), 7, SimConfig(imu_rate_hz=10.0, gnss_rate_hz=5.0, imu2=None))


def _decode(msg) -> object:
    """Pack a message as the simulator does and parse it back with pymavlink."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    return mavlink2.MAVLink(None).parse_char(bytes(msg.pack(mav)))


def test_gravity_messages_carry_the_map_value_at_the_truth_position(small_flight):
    lmap = _map_around(CANBERRA_FIELD)
    grav = gravity_readings(small_flight.profile, lmap, hz=2.0, sigma_mgal=0.0)
    pb = playback_from_flight(small_flight, gravity=grav)
    msgs = [it for it in pb.items if it.msg.get_type() == "NAMED_VALUE_FLOAT"]
    assert len(msgs) == int((small_flight.duration_s - 0.05) * 2.0) + 1
    assert all(it.src == (1, 1) for it in msgs)
    for it in msgs:
        m = _decode(it.msg)
        assert m.get_type() == "NAMED_VALUE_FLOAT" and m.name == "GRAV"
        t = m.time_boot_ms * 1e-3
        assert t == pytest.approx(it.play_s, abs=1e-3)
        tr = small_flight.profile.sample(t)
        expected = float(lmap.gmap.interp(tr.lon_deg, tr.lat_deg)[0])  # the geographic path, independently
        assert abs(m.value - expected) <= abs(np.spacing(np.float32(expected)))  # float32 rounding only


def test_gravity_noise_is_seeded_and_has_sigma(small_flight):
    lmap = _map_around(CANBERRA_FIELD)
    t0, clean = gravity_readings(small_flight.profile, lmap, hz=5.0, sigma_mgal=0.0)
    t1, noisy = gravity_readings(small_flight.profile, lmap, hz=5.0, sigma_mgal=2.0, seed=3)
    _, again = gravity_readings(small_flight.profile, lmap, hz=5.0, sigma_mgal=2.0, seed=3)
    np.testing.assert_array_equal(t0, t1)
    np.testing.assert_array_equal(noisy, again)
    r = noisy - clean
    assert len(r) > 500 and abs(r.mean()) < 0.3 and np.std(r) == pytest.approx(2.0, rel=0.15)


def test_no_gravity_message_off_the_map(small_flight):
    # the map ends 50 m north of the origin: the sample flight (160 m north) leaves it
    lmap = _map_around(CANBERRA_FIELD, lat_max=CANBERRA_FIELD.ref_lat_deg + 50.0 / 111_000.0)
    t, v = gravity_readings(small_flight.profile, lmap, hz=1.0, sigma_mgal=0.0)
    assert 10 < len(t) < int(small_flight.duration_s) and np.all(np.isfinite(v))
    north = small_flight.profile.sample(t).pos_ned_m[:, 0]
    assert north.max() < 50.0


def test_lazy_items_equal_the_eager_list(small_flight):
    grav = gravity_readings(small_flight.profile, _map_around(CANBERRA_FIELD), hz=1.0)
    eager = playback_from_flight(small_flight, gravity=grav, lazy=False)
    lazy = playback_from_flight(small_flight, gravity=grav, lazy=True, chunk_s=7.0)
    assert isinstance(lazy.items, LazyItems) and lazy.duration_s == eager.duration_s

    def key(it):
        return it.play_s, it.msg.get_type(), it.src, it.boot_s

    assert [key(it) for it in lazy.items] == [key(it) for it in eager.items]
    assert [key(it) for it in lazy.items.window(40.0, 60.0)] == [key(it) for it in eager.items if 40.0 <= it.play_s <= 60.0]


def test_simulator_sends_grav_on_the_link_and_silences_it_with_the_link(small_flight):
    """End to end: a VehicleSim on udpout at x30; a plain pymavlink reader gets GRAV from (1, 1) at 2 Hz with
    increasing time_boot_ms -- without asking for any stream -- and none during the link drop."""
    grav = gravity_readings(small_flight.profile, _map_around(CANBERRA_FIELD), hz=2.0, sigma_mgal=1.0)
    port = free_port(socket.SOCK_DGRAM)
    reader = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    end_s, drop = 60.0, (20.0, 30.0)
    sim = VehicleSim(playback_from_flight(small_flight, gravity=grav), f"udpout:127.0.0.1:{port}", speed=30.0,
                     end_s=end_s, faults=Faults(link_drop=drop))
    th = threading.Thread(target=sim.run, daemon=True)
    th.start()
    got = []
    while th.is_alive() or got == []:
        m = reader.recv_match(type="NAMED_VALUE_FLOAT", blocking=True, timeout=0.5)
        if m is None:
            if not th.is_alive():
                break
            continue
        got.append((m.time_boot_ms * 1e-3, m.name, m.get_srcSystem(), m.get_srcComponent()))
    th.join(5.0)
    reader.close()
    t = np.array([g[0] for g in got])
    assert all(g[1:] == ("GRAV", 1, 1) for g in got)
    assert np.all(np.diff(t) > 0)
    assert not np.any((t >= drop[0]) & (t < drop[1]))
    expected = 2.0 * (end_s - (drop[1] - drop[0]))
    assert expected - 3 <= len(t) <= expected + 1
    assert sim.stats.sent["NAMED_VALUE_FLOAT"] == len(t)


def test_cli_gravity_errors_are_one_line(tmp_path, capsys):
    from companion.cli import EXIT_ERROR, main

    bad = tmp_path / "bad.nc"
    bad.write_bytes(b"not a grid")
    base = ["sim", "--profile", "cruise", "--hours", "0.1", "--line-km", "30", "--spacing-km", "10",
            "--listen", "udpout:127.0.0.1:9"]
    assert main([*base, "--gravity-map", str(bad)]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert err.startswith("companion: error: gravity map") and err.count("\n") == 1
    tasman = require(TASMAN_MAP)
    assert main([*base, "--origin", "-40.5,165.0", "--gravity-map", str(tasman)]) == EXIT_ERROR  # east of 160E
    err = capsys.readouterr().err
    assert "off the gravity map" in err and err.count("\n") == 1


def test_aircraft_sensor_set_is_better_than_the_drone_set():
    from companion.sim.flight import SENSOR_SETS

    prof = cruise_profile(LocalFrame(-40.0, 156.0, 0.0), hours=0.15, speed_mps=150.0, line_km=60.0, spacing_km=10.0)
    errs = {}
    for name, kw in SENSOR_SETS.items():
        f = simulate_flight(prof, 3, SimConfig(imu_rate_hz=25.0, gnss_rate_hz=5.0, **kw))
        att = np.degrees(np.abs(f.attitude_euler_rad - f.truth_attitude.euler_rad))
        att[:, 2] = (att[:, 2] + 180.0) % 360.0 - 180.0
        acc = f.imu.accel_frd_mps2 - f.truth_imu.specific_force_frd_mps2
        errs[name] = (np.sqrt(np.mean(att[:, :2] ** 2)), np.sqrt(np.mean(att[:, 2] ** 2)), np.abs(acc.mean(axis=0)).max())
    assert SENSOR_SETS["drone"] == {} and SENSOR_SETS["aircraft"]["imu2"] is None
    d, a = errs["drone"], errs["aircraft"]
    assert a[0] < 0.05 < d[0] / 2 and a[1] < 0.15 < d[1] / 2  # tilt / heading error, deg
    assert a[2] < 0.01 < d[2]  # mean accelerometer error (bias), m/s^2
