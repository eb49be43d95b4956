"""PositionFix: a non-GNSS horizontal position measurement fused by the Navigator."""

import numpy as np

from companion.nav.navigator import run_navigator
from companion.nav.outputs import FusedState, MeasurementUpdate
from companion.sim.circle import SimNoise, simulate_circle_flight
from companion.events import GnssFix, PositionFix

CUT_S = 20.0


def _herr(sim, out, t_from):
    fused = [o for o in out if isinstance(o, FusedState) and o.t_s >= t_from]
    t = np.array([o.t_s for o in fused])
    est = np.array([sim.frame.to_ned_m(o.lat_deg, o.lon_deg, o.alt_msl_m)[:2] for o in fused])
    tp = np.stack([np.interp(t, sim.truth_t_s, sim.truth_pos_ned_m[:, i]) for i in range(2)], 1)
    return np.hypot(*(est - tp).T)


def _fixes(sim, rng, sigma_m, period_s, t_from, outlier_at=None):
    t = np.arange(t_from + period_s, sim.truth_t_s[-1], period_s)
    fixes = []
    for tk in t:
        n, e = (np.interp(tk, sim.truth_t_s, sim.truth_pos_ned_m[:, i]) + rng.normal(0, sigma_m) for i in range(2))
        if outlier_at is not None and abs(tk - outlier_at) < period_s / 2:
            n += 5000.0
        lat, lon, _ = sim.frame.to_geodetic(np.array([n, e, 0.0]))
        fixes.append(PositionFix(float(tk), float(lat), float(lon), sigma_m, sigma_m, "test"))
    return fixes


def test_position_fixes_bound_the_error_after_gnss_cut_and_gate_rejects_outlier():
    noise = SimNoise(accel_bias_mps2=(0.08, -0.06, 0.05), gyro_bias_radps=(0.004, -0.003, 0.002))
    sim = simulate_circle_flight(150.0, np.random.default_rng(3), noise=noise)
    t0 = sim.events[0].t_s
    events = [e for e in sim.events if not (isinstance(e, GnssFix) and e.t_s > t0 + CUT_S)]
    outlier_t = t0 + 100.0
    fixes = _fixes(sim, np.random.default_rng(7), 5.0, 2.0, t0 + CUT_S, outlier_at=outlier_t)
    free = _herr(sim, run_navigator(events), t0 + CUT_S)
    out = run_navigator(events + fixes)
    aided = _herr(sim, out, t0 + CUT_S)
    assert free.max() > 60.0, free.max()  # the INS alone drifts away ...
    assert aided[-300:].max() < 15.0, aided[-300:].max()  # ... fixes at sigma 5 m keep it near truth
    assert aided.max() < 0.5 * free.max()
    ups = [o for o in out if isinstance(o, MeasurementUpdate) and o.kind == "position_fix"]
    assert len(ups) > 0.9 * len(fixes)
    bad = [u for u in ups if abs(u.t_s - outlier_t) < 1.0]
    assert len(bad) == 1 and not bad[0].accepted and bad[0].innovation[0] > 4000.0
    assert sum(u.accepted for u in ups) >= len(ups) - 3
    assert any("position_fix" in o.measurement.split("+") for o in out if isinstance(o, FusedState))


def _verr(sim, out, t_from):
    fused = [o for o in out if isinstance(o, FusedState) and o.t_s >= t_from]
    t = np.array([o.t_s for o in fused])
    d = np.array([sim.frame.to_ned_m(o.lat_deg, o.lon_deg, o.alt_msl_m)[2] for o in fused])
    return np.abs(d - np.interp(t, sim.truth_t_s, sim.truth_pos_ned_m[:, 2]))


def test_autopilot_altitude_holds_the_height_once_gnss_is_gone():
    """GLOBAL_POSITION_INT's (barometric) altitude, 7 m off the GNSS datum: the offset is learnt while GNSS aids
    and the offset-corrected altitude holds the INS height after the cut (without it the height drifts)."""
    from companion.nav.navigator import NavigatorConfig
    from companion.events import AutopilotAltitude

    noise = SimNoise(accel_bias_mps2=(0.08, -0.06, 0.15), gyro_bias_radps=(0.004, -0.003, 0.002))
    sim = simulate_circle_flight(150.0, np.random.default_rng(5), noise=noise)
    t0 = sim.events[0].t_s
    events = [e for e in sim.events if not (isinstance(e, GnssFix) and e.t_s > t0 + CUT_S)]
    rng = np.random.default_rng(11)
    ta = np.arange(0.0, 150.0, 0.2)
    alts = [AutopilotAltitude(float(t0 + t), float(sim.frame.ref_alt_m - np.interp(t0 + t, sim.truth_t_s,
                              sim.truth_pos_ned_m[:, 2]) + 7.0 + rng.normal(0, 0.5))) for t in ta]
    cfg = NavigatorConfig(fuse_autopilot_alt=True)
    free = _verr(sim, run_navigator(events + alts), t0 + CUT_S)  # default: the altitude is not used
    out = run_navigator(events + alts, cfg)
    held = _verr(sim, out, t0 + CUT_S)
    assert free[-1] > 50.0, free[-1]
    assert held.max() < 5.0, held.max()  # offset learnt (7 m), noise 0.5 m, sigma 3 m
    ups = [o for o in out if isinstance(o, MeasurementUpdate) and o.kind == "altitude"]
    assert ups and min(u.t_s for u in ups) > t0 + CUT_S  # fused only after the cut
    assert sum(u.accepted for u in ups) > 0.95 * len(ups)


