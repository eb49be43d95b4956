"""GPS_INPUT injector: wire encoding round trip, fix type from covariance, integrity, activation, time."""

from __future__ import annotations

import calendar
import math
from dataclasses import replace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.nav.outputs import FusedState
from companion.events import FixType, GnssFix, Reboot, SystemTime
from companion.inject import (
    GpsInputRecord,
    InjectConfig,
    Injector,
    InjectorDrop,
    InjectorState,
    decode_gps_input,
    encode_gps_input,
    gps_week_from_unix,
)


def state(t_s=10.0, sigma_h=1.5, sigma_v=2.5, lat=-35.3632, lon=149.1652, **kw) -> FusedState:
    d = dict(
        t_s=t_s, lat_deg=lat, lon_deg=lon, alt_msl_m=604.25, north_m=0.0, east_m=0.0, down_m=-20.25,
        vel_n_mps=3.0, vel_e_mps=-4.0, vel_d_mps=0.5, roll_rad=0.0, pitch_rad=0.0, yaw_rad=math.radians(90.0),
        cov_diag=(sigma_h**2 / 2, sigma_h**2 / 2, sigma_v**2, 0.04, 0.09, 0.01),
        sigma_h_m=sigma_h, sigma_v_m=sigma_v, mode="kinematic", measurement="gnss", innovation_ned_m=(0.0, 0.0, 0.0),
        rejected=0, age_since_fix_s=0.1,
    )
    d.update(kw)
    return FusedState(**d)


def fix(t_s, fix_type=3, instance=0) -> GnssFix:
    has = fix_type >= 2
    return GnssFix(
        t_s, fix_type, -35.3632 if has else None, 149.1652 if has else None, 600.0 if has else None, None, None, None,
        None, None, 10, 0.8, 1.2, None, None, None, 2350, 100_000.0 + t_s, instance,
    )  # (the receiver's own GPS time: a fix is never sent without one)


def tick(inj, st, lag_s=0.2):
    """A navigator state as the pipeline delivers it: once a sensor sample lag_s newer has arrived, so the message
    describes the state's own epoch (no carrying)."""
    from companion.events import ImuSample

    inj.process(ImuSample(t_s=st.t_s + lag_s, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0))
    return inj.process(st)


class Wire:
    """Packs what the injector sends as MAVLink 2 bytes and parses them back, as the autopilot would."""

    def __init__(self):
        self.tx = mav.MAVLink(None, srcSystem=1, srcComponent=191)
        self.rx = mav.MAVLink(None)
        self.msgs = []

    def __call__(self, msg) -> bool:
        self.msgs += self.rx.parse_buffer(bytes(msg.pack(self.tx))) or []
        return True


def test_encode_decode_round_trip_through_wire():
    wire = Wire()
    inj = Injector(InjectConfig(mode="inject", gps_id=1, activate="always"), sender=wire)
    inj.process(SystemTime(t_s=5.0, unix_time_s=calendar.timegm((2025, 3, 15, 1, 30, 0))))
    recs = inj.process(state())
    assert len(recs) == 1 and recs[0].sent and len(wire.msgs) == 1
    got = decode_gps_input(wire.msgs[0])
    r = recs[0]
    assert got["gps_id"] == 1 and got["fix_type"] == 3 and got["ignore_flags"] == 0
    assert abs(got["lat_deg"] - r.lat_deg) <= 0.5e-7 and abs(got["lon_deg"] - r.lon_deg) <= 0.5e-7
    assert got["alt_msl_m"] == pytest.approx(604.25)  # MSL sent unchanged
    assert got["vel_ned_mps"] == pytest.approx((3.0, -4.0, 0.5))
    assert got["h_acc_m"] == pytest.approx(1.5) and got["v_acc_m"] == pytest.approx(2.5)
    assert got["speed_acc_mps"] == pytest.approx(0.3)  # sqrt(max(P_vn, P_ve))
    assert got["hdop"] == pytest.approx(1.5 / 2.5) and got["vdop"] == pytest.approx(1.0)
    assert got["satellites"] == 10 and got["yaw_cdeg"] == 0  # no heading sent by default
    assert got["time_boot_us"] == 10_000_000
    # 2025-03-15 01:30:05 UTC: 16 140 days after the GPS epoch (Sunday 1980-01-06) = week 2357, day 6
    assert got["time_week"] == 2357
    assert got["time_week_ms"] == ((6 * 86400 + 5400 + 5 + 18) * 1000)
    # decode(encode(x)) is the identity on the integers the wire carries
    back = encode_gps_input(replace(r, lat_deg=got["lat_deg"], lon_deg=got["lon_deg"]))
    assert (back.lat, back.lon) == (wire.msgs[0].lat, wire.msgs[0].lon)


