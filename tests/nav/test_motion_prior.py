"""The motion prior (companion.nav.motion_prior): its learnt statistics predict a loitering vehicle's motion with an
honest variance, stationary fixes teach it nothing, the product with the filter weighs each by its variance, and
on a simulated loiter with a tilted autopilot the full navigator is no worse than hold-last-fix."""

import math

import numpy as np
import pytest

from companion.nav.motion_prior import MotionPrior, MotionPriorConfig, blend
from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import FusedState
from companion.sim.flight import CANBERRA_FIELD, SimConfig, simulate_flight
from companion.sim.sensors import AttitudeEstimateModel, ImuModel
from companion.sim.trajectory import Climb, FlightProfile, Hold, Speed, Turn
from tests.helpers import flight_events


def _loiter(rng, n_s=1200, sigma_v=1.0, tau_s=8.0):
    """1 Hz positions and velocities of a loitering vehicle: an Ornstein-Uhlenbeck velocity per horizontal axis."""
    v = np.zeros((n_s, 3))
    a = math.exp(-1.0 / tau_s)
    for k in range(1, n_s):
        v[k, :2] = a * v[k - 1, :2] + rng.normal(0, sigma_v * math.sqrt(1 - a * a), 2)
    p = np.cumsum(v, axis=0)
    return np.arange(n_s, dtype=float), p, v


def test_prior_is_calibrated_on_a_loiter():
    """Predictions made causally from the learnt statistics at ages 5, 15, 30 s: normalised squared error ~1."""
    t, p, v = _loiter(np.random.default_rng(3))
    mp = MotionPrior(MotionPriorConfig(variance_scale=1.0, tau_s=600.0, blend_min_age_s=1.5))  # 5 s predictions too
    z2 = {5: [], 15: [], 30: []}
    for k in range(len(t)):
        mp.add_fix(t[k], p[k], v[k], (0.01, 0.01, 0.01))
        if k < 300:  # learning
            continue
        for age in z2:
            if k + age < len(t):
                mean, var, _ins = mp.predict(t[k] + age)
                z2[age].append(float(np.mean((p[k + age, :2] - mean[:2]) ** 2 / var[:2])))
    for age, z in z2.items():
        assert 0.6 < np.mean(z) < 1.6, (age, np.mean(z))
    # at 30 s a loiter is better predicted by holding than by extrapolating the velocity
    mean, _var, _ = mp.predict(t[-1] + 30.0)
    hold, cv = p[-1], p[-1] + v[-1] * 30.0
    assert np.linalg.norm(mean[:2] - hold[:2]) < np.linalg.norm(mean[:2] - cv[:2]) or np.allclose(hold, cv)


def test_no_prior_before_min_age_or_without_pairs():
    mp = MotionPrior()
    assert mp.predict(10.0) is None
    mp.add_fix(0.0, (0, 0, 0), (0, 0, 0), (0.1, 0.1, 0.1))
    assert mp.predict(5.0) is None  # one fix: no pair yet
    with pytest.raises(ValueError):
        MotionPriorConfig(min_pairs=0.0)
    with pytest.raises(ValueError):
        MotionPriorConfig(blend_min_age_s=-1.0)


def test_the_product_with_the_ins_starts_later_than_the_selection():
    """predict (INS mode's product) answers from blend_min_age_s on, select (kinematic mode) from min_age_s on."""
    t, p, v = _loiter(np.random.default_rng(4), n_s=200)
    mp = MotionPrior(MotionPriorConfig(min_age_s=1.5, blend_min_age_s=6.0, min_pairs=2.0))
    for k in range(len(t)):
        mp.add_fix(t[k], p[k], v[k], (0.01, 0.01, 0.01), ins=(p[k], v[k], p[k], v[k]), ins_epoch=0)
    last = t[-1]
    assert mp.predict(last + 5.9) is None
    assert mp.predict(last + 6.0) is not None
    assert mp.select(last + 1.4, p[-1]) is None
    assert mp.select(last + 2.0, p[-1]) is not None


def test_stationary_fixes_start_no_pair():
    """Two minutes on the ground, then moving: the statistics come from the moving fixes only."""
    mp = MotionPrior(MotionPriorConfig(tau_s=1e6))
    for k in range(120):
        mp.add_fix(float(k), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.01,) * 3, stationary=True)
    for k in range(120, 140):
        mp.add_fix(float(k), (3.0 * (k - 120), 0.0, 0.0), (3.0, 0.0, 0.0), (0.01,) * 3)
    assert mp._w[5] == pytest.approx(15.0, rel=1e-3)  # pairs start at the moving fixes 120 .. 134 only
    assert mp._hh[5, 0] / mp._w[5] > 100.0  # moving 15 m in 5 s, not the ground's zero


