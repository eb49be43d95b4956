"""Navigator (KNN predictor + INS + error-state KF) on simulated flights with known truth."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from companion.nav.navigator import Navigator, NavigatorConfig, run_navigator
from companion.nav.outputs import FusedState, MeasurementUpdate, ModeChange, PredictorPoint
from companion.sim.circle import SimNoise, simulate_circle_flight
from companion.events import GnssFix, ImuSample


# a receiver whose error wanders slowly (Gauss-Markov, 30 s) by 0.5 m: errors against the true trajectory
# then measure the navigator, not the receiver's offset
RECEIVER = SimNoise(gnss_std_h_m=0.5, gnss_std_v_m=0.8)


def _fused(out, mode=None):
    return [o for o in out if isinstance(o, FusedState) and (mode is None or o.mode == mode)]


def _errors(sim, fused):
    t = np.array([o.t_s for o in fused])
    est = np.array([sim.frame.to_ned_m(o.lat_deg, o.lon_deg, o.alt_msl_m) for o in fused])
    vel = np.array([[o.vel_n_mps, o.vel_e_mps, o.vel_d_mps] for o in fused])
    tp = np.stack([np.interp(t, sim.truth_t_s, sim.truth_pos_ned_m[:, i]) for i in range(3)], 1)
    tv = np.stack([np.interp(t, sim.truth_t_s, sim.truth_vel_ned_mps[:, i]) for i in range(3)], 1)
    cov = np.array([o.cov_diag[:6] for o in fused])
    return t, np.hstack([est - tp, vel - tv]), cov


def test_ins_filter_is_consistent_nees_per_axis():
    """Normalised estimation error squared per position/velocity axis averages ~1 (bounds 0.3-2.5).

    White GNSS noise and the filter's matching "accuracy" GNSS model: the setting where the KF's noise
    model is the truth, so its covariance must match its errors.
    """
    nees = []
    for seed in (11, 12):
        sim = simulate_circle_flight(60.0, np.random.default_rng(seed), noise=SimNoise(gnss_corr_tau_s=0.0))
        # the simulated receiver has no latency: the filter must not assume one (gnss_vel_delay_s)
        out = run_navigator(sim.events, NavigatorConfig(gnss_sigma_model="accuracy", gnss_vel_delay_s=0.0))
        fused = _fused(out, "ins")
        t, err, cov = _errors(sim, fused)
        keep = t > t[0] + 15.0  # after attitude/bias convergence
        nees.append((err[keep] ** 2 / cov[keep]).mean(axis=0))
        assert np.sqrt((err[keep, :2] ** 2).sum(axis=1).mean()) < 1.0  # 1.5 m GNSS noise is averaged down
    nees = np.mean(nees, axis=0)
    assert np.all(nees > 0.3) and np.all(nees < 2.5), nees


def test_streaming_with_late_types_equals_batch_replay():
    sim = simulate_circle_flight(30.0, np.random.default_rng(5))
    batch = run_navigator(sim.events)
    # arrival order of a real link: GNSS 0.15 s late, attitude 0.05 s late, IMU on time
    delay = {GnssFix: 0.15, ImuSample: 0.0}
    arrival = sorted(sim.events, key=lambda e: e.t_s + delay.get(type(e), 0.05))
    assert arrival != sim.events
    nav = Navigator()
    stream = []
    for ev in arrival:
        stream.extend(nav.process(ev))
    stream.extend(nav.finish())
    assert len(stream) == len(batch)
    assert [o.to_dict() for o in stream] == [o.to_dict() for o in batch]
    a = np.array([[o.north_m, o.east_m, o.down_m, *o.cov_diag] for o in _fused(stream)])
    b = np.array([[o.north_m, o.east_m, o.down_m, *o.cov_diag] for o in _fused(batch)])
    assert np.array_equal(a, b)


def test_fused_output_is_10_hz_and_names_measurements():
    sim = simulate_circle_flight(20.0, np.random.default_rng(2))
    fused = _fused(run_navigator(sim.events))
    dt = np.diff([o.t_s for o in fused])
    assert np.allclose(dt, 0.1)
    assert {o.measurement for o in fused} >= {"gnss", "predictor"}
    assert all(len(o.cov_diag) == 15 for o in fused)


def _inject_glitch(events, t_start, t_end, offset_n_m):
    out = []
    for e in events:
        if isinstance(e, GnssFix) and t_start <= e.t_s < t_end:
            e = dataclasses.replace(e, lat_deg=e.lat_deg + offset_n_m / 111_200.0)
        out.append(e)
    return out


@pytest.mark.parametrize("with_imu", [True, False], ids=["ins", "kinematic"])
def test_gate_rejects_injected_50_m_glitch(with_imu):
    sim = simulate_circle_flight(50.0, np.random.default_rng(9), with_imu=with_imu)
    t0 = sim.events[0].t_s
    events = _inject_glitch(sim.events, t0 + 30.0, t0 + 32.0, 50.0)
    out = run_navigator(events)
    mode = "ins" if with_imu else "kinematic"
    ups = [u for u in out if isinstance(u, MeasurementUpdate) and u.kind == "gnss_pos" and u.filter == mode]
    glitch = [u for u in ups if t0 + 30.0 <= u.t_s < t0 + 32.0]
    assert len(glitch) == 10 and not any(u.accepted for u in glitch)
    after = [u.accepted for u in ups if t0 + 33.0 <= u.t_s]
    assert np.mean(after) > 0.95  # real fixes are taken again once the glitch is over
    fused = [o for o in _fused(out, mode) if t0 + 30.0 <= o.t_s < t0 + 33.0]
    _t, err, _c = _errors(sim, fused)
    assert np.abs(err[:, 0]).max() < 5.0  # nowhere near the 50 m glitch
    pts = [p for p in out if isinstance(p, PredictorPoint) and t0 + 30.0 <= p.t_s < t0 + 32.0]
    assert max(p.age_s for p in pts) > 1.5  # the predictor bridged the glitch instead of learning it


def test_bridges_8_s_blockage_with_ins():
    sim = simulate_circle_flight(60.0, np.random.default_rng(4), noise=RECEIVER)
    t0 = sim.events[0].t_s
    events = [e for e in sim.events if not (isinstance(e, GnssFix) and t0 + 40.0 < e.t_s < t0 + 48.0)]
    out = run_navigator(events, NavigatorConfig(gnss_vel_delay_s=0.0))  # the simulated receiver has no latency
    fused = [o for o in _fused(out, "ins") if t0 + 40.0 < o.t_s < t0 + 48.0]
    _t, err, cov = _errors(sim, fused)
    herr = np.hypot(err[:, 0], err[:, 1])
    assert herr.max() < 3.0
    assert fused[-1].age_since_fix_s > 7.5
    assert fused[-1].sigma_h_m > fused[0].sigma_h_m  # covariance grows without fixes


@pytest.mark.parametrize("imu_rate,expect", [(50.0, "ins"), (1.2, "kinematic"), (None, "kinematic")])
def test_mode_selection_and_reason(imu_rate, expect):
    sim = simulate_circle_flight(20.0, np.random.default_rng(1), imu_rate_hz=imu_rate or 50.0, with_imu=imu_rate is not None,
                          noise=RECEIVER)
    nav = Navigator()
    out = []
    for e in sim.events:
        out.extend(nav.process(e))
    out.extend(nav.finish())
    assert nav.mode == expect
    modes = [o for o in out if isinstance(o, ModeChange)]
    assert modes and modes[-1].mode == expect and modes[-1].reason == nav.mode_reason
    if imu_rate == 1.2:
        assert "slower than the 20 Hz" in nav.mode_reason and "1.2" not in nav.mode_reason  # one rate: the summary's
        assert modes[-1].imu_rate_hz == pytest.approx(1.2, abs=0.3)  # the measured rate stays in the event
    if imu_rate is None:
        assert "no IMU" in nav.mode_reason
    fused = _fused(out)
    assert fused and all(o.mode == expect for o in fused)
    _t, err, _c = _errors(sim, fused[50:])
    assert np.sqrt((err[:, :2] ** 2).sum(axis=1).mean()) < 2.0


def test_bad_config_raises():
    with pytest.raises(ValueError):
        NavigatorConfig(output_rate_hz=0.0)


SAMPLE = Path(__file__).resolve().parents[2] / "logs" / "sample_flight.tlog"


@pytest.mark.skipif(not SAMPLE.exists(), reason="logs/sample_flight.tlog not generated")
def test_sample_flight_tlog_end_to_end_through_its_8_s_outage():
    """The simulated sample flight (companion.sim) through read_events: GNSS is lost 96-104 s in a turn."""
    from companion.nav.frame import LocalFrame
    from companion.sources import read_events

    events = read_events(SAMPLE)
    truth = np.genfromtxt(SAMPLE.with_name("sample_flight_truth.csv"), delimiter=",", names=True)
    out = run_navigator(events)
    assert [o.mode for o in out if isinstance(o, ModeChange)] == ["ins"]
    fused = [o for o in out if isinstance(o, FusedState) and 96.0 <= o.t_s < 104.0]
    frame = LocalFrame(truth["lat_deg"][0], truth["lon_deg"][0], truth["alt_msl_m"][0])
    est = frame.to_ned_m([o.lat_deg for o in fused], [o.lon_deg for o in fused], [o.alt_msl_m for o in fused])
    t = np.array([o.t_s for o in fused])
    ref = np.stack([np.interp(t, truth["t_s"], truth[k]) for k in ("n_m", "e_m", "d_m")], axis=1)
    herr = np.hypot(*(est - ref)[:, :2].T)
    assert len(fused) == 80 and fused[-1].age_since_fix_s > 7.5
    assert herr.max() < 2.0  # INS through an 8 s outage in a 25 m-radius turn at 6 m/s


def test_velocity_latency_model_matches_a_lagged_receiver():
    """A receiver whose velocity describes the vehicle 0.5 s before its position does (0.10-0.15 s on the shared
    logs; longer here so that the turn, 0.9 m/s^2, changes the velocity well beyond the noise): with gnss_vel_delay_s
    set to it the velocity is compared with the INS velocity of its epoch and its innovations shrink."""
    from companion.sim.circle import circle_trajectory

    sim = simulate_circle_flight(40.0, np.random.default_rng(8), noise=SimNoise(gnss_std_h_m=0.3, gnss_std_v_m=0.5))
    t0 = sim.truth_t_s[0]

    def lagged(e):
        v = circle_trajectory(np.array([e.t_s - t0 - 0.5]))[1][0]
        return dataclasses.replace(e, vel_n_mps=float(v[0]), vel_e_mps=float(v[1]), vel_d_mps=float(v[2]))

    events = [lagged(e) if isinstance(e, GnssFix) else e for e in sim.events]
    nis = []
    for delay in (0.0, 0.5):
        out = run_navigator(events, NavigatorConfig(gnss_vel_delay_s=delay))
        ups = [u for u in out if isinstance(u, MeasurementUpdate) and u.kind == "gnss_vel"][50:]
        nis.append(np.mean([u.nis for u in ups]))
    assert nis[1] < 0.5 * nis[0], nis
    with pytest.raises(ValueError):
        NavigatorConfig(gnss_vel_delay_s=-0.1)


def test_flagged_autopilot_tilt_is_not_fused_in_a_gnss_gap():
    """Once the heading check flags the autopilot (90 deg off), its tilt is fused while GNSS aids and not in a gap."""
    from companion.events import Attitude

    sim = simulate_circle_flight(60.0, np.random.default_rng(21), noise=RECEIVER)
    t0 = sim.truth_t_s[0]
    events = [dataclasses.replace(e, yaw_rad=float((e.yaw_rad + np.pi / 2 + np.pi) % (2 * np.pi) - np.pi))
              if isinstance(e, Attitude) else e for e in sim.events
              if not (isinstance(e, GnssFix) and t0 + 45.0 <= e.t_s < t0 + 55.0)]
    for flagged_in_gap in (False, True):
        out = run_navigator(events, NavigatorConfig(fuse_flagged_tilt_in_gap=flagged_in_gap))
        ups = [u.t_s for u in out if isinstance(u, MeasurementUpdate) and u.kind == "attitude"]
        gap = [t for t in ups if t0 + 47.0 <= t < t0 + 55.0]
        assert [t for t in ups if t0 + 35.0 <= t < t0 + 45.0]  # flagged by then, fused with GNSS
        assert bool(gap) == flagged_in_gap


def test_gnss_delay_model_removes_latency_error():
    """Fixes stamped 0.25 s after their epoch (receiver latency): modelling the delay must help."""
    sim = simulate_circle_flight(40.0, np.random.default_rng(8), noise=SimNoise(gnss_std_h_m=0.3, gnss_std_v_m=0.5))
    late = [dataclasses.replace(e, t_s=round(e.t_s + 0.25, 6)) if isinstance(e, GnssFix) else e for e in sim.events]
    rms = []
    for delay in (0.0, 0.25):
        fused = _fused(run_navigator(late, NavigatorConfig(gnss_delay_s=delay)), "ins")[100:]
        _t, err, _c = _errors(sim, fused)
        rms.append(np.sqrt((err[:, :2] ** 2).sum(axis=1).mean()))
    assert rms[1] < 0.6 * rms[0], rms  # 8 m/s x 0.25 s = 2 m of along-track lag without the model


@pytest.mark.parametrize("offset_deg", [0.0, 90.0])
def test_autopilot_heading_offset_is_detected_and_ins_heading_realigned(offset_deg):
    """An autopilot heading 90 deg off (a compass mounted rotated, as in the Erle PXF log) is detected
    from GNSS velocity changes vs the IMU resolved with the autopilot attitude; the INS heading, which
    starts from the autopilot's, is re-aligned to the true heading. 0 deg: no alarm, no re-alignment."""
    from companion.sim.circle import circle_trajectory
    from companion.events import Attitude

    sim = simulate_circle_flight(60.0, np.random.default_rng(21), noise=RECEIVER)
    off = np.radians(offset_deg)
    events = [dataclasses.replace(e, yaw_rad=float((e.yaw_rad + off + np.pi) % (2 * np.pi) - np.pi))
              if isinstance(e, Attitude) else e for e in sim.events]
    nav = Navigator()
    out = []
    for e in events:
        out += nav.process(e)
    out += nav.finish()
    assert abs(np.degrees(nav.heading.offset_rad) + offset_deg) < 10.0
    assert nav.heading.consistent == (offset_deg == 0.0)
    assert bool(nav.yaw_alignments) == (offset_deg != 0.0)
    fused = [o for o in _fused(out, "ins") if o.t_s > sim.truth_t_s[0] + 20.0]
    true_yaw = circle_trajectory(np.array([o.t_s - sim.truth_t_s[0] for o in fused]))[3][:, 2]
    yaw_err = (np.array([o.yaw_rad for o in fused]) - true_yaw + np.pi) % (2 * np.pi) - np.pi
    assert np.degrees(np.abs(yaw_err)).max() < 20.0  # 90 deg: never fused; the KF refines the re-aligned heading
    # the autopilot's heading is fused only once the check has confirmed it, never before it is measured
    ups = [u for u in out if isinstance(u, MeasurementUpdate) and u.kind == "attitude"]
    assert all(u.sigma[2] > 100.0 for u in ups if u.t_s < sim.truth_t_s[0] + 5.0)  # no heading information yet
    assert any(u.sigma[2] < 1.0 for u in ups) == (offset_deg == 0.0)
    _t, err, _cov = _errors(sim, fused)
    assert np.sqrt((err[:, :2] ** 2).sum(axis=1).mean()) < 1.0


