"""The trust monitor (companion.nav.trust) and the takeover it decides (companion.inject, activate = "takeover"): on
scripted item streams for each measure, and on simulated flights with known truth, where the INS after a manoeuvring
lap carries the vehicle through an outage and the INS after a hover does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.events import GnssFix, SystemTime
from companion.inject.gps_input import GpsInputRecord, InjectConfig, Injector, InjectorState
from companion.nav.navigator import Navigator, NavigatorConfig
from companion.nav.outputs import FusedState, MeasurementUpdate, ModeChange, NavigatorReset
from companion.nav.trust import TrustConfig, TrustMonitor, TrustVerdict
from companion.pipeline.core import Pipeline
from companion.sim.flight import CANBERRA_FIELD, SimConfig, simulate_flight
from companion.sim.trajectory import Climb, FlightProfile, Hold
from companion.sim.waypoints import legs_through_waypoints
from tests.helpers import Collect, flight_events

COV_FIT = (1.0,) * 8 + (0.01**2, 0.05**2, 0.05**2) + (1e-4,) * 4  # heading 0.01 rad, biases 0.07 m/s^2


def _fix(t, vn, ve, fix_type=3, instance=0):
    return GnssFix(t, fix_type, -35.0, 149.0, 600.0, vn, ve, 0.0, None, None, 10, 0.8, 1.2, 0.5, 0.8, 0.2, None, None,
                   instance=instance)


def _state(t, cov=COV_FIT, mode="ins"):
    return FusedState(t, -35.0, 149.0, 600.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, cov, 1.0, 1.0, mode, "gnss",
                      (0.0, 0.0, 0.0), 0, 0.1)


def _nis(t, nis, accepted=True):
    return MeasurementUpdate(t, "gnss_pos", "ins", (0.1, 0.1, 0.1), (1.0, 1.0, 1.0), nis, 16.27, accepted)


def _run(mon, t_end, vel=lambda t: (0.0, 0.0), t0=0.0, cov=COV_FIT, nis=1.0):
    """Feed 10 Hz receiver fixes with velocity vel(t), their innovations (NIS nis) and states; the last verdict."""
    for k in range(int((t_end - t0) * 10)):
        t = t0 + k / 10
        mon.observe(_fix(t, *vel(t)))
        mon.observe(_nis(t, nis))
        mon.observe(_state(t, cov))
    return mon.verdict


def _square_velocity(t, speed=8.0, leg_s=12.5):
    """North, east, south, west legs at 8 m/s: accelerations in both horizontal directions."""
    k = int(t // leg_s) % 4
    return [(speed, 0.0), (0.0, speed), (-speed, 0.0), (0.0, -speed)][k]


def test_fit_after_manoeuvres_in_two_directions():
    v = _run(TrustMonitor(), 60.0, _square_velocity)
    assert v.fit and v.reason == "fit" and v.manoeuvre_mps > 5.0 and v.aided_s >= 59.0


def test_a_hover_or_a_straight_line_is_not_enough():
    hover = _run(TrustMonitor(), 60.0)
    assert not hover.fit and "manoeuvres" in hover.reason and hover.manoeuvre_mps < 0.01
    line = _run(TrustMonitor(), 60.0, lambda t: (min(t, 8.0), 0.0))  # accelerates north only
    assert not line.fit and "manoeuvres" in line.reason and line.manoeuvre_mps < 0.01


@pytest.mark.parametrize("cov,nis,words", [
    (COV_FIT[:8] + (0.2**2,) + COV_FIT[9:], 1.0, "heading sigma"),
    (COV_FIT[:9] + (0.3**2, 0.3**2) + COV_FIT[11:], 1.0, "accelerometer bias sigma"),
    (COV_FIT, 15.0, "GNSS innovations 5.0x"),  # NIS 15 over 3 degrees of freedom
])
def test_each_measure_can_refuse(cov, nis, words):
    v = _run(TrustMonitor(), 60.0, _square_velocity, cov=cov, nis=nis)
    assert not v.fit and words in v.reason


def test_too_short_an_alignment_and_the_kinematic_mode():
    assert "INS aided for" in _run(TrustMonitor(), 20.0, _square_velocity).reason
    mon = TrustMonitor()
    _run(mon, 60.0, _square_velocity)
    assert mon.observe(_state(60.0, cov=(1.0,) * 6, mode="kinematic"))
    assert not mon.verdict.fit and "kinematic" in mon.verdict.reason


def test_a_reinitialisation_forgets_the_alignment_and_a_refusal_waits():
    mon = TrustMonitor()
    _run(mon, 60.0, _square_velocity)
    mon.observe(NavigatorReset(60.0, "reinit", "stream gap", "ins", math.nan, math.nan))
    v = _run(mon, 80.0, t0=60.05)  # hovering after the reset: nothing learnt since
    assert not v.fit and ("INS aided" in v.reason or "manoeuvres" in v.reason)
    mon = TrustMonitor()
    _run(mon, 60.0, _square_velocity)
    mon.observe(_nis(60.0, 30.0, accepted=False))
    assert not _run(mon, 65.0, _square_velocity, t0=60.05).fit  # refused 5 s ago
    assert _run(mon, 75.0, _square_velocity, t0=65.05).fit
    mon.observe(ModeChange(75.0, "kinematic", "IMU lost", 0.0))
    assert not _run(mon, 76.0, _square_velocity, t0=75.05).fit


def test_verdicts_are_reported_at_their_interval_and_on_change():
    mon = TrustMonitor(TrustConfig(report_interval_s=1.0))
    out = []
    for k in range(600):
        t = k / 10
        mon.observe(_fix(t, *_square_velocity(t)))
        mon.observe(_nis(t, 1.0))
        out += mon.observe(_state(t))
    assert all(isinstance(v, TrustVerdict) for v in out)
    changes = [v for a, v in zip(out, out[1:]) if a.fit != v.fit]
    assert len(changes) == 1 and 55 <= len(out) <= 62  # ~1 Hz, plus the change to fit


def test_config_bounds():
    with pytest.raises(ValueError):
        TrustConfig(max_yaw_sigma_rad=0.0)
    with pytest.raises(ValueError):
        TrustConfig(min_aided_s=-1.0)


# -- on simulated flights ------------------------------------------------------------------------------------------------
def _square(laps, side_m=100.0, speed_mps=8.0):
    return legs_through_waypoints([(side_m, 0.0), (side_m, side_m), (0.0, side_m), (0.0, 0.0)] * laps,
                                  start_ne_m=(0.0, 0.0), start_heading_deg=0.0, speed_mps=speed_mps, turn_radius_m=20.0)


def _takeover_flight(pre_laps: int, hover_s: float, seed: int = 3, deny_s: float = 30.0):
    """Take-off, a hover, ``pre_laps`` laps, then GNSS lost while the vehicle flies three more laps; the navigator and
    an injector in takeover (shadow) mode. Returns (verdict at the loss, takeover state, records in the outage with
    their errors against the truth)."""
    pre = [Hold(4.0, mode="STABILIZE"), Hold(2.0, mode="GUIDED"), Climb(20.0, rate_mps=2.5), Hold(hover_s)]
    pre += _square(pre_laps) if pre_laps else []
    t0 = FlightProfile(pre, CANBERRA_FIELD, start_heading_deg=0.0).duration_s
    sim = simulate_flight(FlightProfile(pre + _square(3), CANBERRA_FIELD, start_heading_deg=0.0), seed,
                          SimConfig(gnss_rate_hz=5.0, imu2=None))
    sink = Collect()
    pipe = Pipeline(stages=[Navigator(NavigatorConfig()),
                            Injector(InjectConfig(mode="shadow", activate="takeover", backup_fix_when_armed=False))],
                    sink=sink)
    pipe.process(SystemTime(t_s=0.0, unix_time_s=1.74e9))  # (the vehicle's UTC: a fix is never sent without a time)
    for e in flight_events(sim, deny_s=(t0, t0 + deny_s)):
        pipe.process(e)
    pipe.finish()
    verdict = [o for o in sink.items if isinstance(o, TrustVerdict) and o.t_s <= t0 + 0.7][-1]
    state = next(o for o in sink.items if isinstance(o, InjectorState) and o.t_s >= t0)
    recs = [o for o in sink.items if isinstance(o, GpsInputRecord) and t0 + 1.0 <= o.t_s < t0 + deny_s]
    est = np.array([sim.profile.frame.to_ned_m(r.lat_deg, r.lon_deg, r.alt_msl_m) for r in recs])
    truth = sim.profile.sample(np.array([r.t_s for r in recs]))
    err = np.hypot(*(est[:, :2] - truth.pos_ned_m[:, :2]).T)
    return verdict, state, recs, err


@pytest.mark.slow
def test_takeover_after_a_lap_and_its_accuracy_stays_honest():
    verdict, state, recs, err = _takeover_flight(pre_laps=1, hover_s=10.0)
    assert verdict.fit and state.active and state.reason.startswith("takeover")
    used = np.array([r.fix_type >= 2 for r in recs])
    assert used[:50].all()  # fixes with a fix type for the first seconds: the autopilot follows them
    hacc = np.array([r.h_acc_m for r in recs])
    # the simulated drone's MEMS IMU (0.04 m/s^2, 0.001 rad/s biases): metres in seconds, and the stated accuracy
    # grows with it, so the fix type falls to 2D and then none before the error leaves its stated bounds
    assert np.mean(err[used] <= 2.0 * hacc[used]) >= 0.95
    assert err[:50].max() < 5.0


@pytest.mark.slow
@pytest.mark.parametrize("hover_s", [10.0, 90.0])
def test_no_takeover_after_only_a_hover(hover_s):
    verdict, state, recs, err = _takeover_flight(pre_laps=0, hover_s=hover_s)
    assert not verdict.fit and not state.active and state.reason.startswith("no takeover")
    assert all(r.fix_type <= 1 for r in recs)  # the autopilot gets no fix: it dead-reckons alone