def test_gps_week_known_dates():
    assert gps_week_from_unix(315964800) == (0, 0)  # the GPS epoch: GPS = UTC then
    # 2017-01-01 00:00:00 UTC: GPS week 1930, Sunday -> tow 18 s (GPS-UTC = 18 s from that instant)
    assert gps_week_from_unix(calendar.timegm((2017, 1, 1, 0, 0, 0))) == (1930, 18_000)
    # 2014-11-06 (the Erle log's flight): 16 leap seconds then, not today's 18; Thursday of week 1817
    assert gps_week_from_unix(calendar.timegm((2014, 11, 6, 12, 0, 0))) == (1817, (4 * 86400 + 12 * 3600 + 16) * 1000)


def test_yaw_when_enabled_north_is_36000():
    inj = Injector(InjectConfig(mode="shadow", send_yaw=True))
    assert inj.process(state(yaw_rad=0.0))[0].yaw_cdeg == 36000
    assert inj.process(state(t_s=10.1, yaw_rad=math.radians(-90)))[0].yaw_cdeg == 27000


@pytest.mark.parametrize(
    "sigma_h,sigma_v,expect",
    [(1.0, 2.0, FixType.FIX_3D), (12.0, 2.0, FixType.FIX_2D), (2.0, 25.0, FixType.FIX_2D), (60.0, 5.0, FixType.NO_FIX)],
)
def test_fix_type_follows_covariance_bounds(sigma_h, sigma_v, expect):
    inj = Injector(InjectConfig(mode="shadow", activate="always", max_h_acc_3d_m=10, max_v_acc_3d_m=20, max_h_acc_2d_m=50))
    inj.process(SystemTime(t_s=5.0, unix_time_s=calendar.timegm((2025, 3, 15, 1, 30, 0))))
    (rec,) = inj.process(state(sigma_h=sigma_h, sigma_v=sigma_v))
    assert rec.fix_type == expect and not rec.sent and rec.mode == "shadow"
    assert rec.h_acc_m == sigma_h and rec.v_acc_m == sigma_v  # accuracies are the filter's, not constants
    assert rec.satellites == (10 if expect >= 2 else 0)


def test_accuracy_grows_with_covariance_while_coasting():
    inj = Injector(InjectConfig(mode="shadow"))
    accs = [inj.process(state(t_s=10 + 0.1 * k, sigma_h=1.0 + k))[0].h_acc_m for k in range(5)]
    assert accs == sorted(accs) and len(set(accs)) == 5


BAD_STATES = {
    "nan lat": dict(lat=math.nan),
    "zero zero": dict(lat=0.0, lon=0.0),
    "lat range": dict(lat=91.0),
    "inf velocity": dict(vel_n_mps=math.inf),
    "too fast": dict(vel_n_mps=300.0),
    "nan sigma": dict(sigma_h_m=math.nan),
    "zero sigma": dict(sigma_h_m=0.0),
    "alt range": dict(alt_msl_m=1e6),
}


@pytest.mark.parametrize("kind", BAD_STATES)
def test_bad_states_are_never_sent(kind):
    wire = Wire()
    inj = Injector(InjectConfig(mode="inject"), sender=wire)
    out = inj.process(state(**BAD_STATES[kind]))
    assert not wire.msgs and len(out) == 1 and isinstance(out[0], InjectorDrop)
    assert sum(inj.dropped.values()) == 1 and inj.sent == 0


def test_duplicate_and_out_of_order_states_dropped():
    wire = Wire()
    inj = Injector(InjectConfig(mode="inject"), sender=wire)
    inj.process(state(t_s=10.0))
    assert isinstance(inj.process(state(t_s=10.0))[0], InjectorDrop)
    assert isinstance(inj.process(state(t_s=9.0))[0], InjectorDrop)
    assert len(wire.msgs) == 1 and inj.dropped["time not after the previous state"] == 2


def test_rate_limit_and_minimum_rate():
    inj = Injector(InjectConfig(mode="shadow", rate_hz=5.0))
    outs = [o for k in range(20) for o in inj.process(state(t_s=10 + 0.1 * k))]
    assert len(outs) == 10  # 2 s of 10 Hz states at 5 Hz
    with pytest.raises(ValueError, match=">= 5"):
        InjectConfig(mode="inject", rate_hz=2.0)


