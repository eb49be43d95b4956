"""Gravity-aided navigation on a live vehicle: NAMED_VALUE_FLOAT readings on the vehicle clock, the geographic
match stage (lat/lon, readings averaged per stretch of track), the fix acceptance test and the [gravity] settings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from companion.config import ConfigError, load_config
from companion.nav.outputs import FrameInfo, FusedState
from companion.events import PositionFix
from companion.nav.frame import LocalFrame
from companion.gravity.stage import FixAcceptance, GravityMatchStage, MatchRecord, window_signal_mgal
from companion.gravity.matchers.base import Matcher, MatchResult
from companion.gravity.maps import GravityMap, LocalGravityMap
from companion.events import GravityReading
from companion.mavlink.gravimeter import NamedValueGravityDecoder
from companion.mavlink.decode import MavlinkDecoder


def _msgs(*msgs, src=(1, 1)):
    out = []
    for m in msgs:
        m._header = mav.MAVLink_header(m.id, srcSystem=src[0], srcComponent=src[1])  # what the parser sets on a received frame
        out.append(m)
    return out


def _decoder():
    dec = MavlinkDecoder(gravity=NamedValueGravityDecoder("GRAV", sigma_mgal=0.7))
    hb = mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)
    dec.decode(_msgs(hb)[0], 0.0)
    dec.decode(_msgs(mav.MAVLink_attitude_message(10_000, 0, 0, 0, 0, 0, 0))[0], 0.0)  # boot time 10 s
    return dec


def test_named_value_float_becomes_gravity_reading_on_the_vehicle_clock():
    dec = _decoder()
    (r,) = dec.decode(_msgs(mav.MAVLink_named_value_float_message(10_500, b"GRAV", 12.25))[0], 0.5)
    assert isinstance(r, GravityReading) and r.t_s == pytest.approx(10.5) and r.gravity_mgal == 12.25
    assert r.sigma_mgal == 0.7
    # a gravimeter as its own component of the vehicle is accepted; another system and other names are not
    (r2,) = dec.decode(_msgs(mav.MAVLink_named_value_float_message(11_000, b"GRAV", 1.0), src=(1, 25))[0], 1.0)
    assert r2.t_s == pytest.approx(11.0)
    assert dec.decode(_msgs(mav.MAVLink_named_value_float_message(11_100, b"GRAV", 1.0), src=(2, 1))[0], 1.1) == []
    assert dec.decode(_msgs(mav.MAVLink_named_value_float_message(11_200, b"RPM", 1.0))[0], 1.2) == []
    assert dec.decode(_msgs(mav.MAVLink_named_value_float_message(11_300, b"GRAV", math.nan))[0], 1.3) == []
    # time_boot_ms 0: placed by receive time after the last boot time (11.0 s at receive 1.0 s)
    (r3,) = dec.decode(_msgs(mav.MAVLink_named_value_float_message(0, b"GRAV", 3.0))[0], 1.5)
    assert r3.t_s == pytest.approx(11.5)
    # the autopilot's (barometric) altitude: GLOBAL_POSITION_INT.alt in mm MSL
    from companion.events import AutopilotAltitude
    from companion.sim.mavlink_out import global_position_int

    a, _position = dec.decode(_msgs(global_position_int(12.0, -40.0, 156.0, 301.25, 0.0, (150.0, 0.0, 0.0), 0.0))[0],
                              2.0)  # (and the autopilot's position, its Map track)
    assert isinstance(a, AutopilotAltitude) and a.t_s == pytest.approx(12.0) and a.alt_msl_m == pytest.approx(301.25)
    # without a gravity decoder the message is ignored
    plain = MavlinkDecoder()
    plain.decode(_msgs(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))[0], 0.0)
    assert plain.decode(_msgs(mav.MAVLink_named_value_float_message(1000, b"GRAV", 1.0))[0], 0.1) == []


def test_fix_acceptance_and_window_signal():
    acc = FixAcceptance(min_track_cells=2.0, min_signal_ratio=1.0)
    assert acc.check(6000.0, 2900.0, 5.0, 1.0) == ""
    assert acc.check(5000.0, 2900.0, 5.0, 1.0).startswith("track")
    assert acc.check(6000.0, 2900.0, 0.5, 1.0).startswith("signal")
    assert acc.check(math.nan, 2900.0, 5.0, 1.0).startswith("track")
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 1.0, 4000)
    assert window_signal_mgal(noise, 1.0) < 0.15  # pure noise: no signal left
    ramp = np.linspace(-10.0, 10.0, 4000)
    assert window_signal_mgal(ramp + noise, 1.0) == pytest.approx(np.std(ramp, ddof=1), rel=0.02)
    assert window_signal_mgal(np.array([1.0]), 1.0) == 0.0


class _Recording(Matcher):
    """Records what it is fed; every `fix_every` samples answers 'the vehicle is at `answer_ne`' (map metres)."""

    name = "recording"
    supports_prior = True  # as a Viterbi matcher: takes the navigator prior

    def __init__(self, lmap, answer_ne, sigma_m=400.0):
        super().__init__(lmap, min_len=3, window_len=3, fix_every=3)
        self.answer_ne, self.sigma_m, self.fed, self.priors = np.asarray(answer_ne, float), sigma_m, [], []

    def feed(self, t_s, ins_ne_m, ins_vel_ne_mps, gravity_mgal, *, prior_sigma_m=None):
        self.fed.append((t_s, *np.asarray(ins_ne_m), *np.asarray(ins_vel_ne_mps), gravity_mgal))
        self.priors.append(prior_sigma_m)
        return super().feed(t_s, ins_ne_m, ins_vel_ne_mps, gravity_mgal, prior_sigma_m=prior_sigma_m)

    def _match(self, window, prior_sigma_m=None):
        return MatchResult(True, self.name, float(window.t_s[-1]), self.answer_ne.copy(), self.sigma_m)


def _geo_map():
    lon = np.arange(150.0, 160.0001, 1 / 30)  # 2' cells
    lat = np.arange(-45.0, -35.0001, 1 / 30)
    LON, LAT = np.meshgrid(lon, lat)
    g = 40.0 * np.sin(LON * 7.0) * np.cos(LAT * 5.0)
    return LocalGravityMap.around(GravityMap(g, lon, lat, "geographic_deg"))


def _state(frame, t, n, e, vn, ve):
    lat, lon, alt = frame.to_geodetic(np.array([n, e, 0.0]))
    nan = math.nan
    return FusedState(t, float(lat), float(lon), float(alt), n, e, 0.0, vn, ve, 0.0, nan, nan, nan, (), 5.0, 5.0,
                      "ins", "none", (nan, nan, nan), 0, 0.0)


@pytest.mark.parametrize("accept", [True, False])
def test_geographic_stage_uses_lat_lon_averages_readings_and_gates_fixes(accept):
    """A vehicle 300 km east of the map's own frame origin flies east at 150 m/s: positions reach the matcher through
    lat/lon (not through the vehicle's tangent plane, which is off by kilometres there), readings are averaged over
    each 3 km of track, and a fix answered in map metres comes back as the right lat/lon -- fused only if accepted."""
    lmap = _geo_map()
    frame = LocalFrame(-40.0, 158.5, 0.0)  # vehicle frame: ~300 km east of the map frame's origin (155.0 E)
    answer_map_ne = np.array(lmap.xy_to_ne(158.7, -40.02))
    matcher = _Recording(lmap, answer_map_ne)
    acceptance = FixAcceptance(2.0, 0.0) if accept else FixAcceptance(2.0, 1e6)
    stage = GravityMatchStage(lmap, matcher, geographic=True, feed_spacing_m=3000.0, acceptance=acceptance,
                              sigma_mgal=1.0)
    stage.process(FrameInfo(0.0, frame.ref_lat_deg, frame.ref_lon_deg, 0.0))
    out = []
    readings = []
    for k in range(0, 201):
        t = float(k)
        st = _state(frame, t, 0.0, 150.0 * t, 0.0, 150.0)
        lat, lon, _ = frame.to_geodetic(np.array([0.0, 150.0 * t, 0.0]))
        g = float(lmap.gmap.interp(lon, lat))
        readings.append(g)
        out += stage.process(GravityReading(t, g))
        out += stage.process(st)
    fed = np.asarray(matcher.fed)
    # one sample per 3 km of track (in map metres: ~149.96 m per second here, so 21 readings a stretch)
    assert len(fed) == 9 and np.allclose(np.diff(fed[:, 0]), 21.0, atol=0.51)
    # stretch 1 = readings 1..22 (the reading at t 0 precedes every state): mean time 11.5 s
    assert fed[0, 0] == pytest.approx(11.5)
    # positions are exact map metres of the vehicle's lat/lon (the mean of the stretch's positions)
    lat, lon, _ = frame.to_geodetic(np.array([0.0, 150.0 * 11.5, 0.0]))
    np.testing.assert_allclose(fed[0, 1:3], lmap.xy_to_ne(lon, lat), atol=1.0)
    # velocity in map metres per second: east scale of the map frame at the vehicle's latitude
    assert fed[0, 4] == pytest.approx(150.0, rel=0.01) and abs(fed[0, 3]) < 1.0
    assert fed[0, 5] == pytest.approx(np.mean(readings[1:23]))
    recs = [o for o in out if isinstance(o, MatchRecord)]
    fixes = [o for o in out if isinstance(o, PositionFix)]
    assert len(recs) == len(fed) // 3 and all(r.ok for r in recs)
    lon_a, lat_a = lmap.ne_to_xy(*answer_map_ne)
    if accept:
        assert len(fixes) == len(recs) and all(r.accepted for r in recs)
        assert fixes[0].lat_deg == pytest.approx(float(lat_a), abs=1e-9) and fixes[0].lon_deg == pytest.approx(float(lon_a), abs=1e-9)
        assert fixes[0].sigma_n_m == pytest.approx(max(400.0, stage.cell_m))
    else:
        assert fixes == [] and all(not r.accepted and r.reason.startswith("signal") for r in recs)
        assert all("sigma 0.21" in r.reason for r in recs)  # 1 mGal readings, ~21 averaged per sample
    # the window of the first fix: fed samples 1..3, two stretches of ~3.15 km
    assert recs[0].track_m == pytest.approx(np.hypot(*np.diff(fed[:3, 1:3], axis=0).T).sum())
    # the navigator's sigma_h (5 m here) became the prior of the window's first state, floored at half a cell
    assert stage.navigator_prior and matcher.priors[:2] == [None, None]
    assert matcher.priors[-1] == pytest.approx(0.5 * stage.cell_m)
    assert 6000.0 < recs[0].track_m < 6500.0


def test_gravity_settings_are_checked_at_start(tmp_path):
    grid = tmp_path / "g.nc"
    grid.write_bytes(b"not netcdf")
    base = {"link.connect": "udpin:127.0.0.1:14550"}
    cfg = load_config(None, {**base, "gravity.map": str(grid), "gravity.named_value": "GRAVX"})
    assert cfg.gravity.map == str(grid) and cfg.gravity.named_value == "GRAVX" and cfg.gravity.matcher == "viterbi"
    assert cfg.as_flat_dict()["gravity.sigma_mgal"] == "1.0"
    g_cfg = load_config(None, {**base, "gravity.map": str(grid), "navigator.uere_h_m": 2.0})
    nav = g_cfg.nav_config()
    assert nav.gnss_sigma_model == "accuracy" and nav.fuse_predictor is False and nav.uere_h_m == 2.0
    assert nav.fuse_autopilot_alt  # vertical aid from the autopilot's altitude ...
    assert g_cfg.streams.rates_hz["GLOBAL_POSITION_INT"] == 5.0  # ... which is requested
    # requested without gravity too (the autopilot's Map track); turned off, gravity aiding still requests it
    assert load_config(None, base).streams.rates_hz["GLOBAL_POSITION_INT"] == 5.0
    off = {**base, "streams.GLOBAL_POSITION_INT": 0}
    assert "GLOBAL_POSITION_INT" not in load_config(None, off).streams.rates_hz
    assert load_config(None, {**off, "gravity.map": str(grid)}).streams.rates_hz["GLOBAL_POSITION_INT"] == 5.0
    for over, text in [({"gravity.map": str(tmp_path / "missing.nc")}, "is not a file"),
                       ({"gravity.map": str(grid), "gravity.matcher": "tercom"}, "gravity.matcher"),
                       ({"gravity.map": str(grid), "gravity.named_value": "ELEVENCHARS"}, "1-10 characters"),
                       ({"gravity.map": str(grid), "gravity.sigma_mgal": 0}, "sigma_mgal"),
                       ({"gravity.map": str(grid), "gravity.accept_min_track_cells": -1}, "accept_min_track_cells"),
                       ({"gravity.mapp": "x"}, "unknown setting 'mapp'")]:
        with pytest.raises(ConfigError, match=text):
            load_config(None, {**base, **over})


def test_navigator_settings_section():
    base = {"link.connect": "udpin:127.0.0.1:14550"}
    cfg = load_config(None, {**base, "navigator.att_sigma_tilt_rad": 0.001, "navigator.fuse_predictor": False})
    nav = cfg.nav_config()
    assert nav.att_sigma_tilt_rad == 0.001 and nav.fuse_predictor is False and nav.gnss_sigma_model == "short_term"
    assert cfg.as_flat_dict()["navigator.att_sigma_tilt_rad"] == "0.001"
    assert load_config(None, base).nav_config() is None  # defaults
    for over, text in [({"navigator.knn": 3}, "unknown setting 'knn'"),
                       ({"navigator.att_sigma_tilt_rad": "x"}, "expected a number"),
                       ({"navigator.gnss_sigma_model": "magic"}, "gnss_sigma_model")]:
        with pytest.raises(ConfigError, match=text):
            load_config(None, {**base, **over})


def test_live_companion_matches_simulated_gravimeter_and_fuses_fixes(tmp_path):
    """HIL: `companion sim` flies a 12-minute aircraft cruise over the real Tasman grid sending NAMED_VALUE_FLOAT GRAV;
    the real `companion run --gravity-map` decodes the readings, matches them, fuses accepted fixes and injects."""
    import json

    from companion.record import iter_payloads, summarize
    from tests.conftest import SHARED, require
    from tests.runtime.test_hil import Sim, StderrWatch, run_companion

    tasman = require(SHARED / "data" / "gravity" / "tasman_grav_west_145E-160E.nc")
    sim = Sim(tmp_path, "--profile", "cruise", "--hours", 0.2, "--cruise-speed", 150, "--line-km", 60,
              "--spacing-km", 10, "--gravity-map", tasman, "--sensors", "aircraft", "--speed", 10, "--seed", 3)
    out = tmp_path / "c.mcap"
    comp = run_companion(sim.port, out, "--inject", "inject", "--gravity-map", tasman,
                         "--set", "inject.max_speed_mps=400", "--set", "navigator.fuse_attitude_yaw=true")
    watch = StderrWatch(comp)
    sim.proc.wait(timeout=300)  # the simulator ends with its flight
    recs = sim.finish(timeout=10)
    # x10, not faster: behind the link the companion rightly withholds stale states, and a loaded machine leaves it
    # behind a x40 stream; let it work off what is queued before the stop (SIGTERM drops what is still queued)
    assert watch.caught_up_after_link_loss(), watch.text()[-2000:]
    comp.send_signal(15)  # SIGTERM: the service's stop
    stdout, _ = comp.communicate(timeout=120)
    err = watch.text()
    assert "Traceback" not in err, err
    topics = {t.topic: t.count for t in summarize(out).topics}
    sent = next(r for r in recs if r["event"] == "end")["sent"]
    assert sent["NAMED_VALUE_FLOAT"] > 650  # 1 Hz over the ~0.2 h flight ...
    assert topics["/input/gravity"] == sent["NAMED_VALUE_FLOAT"]  # ... every reading decoded, none lost
    assert topics["/input/altitude"] == sent["GLOBAL_POSITION_INT"] > 0  # requested with gravity aiding
    matches = [json.loads(p) for _t, _ns, p in iter_payloads(out, "/gravity/match")]
    accepted = [m for m in matches if m["accepted"]]
    assert len(matches) >= 3 and accepted
    assert all(m["track_m"] >= 2 * 2000.0 for m in accepted)  # >= 2 map cells (~2.9 km here) of track
    assert topics["/input/position_fix"] == len(accepted)
    assert any(b'"position_fix"' in p for _t, _ns, p in iter_payloads(out, "/estimation/update"))
    assert "fixes fused" in stdout
    gi = [r for r in recs if r["event"] == "gps_input" and "err_h_m" in r]
    assert np.median([r["err_h_m"] for r in gi]) < 5.0  # GNSS on throughout: metre level
    # ~7200 states at 10 Hz over the 0.2 h: each one is sent, or withheld because its input had arrived too long ago
    # (a loaded machine leaves the companion behind the x10 stream: how many is the machine's, not the code's)
    inj = summarize(out).metadata_dict("Injector")
    withheld = sum(int(v) for k, v in inj.items() if k.startswith("dropped.stale"))
    assert len(gi) > 1000 and len(gi) + withheld > 6500, (len(gi), withheld, inj)


def test_readings_marked_uncorrected_reach_the_stage_so(tmp_path):
    """gravity.eotvos_corrected = false: the link's readings say they still hold the Eotvos term (the sequential stage
    then corrects them); other matchers cannot, so the setting is refused for them."""
    dec = MavlinkDecoder(gravity=NamedValueGravityDecoder("GRAV", eotvos_corrected=False))
    dec.decode(_msgs(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))[0], 0.0)
    dec.decode(_msgs(mav.MAVLink_attitude_message(10_000, 0, 0, 0, 0, 0, 0))[0], 0.0)
    out = dec.decode(_msgs(mav.MAVLink_named_value_float_message(10_500, b"GRAV", 12.5))[0], 0.1)
    (r,) = [e for e in out if isinstance(e, GravityReading)]
    assert r.eotvos_corrected is False and r.gravity_mgal == 12.5
    assert NamedValueGravityDecoder("GRAV").reading(1.0, 2.0).eotvos_corrected is True
    grid = tmp_path / "m.nc"
    grid.write_bytes(b"")
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[link]\nconnect = "udpin:127.0.0.1:14550"\n[gravity]\nmap = "{grid}"\neotvos_corrected = false\n')
    with pytest.raises(ConfigError, match="eotvos_corrected"):
        load_config(cfg)
