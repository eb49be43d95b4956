"""The simulated vehicle as an ArduPilot with a MAVLink GPS instance (companion.sim.autopilot_gps): which GPS_INPUT it
ignores, and arming that waits for a 3D fix on that instance while the flight's timeline shifts by the wait."""

from __future__ import annotations

import json
import math
import socket
import threading

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion import units
from companion.sim.autopilot_gps import PREARM_DISPLAY_PERIOD_S, ArmingCheck, ignored_by
from companion.sim.flight import CANBERRA_FIELD, SimConfig, simulate_flight
from companion.sim.playback import playback_from_flight
from companion.sim.sensors import GnssModel, ImuModel
from companion.sim.trajectory import Climb, FlightProfile, Hold
from companion.sim.vehicle import VehicleSim
from tests.conftest import free_port


def test_arming_needs_a_fresh_3d_fix_on_the_mav_instance():
    a = ArmingCheck(instance=1)
    assert a.attempt(10.0) == (False, "PreArm: GPS 2: Bad fix")  # nothing heard: refused, said at once
    a.on_gps_input(10.5, gps_id=0, fix_type=3)  # another instance's fix does not count
    a.on_gps_input(10.6, gps_id=1, fix_type=2)  # a 2D fix is a bad fix
    assert a.attempt(11.0) == (False, None)  # refused again, not repeated within the display period
    a.on_gps_input(11.5, gps_id=1, fix_type=3)
    assert a.failure(12.4) == "" and a.failure(12.6) == "GPS 2: Bad fix"  # at most 1 s old
    a.on_gps_input(12.9, gps_id=1, fix_type=2)  # the last message counts, not the best
    assert a.failure(13.0) == "GPS 2: Bad fix"
    assert a.attempt(10.0 + PREARM_DISPLAY_PERIOD_S) == (False, "PreArm: GPS 2: Bad fix")  # every 30 s
    a.on_gps_input(40.5, gps_id=1, fix_type=4)  # DGPS and better are 3D too
    assert a.attempt(41.0) == (True, None)
    assert (a.refused_at_s, a.armed_at_s, a.attempts) == (10.0, 41.0, 4)
    assert ArmingCheck(instance=0).failure(0.0) == "GPS 1: Bad fix"


def test_ignored_by_ekf3_below_3d_and_by_ap_gps_for_another_instance():
    assert ignored_by(1, 3, 1) is None and ignored_by(1, 5, None) is None
    assert ignored_by(1, 2, 1) == ignored_by(0, 2, None) == "by EKF3: fix_type < 3"
    assert ignored_by(1, 1, None) == "by EKF3: fix_type < 3"
    assert "instance 1" in ignored_by(0, 3, 1)


def _gps_input(boot_s, gps_id, fix_type, lat_deg, lon_deg, alt_m):
    return mavlink2.MAVLink_gps_input_message(
        units.us_from_s(boot_s), gps_id, 0, 0, 0, fix_type, units.degE7_from_deg(lat_deg), units.degE7_from_deg(lon_deg),
        alt_m, 0.8, 1.2, 0.0, 0.0, 0.0, 0.3, 1.0, 2.0, 10 if fix_type >= 2 else 0, 0)


def _parsed(msg):
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    return mavlink2.MAVLink(None).parse_char(bytes(msg.pack(mav)))


@pytest.mark.parametrize("instance", [None, 1])
def test_record_marks_what_the_autopilot_ignores(tmp_path, instance):
    """The sim's recording of received GPS_INPUT (no link): below 3D is marked ignored by EKF3; with a MAVLink
    instance configured, another instance's message is marked ignored by AP_GPS; a usable one carries no mark."""
    flight = simulate_flight(_profile(), 3, SimConfig(gnss_rate_hz=5.0, imu2=None))
    sim = VehicleSim(playback_from_flight(flight), "udpout:127.0.0.1:9", record=tmp_path / "r.jsonl",
                     gps_mav_instance=instance)
    lat, lon, alt = CANBERRA_FIELD.ref_lat_deg, CANBERRA_FIELD.ref_lon_deg, CANBERRA_FIELD.ref_alt_m
    for k, (gps_id, fix) in enumerate([(1, 3), (1, 2), (1, 1), (0, 3), (1, 6)]):
        sim._handle(_parsed(_gps_input(1.0 + 0.1 * k, gps_id, fix, lat, lon, alt)), 1.0 + 0.1 * k)
    sim._record.close()
    recs = [json.loads(line) for line in (tmp_path / "r.jsonl").read_text().splitlines()]
    marks = [(r["gps_id"], r["fix_type"], r.get("ignored")) for r in recs]
    other = "by AP_GPS: gps_id 0 is not the MAVLink GPS instance 1" if instance == 1 else None
    assert marks == [(1, 3, None), (1, 2, "by EKF3: fix_type < 3"), (1, 1, "by EKF3: fix_type < 3"), (0, 3, other),
                     (1, 6, None)]
    assert all(r["err_h_m"] < 0.01 for r in recs)  # on the ground at the origin: the truth is still recorded
    if instance == 1:
        assert sim.arming.last_fix == pytest.approx((1.4, 6))  # instance 1's last message, not instance 0's


def _profile() -> FlightProfile:
    """On the ground 5 s, climbs 10 m at 2.5 m/s, hovers."""
    return FlightProfile([Hold(3.0, mode="STABILIZE"), Hold(2.0, mode="AUTO"), Climb(10.0, rate_mps=2.5), Hold(3.0)],
                         CANBERRA_FIELD)


