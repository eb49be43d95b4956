"""What leaves for the autopilot describes the vehicle now, on its current boot, with a real time: a burst of old
messages after a silent link, a reboot between build and send, a time not known yet."""

from __future__ import annotations

import calendar

import pytest

from companion.events import FixType, ImuSample, Reboot, SystemTime
from companion.inject import GpsInputRecord, InjectConfig, Injector
from companion.inject.link_clock import LinkClock

from tests.inject.test_inject import Wire, fix, state, tick

UTC0 = calendar.timegm((2025, 3, 15, 1, 30, 0))


def imu(t_s):
    return ImuSample(t_s=t_s, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0)


class Host:
    """The host's clock, set by the test (the injector's arrival_clock)."""

    def __init__(self, now=1000.0):
        self.now = now

    def __call__(self):
        return self.now


def _live_injector():
    wire, host = Wire(), Host()
    inj = Injector(InjectConfig(mode="inject", activate="always"), sender=wire)
    inj.arrival_clock = host
    inj.process(SystemTime(t_s=1.0, unix_time_s=UTC0))
    return inj, wire, host


def _step(inj, host, t_s, arrival_s):
    """One IMU sample (vehicle time t_s + 0.2) and the state at t_s, both from bytes that arrived at arrival_s."""
    host.now = arrival_s
    inj.arrival_s = arrival_s
    inj.process(imu(t_s + 0.2))
    return [r for r in inj.process(state(t_s=t_s)) if isinstance(r, GpsInputRecord)]


def test_link_clock_takes_the_freshest_relation_and_relaxes_slowly():
    c = LinkClock(relax_s_per_s=1e-3)
    assert c.vehicle_now(5.0) is None
    c.observe(10.0, 100.02)
    c.observe(10.1, 100.11)  # 10 ms sooner after its stamp: the freshest relation so far
    assert c.vehicle_now(100.11) == pytest.approx(10.1)
    c.observe(11.0, 105.0)  # 4 s later, stamped 3.1 s before it arrived: old, not a new relation
    assert c.vehicle_now(105.0) == pytest.approx(105.0 - 90.01 - 1e-3 * 4.89)  # (4.9 ms of relaxation in 4.89 s)


def test_burst_after_a_silent_link_is_not_sent_and_fresh_fixes_follow_at_once():
    inj, wire, host = _live_injector()
    t = 10.0
    for k in range(20):  # 2 s of a healthy link: each input 10 ms after its stamp
        assert _step(inj, host, t + 0.1 * k, t + 0.1 * k + 0.2 + 0.01 + 990.0)[0].sent
    sent_before = inj.sent
    # 4 s of silence, then everything held back arrives within 10 ms: bytes new, contents up to 4 s old
    burst_at = t + 2.0 + 4.0 + 0.21 + 990.0
    recs = [r for k in range(40) for r in _step(inj, host, t + 2.0 + 0.1 * k, burst_at + 0.00025 * k)]
    sent = [r for r in recs if r.sent]
    ages = [(host.now - 990.01) - r.t_s - 0.2 for r in sent]  # the vehicle's time now minus the stated epoch and lag
    assert sent and max(ages) <= 0.5, ages  # only the newest of the backlog: what is still fresh
    assert inj.sent - sent_before == len(sent) <= 6
    assert inj.dropped["stale: older than its stated lag by more than 0.5 s on the autopilot's clock (old messages "
                       "delivered late)"] >= 30
    # the live stream goes on: the next state built from a fresh input is sent
    fresh = _step(inj, host, t + 6.1, t + 6.1 + 0.2 + 0.01 + 990.0)
    assert fresh and fresh[0].sent and fresh[0].fix_type == FixType.FIX_3D


def test_nothing_from_before_a_reboot_and_never_time_zero_with_a_fix():
    inj, wire, host = _live_injector()
    assert _step(inj, host, 19.5, 1000.2)[0].sent
    host.now = inj.arrival_s = 1000.5
    inj.process(imu(20.0))  # the previous boot's last sample
    # the autopilot rebooted (boot 20 s -> 1 s at vehicle time 21): time_usec counts from its new boot, at 20
    inj.process(Reboot(t_s=21.0, previous_boot_s=20.0, new_boot_s=1.0))
    host.now = inj.arrival_s = 1001.0
    out = inj.process(state(t_s=19.9))  # finalised late by the navigator: the previous boot's state
    assert not [r for r in out if isinstance(r, GpsInputRecord)]
    assert inj.dropped["from before the autopilot's last reboot"] == 1
    # after it: GPS time unknown again (SYSTEM_TIME is re-sent), so no fix is claimed until it is known
    (rec,) = _step(inj, host, 21.5, 1001.72)
    assert rec.sent and rec.time_boot_us == 1_500_000 and rec.time_week == 0 and rec.fix_type == FixType.NO_FIX
    inj.process(SystemTime(t_s=21.6, unix_time_s=UTC0 + 100.0))
    (rec,) = _step(inj, host, 21.8, 1002.02)
    assert rec.sent and rec.fix_type == FixType.FIX_3D and rec.time_week > 0 and rec.time_boot_us == 1_800_000
    for m in wire.msgs:
        assert m.fix_type < 2 or (m.time_usec > 0 and m.time_week > 0)


def test_a_reboot_the_link_saw_first_stops_the_send():
    """The reader thread confirms a reboot before the loop has processed it: a state built meanwhile is not sent."""
    inj, wire, host = _live_injector()
    link_reboots = [0]
    inj.link_reboots = lambda: link_reboots[0]
    assert _step(inj, host, 10.0, 1000.2)[0].sent
    link_reboots[0] = 1
    (rec,) = _step(inj, host, 10.1, 1000.3)
    assert not rec.sent and len(wire.msgs) == 1
    assert inj.dropped["built on the autopilot's previous boot (it rebooted meanwhile)"] == 1


def test_no_fix_without_gps_time():
    inj = Injector(InjectConfig(mode="shadow", activate="always"))
    (rec,) = tick(inj, state(t_s=10.0))
    assert rec.fix_type == FixType.NO_FIX and rec.time_week == 0 and "GPS time not known" in rec.fix_reason
    inj.process(fix(10.05))  # the receiver's own GPS time
    (rec,) = tick(inj, state(t_s=10.2))
    assert rec.fix_type == FixType.FIX_3D and rec.time_week == 2350