def test_blend_weighs_by_variance_and_widens_a_contradicted_prior():
    prior = (np.array([4.0, 4.0, 0.0]), np.array([4.0, 4.0, 4.0]), None)
    out, var = blend((0.0, 0.0, 0.0), (4.0, 4.0, 4.0), prior, consistency_sigma=3.0)
    assert out == pytest.approx([2.0, 2.0, 0.0])  # equal variances: the midpoint
    # claimed as the two estimates mixed half and half, their 4 m disagreement included (not the product's 2 m^2)
    assert var == pytest.approx([0.5 * 4 + 0.5 * 4 + 0.25 * 16, 0.5 * 4 + 0.5 * 4 + 0.25 * 16, 4.0])
    out, _ = blend((0.0, 0.0, 0.0), (400.0, 400.0, 400.0), prior, consistency_sigma=3.0)
    assert out[0] == pytest.approx(4.0 * 400.0 / 404.0)  # a drifting filter leans on the prior
    out, _ = blend((0.0, 0.0, 0.0), (400.0, 400.0, 400.0), (prior[0], prior[1], np.array([1.0, 1.0, 1.0])), 3.0)
    assert out[0] == pytest.approx(4.0 * 1.0 / 5.0)  # ... unless its own dead-reckoning record says it does not drift
    out, _ = blend((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), prior, consistency_sigma=1.0)
    # 4 m apart at a combined sigma of sqrt(5) m: the prior is widened to agree at 1 sigma (variance 15)
    assert out[0] == pytest.approx(4.0 * 1.0 / 16.0)


def _loiter_flight(seed):
    """Tight circles (1.2 m/s, radius 4 m) for 4 minutes; the autopilot's tilt is off by ~2 deg for minutes."""
    legs = [Hold(5.0), Climb(15.0, rate_mps=2.5), Hold(3.0), Speed(1.2, max_accel_mps2=0.5),
            *[Turn(360.0, 4.0)] * 12, Speed(0.0), Hold(5.0)]
    cfg = SimConfig(imu=ImuModel(accel_noise_mps2=0.3, gyro_noise_radps=0.005, accel_bias_sigma_mps2=0.05), imu2=None,
                    attitude=AttitudeEstimateModel(roll_pitch_sigma_rad=math.radians(2.0), tau_s=300.0))
    return simulate_flight(FlightProfile(legs, CANBERRA_FIELD), seed=seed, config=cfg)


def test_full_navigator_no_worse_than_hold_on_a_loiter():
    """A 30 s blockage on four simulated loiters (seeds 1-4), pooled as the benchmark pools a log's blockages."""
    deny = (170.0, 200.0)
    sq = {True: [], False: [], "hold": []}
    for seed in (1, 2, 3, 4):
        sim = _loiter_flight(seed)
        events = flight_events(sim, gnss_every=5, deny_s=deny)
        g = sim.gnss
        last = max(k for k in range(0, len(g.t_s), 5) if g.t_s[k] < deny[0])
        hold_ne = CANBERRA_FIELD.to_ned_m(g.lat_deg[last], g.lon_deg[last], g.alt_msl_m[last])[:2]
        for on in (True, False):
            cfg = NavigatorConfig(gnss_vel_delay_s=0.0, motion_prior=on)  # the simulated receiver has no latency
            fs = [o for o in run_navigator(events, cfg) if isinstance(o, FusedState) and deny[0] <= o.t_s < deny[1]]
            ned = CANBERRA_FIELD.to_ned_m(np.array([o.lat_deg for o in fs]), np.array([o.lon_deg for o in fs]),
                                          np.array([o.alt_msl_m for o in fs]))
            tr = sim.profile.sample(np.array([o.t_s for o in fs]))
            truth = CANBERRA_FIELD.to_ned_m(tr.lat_deg, tr.lon_deg, tr.alt_msl_m)[:, :2]
            sq[on] += list(np.sum((ned[:, :2] - truth) ** 2, axis=1))
        sq["hold"] += list(np.sum((truth - hold_ne) ** 2, axis=1))
    rmse = {k: float(np.sqrt(np.mean(v))) for k, v in sq.items()}
    assert rmse[False] > 1.3 * rmse["hold"], rmse  # the INS alone loses to holding the last fix ...
    assert rmse[True] <= 1.1 * rmse["hold"], rmse  # ... the motion prior keeps the navigator within 10 % of it


def test_nonneg_blue_weights():
    """Independent models: inverse-variance weights; a model whose unconstrained weight would be negative is dropped,
    and the mix is never worse than the best single model."""
    from companion.nav.motion_prior import _nonneg_blue

    w = _nonneg_blue(np.diag([1.0, 4.0, 4.0]))
    assert w == pytest.approx([2 / 3, 1 / 6, 1 / 6])
    S = np.array([[1.0, 0.99, 0.0], [0.99, 1.0, 0.0], [0.0, 0.0, 9.0]]) * 1.0
    S[1, 1] = 1.2  # the second model: the first one's error plus a little more of the same sign
    w = _nonneg_blue(S)
    assert np.all(w >= 0) and w.sum() == pytest.approx(1.0)
    assert float(w @ S @ w) <= min(np.diag(S)) + 1e-12


