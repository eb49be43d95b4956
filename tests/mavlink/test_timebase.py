"""One monotonic vehicle clock: reboots, jitter, reordering, boot-time-less messages."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.events import Attitude, GnssFix, Reboot
from companion.mavlink.decode import MavlinkDecoder
from companion.nav.reorder import ReorderBuffer
from companion.timebase import VehicleClock


def test_clock_jitter_is_not_a_reboot():
    c = VehicleClock()
    assert c.to_vehicle(10.0) == (10.0, None)
    t, rb = c.to_vehicle(9.8)  # a GPS row stamped 200 ms before the last IMU row
    assert rb is None and t == pytest.approx(9.8)


def test_clock_reboot_confirmed_after_three_messages_continues_monotonic():
    c = VehicleClock()
    for b in np.arange(0.0, 300.0, 0.02):
        c.to_vehicle(float(b))
    assert c.to_vehicle(0.5) == (None, None)  # held back until confirmed
    assert c.to_vehicle(0.52) == (None, None)
    t, rb = c.to_vehicle(0.54)
    assert isinstance(rb, Reboot)
    assert rb.previous_boot_s == pytest.approx(299.98) and rb.new_boot_s == 0.5
    assert t == pytest.approx(299.98 + 0.54)
    t2, rb2 = c.to_vehicle(1.0)
    assert rb2 is None and t2 == pytest.approx(300.98)
    assert c.reboots == 1 and c.held_back == 2


def test_clock_one_very_late_sample_is_dropped_not_a_reboot():
    c = VehicleClock()
    for b in np.arange(0.0, 100.0, 0.02):
        c.to_vehicle(float(b))
    assert c.to_vehicle(95.0) == (None, None)  # 5 s late
    t, rb = c.to_vehicle(100.0)
    assert rb is None and t == pytest.approx(100.0) and c.reboots == 0 and c.offset_s == 0.0
    # extrapolated (derived) boot times neither confirm nor cancel a pending reboot
    c.to_vehicle(1.0)
    c.to_vehicle(50.0, derived=True)
    c.to_vehicle(1.02)
    t, rb = c.to_vehicle(1.04)
    assert isinstance(rb, Reboot) and t == pytest.approx(100.0 + 1.04)


def _wire(msg):
    buf = msg.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1))
    return mavlink.MAVLink(None).decode(bytearray(buf))


def test_decoder_reboot_mid_stream_emits_reboot_and_stays_monotonic():
    dec = MavlinkDecoder()
    dec.decode(_wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)), 0.0)
    out = []
    boots_ms = list(range(100_000, 120_000, 100)) + list(range(3_000, 10_000, 100))
    for i, ms in enumerate(boots_ms):
        out += dec.decode(_wire(mavlink.MAVLink_attitude_message(ms, 0.1, 0.2, 0.3, 0, 0, 0)), i * 0.1)
    reboots = [e for e in out if isinstance(e, Reboot)]
    att = [e for e in out if isinstance(e, Attitude)]
    assert len(reboots) == 1 and len(att) == len(boots_ms) - 2  # two held back until the reboot is confirmed
    assert sum(n for why, n in dec.dropped.items() if why.startswith("time jumped back")) == 2
    t = np.array([e.t_s for e in att])
    assert np.all(np.diff(t) > 0), "vehicle time must keep increasing through the reboot"
    assert reboots[0].previous_boot_s == pytest.approx(119.9)


def test_gps_time_usec_zero_uses_receive_time_since_last_boot_stamp():
    dec = MavlinkDecoder()
    dec.decode(_wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)), 0.0)
    dec.decode(_wire(mavlink.MAVLink_attitude_message(50_000, 0, 0, 0, 0, 0, 0)), 1000.0)
    (fix,) = dec.decode(_wire(mavlink.MAVLink_gps_raw_int_message(0, 1, 0, 0, 0, 9999, 9999, 0, 0, 0)), 1000.25)
    assert isinstance(fix, GnssFix) and fix.t_s == pytest.approx(50.25)


def test_no_fix_with_the_time_of_the_last_fix_is_an_outage_now_not_a_late_sample():
    """ArduPilot keeps GPS_RAW_INT.time_usec at the last fix during an outage: every no-fix message of a 30 s outage
    is news of the outage at its arrival, none is dropped as late."""
    dec = MavlinkDecoder()
    dec.decode(_wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)), 0.0)
    fixes = []
    for k in range(400):  # 40 s at 10 Hz: fix until 10 s, then no fix, time frozen at the last fix
        boot_ms = 100_000 + k * 100
        recv = k * 0.1
        dec.decode(_wire(mavlink.MAVLink_attitude_message(boot_ms, 0, 0, 0, 0, 0, 0)), recv)
        lost = k >= 100
        t_us = (100_000 + 99 * 100) * 1000 if lost else boot_ms * 1000
        msg = mavlink.MAVLink_gps_raw_int_message(t_us, 1 if lost else 3, 0 if lost else -353632000,
                                                  0 if lost else 1491652000, 0 if lost else 600_000, 90, 120, 0, 0, 10)
        fixes += [e for e in dec.decode(_wire(msg), recv + 0.01) if isinstance(e, GnssFix)]
    assert len(fixes) == 400 and not any(k.startswith("time jumped back") for k in dec.dropped)
    lost = [f for f in fixes if f.fix_type < 2]
    assert len(lost) == 300 and not any(f.has_position for f in lost)
    assert lost[0].t_s == pytest.approx(110.01) and lost[-1].t_s == pytest.approx(139.91)  # stamped as they arrive


def test_messages_from_other_systems_are_dropped():
    dec = MavlinkDecoder()
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    hb_gcs = mavlink.MAVLink(None).decode(bytearray(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(gcs)))
    assert dec.decode(hb_gcs, 0.0) == [] and dec.target_system is None  # a GCS heartbeat names no vehicle
    dec.decode(_wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)), 0.0)
    foreign = mavlink.MAVLink(None).decode(
        bytearray(mavlink.MAVLink_attitude_message(1000, 0, 0, 0, 0, 0, 0).pack(gcs))
    )
    assert dec.decode(foreign, 0.1) == []
    assert any("other system 255/190" in k for k in dec.dropped)


def test_reorder_buffer_orders_within_horizon_and_is_stable():
    buf = ReorderBuffer(0.5)
    evs = [Attitude(t, 0.01 * k, 0, 0) for k, t in enumerate((1.0, 1.2, 1.1, 1.1, 2.0, 1.9, 3.0))]
    out = []
    for e in evs:
        out += buf.push(e)
    out += buf.flush()
    assert [e.t_s for e in out] == sorted(e.t_s for e in evs)
    assert out[1] is evs[2] and out[2] is evs[3]  # equal times keep arrival order
    assert buf.late == 0


def test_reorder_buffer_drops_repeats_and_holds_a_bounded_number():
    buf = ReorderBuffer(0.5, max_held=100)
    same = [Attitude(5.0, 0.1, 0.2, 0.3) for _ in range(1000)]  # one record repeated: same time, same values
    assert sum(len(buf.push(e)) for e in same) == 0 and buf.duplicates == 999
    distinct = [Attitude(5.0, 0.001 * k, 0, 0) for k in range(1, 1001)]  # one time, distinct values: none ages
    out = [o for e in distinct for o in buf.push(e)]
    assert len(out) == 901 and buf.forced == 901 and len(buf.flush()) == 100


def test_reboot_keeps_the_downtime_when_receive_times_are_known():
    c = VehicleClock()
    for k in range(1000):
        c.to_vehicle(200.0 + k * 0.1, recv_s=1000.0 + k * 0.1)  # last: boot 299.9 received at 1099.9
    # the autopilot restarts; its first message (boot 0.5 s) is received 5 s after the last old one
    assert c.to_vehicle(0.5, recv_s=1104.9)[0] is None
    assert c.to_vehicle(0.52, recv_s=1104.92)[0] is None
    t, rb = c.to_vehicle(0.54, recv_s=1104.94)
    assert isinstance(rb, Reboot)
    assert rb.t_s == pytest.approx(299.9 + 5.0)  # the 5 s the vehicle kept moving are not lost
    assert t == pytest.approx(299.9 + 5.04)


@pytest.mark.parametrize("lat_e7, lon_e7, alt_mm", [(900_000_000, 1_491_652_000, 600_000), (-900_000_000, 0, 600_000),
                                                     (-353_632_000, 1_800_000_000, 600_000),
                                                     (-353_632_000, -1_800_000_000, 600_000),
                                                     (-353_632_000, 1_491_652_000, 2_147_483_647),
                                                     (-353_632_000, 1_491_652_000, -2_147_483_648)])
def test_gps_at_the_limits_of_its_integers_is_no_fix(lat_e7, lon_e7, alt_mm):
    dec = MavlinkDecoder()
    dec.decode(_wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)), 0.0)
    (fix,) = dec.decode(_wire(mavlink.MAVLink_gps_raw_int_message(5_000_000, 3, lat_e7, lon_e7, alt_mm, 90, 120, 0, 0, 10)), 5.0)
    assert not fix.has_position and fix.fix_type < 2 and dec.dropped["GPS position out of range"] == 1


def test_clock_one_message_far_ahead_is_dropped_and_counted_not_a_gap():
    c = VehicleClock()
    for b in np.arange(0.0, 100.0, 0.02):
        c.to_vehicle(float(b))
    assert c.to_vehicle(1100.0) == (None, None)  # a bit flip: 1000 s ahead
    assert c.held_ahead == 1 and c.last_hold == "ahead"
    t, rb = c.to_vehicle(100.02)
    assert rb is None and t == pytest.approx(100.02) and c.max_boot_s == pytest.approx(100.02)
    assert c.gaps == 0


def test_clock_forward_jump_moves_only_on_consistent_messages():
    c = VehicleClock()
    for b in np.arange(0.0, 10.0, 0.02):
        c.to_vehicle(float(b))
    assert c.to_vehicle(40.0) == (None, None)
    assert c.to_vehicle(40.02) == (None, None)
    t, rb = c.to_vehicle(40.04)  # three in a row agree: the log really jumped (logging paused)
    assert rb is None and t == pytest.approx(40.04) and c.gaps == 1 and c.held_ahead == 2


def test_clock_forward_jump_the_receive_clock_shows_is_accepted_at_once():
    c = VehicleClock()
    for i, b in enumerate(np.arange(0.0, 10.0, 0.1)):
        c.to_vehicle(float(b), recv_s=1000.0 + i * 0.1)
    t, rb = c.to_vehicle(40.0, recv_s=1000.0 + 9.9 + 30.0)  # link silent for 30 s
    assert t == pytest.approx(40.0) and c.held_ahead == 0


def test_clock_non_physical_boot_time_is_dropped():
    c = VehicleClock()
    c.to_vehicle(1.0)
    for bad in (float("nan"), float("inf"), -5.0, 2.0**64 * 1e-6):
        assert c.to_vehicle(bad) == (None, None) and c.last_hold == "invalid"
    assert c.invalid == 4 and c.to_vehicle(1.1)[0] == pytest.approx(1.1)


def test_decoder_one_attitude_30_s_ahead_is_no_reboot_and_no_jump():
    dec = MavlinkDecoder()
    dec.decode(_wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)), 0.0)
    out = []
    for i in range(200):
        ms = 100_000 + i * 100
        if i == 100:
            ms += 30_000  # one message stamped 30 s ahead
        out += dec.decode(_wire(mavlink.MAVLink_attitude_message(ms, 0.1, 0.2, 0.3, 0, 0, 0)), 10.0 + i * 0.1)
    assert not [e for e in out if isinstance(e, Reboot)]
    t = np.array([e.t_s for e in out if isinstance(e, Attitude)])
    assert len(t) == 199 and np.all(np.diff(t) > 0) and np.max(np.diff(t)) < 0.25
    assert dec.dropped["time jumped ahead (one outlier, or a gap not yet confirmed)"] == 1
