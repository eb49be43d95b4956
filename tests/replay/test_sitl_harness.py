"""The SITL A/B harness's pure logic (replay/live/sitl_core.py, its tables and verdicts in sitl_report.py, the
parameter checks of sitl_vehicle.py) against scripted message streams: no SITL."""

from __future__ import annotations

import math

import numpy as np
import pytest

from replay.live import sitl_core as core
from replay.live import sitl_report as report
from replay.live.sitl_vehicle import param_mismatches, suggested_drag

LAT0, LON0 = -35.0, 149.0
M_PER_DEG = math.radians(1) * core.EARTH_R_M


class Msg:
    """A scripted MAVLink message: type name and fields, like pymavlink's objects."""

    def __init__(self, kind: str, comp: int = 1, **fields):
        self._kind = kind
        self._comp = comp
        self.__dict__.update(fields)

    def get_type(self):
        return self._kind

    def get_srcComponent(self):
        return self._comp


def gpi(t, n=0.0, e=0.0, alt=20.0):
    lat = LAT0 + n / M_PER_DEG
    lon = LON0 + e / (M_PER_DEG * math.cos(math.radians(LAT0)))
    return Msg("GLOBAL_POSITION_INT", time_boot_ms=int(round(t * 1000)), lat=int(round(lat * 1e7)),
               lon=int(round(lon * 1e7)), relative_alt=int(alt * 1000))


def simstate(n=0.0, e=0.0):
    lat = LAT0 + n / M_PER_DEG
    lon = LON0 + e / (M_PER_DEG * math.cos(math.radians(LAT0)))
    return Msg("SIMSTATE", lat=int(round(lat * 1e7)), lng=int(round(lon * 1e7)))


def att(t):
    return Msg("ATTITUDE", time_boot_ms=int(round(t * 1000)))


def hb(mode, armed=True, comp=1, type_=2):
    return Msg("HEARTBEAT", comp=comp, type=type_, autopilot=3, base_mode=128 if armed else 0, custom_mode=mode)


def text(s, sev=2):
    return Msg("STATUSTEXT", severity=sev, text=s)


def scripted_flight(ekf_offset_e, deny_on=40.0, deny_off=70.0, end=100.0, dt=0.1, failsafe_at=None):
    """Truth flies north at 5 m/s from t=0; the EKF reports truth + an east offset given as a function of t."""
    log = core.FlightLog()
    log.on_message(hb(core.MODE_GUIDED, armed=False))
    t = 0.0
    while t <= end + 1e-9:
        log.on_message(att(t))
        log.on_message(simstate(n=5.0 * t))
        log.on_message(gpi(t, n=5.0 * t, e=ekf_offset_e(t)))
        if t == pytest.approx(1.0):
            log.on_message(hb(core.MODE_GUIDED, armed=True))
        if failsafe_at is not None and abs(t - failsafe_at) < dt / 2:
            log.on_message(text("EKF variance: position lost"))
            log.on_message(text("EKF Failsafe: changed to LAND Mode"))
            log.on_message(hb(core.MODE_LAND))
        t = round(t + dt, 6)
    log.marks.update(hover=5.0, route=20.0, deny_on=deny_on, deny_off=deny_off, end=end)
    return log


def test_truth_interpolated_to_the_ekf_times():
    truth = [(0.0, 0.0, 0.0), (0.4, 1e-5, 0.0), (0.8, 2e-5, 2e-5)]
    lat, lon = core.truth_at(truth, [0.2, 0.6, -1.0, 1.0])
    assert lat[0] == pytest.approx(0.5e-5) and lon[0] == 0.0
    assert lat[1] == pytest.approx(1.5e-5) and lon[1] == pytest.approx(1e-5)
    assert math.isnan(lat[2]) and math.isnan(lat[3])  # outside the truth's span: no truth


