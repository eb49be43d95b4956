"""A boat's water-speed log, end to end: the simulated log on SITL's truth (companion.sim.speed_log), its
NAMED_VALUE_FLOAT decoded on the vehicle clock (companion.mavlink.speed_log), and the air-data stage taking it in
place of the airspeed (companion.gravity.air_data_stage). Known truth in every test."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.events import AirData, AutopilotAltitude, WaterSpeed
from companion.gravity.air_data import radii_m
from companion.mavlink.decode import MavlinkDecoder
from companion.mavlink.gravimeter import NamedValueGravityDecoder
from companion.mavlink.speed_log import NamedValueSpeedLogDecoder
from companion.sim.sitl_gravimeter_link import GravimeterOnLink, SitlTide, speed_log_values
from companion.sim.speed_log import SpeedLog, SpeedLogSpec

LAT0, LON0 = -31.0, 156.0


def _track(speed_mps: float, heading_deg: float, t_s: np.ndarray):
    rm, rn = radii_m(LAT0)
    n = speed_mps * math.cos(math.radians(heading_deg)) * t_s
    e = speed_mps * math.sin(math.radians(heading_deg)) * t_s
    return LAT0 + np.degrees(n / rm), LON0 + np.degrees(e / (rn * math.cos(math.radians(LAT0))))


def test_log_reads_the_true_speed_with_its_scale_bias_and_noise():
    t = np.arange(0.0, 600.0, 0.1)
    lat, lon = _track(8.0, 30.0, t)
    log = SpeedLog(SpeedLogSpec(period_s=0.5), np.random.default_rng(4))
    out = [v for ti, la, lo in zip(t, lat, lon) for v in log.truth(float(ti), float(la), float(lo))]
    ts = np.array([o[0] for o in out])
    sp = np.array([o[1] for o in out])
    assert np.allclose(np.diff(ts), 0.5, atol=1e-6)  # one value every period
    assert log.scale != 1.0 and log.bias_mps != 0.0
    expect = 8.0 * log.scale + log.bias_mps
    assert abs(sp.mean() - expect) < 4 * 0.05 / math.sqrt(len(sp))
    assert sp.std() == pytest.approx(0.05, rel=0.15)
    # the same seed draws the same log; the memory is the window's
    log2 = SpeedLog(SpeedLogSpec(period_s=0.5), np.random.default_rng(4))
    out2 = [v for ti, la, lo in zip(t, lat, lon) for v in log2.truth(float(ti), float(la), float(lo))]
    assert out2 == out
    assert len(log._pts) <= 12


def test_log_ignores_repeated_or_bad_truth_and_never_reads_negative():
    log = SpeedLog(SpeedLogSpec(period_s=0.5, bias_sigma_mps=0.0, white_sigma_mps=1.0), np.random.default_rng(1))
    vals = []
    for i in range(200):  # at rest: noise around 0 is clipped, never negative
        vals += log.truth(i * 0.1, LAT0, LON0)
    assert vals and min(v for _, v in vals) >= 0.0
    assert log.truth(5.0, LAT0, LON0) == []  # not after the previous truth
    assert log.truth(math.nan, LAT0, LON0) == [] and log.truth(30.0, math.nan, LON0) == []


def _msgs(*msgs, src=(1, 1)):
    for m in msgs:
        m._header = mav.MAVLink_header(m.id, srcSystem=src[0], srcComponent=src[1])
    return list(msgs)


def test_link_stamps_the_log_as_the_gravimeter_and_the_decoder_puts_it_on_the_vehicle_clock():
    gl = GravimeterOnLink(type("M", (), {"sample": lambda *a: None, "read": lambda *a: None})(), 1.0)
    log = SpeedLog(SpeedLogSpec(period_s=0.5, scale_sigma=0.0, bias_sigma_mps=0.0, white_sigma_mps=0.0),
                   np.random.default_rng(0))
    t = np.arange(0.0, 3.0, 0.1)
    lat, lon = _track(6.0, 90.0, t)
    sent = []
    for ti, la, lo in zip(t, lat, lon):
        tb = int(round((100.0 + ti) * 1000))
        for m in (mav.MAVLink_attitude_message(tb, 0, 0, 0, 0, 0, 0),
                  mav.MAVLink_simstate_message(0, 0, 0, 0, 0, 0, 0, 0, 0, int(round(la * 1e7)), int(round(lo * 1e7)))):
            gl.on_message(m)
            sent += speed_log_values(log, gl, m)
    assert [s[0] for s in sent] == [100500 + 500 * i for i in range(len(sent))] and len(sent) >= 4
    assert all(v == pytest.approx(6.0, abs=0.02) for _, v in sent)  # degE7 rounding only

    dec = MavlinkDecoder(gravity=NamedValueGravityDecoder("GRAV"), speed_log=NamedValueSpeedLogDecoder("WSPD"))
    dec.decode(_msgs(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))[0], 0.0)
    dec.decode(_msgs(mav.MAVLink_attitude_message(100_000, 0, 0, 0, 0, 0, 0))[0], 0.0)
    (w,) = dec.decode(_msgs(mav.MAVLink_named_value_float_message(sent[0][0], b"WSPD", sent[0][1]), src=(1, 158))[0], 0.5)
    assert isinstance(w, WaterSpeed) and w.t_s == pytest.approx(100.5) and w.speed_mps == pytest.approx(sent[0][1], rel=1e-6)
    (g,) = dec.decode(_msgs(mav.MAVLink_named_value_float_message(100_600, b"GRAV", 3.0))[0], 0.6)
    assert g.gravity_mgal == 3.0  # the gravimeter beside it is unchanged
    for bad in (-0.5, math.nan, 1e4):
        assert dec.decode(_msgs(mav.MAVLink_named_value_float_message(100_700, b"WSPD", bad))[0], 0.7) == []
    assert dec.speed_log.dropped == 3
    with pytest.raises(ValueError):
        NamedValueSpeedLogDecoder("")
    # without a speed log the same message is nothing
    plain = MavlinkDecoder(gravity=NamedValueGravityDecoder("GRAV"))
    plain.decode(_msgs(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))[0], 0.0)
    assert plain.decode(_msgs(mav.MAVLink_named_value_float_message(1000, b"WSPD", 5.0))[0], 0.1) == []


def test_log_reads_through_the_water_of_sitls_tide_once_armed():
    """SITL's tide (SIM_TIDE_SPEED 0.5 m/s coming from SIM_TIDE_DIR 180 deg: flowing north) carries a boat going
    north at 8 m/s over the ground: through the water it makes 7.5 m/s; going south, 8.5 m/s. Before the autopilot
    arms SITL applies no tide, and neither does the log; the parameters come as the autopilot's PARAM_VALUE, the armed
    state from its own HEARTBEAT (not another component's)."""
    tide = SitlTide(1)
    for m in _msgs(mav.MAVLink_param_value_message(b"SIM_TIDE_SPEED", 0.5, 9, 1000, -1),
                   mav.MAVLink_param_value_message(b"SIM_TIDE_DIR", 180.0, 9, 1000, -1)):
        tide.on_message(m)
    armed = mav.MAV_MODE_FLAG_SAFETY_ARMED | mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    tide.on_message(_msgs(mav.MAVLink_heartbeat_message(6, 3, armed, 0, 4, 3), src=(1, 191))[0])
    assert tide.current_ne_mps() == (0.0, 0.0)  # another component's heartbeat: not the autopilot arming
    expect = {}
    for heading, want in ((0.0, 8.0), (180.0, 8.5)):
        gl = GravimeterOnLink(type("M", (), {"sample": lambda *a: None, "read": lambda *a: None})(), 1.0)
        log = SpeedLog(SpeedLogSpec(period_s=0.5, scale_sigma=0.0, bias_sigma_mps=0.0, white_sigma_mps=0.0),
                       np.random.default_rng(0))
        t = np.arange(0.0, 3.0, 0.1)
        lat, lon = _track(8.0, heading, t)
        tide.on_message(_msgs(mav.MAVLink_heartbeat_message(10, 3, armed if heading else 0, 0, 4, 3))[0])
        sent = []
        for ti, la, lo in zip(t, lat, lon):
            tb = int(round((100.0 + ti) * 1000))
            for m in (mav.MAVLink_attitude_message(tb, 0, 0, 0, 0, 0, 0),
                      mav.MAVLink_simstate_message(0, 0, 0, 0, 0, 0, 0, 0, 0, int(round(la * 1e7)),
                                                   int(round(lo * 1e7)))):
                gl.on_message(m)
                sent += speed_log_values(log, gl, m, tide)
        expect[heading] = (sent, want)
    assert all(v == pytest.approx(8.0, abs=0.02) for _, v in expect[0.0][0])  # disarmed: no tide
    assert len(expect[180.0][0]) >= 4 and all(v == pytest.approx(8.5, abs=0.02) for _, v in expect[180.0][0])
    tide.on_message(_msgs(mav.MAVLink_heartbeat_message(10, 3, armed, 0, 4, 3))[0])
    assert tide.current_ne_mps() == pytest.approx((0.5, 0.0), abs=1e-9)  # flowing north
    log = SpeedLog(SpeedLogSpec(scale_sigma=0.0, bias_sigma_mps=0.0, white_sigma_mps=0.0), np.random.default_rng(0))
    t = np.arange(0.0, 3.0, 0.1)
    lat, lon = _track(8.0, 0.0, t)
    vals = [v for ti, la, lo in zip(t, lat, lon) for _, v in log.truth(float(ti), float(la), float(lo),
                                                                         tide.current_ne_mps())]
    assert vals and all(v == pytest.approx(7.5, abs=0.02) for v in vals)


@pytest.mark.parametrize("speed_log", [False, True])
def test_air_data_stage_takes_the_log_on_a_boat_and_the_airspeed_otherwise(speed_log):
    """A boat's reference moves at its log's speed along its heading; VFR_HUD.airspeed (on ArduRover the GPS's ground
    speed: in an outage the companion's own fixes) is ignored. Without the log it is the other way round."""
    from companion.gravity.air_data import AirDataConfig
    from companion.gravity.air_data_stage import AirDataGravityStage
    from companion.gravity.maps import GravityMap, LocalGravityMap
    from companion.gravity.sequential import InsErrorSpec, SeqGravConfig
    from companion.events import Attitude

    lon, lat = np.linspace(155.0, 157.0, 41), np.linspace(-32.0, -30.0, 41)
    lmap = LocalGravityMap.around(GravityMap(np.zeros((41, 41)), lon, lat, "geographic_deg"))
    cfg = SeqGravConfig(n_particles=50, ins=InsErrorSpec(air_data=True))
    stage = AirDataGravityStage(lmap, cfg, AirDataConfig(min_airspeed_mps=0.3), speed_log=speed_log)
    yaw = math.radians(60.0)
    for ev in (AutopilotAltitude(t_s=1.0, alt_msl_m=0.0), Attitude(t_s=1.0, roll_rad=0.0, pitch_rad=0.0, yaw_rad=yaw),
               AirData(t_s=1.0, airspeed_mps=20.0), WaterSpeed(t_s=1.0, speed_mps=7.5)):
        stage.process(ev)
    v = stage.dr.air_velocity(1.0)
    # the log as it reads; the airspeed EAS to TAS at sea level (a factor within a percent of 1)
    assert np.hypot(*v) == (pytest.approx(7.5, rel=1e-9) if speed_log else pytest.approx(20.0, rel=0.01))
    assert math.atan2(v[1], v[0]) == pytest.approx(yaw)


def _boat_stage(speed_log: bool):
    from companion.gravity.air_data import AirDataConfig
    from companion.gravity.air_data_stage import AirDataGravityStage
    from companion.gravity.maps import GravityMap, LocalGravityMap
    from companion.gravity.sequential import InsErrorSpec, SeqGravConfig

    lon, lat = np.linspace(155.5, 156.5, 101), np.linspace(-31.5, -30.5, 101)
    g = 30.0 * np.sin(np.radians(lat)[:, None] * 2000.0) * np.cos(np.radians(lon)[None, :] * 1500.0)
    lmap = LocalGravityMap.around(GravityMap(g, lon, lat, "geographic_deg"))
    cfg = SeqGravConfig(n_particles=100, noise_corr_s=1.0, ins=InsErrorSpec(air_data=True, init_vel_sigma_mps=1.0))
    return AirDataGravityStage(lmap, cfg, AirDataConfig(min_airspeed_mps=0.3, wind_window_s=60.0),
                               reading_delay_s=15.0, speed_log=speed_log), lmap


@pytest.mark.parametrize("speed_log", [False, True])
def test_a_boat_is_carried_by_its_log_from_the_loss_and_a_plane_waits_for_its_readings(speed_log):
    """A boat heading north at 8 m/s in still water loses GNSS at 300 s (its VFR_HUD airspeed, which ArduRover fills
    with the GPS's ground speed, says 20 m/s and is ignored). With its log the stage's state goes out from
    the loss as an aid (``speed_log``: the autopilot has no log) until the first reading after it (15 s: a reading
    describes the vehicle reading_delay_s before its stamp), then as the gravity filter's; it is where the boat is, and
    states a covariance that covers it. Without a log (a plane's airspeed) nothing replaces the navigator's state
    until that first reading (the plane's airspeed then says 8 m/s)."""
    from companion.events import Attitude, GnssFix, GravityReading
    from companion.gravity.air_data_stage import AID, SPEED_LOG_AID, AirDataState
    from companion.gravity.air_data import radii_m as radii
    from companion.nav.outputs import FusedState

    stage, lmap = _boat_stage(speed_log)
    rm, _ = radii(LAT0)
    nan = math.nan
    states = []
    for k in range(0, 3300):
        t = k * 0.1
        lat = LAT0 + math.degrees(8.0 * t / rm)
        items = [Attitude(t_s=t, roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0), AutopilotAltitude(t_s=t, alt_msl_m=0.0)]
        if k % 5 == 0:
            items += [WaterSpeed(t_s=t, speed_mps=8.0), AirData(t_s=t, airspeed_mps=8.0 if not speed_log else 20.0)]
            items.append(GnssFix(t, 3, lat, LON0, 0.0, 8.0, 0.0, 0.0, None, None, 12, 0.8, 1.0, 1.5, 2.0, 0.3, None, None)
                         if t < 300.0 else
                         GnssFix(t, 1, None, None, None, None, None, None, None, None, 0, None, None, None, None, None,
                                 None, None))
        if k % 10 == 0 and t >= 15.0:
            lat_r = LAT0 + math.degrees(8.0 * (t - 15.0) / rm)
            n, e = lmap.xy_to_ne(LON0, lat_r)  # the map where the boat was, Eotvos-corrected by the sender
            items.append(GravityReading(t, float(np.asarray(lmap.interp_ne(n, e)).ravel()[0]), 1.0,
                                        eotvos_corrected=True))
        items.append(FusedState(t, lat, LON0, 0.0, 8.0, 0.0, 0.0, 0.0, 0.0, 0.0, nan, nan, nan,
                                (1e6, 1e6, 1.0, 1e4, 1e4, 1.0), 1e3, 1.0, "ins", "none", (nan, nan, nan), 0, 1e3))
        for it in items:
            for o in stage.process(it):
                if isinstance(o, AirDataState):
                    states.append((t, lat, o))
    early = [(t, la, o) for t, la, o in states if t < 315.0]
    late = [(t, la, o) for t, la, o in states if t >= 317.0]
    assert late and all(o.measurement in (AID, SPEED_LOG_AID) for _, _, o in late)
    if not speed_log:
        assert early == [] and all(o.measurement == AID for _, _, o in late)
        return
    assert early and early[0][0] <= 301.0  # from the loss (0.6 s of GNSS timeout)
    assert all(o.measurement == SPEED_LOG_AID for _, _, o in early)
    for t, la, o in early + late:
        err = abs(math.radians(o.lat_deg - la) * rm) + abs(o.lon_deg - LON0) * 1e5  # north, and a bound on east
        assert err <= 2.0 * o.sigma_h_m + 1.0, (t, err, o.sigma_h_m)
    s = [o.sigma_h_m for _, _, o in early]
    assert s[0] < 5.0 and s[-1] > 3.0 * s[0]  # the reckoning's covariance grows from the loss (held-speed prior 1 m/s)


def test_the_correction_a_state_carries_moves_at_most_its_rate_and_states_what_it_has_not_taken():
    """A boat's EKF3 fuses the states and checks their velocity against its own, which follows their positions: a
    correction taken at once fails it. Limited to 2 m/s, a 100 m correction is taken over 50 s, and the part not yet
    taken is in the stated covariance; at rate 0 it is taken at once."""
    stage, _ = _boat_stage(True)
    stage.correction_rate_mps = 2.0
    cov0 = np.eye(2) * 400.0
    err, cov = stage._limit_rate(10.0, np.zeros(2), cov0)  # the first state carries the filter's correction
    assert np.all(err == 0.0) and np.all(cov == cov0)
    target = np.array([60.0, 80.0])  # 100 m
    for k in range(1, 60):
        err, cov = stage._limit_rate(10.0 + k, target, cov0)
        taken = min(2.0 * k, 100.0)
        assert err == pytest.approx(target * taken / 100.0)
        pending = target - err
        assert cov == pytest.approx(cov0 + np.outer(pending, pending))
    assert err == pytest.approx(target) and cov == pytest.approx(cov0)
    stage.correction_rate_mps = 0.0
    err, cov = stage._limit_rate(100.0, -target, cov0)
    assert np.all(err == -target) and np.all(cov == cov0)


def test_the_boat_settings_reach_the_live_stage():
    """gravity.air_speed_log and air_correction_rate_mps from the configuration to the stage: the log in place of the
    airspeed, a reckoning that moves from a walking pace (a log reads ~0 at rest), the rate limit."""
    from companion.config import load_config, parse_override
    from companion.gravity.stage import live_gravity_stage
    from tests.conftest import AK_MAP, require

    sets = ['link.connect="tcp:127.0.0.1:1"', f'gravity.map="{require(AK_MAP)}"', "gravity.matcher=sequential",
            'gravity.reference="air_data"']
    plane = live_gravity_stage(load_config(None, dict(parse_override(s) for s in sets)).gravity)
    boat = live_gravity_stage(load_config(None, dict(parse_override(s) for s in sets + [
        'gravity.air_speed_log="WSPD"', "gravity.air_correction_rate_mps=2"])).gravity)
    assert (plane.speed_log, plane.correction_rate_mps, plane.dr.cfg.min_airspeed_mps) == (False, 0.0, 5.0)
    assert (boat.speed_log, boat.correction_rate_mps, boat.dr.cfg.min_airspeed_mps) == (True, 2.0, 0.3)