def test_rate_limit_keeps_the_rate_when_the_epochs_jitter():
    """10 Hz states, each final once the first 50 Hz IMU sample past its reorder window arrives (0-20 ms past it):
    all go out at rate_hz 10 (a strict 0.1 s gap sent about 8 a second), and never two within 0.75 / rate_hz."""
    import numpy as np

    from companion.events import ImuSample

    inj = Injector(InjectConfig(mode="shadow", rate_hz=10.0))
    jitter = np.random.default_rng(3).uniform(0.0, 0.02, 100)
    recs = []
    for k in range(100):
        t = 10 + 0.1 * k
        inj.process(ImuSample(t + 0.25 + jitter[k], (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0))
        recs += [o for o in inj.process(state(t_s=t)) if isinstance(o, GpsInputRecord)]
    assert len(recs) >= 98
    gaps = [b.t_s - a.t_s for a, b in zip(recs, recs[1:])]
    assert min(gaps) >= 0.75 / 10.0 - 1e-9


def test_off_mode_builds_nothing():
    inj = Injector(InjectConfig(mode="off"))
    assert inj.process(state()) == [] and inj.built == 0


def test_link_not_ready_is_counted():
    inj = Injector(InjectConfig(mode="inject"), sender=lambda m: False)
    (rec,) = inj.process(state())
    assert not rec.sent and inj.dropped["link not ready"] == 1


def test_gnss_loss_activation():
    inj = Injector(InjectConfig(mode="shadow", activate="gnss_loss", recover_s=2.0, gnss_timeout_s=0.6))
    assert inj.process(fix(9.9)) == []
    assert inj.process(state(t_s=10.0)) == []  # receiver healthy: nothing
    on = inj.process(fix(10.1, fix_type=1))
    assert isinstance(on[0], InjectorState) and on[0].active
    assert isinstance(inj.process(state(t_s=10.2))[0], GpsInputRecord)
    inj.process(fix(10.3))
    assert isinstance(inj.process(state(t_s=10.4))[0], GpsInputRecord)  # still on during recovery
    off = inj.process(fix(12.4))
    assert isinstance(off[0], InjectorState) and not off[0].active
    assert inj.process(state(t_s=12.5)) == []
    # receiver silent (no GPS_RAW_INT at all) also switches on; GPS2 (our own instance echoed) is ignored
    inj.process(fix(13.0, instance=1))
    out = inj.process(state(t_s=13.2))
    assert isinstance(out[0], InjectorState) and out[0].active and isinstance(out[1], GpsInputRecord)


def test_reboot_restarts_boot_time_and_forgets_utc():
    inj = Injector(InjectConfig(mode="shadow"))
    inj.process(SystemTime(t_s=90.0, unix_time_s=1.7e9))
    assert inj.process(state(t_s=100.0))[0].time_week > 0
    inj.process(Reboot(t_s=120.0 + 1.0, previous_boot_s=120.0, new_boot_s=1.0))
    rec = inj.process(state(t_s=125.0))[-1]
    assert rec.time_boot_us == 5_000_000 and rec.time_week == 0 and rec.time_week_ms == 0


def test_encoder_refuses_zero_zero():
    inj = Injector(InjectConfig(mode="shadow"))
    (rec,) = inj.process(state())
    with pytest.raises(ValueError):
        encode_gps_input(replace(rec, lat_deg=0.0, lon_deg=0.0))


@pytest.mark.parametrize(
    "kw", [dict(mode="on"), dict(gps_id=2), dict(activate="sometimes"), dict(satellites=4), dict(max_h_acc_3d_m=100.0)]
)
def test_config_validation(kw):
    with pytest.raises(ValueError):
        InjectConfig(**kw)


def test_accuracy_never_better_than_the_receiver():
    inj = Injector(InjectConfig(mode="shadow"))
    inj.process(replace(fix(9.9), h_acc_m=0.9, v_acc_m=1.8))
    rec = tick(inj, state(sigma_h=0.2, sigma_v=0.3))[0]
    assert rec.h_acc_m == 0.9 and rec.v_acc_m == 1.8 and rec.h_floor_m == 0.9
    rec = tick(inj, state(t_s=10.1, sigma_h=4.0, sigma_v=5.0))[0]  # coasting: the filter's growth shows
    assert rec.h_acc_m == 4.0 and rec.v_acc_m == 5.0
    inj2 = Injector(InjectConfig(mode="shadow", floor_to_receiver=False))
    inj2.process(replace(fix(9.9), h_acc_m=0.9))
    assert tick(inj2, state(sigma_h=0.2))[0].h_acc_m == 0.2


def test_stale_states_after_a_gap_are_not_sent():
    from companion.events import ImuSample

    inj = Injector(InjectConfig(mode="shadow"))
    inj.process(ImuSample(t_s=20.0, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0))
    out = inj.process(state(t_s=12.0))  # a navigator catching up 8 s late
    assert isinstance(out[0], InjectorDrop) and out[0].reason.startswith("stale")
    assert isinstance(inj.process(state(t_s=19.9))[0], GpsInputRecord)


def test_cross_check_against_the_receiver():
    inj = Injector(InjectConfig(mode="shadow"))
    rx = replace(fix(9.95), lat_deg=-35.3632, lon_deg=149.1652, h_acc_m=1.0)
    inj.process(rx)
    # 1 m away (within the gate: 13.8 x (1.5^2 + 1^2) + (5 m/s x 0.2 s)^2 -> 6.8 m)
    ok = tick(inj, state(t_s=10.0, lat=-35.3632 + 1.0 / 111_000))
    assert isinstance(ok[0], GpsInputRecord)
    bad = tick(inj, state(t_s=10.1, lat=-35.3632 + 15.0 / 111_000))
    assert isinstance(bad[0], InjectorDrop) and bad[0].reason == "inconsistent with the receiver"
    # no newer receiver fix to check against: stays refused until a check passes
    held = tick(inj, state(t_s=10.7, lat=-35.3632))
    assert isinstance(held[0], InjectorDrop) and "not yet re-checked" in held[0].reason
    inj.process(replace(rx, t_s=10.75))
    assert isinstance(tick(inj, state(t_s=10.8, lat=-35.3632))[0], GpsInputRecord)


def test_gnss_time_preferred_over_system_time():
    inj = Injector(InjectConfig(mode="shadow"))
    inj.process(SystemTime(t_s=9.0, unix_time_s=1.7e9))
    inj.process(replace(fix(9.9), gps_week=2357, gps_tow_s=518_423.0))
    rec = tick(inj, state(t_s=10.0))[0]
    assert (rec.time_week, rec.time_week_ms) == (2357, 518_423_100)


def test_altitude_without_vertical_aid_is_flagged_ignored_not_sent():
    """After a long denial the navigator's height (no baro of its own) drifts without bound: beyond max_v_acc_alt_m
    the altitude is flagged ignored (ArduPilot keeps its baro height) and repeats the last good one; the horizontal
    fix still goes out. An out-of-range altitude with a small sigma_v is still refused."""
    from companion.inject.gps_input import IGNORE_ALT, IGNORE_VEL_VERT, IGNORE_VERTICAL_ACCURACY

    wire = Wire()
    inj = Injector(InjectConfig(mode="inject", max_v_acc_alt_m=200.0), sender=wire)
    (good,) = inj.process(state(t_s=10.0, sigma_v=150.0))
    assert good.ignore_flags & IGNORE_ALT == 0 and good.alt_msl_m == 604.25
    (rec,) = inj.process(state(t_s=11.0, sigma_h=900.0, sigma_v=4000.0, alt_msl_m=-9000.0, vel_d_mps=-400.0))
    flags = IGNORE_ALT | IGNORE_VEL_VERT | IGNORE_VERTICAL_ACCURACY
    assert rec.ignore_flags & flags == flags and rec.alt_msl_m == 604.25 and rec.vel_d_mps == 0.0 and rec.sent
    got = decode_gps_input(wire.msgs[-1])
    assert got["ignore_flags"] & flags == flags and got["alt_msl_m"] == pytest.approx(604.25)
    assert got["lat_deg"] == pytest.approx(-35.3632, abs=1e-7)
    (bad,) = inj.process(state(t_s=12.0, sigma_v=3.0, alt_msl_m=-9000.0))
    assert isinstance(bad, InjectorDrop) and bad.reason == "altitude out of range"
    with pytest.raises(ValueError):
        InjectConfig(max_v_acc_3d_m=20.0, max_v_acc_alt_m=10.0)


def test_a_free_vertical_channel_does_not_degrade_a_good_horizontal_fix_where_the_height_is_ignored():
    """With max_v_acc_alt_m = max_v_acc_3d_m (an autopilot on its barometer), a vertical sigma beyond it flags the
    vertical ignored and the fix stays 3D on its horizontal accuracy; with the default band (20-200 m) the same state
    is a 2D fix carrying its altitude, and a poor horizontal is 2D either way."""
    from companion.inject.gps_input import IGNORE_ALT

    utc = SystemTime(t_s=5.0, unix_time_s=calendar.timegm((2025, 3, 15, 1, 30, 0)))
    baro = Injector(InjectConfig(mode="shadow", activate="always", max_v_acc_3d_m=20.0, max_v_acc_alt_m=20.0))
    baro.process(utc)
    (ok,) = baro.process(state(t_s=10.0, sigma_h=3.0, sigma_v=15.0))
    assert ok.fix_type == FixType.FIX_3D and ok.ignore_flags & IGNORE_ALT == 0
    (free,) = baro.process(state(t_s=11.0, sigma_h=3.0, sigma_v=25.0))
    assert free.fix_type == FixType.FIX_3D and free.ignore_flags & IGNORE_ALT and free.alt_msl_m == ok.alt_msl_m
    (poor,) = baro.process(state(t_s=12.0, sigma_h=30.0, sigma_v=25.0))
    assert poor.fix_type == FixType.FIX_2D
    band = Injector(InjectConfig(mode="shadow", activate="always", max_v_acc_3d_m=20.0))
    band.process(utc)
    (two_d,) = band.process(state(t_s=10.0, sigma_h=3.0, sigma_v=25.0))
    assert two_d.fix_type == FixType.FIX_2D and two_d.ignore_flags & IGNORE_ALT == 0


def test_vertical_velocity_worse_than_the_stated_speed_accuracy_is_flagged_ignored():
    """EKF3 weighs vn, ve and vd by the one speed_accuracy sent (the horizontal sigma): a vd with a larger sigma is
    flagged ignored (sent as 0) rather than fused overconfident; within it, vd goes out as it is."""
    from companion.inject.gps_input import IGNORE_VEL_VERT

    inj = Injector(InjectConfig(mode="shadow", activate="always"))
    inj.process(SystemTime(t_s=5.0, unix_time_s=calendar.timegm((2025, 3, 15, 1, 30, 0))))
    (good,) = inj.process(state(t_s=10.0))  # sigma vd 0.1 m/s, speed accuracy 0.3 m/s
    assert good.ignore_flags & IGNORE_VEL_VERT == 0 and good.vel_d_mps == 0.5 and good.speed_acc_mps == pytest.approx(0.3)
    (bad,) = inj.process(state(t_s=11.0, cov_diag=(1.1, 1.1, 6.25, 0.04, 0.09, 0.25)))  # sigma vd 0.5 m/s
    assert bad.ignore_flags & IGNORE_VEL_VERT and bad.vel_d_mps == 0.0 and bad.fix_type == FixType.FIX_3D


def test_each_message_describes_the_epoch_it_claims_on_a_simulated_flight():
    """The navigator's state is final only once its reorder window (0.25 s) has passed; ArduPilot fuses a GPS_INPUT as
    the vehicle autopilot_lag_s (0.2 s) before it arrives. Each message must describe that epoch: its position matches
    the truth at its own t_s within the INS's error, and is far closer to it than the uncarried state would be."""
    import numpy as np

    from companion.nav.navigator import Navigator
    from companion.sim.circle import SimNoise, simulate_circle_flight as simulate_flight

    sim = simulate_flight(40.0, np.random.default_rng(3), noise=SimNoise(gnss_std_h_m=0.3, gnss_std_v_m=0.5))
    nav, inj = Navigator(), Injector(InjectConfig(mode="shadow"))
    recs = []
    for ev in sim.events:
        out = nav.process(ev)
        inj.process(ev)
        for o in out:
            recs += [r for r in inj.process(o) if isinstance(r, GpsInputRecord)]
    recs = [r for r in recs if r.t_s > sim.truth_t_s[0] + 10.0]  # after the filter settled
    assert len(recs) > 200
    carried = np.array([r.extrapolated_s for r in recs])
    assert np.all((carried > 0.0) & (carried < 0.2))  # states are 0.25-0.35 s old when final: carried 0.05-0.15 s
    ned = sim.frame.to_ned_m([r.lat_deg for r in recs], [r.lon_deg for r in recs], [r.alt_msl_m for r in recs])
    t = np.array([r.t_s for r in recs])
    truth = np.stack([np.interp(t, sim.truth_t_s, sim.truth_pos_ned_m[:, i]) for i in range(3)], axis=1)
    truth_then = np.stack([np.interp(t - carried, sim.truth_t_s, sim.truth_pos_ned_m[:, i]) for i in range(3)], axis=1)
    err = np.hypot(*(ned - truth)[:, :2].T)
    lag_err = np.hypot(*(truth_then - truth)[:, :2].T)  # what describing the uncarried epoch would cost
    assert np.sqrt(np.mean(err**2)) < 0.5  # the navigator's own error on this flight (GNSS 0.3 m)
    # closer to the truth of the epoch it claims than to the truth of the state's own (older) epoch
    assert np.sqrt(np.mean(err**2)) < np.sqrt(np.mean(np.sum((ned - truth_then)[:, :2] ** 2, axis=1)))
    assert np.mean(lag_err) > 0.2  # the flight moves enough for the epoch to matter


def test_a_corrupt_clock_or_field_never_stops_the_injector():
    """SYSTEM_TIME of year ~3000 (time_unix_usec 4e16) is refused as a clock; a field that does not fit its wire type
    drops that one message with a reason."""
    wire = Wire()
    inj = Injector(InjectConfig(mode="inject"), sender=lambda m: wire(m))
    inj.process(SystemTime(t_s=9.0, unix_time_s=4e10))
    assert inj.dropped["SYSTEM_TIME without a valid UTC"] == 1
    (rec,) = tick(inj, state(t_s=10.0))
    assert rec.sent and rec.time_week == 0
    (bad,) = tick(inj, state(t_s=10.2, sigma_h=1e39))  # finite, but beyond float32
    assert isinstance(bad, InjectorDrop) and bad.reason.startswith("not encodable")
    (rec,) = tick(inj, state(t_s=10.4))
    assert rec.sent and len(wire.msgs) == 2


def test_backup_claims_a_fix_in_an_outage_only_with_an_aid_the_autopilot_lacks():
    """Beside a real receiver that stays primary (GPS_AUTO_SWITCH = 4), the default: while the receiver is healthy every
    state goes out with its fix (the instance passes arming); in an outage the INS alone is no better than ArduPilot's
    own dead reckoning, so it goes out as no fix until a matcher fix aids it, and again once that aid is too old."""
    inj = Injector(InjectConfig(mode="shadow", aid_valid_s=60.0))
    assert inj.config.activate == "backup"
    inj.process(fix(9.95))
    (rec,) = tick(inj, state(t_s=10.0))
    assert rec.fix_type == FixType.FIX_3D
    inj.process(fix(10.1, fix_type=1))  # the receiver loses its fix
    (rec,) = tick(inj, state(t_s=10.3, sigma_h=2.0))
    assert rec.fix_type == FixType.NO_FIX and rec.satellites == 0 and "dead-reckons alone" in rec.fix_reason
    (rec,) = tick(inj, state(t_s=11.0, sigma_h=2.0, measurement="position_fix"))
    assert rec.fix_type == FixType.FIX_3D
    (rec,) = tick(inj, state(t_s=50.0, sigma_h=4.0, measurement="none"))  # aided 39 s ago: still within 60 s
    assert rec.fix_type == FixType.FIX_3D
    (rec,) = tick(inj, state(t_s=72.0, sigma_h=4.0, measurement="none"))
    assert rec.fix_type == FixType.NO_FIX
    inj.process(fix(72.1))  # the receiver is back: the state follows it again with its fix
    (rec,) = tick(inj, state(t_s=72.2, sigma_h=1.0, measurement="gnss"))
    assert rec.fix_type == FixType.FIX_3D


def test_every_state_is_checked_against_the_nearest_receiver_fix_newer_or_older():
    """States leave the navigator behind the newest input, so the nearest receiver fix is often newer than the state:
    it is carried to the state's epoch at its own velocity and still judged."""
    m_deg = 1.0 / 111_000
    inj = Injector(InjectConfig(mode="shadow"))
    # vehicle and receiver go north at 20 m/s; the receiver's fix 0.2 s after the state's epoch is 4 m further on
    inj.process(replace(fix(10.3), lat_deg=-35.3632 + 6.0 * m_deg, h_acc_m=1.0, vel_n_mps=20.0, vel_e_mps=0.0))
    st = dict(sigma_h=0.3, vel_n_mps=20.0, vel_e_mps=0.0)
    # gate: 13.8 x (0.3^2 + 1^2) + (20 m/s x 0.2 s)^2 -> 5.6 m; the 4 m would pass anyway, 6 m would not: the carry
    # makes the difference only if the comparison happens at the state's epoch (10.1 s once tick carries it)
    (ok,) = tick(inj, state(t_s=10.0, **st))
    assert isinstance(ok, GpsInputRecord) and ok.t_s == pytest.approx(10.1)
    (bad,) = tick(inj, state(t_s=10.2, lat=-35.3632 + (4.0 - 7.0) * m_deg, **st))  # 7 m behind: refused
    assert isinstance(bad, InjectorDrop) and bad.reason == "inconsistent with the receiver"
    meta = inj.metadata()
    assert (meta["cross_check.states"], meta["cross_check.checked"], meta["cross_check.fraction"]) == ("2", "2", "1.0000")
    # no fix within consistency_window_s on either side: not checked (held after the disagreement), and counted
    (held,) = tick(inj, state(t_s=11.0, lat=-35.3632 + 20.0 * m_deg, **st))
    assert isinstance(held, InjectorDrop) and "not yet re-checked" in held.reason
    assert inj.metadata()["cross_check.fraction"] == f"{2 / 3:.4f}"
    assert any("cross-check on 2 of 3 states" in line for line in inj.summary_lines())


def test_a_state_velocity_off_the_receiver_is_refused():
    """On the receiver's position but moving 17 m/s off its velocity (an INS after a clamped IMU sample): metres off a
    tenth of a second later whatever its sigma_h says, so not sent until it agrees again."""
    m_deg = 1.0 / 111_000
    inj = Injector(InjectConfig(mode="shadow"))
    rx = replace(fix(9.95), h_acc_m=1.0, vel_n_mps=8.0, vel_e_mps=0.0, speed_acc_mps=0.3)
    inj.process(rx)
    # state velocity sigma sqrt(0.09) = 0.3 m/s; allowed sqrt(13.8 x (0.3^2 + 0.3^2) + (10 x (0.05 + 0.2))^2) = 2.8 m/s
    (ok,) = tick(inj, state(t_s=10.0, lat=-35.3632 + 0.4 * m_deg, vel_n_mps=9.5, vel_e_mps=1.0))
    assert isinstance(ok, GpsInputRecord)
    inj.process(replace(rx, t_s=10.05))
    (bad,) = tick(inj, state(t_s=10.1, lat=-35.3632 + 1.2 * m_deg, vel_n_mps=25.0, vel_e_mps=2.0))
    assert isinstance(bad, InjectorDrop) and bad.reason == "inconsistent with the receiver"
    (slow,) = tick(inj, state(t_s=10.2, lat=-35.3632 + 0.8 * m_deg, vel_n_mps=4.0, vel_e_mps=-1.5))  # 4.3 m/s off
    assert isinstance(slow, InjectorDrop) and slow.reason == "inconsistent with the receiver"
    inj.process(replace(rx, t_s=10.25))
    (back,) = tick(inj, state(t_s=10.3, lat=-35.3632 + 2.8 * m_deg, vel_n_mps=8.0, vel_e_mps=0.0))
    assert isinstance(back, GpsInputRecord)


def test_a_fix_far_from_the_state_for_seconds_stops_every_message():
    """Do no harm: a receiver 300 m away (newer than every state) refuses each state, not one in a hundred."""
    inj = Injector(InjectConfig(mode="shadow"))
    refused = 0
    for k in range(50):
        t = 10.0 + 0.1 * k
        inj.process(replace(fix(t + 0.15), lat_deg=-35.3632 + 300.0 / 111_000, h_acc_m=1.0))
        out = tick(inj, state(t_s=t, vel_n_mps=0.0, vel_e_mps=0.0))
        refused += isinstance(out[0], InjectorDrop) and out[0].reason == "inconsistent with the receiver"
    assert refused == 50 and inj.built == 0


def test_gps_time_out_of_the_uint16_week_is_never_sent():
    """A receiver GPS time outside the week's range is not used; a derived week beyond uint16 goes out as unknown."""
    inj = Injector(InjectConfig(mode="shadow"))
    inj.process(replace(fix(9.9), gps_week=70_000, gps_tow_s=1.0))
    inj.process(replace(fix(9.95), gps_week=2357, gps_tow_s=-5.0))
    assert inj.dropped["receiver GPS time out of range (not used)"] == 2
    (rec,) = tick(inj, state(t_s=10.0))
    assert (rec.time_week, rec.time_week_ms) == (0, 0)
    inj.process(replace(fix(10.1), gps_week=65535, gps_tow_s=604_799.0))  # the last second of the last week
    (rec,) = tick(inj, state(t_s=10.2))
    assert rec.time_week == 65535
    (rec,) = tick(inj, state(t_s=11.5))  # carried past it: week 65536 does not exist on the wire
    assert (rec.time_week, rec.time_week_ms) == (0, 0)
    assert inj.dropped["GPS week beyond uint16: time sent as unknown (0/0)"] == 1


def test_a_record_that_cannot_be_encoded_is_not_built_in_shadow_mode_either():
    inj = Injector(InjectConfig(mode="shadow"))
    (bad,) = tick(inj, state(t_s=10.0, sigma_h=1e39))  # finite, but beyond float32
    assert isinstance(bad, InjectorDrop) and bad.reason.startswith("not encodable (hdop") and inj.built == 0


EXTREME = [math.nan, math.inf, -math.inf, 1e300, -1e300, 1e39, -1e39, 4e16, -4e16, 2.0**64, -(2.0**63), 0.0, -0.0,
           1e-300, 65536.0, 604800.0, -1.0]


def test_any_field_at_any_value_is_dropped_or_clamped_never_raised():
    """Seeded: states, receiver fixes and clocks with extreme values in one field each, in inject mode. Nothing
    raises, and every message that left fits GPS_INPUT's wire types (it parsed back) with its stated week in uint16."""
    import random

    from companion.events import ImuSample

    rng = random.Random(7)
    wire = Wire()
    inj = Injector(InjectConfig(mode="inject"), sender=lambda m: wire(m))
    s_fields = ["t_s", "lat_deg", "lon_deg", "alt_msl_m", "vel_n_mps", "vel_e_mps", "vel_d_mps", "sigma_h_m",
                "sigma_v_m", "yaw_rad"]
    # a receiver fix's time is only made non-finite: the vehicle clock upstream refuses finite time outliers
    f_fields = ["lat_deg", "lon_deg", "hdop", "h_acc_m", "v_acc_m", "vel_n_mps", "gps_tow_s"]
    t = 10.0
    for k in range(3000):
        t += 0.1
        kind = rng.random()
        bad = rng.choice(EXTREME)
        if kind < 0.1:
            inj.process(SystemTime(t_s=t, unix_time_s=rng.choice([bad, 1.7e9])))
        elif kind < 0.4:
            f = replace(fix(t), gps_week=rng.choice([2357, 0, 65535, 70_000, -1]), gps_tow_s=1.0, h_acc_m=1.0)
            inj.process(replace(f, **{rng.choice(f_fields): bad}) if rng.random() < 0.5 else f)
            if rng.random() < 0.05:
                inj.process(replace(f, t_s=rng.choice([math.nan, math.inf, -math.inf])))
        else:
            st = state(t_s=t, vel_n_mps=0.0, vel_e_mps=0.0, vel_d_mps=0.0)
            inj.process(ImuSample(t_s=t + 0.2, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0,) * 3, imu_index=0))
            inj.process(replace(st, **{rng.choice(s_fields): bad}) if rng.random() < 0.5 else st)
    assert inj.sent == len(wire.msgs) > 100, inj.dropped
    assert all(0 <= m.time_week <= 65535 and m.time_usec >= 0 for m in wire.msgs)
    assert sum(inj.dropped.values()) > 100


def test_fast_replace_builds_what_dataclasses_replace_builds():
    from companion.inject.carry import carry as _carry
    from companion.inject.gps_input import _replace, _replace_sent

    s = state()
    changed = dict(t_s=11.0, lat_deg=-35.0, north_m=1.5, age_since_fix_s=0.3)
    assert _replace(s, **changed) == replace(s, **changed)
    carried = _carry(s, 10.1)
    assert carried.t_s == 10.1 and carried.north_m == pytest.approx(0.3) and carried.east_m == pytest.approx(-0.4)
    assert replace(carried, t_s=s.t_s) != s  # (it moved)
    rec = Injector(InjectConfig(mode="shadow", activate="always"))._record(s, False)
    assert not rec.sent
    assert _replace_sent(rec) == replace(rec, sent=True)
    with pytest.raises(TypeError):
        _replace(s, no_such_field=1.0)