def test_no_truth_across_a_gap():
    truth = [(0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (3.0, 1e-4, 0.0), (3.1, 1e-4, 0.0)]
    lat, _ = core.truth_at(truth, [0.05, 1.5, 3.05])
    assert np.isfinite(lat[[0, 2]]).all() and math.isnan(lat[1])


def test_error_of_a_moving_vehicle_is_measured_at_the_same_instant():
    """EKF exactly on a truth flying 5 m/s: any time mismatch would show as 5 m/s x mismatch."""
    log = scripted_flight(lambda t: 0.0)
    t, err = core.ekf_error(log)
    assert len(t) > 900
    assert err.max() < 0.02  # 1e-7 deg quantisation only


def test_simstate_takes_the_newest_boot_time():
    log = core.FlightLog()
    log.on_message(simstate())  # before any time: dropped
    log.on_message(att(1.234))
    log.on_message(simstate(n=1.0))
    log.on_message(Msg("SIMSTATE", lat=0, lng=0, time_boot_ms=99999))  # never trusted for time
    assert [round(x[0], 3) for x in log.truth] == [1.234, 1.234]
    assert log.t_boot == pytest.approx(1.234)


def test_phase_intervals_cut_at_the_denial():
    iv = core.phase_intervals({"hover": 5.0, "route": 20.0, "deny_on": 40.0, "deny_off": 70.0, "end": 100.0})
    assert iv == {"hover": (5.0, 20.0), "route": (20.0, 40.0), "denial": (40.0, 70.0), "recovery": (70.0, 100.0)}
    iv = core.phase_intervals({"hover": 5.0, "deny_on": 20.0, "deny_off": 50.0, "end": 80.0})  # denied in the hover
    assert iv == {"hover": (5.0, 20.0), "denial": (20.0, 50.0), "recovery": (50.0, 80.0)}
    assert core.phase_intervals({"hover": 5.0, "route": 20.0, "end": 60.0}) == {"hover": (5.0, 20.0), "route": (20.0, 60.0)}
    assert core.phase_intervals({"hover": 5.0}) == {}  # never finished: no phase


def test_phase_stats_and_5s_marks():
    # EKF 1 m east in hover/square, grows 0.5 m/s during the denial, back to 0.2 m after
    def off(t):
        if t < 40:
            return 1.0
        if t < 70:
            return 1.0 + 0.5 * (t - 40)
        return 0.2

    log = scripted_flight(off)
    r = core.analyse(core.SCENARIOS["lap-deny-30"], "A", log)
    assert r.phases["hover"][0] == pytest.approx(1.0, abs=0.02)
    assert r.phases["route"][1] == pytest.approx(1.0, abs=0.02)
    assert r.phases["denial"][1] == pytest.approx(15.95, abs=0.1)
    assert r.phases["recovery"][0] == pytest.approx(0.2, abs=0.02)
    marks = dict(r.marks_err)
    assert sorted(marks) == [5.0 * k for k in range(13)]  # 0 .. 60 s (denial 30 s + 30 s after)
    assert marks[10.0] == pytest.approx(6.0, abs=0.05)
    assert marks[25.0] == pytest.approx(13.5, abs=0.05)
    assert marks[35.0] == pytest.approx(0.2, abs=0.02)
    assert r.armed and r.arm_time_s == pytest.approx(1.0)


def test_failsafe_and_land_timing_after_the_denial():
    log = scripted_flight(lambda t: 0.0, failsafe_at=48.0)
    log.texts.insert(0, (2.0, 2, "EKF Failsafe"))  # before the denial: not this denial's failsafe
    log.on_message(text("EKF Failsafe Cleared"))
    r = core.analyse(core.SCENARIOS["lap-deny-30"], "A", log)
    assert r.failsafe_s == pytest.approx(8.0, abs=0.06)
    assert r.variance_s == pytest.approx(8.0, abs=0.06)
    assert r.land_s == pytest.approx(8.0, abs=0.06)
    assert "EKF failsafe" in report.phase_table([r]).replace("EKF Failsafe", "EKF failsafe")


def test_no_failsafe_is_nan_and_shown_as_dash():
    r = core.analyse(core.SCENARIOS["lap-deny-30"], "B", scripted_flight(lambda t: 0.0))
    assert math.isnan(r.failsafe_s) and math.isnan(r.land_s)
    assert "| — | — | — |" in report.phase_table([r])


def test_modes_keep_changes_only_and_ignore_other_components():
    log = core.FlightLog()
    log.on_message(att(1.0))
    for m in (hb(4, False), hb(4, False), hb(4, True), hb(0, False, comp=191, type_=18), hb(9, True)):
        log.on_message(m)
    assert [(m, a) for _t, m, a in log.modes] == [(4, False), (4, True), (9, True)]
    assert log.mode == core.MODE_LAND and log.armed


def test_arming_refusals_deduplicated():
    log = core.FlightLog()
    for s in ("PreArm: GPS 2: Bad fix", "PreArm: GPS 2: Bad fix", "Arm: GPS 2: Bad fix", "EKF3 IMU0 is using GPS"):
        log.on_message(text(s))
    assert core.arm_refusals(log) == ["PreArm: GPS 2: Bad fix", "Arm: GPS 2: Bad fix"]
    r = core.analyse(core.SCENARIOS["healthy"], "B", log)
    assert not r.armed and "refusals seen: PreArm: GPS 2: Bad fix" in report.arming_lines([r])


def test_gps_fix_types_counted_per_instance_and_window():
    log = core.FlightLog()
    for t, fx in ((1.0, 3), (2.0, 3), (3.0, 2), (4.0, 0)):
        log.on_message(att(t))
        log.on_message(Msg("GPS2_RAW", fix_type=fx, satellites_visible=10))
        log.on_message(Msg("GPS_RAW_INT", fix_type=3, satellites_visible=10))
    assert core.fix_counts(log, 2) == {0: 1, 2: 1, 3: 2}
    assert core.fix_counts(log, 2, 2.5, 10) == {0: 1, 2: 1}
    assert core.fix_counts(log, 1) == {3: 4}
    assert log.gps_fix(2) == 0


def test_companion_error_against_the_time_it_claims():
    log = scripted_flight(lambda t: 0.0)
    recs = []
    for k in range(0, 1000, 2):
        t = k / 10
        late = 0.3  # the record says it describes t; its position is truth at t - 0.3 (5 m/s -> 1.5 m)
        m = gpi(t, n=5.0 * (t - late))
        recs.append({"sent": True, "time_boot_us": int(t * 1e6), "lat_deg": m.lat * 1e-7, "lon_deg": m.lon * 1e-7,
                     "fix_type": 3 if t < 50 else 2, "h_acc_m": 1.0 if t < 60 else 0.5})
    recs.append({"sent": False, "time_boot_us": 10_000_000, "lat_deg": 0.0, "lon_deg": 0.0, "fix_type": 3})
    r = core.analyse(core.SCENARIOS["lap-deny-30"], "B", log, recs)
    assert r.own_healthy_mean == pytest.approx(1.5, abs=0.02)
    assert r.own_err_at[10.0] == pytest.approx(1.5, abs=0.02)
    assert r.sent_fix == {2: 250, 3: 250}
    # 1.5 m of error, 3D fixes (what EKF3 fuses) before t = 50 s: within 2 x 1.0 m; the 2D fixes after do not count
    assert r.fixes_with_hacc == 250 and r.within_2hacc == pytest.approx(1.0)
    assert math.isnan(r.last_hacc_m)  # the last fix before GPS1 came back (t 69.8 s) was 2D: no claim standing
    recs3 = [dict(x, fix_type=3) for x in recs]
    assert core.analyse(core.SCENARIOS["lap-deny-30"], "B", log, recs3).last_hacc_m == pytest.approx(0.5)
    table = report.companion_table([r])
    assert "3:250" in table and "1.5" in table and "100.0 % of 250" in table
    recs = [dict(x, h_acc_m=0.5) for x in recs]
    assert core.analyse(core.SCENARIOS["lap-deny-30"], "B", log, recs).within_2hacc == 0.0  # 1.5 m > 2 x 0.5 m


def _ab(sc="lap-deny-30", a_off=lambda t: 0.2, b_off=lambda t: 0.2, a_fs=None, b_fs=None, takeover="takeover: fit"):
    a = core.analyse(core.SCENARIOS[sc], "A", scripted_flight(a_off, failsafe_at=a_fs))
    b = core.analyse(core.SCENARIOS[sc], "B", scripted_flight(b_off, failsafe_at=b_fs))
    b.takeover = takeover
    return a, b, "\n".join(report.ab_verdicts([a, b]))


def test_verdict_of_a_takeover():
    """A takeover is judged by its own target: no failsafe and <= 3 m at every 5 s mark of a 30 s denial."""
    _, _, v = _ab(a_off=lambda t: 0.2 if t < 40 else 0.2 + (t - 40),
                  b_off=lambda t: 0.05 if t < 40 else 0.05 + 0.065 * (t - 40), a_fs=48.0)
    assert "took over; no failsafe: yes, EKF error <= 2.0 m at every 5 s mark" in v and "no failsafe: met" in v
    assert "B vs A: better by > 0.5 m at 6 of 7 denial marks, worse at 0" in v
    _, _, v = _ab(b_off=lambda t: 0.05 if t < 40 else 4.0)
    assert "(target <= 3 m, no failsafe: NOT met)" in v and "worse at 7" in v
    _, _, v = _ab(b_off=lambda t: 0.05, b_fs=50.0)
    assert "no failsafe: NO" in v and "NOT met" in v


def test_verdict_of_a_60_s_takeover():
    _, _, v = _ab("lap-deny-60", b_off=lambda t: 0.1 if t < 40 else 0.1 + 0.1 * (t - 40))
    assert "flew on 60.0 s of the 60 s denial, <= 4.6 m to +45 s (target >= 45 s at <= 5 m: met)" in v
    _, _, v = _ab("lap-deny-60", b_off=lambda t: 0.1, b_fs=80.0)
    assert "flew on 40.0 s of the 60 s denial" in v and "NOT met" in v


def test_verdict_when_the_companion_stays_out():
    """Not fit: never worse than alone by more than 0.5 m at a denial mark, the failsafe no later than alone's (within
    ArduCopter's 0.1 s check period)."""
    _, _, v = _ab(a_fs=48.0, b_fs=48.05, takeover="no takeover: manoeuvres 0.3 m/s < 3")
    assert "companion stayed out (no takeover: manoeuvres 0.3 m/s < 3), vs A" in v and "0 of 7" in v and "(met)" in v
    _, _, v = _ab(a_fs=48.0, b_fs=49.0, takeover="no takeover: x")
    assert "(later: NOT met)" in v
    _, _, v = _ab(b_off=lambda t: 0.2 if t < 50 else 1.0, takeover="no takeover: x")
    assert "(NOT met)" in v and "worst +10 s: +0.8 m" in v


def test_verdicts_pool_the_healthy_flight_and_tolerate_the_resolution():
    runs = []
    for sc, (ea, eb) in {"lap-deny-30": (0.10, 0.13), "lap-deny-60": (0.20, 0.19)}.items():
        runs.append(core.analyse(core.SCENARIOS[sc], "A", scripted_flight(lambda t, e=ea: e)))
        runs.append(core.analyse(core.SCENARIOS[sc], "B", scripted_flight(lambda t, e=eb: e)))
    v = "\n".join(report.ab_verdicts(runs))
    means = {arm: np.mean([r.phases["route"][0] for r in runs if r.arm == arm]) for arm in ("A", "B")}
    ratio = means["B"] / means["A"]  # ~ (0.13 + 0.19) / (0.10 + 0.20), to the 1e-7 deg steps of the positions
    assert f"2 flights pooled, route B/A: mean EKF error {ratio:.2f}x" in v and "target <= 1.1x: met" in v
    # 1-2 cm hover errors differ by less than GLOBAL_POSITION_INT's 1e-7 deg step: not a difference between the arms
    a, b = (core.analyse(core.SCENARIOS["lap-deny-30"], arm, scripted_flight(lambda t, e=e: e))
            for arm, e in (("A", 0.010), ("B", 0.016)))
    assert "NOT met" not in "\n".join(x for x in report.ab_verdicts([a, b]) if "healthy" in x)


def test_return_jump_is_the_step_of_the_error_not_the_motion():
    """The vehicle flies 5 m/s; the EKF is 3 m east until GPS1 is back at 70 s, then snaps onto the truth."""
    log = scripted_flight(lambda t: 3.0 if t < 70.05 else 0.0)
    assert core.return_jump(log, 70.0) == pytest.approx(3.0, abs=0.02)
    assert core.return_jump(scripted_flight(lambda t: 3.0), 70.0) < 0.02  # a constant offset is no jump


def test_mode_events_and_leaving_guided():
    log = scripted_flight(lambda t: 0.0, failsafe_at=48.0)
    log.on_message(text("Dead Reckoning started"))
    r = core.analyse(core.SCENARIOS["lap-deny-30"], "AD", log)
    assert r.left_guided_s == pytest.approx(8.0, abs=0.06)
    assert [txt for _t, txt in r.events][:3] == ["EKF Failsafe: changed to LAND Mode", "mode LAND", "Dead Reckoning started"]
    assert "+8.0 s mode LAND" in report.events_lines([r])


def test_parameters_not_held_are_named():
    bad = param_mismatches({"WP_SPD": 8.0, "FS_DR_TIMEOUT": 30, "EK3_DRAG_MCOEF": 0.209},
                           {"WP_SPD": None, "FS_DR_TIMEOUT": 30.0, "EK3_DRAG_MCOEF": 0.20900000631809235})
    assert bad == ["WP_SPD: unknown to this autopilot (no PARAM_VALUE)"]
    assert param_mismatches({"X": 1.0}, {"X": 2.0}) == ["X: holds 2, not 1"]


def test_drag_coefficients_read_from_sitl_output():
    out = "Starting sketch 'ArduCopter'\nSuggested EK3_DRAG_BCOEF_* = 17.209, EK3_DRAG_MCOEF = 0.209\nbind port"
    assert suggested_drag(out) == {"EK3_DRAG_BCOEF_X": 17.209, "EK3_DRAG_BCOEF_Y": 17.209, "EK3_DRAG_MCOEF": 0.209}
    assert suggested_drag("no such line") is None


def test_scenarios_are_consistent():
    for name, sc in core.SCENARIOS.items():
        assert sc.name == name
        if sc.denies:
            assert sc.deny_in in ("hover", "route") and sc.recover_s > 0
            if sc.deny_in == "hover":
                assert sc.deny_at_s < sc.hover_s  # denied before the vehicle leaves its hover
        if sc.deny_lap:
            assert 0 < sc.deny_lap <= sc.laps
        corners = core.route_corners(sc)
        assert corners[-1] == (0.0, 0.0) and len(corners) in (4, 8)
    for d in core.DEFAULT_SCENARIOS:
        assert d in core.SCENARIOS


def test_best_lag_finds_a_delayed_source():
    """An EKF that reports the truth of 0.3 s ago, on a vehicle flying 5 m/s north: tau = 0.3 s, error ~0."""
    log = scripted_flight(lambda t: 0.0)
    a = np.asarray(log.ekf)
    tau, e = core.best_lag(a[:, 0], a[:, 1], a[:, 2], log.truth)
    assert tau == pytest.approx(0.0, abs=0.011) and e < 0.02
    delayed = [(t, LAT0 + 5.0 * (t - 0.3) / M_PER_DEG, lon) for t, _lat, lon, _alt in log.ekf]
    d = np.asarray(delayed)
    tau, e = core.best_lag(d[:, 0], d[:, 1], d[:, 2], log.truth)
    assert tau == pytest.approx(0.3, abs=0.011) and e < 0.05
    r = core.analyse(core.SCENARIOS["lap-deny-30"], "A", log)
    assert r.ekf_lag_s == pytest.approx(0.0, abs=0.011)
    assert "EKF delay vs truth" in report.lag_table([r])


def test_flight_log_round_trips_through_json():
    import json

    log = scripted_flight(lambda t: 0.5, failsafe_at=50.0)
    log.on_message(Msg("GPS2_RAW", fix_type=3, satellites_visible=10))
    log.note("lap 1")
    back = core.FlightLog.from_dict(json.loads(json.dumps(log.to_dict()).replace("NaN", "null")))
    a = core.analyse(core.SCENARIOS["lap-deny-30"], "A", log)
    b = core.analyse(core.SCENARIOS["lap-deny-30"], "A", back)
    assert report.phase_table([a]) == report.phase_table([b]) and report.marks_table([a]) == report.marks_table([b])
    assert back.gps[2] == log.gps[2] and back.events == log.events


def test_truth_velocity_and_velocity_steps():
    """A vehicle going north at 20 m/s then east at 20 m/s: the truth's velocity from its positions, and the steps of
    a velocity series against what it really does."""
    lat0, lon0 = -31.0, 156.0
    r = core.EARTH_R_M
    truth = []
    for k in range(201):  # 10 Hz, north for 10 s then east
        t = 0.1 * k
        n, e = (20.0 * t, 0.0) if t <= 10.0 else (200.0, 20.0 * (t - 10.0))
        truth.append((t, lat0 + math.degrees(n / r), lon0 + math.degrees(e / (r * math.cos(math.radians(lat0))))))
    v = core.truth_velocity_ne(truth, np.array([5.0, 15.0, 10.0, 30.0]))
    assert np.allclose(v[0], [20.0, 0.0], atol=0.01) and np.allclose(v[1], [0.0, 20.0], atol=0.01)
    assert np.allclose(v[2], [10.0, 10.0], atol=0.01)  # across the corner: the mean over +-0.5 s
    assert np.all(np.isnan(v[3]))  # beyond the truth
    t = np.array([0.0, 0.5, 0.5, 1.0, 2.0])
    vel = np.array([[20.0, 0.0], [20.0, 1.0], [25.0, 1.0], [20.0, 1.0], [20.0, 4.0]])
    assert np.allclose(core.velocity_steps_mps2(t, vel), [2.0, 10.0, 3.0])  # the repeated stamp is skipped


def test_a_link_the_autopilot_closed_ends_the_wait_with_a_harness_error():
    """SITL gone (a crash, or its port taken by another run): pymavlink's TCP link prints "EOF on TCP socket" at every
    read and returns nothing, so a wait for the vehicle's time would spin for its whole bound. It raises instead."""
    import socket
    import threading
    import time

    from replay.live.sitl_vehicle import HarnessError, Vehicle

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]

    def accept_and_close():
        conn, _ = srv.accept()
        conn.close()

    th = threading.Thread(target=accept_and_close, daemon=True)
    th.start()
    veh = Vehicle(f"tcp:127.0.0.1:{port}", lambda m: None, lambda: None, connect_s=30.0)
    th.join(30.0)
    t0 = time.monotonic()
    with pytest.raises(HarnessError, match="link closed while waiting for the vehicle"):
        veh.pump(lambda: False, 120.0, "the vehicle")
    assert time.monotonic() - t0 < 60.0  # raised at the close, not at the 120 s bound
    veh.close()
    srv.close()


def test_runs_started_together_are_handed_different_sitl_instances(tmp_path):
    """Two runs started at once used to take the same instance (both found its ports free before either SITL bound
    them): an instance handed out stays claimed for a while."""
    from replay.live.sitl_vehicle import free_instance

    reg = tmp_path / "claims"
    a = free_instance(registry=reg)
    b = free_instance(registry=reg)
    c = free_instance(start=b, registry=reg)
    assert len({a, b, c}) == 3 and c > b
    assert free_instance(registry=reg, claim_s=0.0) == a  # expired claims are dropped
    (reg).write_text("garbage\n3 not-a-time\n")
    assert free_instance(registry=reg) == a  # an unreadable line is no claim
