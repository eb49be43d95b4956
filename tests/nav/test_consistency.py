"""Consistency of the autopilot's tilt (covariance matching against GNSS) on simulated flights with known truth."""

import dataclasses
import math

import numpy as np
import pytest

from companion.events import Attitude
from companion.nav.consistency import NisMonitor
from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import MeasurementUpdate
from companion.sim.circle import SimNoise, simulate_circle_flight
from tests.helpers import tilted_in_ned

RECEIVER = SimNoise(gnss_std_h_m=0.5, gnss_std_v_m=0.8)


def test_monitor_mean_is_time_weighted_and_inflation_at_least_one():
    for rate_hz in (1.0, 10.0, 50.0):  # the window is time, not a count: the source's rate does not matter
        m = NisMonitor(tau_s=10.0, min_weight_s=3.0)
        ts = np.arange(0.0, 60.0, 1.0 / rate_hz)
        for t in ts:
            m.add(float(t), 4.0 if t >= 30.0 else 0.5, 1)
        assert m.ratio() == pytest.approx(4.0, rel=0.06)  # 30 s = 3 tau after the step
        assert m.inflation() == pytest.approx(m.ratio())
    m = NisMonitor(tau_s=10.0, min_weight_s=3.0)
    for t in np.arange(0.0, 30.0, 0.1):
        m.add(float(t), 1.0, 2)  # NIS 1 on 2 dof: better than modelled
    assert m.ratio() == pytest.approx(0.5) and m.inflation() == 1.0
    m = NisMonitor(tau_s=10.0, min_weight_s=3.0)
    for t in (0.0, 0.5, 1.0):
        m.add(t, 50.0, 1)
    assert m.inflation() == 1.0  # not enough evidence yet
    with pytest.raises(ValueError):
        NisMonitor(tau_s=0.0)


def _tilt_variance_factor(kind: str, seed: int, config: NavigatorConfig) -> tuple[float, list[MeasurementUpdate]]:
    """Mean fused tilt variance / the nominal one, over the attitude updates after the first 10 s."""
    sim = simulate_circle_flight(60.0, np.random.default_rng(seed), noise=RECEIVER)
    events = []
    for e in sim.events:
        if isinstance(e, Attitude):
            if kind == "tilt3":
                e = tilted_in_ned(e, math.radians(3.0))
            elif kind == "yaw90":
                e = dataclasses.replace(e, yaw_rad=float((e.yaw_rad + math.pi / 2 + math.pi) % (2 * math.pi) - math.pi))
        events.append(e)
    ups = [u for u in run_navigator(events, config) if isinstance(u, MeasurementUpdate) and u.kind == "attitude"]
    s = np.array([u.sigma[0] for u in ups if u.t_s > sim.truth_t_s[0] + 10.0])
    return (float(np.mean((s / config.att_sigma_tilt_rad) ** 2)) if s.size else math.nan), ups


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_consistent_autopilot_fully_fused_biased_one_deweighted(seed):
    """Truth + white noise of the nominal sigma: its tilt is fused with the nominal variance (factor <= 1.1 on
    average; it is never rejected). Tilted 3 deg in the navigation frame (under 2 x the nominal 1.7 deg sigma): the
    residual against GNSS shows it and its variance grows (>= 1.2 x). Off, neither changes."""
    on = NavigatorConfig(att_consistency=True)
    ok, ups = _tilt_variance_factor("none", seed, on)
    assert ok <= 1.1, ok
    assert all(u.accepted for u in ups)
    biased, _ = _tilt_variance_factor("tilt3", seed, on)
    assert biased >= 1.2 and biased > ok + 0.15, (ok, biased)
    off = NavigatorConfig(att_consistency=False)
    assert _tilt_variance_factor("tilt3", seed, off)[0] == pytest.approx(1.0)