def test_refused_arming_holds_the_vehicle_and_shifts_the_flight(tmp_path):
    """End to end on UDP at x2: a client answers each GPS_RAW_INT with a GPS_INPUT -- always a 3D fix for instance 0,
    for instance 1 a 2D fix up to boot time 6 s and a 3D one after. With instance 1 as the MAVLink GPS the vehicle
    refuses at its scripted arming time (3 s, "PreArm: GPS 2: Bad fix" once), holds at rest, and arms at the first
    attempt after a 3D fix came (7 s). Everything after
    moves by the delay: the armed HEARTBEAT, the climb; the boot clock and every stream run on without a gap."""
    profile = _profile()
    flight = simulate_flight(profile, 11, SimConfig(gnss_rate_hz=10.0, imu_rate_hz=50.0, imu2=None, imu=ImuModel.perfect(),
                                                    gnss=GnssModel.perfect(), armed_s=(3.0, profile.duration_s)))
    port = free_port(socket.SOCK_DGRAM)
    client = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    record = tmp_path / "sim.jsonl"
    sim = VehicleSim(playback_from_flight(flight), f"udpout:127.0.0.1:{port}", speed=2.0, streams="all",
                     record=record, gps_mav_instance=1)
    th = threading.Thread(target=sim.run, daemon=True)
    th.start()
    boot_s, imu_t, gps, heartbeats, texts = 0.0, [], [], [], []
    while th.is_alive():
        m = client.recv_match(blocking=True, timeout=0.5)
        if m is None:
            continue
        mtype = m.get_type()
        if mtype == "RAW_IMU":
            boot_s = m.time_usec * 1e-6
            imu_t.append(boot_s)
        elif mtype == "GPS_RAW_INT":
            boot_s = m.time_usec * 1e-6
            lat, lon, alt = units.deg_from_degE7(m.lat), units.deg_from_degE7(m.lon), units.m_from_mm(m.alt)
            gps.append((boot_s, alt))
            client.mav.send(_gps_input(boot_s, 0, 3, lat, lon, alt))
            client.mav.send(_gps_input(boot_s, 1, 3 if boot_s > 6.05 else 2, lat, lon, alt))
        elif mtype == "HEARTBEAT" and m.get_srcSystem() == 1:
            heartbeats.append((boot_s, bool(m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)))
        elif mtype == "STATUSTEXT":
            texts.append((boot_s, m.severity, m.text))
    th.join(10.0)
    client.close()
    recs = [json.loads(line) for line in record.read_text().splitlines()]
    refused = [r for r in recs if r["event"] == "arming_refused"]
    armed = [r for r in recs if r["event"] == "armed"]
    assert len(refused) == 1 and refused[0]["text"] == "PreArm: GPS 2: Bad fix"
    assert refused[0]["play_s"] == pytest.approx(3.0, abs=0.3)
    assert len(armed) == 1
    delay = armed[0]["delay_s"]
    # 4 s on a machine that keeps up; one retry more if the first 3D fix came more than a second late
    assert delay in (4.0, 5.0) and armed[0]["attempts"] == delay + 1
    assert armed[0]["play_s"] == pytest.approx(3.0 + delay, abs=0.3)
    assert recs[-1]["event"] == "end" and recs[-1]["arm_delay_s"] == delay
    assert texts == [(pytest.approx(3.0, abs=0.05), mavlink2.MAV_SEVERITY_CRITICAL, "PreArm: GPS 2: Bad fix")]
    # the armed HEARTBEAT and the climb come `delay` later; the boot clock and the streams never pause or repeat
    first_armed = next(t for t, a in heartbeats if a)
    assert first_armed == pytest.approx(3.0 + delay, abs=0.05)  # the flight's first armed HEARTBEAT is at 3 s
    n = int(3.0 + delay)  # disarmed at 0, 1, 2 s of the flight, then once a second while held
    assert [a for _, a in heartbeats[:n + 1]] == [False] * n + [True]
    t_gps = np.array([t for t, _ in gps])
    alt = np.array([a for _, a in gps])
    assert np.allclose(np.diff(t_gps), 0.1, atol=1e-3) and np.allclose(np.diff(imu_t), 0.02, atol=1e-3)
    g = flight.gnss
    scripted_up = g.t_s[np.argmax(g.alt_msl_m > g.alt_msl_m[0] + 0.05)]  # the climb starts at 5 s of the flight
    assert 5.0 < scripted_up < 6.0
    assert t_gps[np.argmax(alt > alt[0] + 0.05)] == pytest.approx(scripted_up + delay, abs=0.01)
    assert alt.max() == pytest.approx(alt[0] + 10.0, abs=0.01)  # and is flown in full
    # the record's truth follows the shifted flight: the echoed (perfect) fixes match it all along
    gi = [r for r in recs if r["event"] == "gps_input"]
    assert len(gi) > 150 and max(r["err_v_m"] for r in gi) < 0.01 and max(r["err_h_m"] for r in gi) < 0.01
    assert all(r.get("ignored") for r in gi if r["gps_id"] == 0 or r["fix_type"] < 3)
    assert not any(r.get("ignored") for r in gi if r["gps_id"] == 1 and r["fix_type"] >= 3)
    assert math.isclose(gi[-1]["state_play_s"], gps[-1][0], abs_tol=0.2)