def test_imu_stopping_falls_back_to_kinematic_from_the_fix():
    """The kinematic filter is not run beside the INS: when the IMU stops mid-flight, the fallback starts it from the
    next fix (and that fix's velocity); the output goes on at 10 Hz and stays on the vehicle after the switch."""
    sim = simulate_circle_flight(60.0, np.random.default_rng(6), noise=RECEIVER)
    t0 = sim.events[0].t_s
    events = [e for e in sim.events if not (isinstance(e, ImuSample) and e.t_s > t0 + 35.0)]
    out = run_navigator(events, NavigatorConfig(gnss_vel_delay_s=0.0))
    changes = [(m.mode, m.t_s) for m in out if isinstance(m, ModeChange)]
    assert [m for m, _ in changes][-2:] == ["ins", "kinematic"]
    t_switch = changes[-1][1]
    assert t0 + 35.0 < t_switch < t0 + 35.0 + NavigatorConfig().imu_timeout_s + 1.0
    kin = _fused(out, "kinematic")
    assert kin and kin[0].t_s >= t_switch
    _t, err, _c = _errors(sim, kin)
    herr = np.hypot(err[:, 0], err[:, 1])
    assert herr.max() < 3.0, herr.max()
    assert np.sqrt((herr ** 2).mean()) < 1.5
    ups = [u for u in out if isinstance(u, MeasurementUpdate) and u.kind == "gnss_pos" and u.filter == "kinematic"
           and u.t_s > t_switch]
    assert len(ups) > 100 and np.mean([u.accepted for u in ups]) > 0.95
