"""The sequential gravity filter as a pipeline stage (companion/gravity/sequential_stage.py): the fix it sends makes
the navigator's posterior the filter's (nothing counted twice), it follows the navigator's correction, it is pinned
to the navigator only while GNSS keeps it good, raw readings are Eotvos-corrected with the navigator's velocity, and
the [gravity] settings reach it. Truth is known in every test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.events import GravityReading, PositionFix
from companion.gravity.eotvos import eotvos_from_ne_mgal
from companion.gravity.maps import GravityMap, LocalGravityMap
from companion.gravity.placement import Placement
from companion.gravity.sequential import SeqGravConfig
from companion.gravity.sequential_stage import SequentialGravityStage, SequentialRecord, channel_fix
from companion.nav.frame import LocalFrame
from companion.nav.outputs import FrameInfo, FusedState

REF = (-40.0, 155.0, 0.0)
FRAME = LocalFrame(*REF)


def _map() -> LocalGravityMap:
    rng = np.random.default_rng(3)
    ax = np.arange(-60_000.0, 60_001.0, 500.0)
    N, E = np.meshgrid(ax, ax, indexing="ij")
    g = np.zeros_like(N)
    for _ in range(300):
        c = rng.uniform(-60_000.0, 60_000.0, 2)
        w = rng.uniform(2000.0, 5000.0)
        g += rng.normal(0.0, 20.0) * np.exp(-((N - c[0]) ** 2 + (E - c[1]) ** 2) / (2 * w * w))
    return LocalGravityMap(GravityMap(g, ax, ax, "local_m"))


MAP = _map()


def _state(t, ne, vel, sigma_m, gnss_age_s, measurement="none", yaw=None, sigma_v_mps=None):
    lat, lon, alt = FRAME.geodetic_tuple(ne[0], ne[1], 0.0)
    var = sigma_m**2 / 2.0
    yaw = math.atan2(vel[1], vel[0]) if yaw is None else yaw
    cov = (var, var, 1.0) if sigma_v_mps is None else (var, var, 1.0, sigma_v_mps**2, sigma_v_mps**2, 1.0)
    return FusedState(t, lat, lon, alt, ne[0], ne[1], 0.0, vel[0], vel[1], 0.0, 0.0, 0.0, yaw, cov,
                      sigma_m, 1.0, "ins", measurement, (math.nan,) * 3, 0, gnss_age_s)


def test_channel_fix_makes_the_navigator_posterior_the_filters():
    rng = np.random.default_rng(0)
    for _ in range(50):
        x, p_nav = rng.normal(0, 1000), rng.uniform(1e4, 1e7)
        m, p_f = rng.normal(0, 1000), p_nav * rng.uniform(0.01, 0.85)
        z, r = channel_fix(m, p_f, x, p_nav, 0.1)
        k = p_nav / (p_nav + r)  # the navigator's Kalman update with the fix
        assert x + k * (z - x) == pytest.approx(m, rel=1e-9, abs=1e-6)
        assert (1 - k) * p_nav == pytest.approx(p_f, rel=1e-9)
    assert channel_fix(0.0, 95.0, 0.0, 100.0, 0.1) is None  # not 10 % more certain: nothing to add
    assert channel_fix(0.0, 100.0, 0.0, 100.0, 0.0) is None


def _run(stage, n_s, cut_s, drift_mps=(0.3, -0.2), jump_at=None, jump=(0.0, 0.0), readings=True, vel_error=False):
    """A ship at 8 m/s heading 60 deg; the navigator is the truth until cut_s, then drifts at drift_mps; its
    sigma grows at 5 m/s after the cut. FusedState at 10 Hz, readings (the map at the truth) at 1 Hz. vel_error:
    the navigator's velocity is off by the drift too (else it reports the true velocity), with a 1 m/s sigma."""
    v = 8.0 * np.array([math.cos(math.radians(60)), math.sin(math.radians(60))])
    out = [stage.process(FrameInfo(0.0, *REF))]
    offset = np.zeros(2)
    jumped = False
    for k in range(int(n_s * 10) + 1):
        t = k / 10.0
        truth = v * t - np.array([20_000.0, 20_000.0])
        after = max(t - cut_s, 0.0)
        nav = truth + np.asarray(drift_mps) * after + offset
        meas = "none"
        if jump_at is not None and not jumped and t >= jump_at and stage._fix_out:
            offset = offset + np.asarray(jump)
            nav = nav + np.asarray(jump)
            meas, jumped = "position_fix", True
        sigma = 2.0 if t < cut_s else 2.0 + 5.0 * after
        v_nav = v + (np.asarray(drift_mps) if vel_error and t >= cut_s else 0.0)
        out.append(stage.process(_state(t, nav, v_nav, sigma, 0.0 if t < cut_s else after, meas,
                                        sigma_v_mps=(0.05 if t < cut_s else 1.0) if vel_error else None)))
        if readings and k % 10 == 0:
            g = float(MAP.interp_ne(*truth))
            out.append(stage.process(GravityReading(t, g, 0.5)))
    return [o for batch in out for o in batch], jumped