def _select_run(filter_vel_noise: float, seed: int = 3):
    """A loiter fed with a filter's state at each fix: position = the fix, velocity = the mean velocity of the next
    10 s (a dead reckoning that knows where the vehicle goes) plus noise of filter_vel_noise; then a prediction 10 s
    after the last fix."""
    rng = np.random.default_rng(seed)
    t, p, v = _loiter(rng, n_s=600)
    mp = MotionPrior(MotionPriorConfig(select=True, variance_scale=1.0, tau_s=600.0))
    for k in range(len(t)):
        j = min(k + 10, len(t) - 1)
        vf = (p[j] - p[k]) / max(t[j] - t[k], 1.0) + rng.normal(0, filter_vel_noise, 3) * np.array([1, 1, 0])
        mp.add_fix(t[k], p[k], v[k], (0.01,) * 3, ins=(p[k], vf, (0.0,) * 3, (0.0,) * 3), ins_epoch=-2)
    return mp, t[-1], p[-1]


def test_select_follows_the_filter_only_as_far_as_its_record_on_this_flight_allows():
    good, t_end, p_end = _select_run(0.01)
    bad, _, _ = _select_run(3.0)
    far = tuple(p_end + (100.0, 100.0, 0.0))  # the filter's estimate at the prediction time, far from hold and CV
    assert good.select(t_end + 0.5, far) is None  # before min_age_s
    out_good, var_good = good.select(t_end + 10.0, far)
    out_bad, var_bad = bad.select(t_end + 10.0, far)
    # the dead reckoning that matched this flight's fixes at 10 s takes most of the weight ...
    assert out_good[0] - p_end[0] > 80.0 and out_good[1] - p_end[1] > 80.0
    # ... the one whose record is 3 m/s x 10 s off is all but ignored
    assert abs(out_bad[0] - p_end[0]) < 15.0 and abs(out_bad[1] - p_end[1]) < 15.0
    assert var_good[0] < var_bad[0]
    assert MotionPrior().select(1.0, far) is None


def test_select_kinematic_streaming_equals_batch():
    """Kinematic mode with the selection on: event-by-event processing gives the batch replay's outputs."""
    from companion.nav.navigator import Navigator
    from tests.nav.test_hold_cv import _kin_hover_events

    ev, _truth, _ = _kin_hover_events(np.random.default_rng(11), n=120)
    ev = [e for e in ev if not 160.0 <= e.t_s < 164.0]
    cfg = NavigatorConfig(motion=MotionPriorConfig(select=True))
    batch = run_navigator(ev, cfg)
    nav = Navigator(cfg)
    stream = [o for e in ev for o in nav.process(e)] + nav.finish()
    assert [o.to_dict() for o in stream] == [o.to_dict() for o in batch]
    used = [o.measurement for o in batch if isinstance(o, FusedState) and 161.6 <= o.t_s < 164.0]
    assert used and all("motion_prior" in u for u in used)
    off = run_navigator(ev, NavigatorConfig(motion=MotionPriorConfig(select=False)))
    assert [o.to_dict() for o in off] != [o.to_dict() for o in batch]


def test_output_selects_in_kinematic_mode_and_blends_in_ins_mode():
    """MotionPrior.output, the navigator's one call: the selection for the kinematic filter, the product for the INS
    (bounded by the learnt INS error only for an attitude-aided INS), and nothing before its age or anything learnt."""
    t, p, v = _loiter(np.random.default_rng(5), n_s=400)
    mp = MotionPrior()
    P = np.diag([4.0, 4.0, 9.0, 1.0, 1.0, 1.0])
    ned = (1.0, 2.0, 3.0)
    assert mp.output(10.0, ned, P, True, True) == (ned, P, False)  # nothing learnt
    for k in range(len(t)):  # the filter's dead reckoning from each fix: the fix plus its velocity
        rec = (p[k], v[k], p[k], v[k])
        mp.add_fix(t[k], p[k], v[k], (0.01, 0.01, 0.01), ins=rec, ins_epoch=1)
    last = t[-1]
    assert mp.output(last + 3.0, ned, P, True, True)[2] is False  # INS mode: from blend_min_age_s (6 s) only
    t8 = last + 8.0
    mean, var, ins_var = mp.predict(t8)
    assert ins_var is not None
    outs = []
    for learnt, prior in ((True, (mean, var, ins_var)), (False, (mean, var, None))):
        out, Q, applied = mp.output(t8, ned, P, True, learnt)
        want, wvar = blend(ned, (4.0, 4.0, 9.0), prior, mp.config.consistency_sigma)
        assert applied and out == pytest.approx(want) and Q.diagonal()[:3] == pytest.approx(wvar)
        assert Q[3, 3] == 1.0 and P[0, 0] == 4.0  # a new covariance, the filter's untouched
        outs.append(out)
    assert outs[0] != pytest.approx(outs[1])  # the learnt INS error bounds the filter's variance
    sel = mp.select(last + 3.0, ned)
    out, Q, applied = mp.output(last + 3.0, ned, P, False, False)  # kinematic: the per-age selection
    assert applied and out == pytest.approx(tuple(sel[0])) and Q.diagonal()[:3] == pytest.approx(sel[1])