def test_heading_off_autopilot_tilt_deweighted_then_not_fused_when_configured():
    """Heading 90 deg off (the Erle PXF case). Until the heading check has measured the offset and flagged the
    autopilot (its heading-induced tilt term then takes over), only the residual against GNSS can de-weight its tilt:
    on, it does; off, the tilt is fused at the nominal sigma until the flag. With fuse_flagged_tilt off, the tilt is
    not fused at all once flagged."""
    nominal = NavigatorConfig().att_sigma_tilt_rad
    _f, ups_off = _tilt_variance_factor("yaw90", 21, NavigatorConfig(att_consistency=False))
    t_flag = min(u.t_s for u in ups_off if u.sigma[0] > 3.0 * nominal)
    assert all(u.sigma[0] == pytest.approx(nominal) for u in ups_off if u.t_s < t_flag)
    _f, ups = _tilt_variance_factor("yaw90", 21, NavigatorConfig(att_consistency=True))
    assert max(u.sigma[0] for u in ups if u.t_s < t_flag) > 1.5 * nominal
    _f, ups_drop = _tilt_variance_factor("yaw90", 21, NavigatorConfig(att_consistency=True, fuse_flagged_tilt=False))
    assert 0 < len(ups_drop) < 0.5 * len(ups)  # fused until the heading check flags the autopilot, then never
    last = max(u.t_s for u in ups_drop)
    assert last < t_flag + 1.0 and sum(u.t_s > last + 10.0 for u in ups) > 100  # by default still fused, de-weighted


def test_no_tilt_reset_onto_an_autopilot_gnss_shows_wrong():
    """The autopilot's roll jumps 0.5 rad while the vehicle does not: its updates are rejected, and without the
    monitor 50 rejections reset the INS tilt onto it (companion.nav.recovery). The GNSS residual shows the autopilot
    wrong, so with the monitor its tilt is de-weighted instead: no reset, and the INS roll stays much closer to
    truth (still pulled: about 9 deg off, against 28 deg after the reset)."""
    from companion.nav.outputs import FusedState, NavigatorReset

    sim = simulate_circle_flight(40.0, np.random.default_rng(8), noise=RECEIVER)
    t0 = sim.events[0].t_s
    events = [dataclasses.replace(e, roll_rad=e.roll_rad + 0.5) if isinstance(e, Attitude) and e.t_s >= t0 + 20.0
              else e for e in sim.events]
    true_roll = {round(e.t_s, 1): e.roll_rad for e in sim.events if isinstance(e, Attitude)}
    med = {}
    for on in (False, True):
        out = run_navigator(events, NavigatorConfig(att_consistency=on))
        assert any(isinstance(o, NavigatorReset) and o.kind == "attitude_rejected" for o in out) == (not on)
        err = [abs(o.roll_rad - true_roll[round(o.t_s, 1)]) for o in out
               if isinstance(o, FusedState) and o.t_s > t0 + 22.0 and round(o.t_s, 1) in true_roll]
        med[on] = np.degrees(np.median(err))
    assert med[False] > 20.0 and med[True] < 0.5 * med[False], med


def test_streaming_equals_batch_with_the_monitor_on():
    """The monitor is fed from reordered fixes only: late-arriving types give the same output as the sorted batch."""
    from companion.events import GnssFix, ImuSample
    from companion.nav.navigator import Navigator

    sim = simulate_circle_flight(30.0, np.random.default_rng(5), noise=RECEIVER)
    events = [tilted_in_ned(e, math.radians(3.0)) if isinstance(e, Attitude) else e for e in sim.events]
    cfg = NavigatorConfig(att_consistency=True)
    batch = run_navigator(events, cfg)
    delay = {GnssFix: 0.15, ImuSample: 0.0}
    nav = Navigator(cfg)
    stream = []
    for ev in sorted(events, key=lambda e: e.t_s + delay.get(type(e), 0.05)):
        stream.extend(nav.process(ev))
    stream.extend(nav.finish())
    assert nav.heading.tilt_nis.inflation() > 1.0  # the monitor acted
    assert [o.to_dict() for o in stream] == [o.to_dict() for o in batch]