def test_stage_pins_to_gnss_then_sends_fixes_and_follows_the_correction():
    stage = SequentialGravityStage(MAP, SeqGravConfig(n_particles=300), Placement(), sigma_mgal=0.5, seed=1)
    out, _ = _run(stage, 900.0, 300.0)
    recs = [o for o in out if isinstance(o, SequentialRecord)]
    fixes = [o for o in out if isinstance(o, PositionFix)]
    t = np.array([r.t_s for r in recs])
    st = np.array([r.status for r in recs])
    assert set(st[t < 299.0]) == {"anchored"} and "anchored" not in set(st[t > 302.0])
    assert fixes and all(f.t_s > 300.0 for f in fixes) and all(r.sent == (r.status == "ok") or not r.sent for r in recs)
    # a fix claims less than the filter knows (1/R = 1/P_filter - 1/P_nav per axis): R_n + R_e >= trace P_filter
    by_t = {r.t_s: r for r in recs}
    for f in fixes:
        assert f.sigma_n_m**2 + f.sigma_e_m**2 >= by_t[f.t_s].h_acc_m**2 * 0.999

    # the navigator fuses a fix: its position jumps 400 m north, 250 m west; the filter's estimate does not move
    stage2 = SequentialGravityStage(MAP, SeqGravConfig(n_particles=300), Placement(), sigma_mgal=0.5, seed=1)
    captured = {}
    orig = stage2.filter.apply_correction

    def spy(d_pos, d_vel=None):
        captured["before"] = stage2.filter.be.moments()[0].copy()
        orig(d_pos, d_vel)
        captured["after"] = stage2.filter.be.moments()[0].copy()
        captured["d"] = (np.asarray(d_pos), np.asarray(d_vel))

    stage2.filter.apply_correction = spy
    _, jumped = _run(stage2, 700.0, 300.0, jump_at=600.0, jump=(400.0, -250.0))
    assert jumped and stage2.n_corrections == 1
    d_pos, d_vel = captured["d"]
    np.testing.assert_allclose(d_pos, [400.0, -250.0], atol=0.5)  # the jump, beyond 0.1 s of motion at 8 m/s
    np.testing.assert_allclose(d_vel, [0.0, 0.0], atol=0.05)
    np.testing.assert_allclose(captured["after"] - captured["before"], d_pos, atol=1e-6)  # error = nav - truth


def test_not_pinned_when_the_navigator_is_good_without_gnss():
    """A navigator 2 m good but with no GNSS for minutes (e.g. after our own fixes) does not pin the filter."""
    stage = SequentialGravityStage(MAP, SeqGravConfig(n_particles=200), Placement(), sigma_mgal=0.5)
    stage.process(FrameInfo(0.0, *REF))
    v = np.array([8.0, 0.0])
    statuses = []
    for k in range(0, 600):
        t = k / 10.0
        ne = v * t
        out = stage.process(_state(t, ne, v, 2.0, 300.0 + t))
        if k % 10 == 0:
            out += stage.process(GravityReading(t, float(MAP.interp_ne(*ne)), 0.5))
        statuses += [o.status for o in out if isinstance(o, SequentialRecord)]
    assert statuses and "anchored" not in statuses