def test_position_only_fixes_leave_the_velocity_to_the_ins():
    """NavigatorConfig.position_fix_position_only: a PositionFix moves the INS position and nothing else. Fixes
    with a common 300 m offset (a running filter's slowly varying error) give the full update a velocity error from
    the cross-covariance the coast built up; the position-only update leaves the velocity as the free INS has it."""
    from companion.nav.navigator import NavigatorConfig

    noise = SimNoise(accel_bias_mps2=(0.08, -0.06, 0.05), gyro_bias_radps=(0.004, -0.003, 0.002))
    sim = simulate_circle_flight(150.0, np.random.default_rng(3), noise=noise)
    t0 = sim.events[0].t_s
    events = [e for e in sim.events if not (isinstance(e, GnssFix) and e.t_s > t0 + CUT_S)]
    fixes = []
    for f in _fixes(sim, np.random.default_rng(7), 50.0, 5.0, t0 + 60.0):
        n, e, _ = sim.frame.to_ned_m(f.lat_deg, f.lon_deg, 0.0)
        lat, lon, _ = sim.frame.to_geodetic(np.array([n + 300.0, e, 0.0]))
        fixes.append(PositionFix(f.t_s, float(lat), float(lon), 50.0, 50.0, "test"))

    def vel_err(out):
        fused = [o for o in out if isinstance(o, FusedState) and o.t_s >= t0 + 60.0]
        t = np.array([o.t_s for o in fused])
        v = np.array([(o.vel_n_mps, o.vel_e_mps) for o in fused])
        vt = np.stack([np.interp(t, sim.truth_t_s, np.gradient(sim.truth_pos_ned_m[:, i], sim.truth_t_s))
                       for i in range(2)], 1)
        return np.hypot(*(v - vt).T)

    free = vel_err(run_navigator(events))
    full = vel_err(run_navigator(events + fixes))
    only = run_navigator(events + fixes, NavigatorConfig(position_fix_position_only=True))
    ups = [o for o in only if isinstance(o, MeasurementUpdate) and o.kind == "position_fix"]
    assert sum(u.accepted for u in ups) > 0.9 * len(fixes)
    # the velocity is the free INS's (but for the position's own effect on gravity and the transport rate)
    assert np.abs(vel_err(only) - free).max() < 0.01
    assert full.max() > free.max() + 0.5  # the full update moved the velocity (here, away from the truth)


def test_a_fixs_velocity_corrects_the_velocity_only():
    """A PositionFix carrying a velocity (the sequential gravity filter's): with position_fix_position_only each part
    corrects the states it measures. True velocities at 0.2 m/s keep the velocity near the truth where the free INS
    drifts; an empty velocity (NaN) is not fused."""
    from companion.nav.navigator import NavigatorConfig

    noise = SimNoise(accel_bias_mps2=(0.08, -0.06, 0.05), gyro_bias_radps=(0.004, -0.003, 0.002))
    sim = simulate_circle_flight(150.0, np.random.default_rng(3), noise=noise)
    t0 = sim.events[0].t_s
    events = [e for e in sim.events if not (isinstance(e, GnssFix) and e.t_s > t0 + CUT_S)]
    vt_of = [np.gradient(sim.truth_pos_ned_m[:, i], sim.truth_t_s) for i in range(2)]
    rng = np.random.default_rng(5)
    pos_fixes = _fixes(sim, np.random.default_rng(7), 50.0, 5.0, t0 + 60.0)
    vel_fixes = [PositionFix(f.t_s, f.lat_deg, f.lon_deg, f.sigma_n_m, f.sigma_e_m, "test",
                             *(float(np.interp(f.t_s, sim.truth_t_s, vt_of[i])) + rng.normal(0, 0.2) for i in range(2)),
                             0.2, 0.2) for f in pos_fixes]

    def vel_err(out):
        fused = [o for o in out if isinstance(o, FusedState) and o.t_s >= t0 + 90.0]
        t = np.array([o.t_s for o in fused])
        v = np.array([(o.vel_n_mps, o.vel_e_mps) for o in fused])
        return np.hypot(*(v - np.stack([np.interp(t, sim.truth_t_s, vt_of[i]) for i in range(2)], 1)).T)

    cfg = NavigatorConfig(position_fix_position_only=True)
    pos_only = run_navigator(events + pos_fixes, cfg)
    with_vel = run_navigator(events + vel_fixes, cfg)
    ups = [o for o in with_vel if isinstance(o, MeasurementUpdate) and o.kind == "velocity_fix"]
    assert len(ups) == len(vel_fixes) and sum(u.accepted for u in ups) > 0.9 * len(ups)
    assert not any(isinstance(o, MeasurementUpdate) and o.kind == "velocity_fix" for o in pos_only)
    assert vel_err(with_vel).mean() < 0.5 and vel_err(pos_only).mean() > 2 * vel_err(with_vel).mean()