def test_raw_readings_are_eotvos_corrected_with_the_navigator_velocity():
    stage = SequentialGravityStage(MAP, SeqGravConfig(n_particles=100), Placement(), sigma_mgal=0.5)
    fed = []
    stage.filter.feed = lambda t, g, *a, **kw: fed.append((g, kw["eotvos_from_reference"])) or None
    stage.process(FrameInfo(0.0, *REF))
    v = np.array([3.0, 7.0])
    stage.process(_state(0.0, (0.0, 0.0), v, 2.0, 0.0))
    stage.process(GravityReading(0.05, 100.0, 0.5, eotvos_corrected=False))
    stage.process(GravityReading(0.06, 100.0, 0.5))
    stage.process(_state(0.1, v * 0.1, v, 2.0, 0.0))
    lat = REF[0]
    assert fed[0][0] == pytest.approx(100.0 - float(eotvos_from_ne_mgal(v, lat)), abs=1e-3) and fed[0][1] is True
    assert fed[1] == (100.0, False)


def test_gravity_settings_reach_the_live_stage(tmp_path):
    from companion.config import ConfigError, load_config
    from companion.gravity.stage import live_gravity_stage
    from tests.conftest import SHARED, require

    tasman = require(SHARED / "data" / "gravity" / "tasman_grav_west_145E-160E.nc")
    base = {"link.connect": "udpin:127.0.0.1:14550", "gravity.map": str(tasman), "gravity.matcher": "sequential"}
    cfg = load_config(None, {**base, "gravity.seq_particles": 400, "gravity.seq_gyro_bias_degph": 0.5,
                             "gravity.seq_min_gain": 0.3, "gravity.seq_velocity_fixes": True})
    stage = live_gravity_stage(cfg.gravity)
    assert isinstance(stage, SequentialGravityStage) and stage.view.geographic
    assert stage.cfg.n_particles == 400 and stage.cfg.ins.gyro_bias_degph == 0.5 and stage.min_gain == 0.3
    assert stage.velocity_fixes and not live_gravity_stage(load_config(None, base).gravity).velocity_fixes
    with pytest.raises(ConfigError, match="seq_particles"):
        load_config(None, {**base, "gravity.seq_particles": 5})
    with pytest.raises(ConfigError, match="seq_min_gain"):
        load_config(None, {**base, "gravity.seq_min_gain": 1.5})


def test_velocity_fixes_carry_the_filters_estimate_of_the_navigators_velocity():
    """The navigator's velocity is 0.36 m/s off after the cut (its position drifts with it): with velocity_fixes the
    fixes carry a velocity nearer the truth than the navigator's, with a sigma that covers its error; without, none."""
    v_true = 8.0 * np.array([math.cos(math.radians(60)), math.sin(math.radians(60))])
    stage = SequentialGravityStage(MAP, SeqGravConfig(n_particles=300), Placement(), sigma_mgal=0.5, seed=1,
                                   velocity_fixes=True)
    out, _ = _run(stage, 1500.0, 300.0, vel_error=True)
    fixes = [o for o in out if isinstance(o, PositionFix) and math.isfinite(o.vel_n_mps)]
    late = [f for f in fixes if f.t_s > 900.0]
    assert len(late) > 100
    err = np.array([[f.vel_n_mps - v_true[0], f.vel_e_mps - v_true[1]] for f in late])
    sig = np.array([[f.sigma_vn_mps, f.sigma_ve_mps] for f in late])
    e_h = np.hypot(err[:, 0], err[:, 1])
    assert e_h[-100:].mean() < 0.5 * math.hypot(0.3, -0.2) and e_h[-100:].mean() < e_h[:100].mean()
    assert np.mean(np.abs(err) <= 2.0 * sig) >= 0.9

    plain = SequentialGravityStage(MAP, SeqGravConfig(n_particles=300), Placement(), sigma_mgal=0.5, seed=1)
    out2, _ = _run(plain, 400.0, 300.0, vel_error=True)
    fixes2 = [o for o in out2 if isinstance(o, PositionFix)]
    assert fixes2 and all(math.isnan(f.vel_n_mps) and math.isnan(f.sigma_vn_mps) for f in fixes2)
