"""A wind shift seen in the gravity filter's innovations (companion.gravity.wind_shift): the detector on known NIS
series, and the air-data filter on a synthetic map whose held wind's error steps by 5 m/s east (the component the
readings see through the Eotvos term) -- with the detector the filter's velocity error takes the step, without it
the particles' positions do."""

from __future__ import annotations

import numpy as np
import pytest

from companion.gravity.eotvos import eotvos_from_ne_mgal
from companion.gravity.sequential import InsErrorSpec, SeqGravConfig, SequentialGravityFilter
from companion.gravity.wind_shift import WindShiftDetector, WindShiftSpec
from tests.gravity.test_sequential_gravity import MAP


def _feed(det: WindShiftDetector, t0: float, t1: float, nis: float) -> list[float]:
    return [float(t) for t in np.arange(t0, t1) if det.add(float(t), nis)]


def test_a_rise_of_the_nis_is_a_shift_once_per_holdoff_and_not_without_history():
    det = WindShiftDetector(WindShiftSpec(step_mps=5.0, nis_ratio=5.0, window_s=60.0, min_history_s=240.0,
                                          holdoff_s=300.0), history_s=900.0)
    assert _feed(det, 0.0, 600.0, 0.02) == []  # steady
    assert _feed(det, 600.0, 610.0, 0.05) == []  # within the window's mean: 2.5x at most, below 5x
    hits = _feed(det, 610.0, 700.0, 1.0)
    # the window's mean passes 5x the history's (0.02) at the fifth reading of 1.0 (49 x 0.02 + 10 x 0.05 + 5 x 1.0
    # over 60 readings, less those the window dropped: 0.104); then held off
    assert hits == [614.0]
    assert _feed(det, 700.0, 905.0, 1.0) == []  # held off, and by then the history has risen with it
    det.reset()
    assert _feed(det, 1000.0, 1200.0, 0.02) + _feed(det, 1200.0, 1250.0, 10.0) == []  # 200 s of history: too little


def test_the_detector_is_off_without_a_step_and_refuses_inconsistent_settings():
    det = WindShiftDetector(WindShiftSpec(step_mps=0.0), history_s=900.0)
    assert not det.enabled
    assert _feed(det, 0.0, 600.0, 0.02) + _feed(det, 600.0, 700.0, 10.0) == []
    with pytest.raises(ValueError):
        WindShiftDetector(WindShiftSpec(step_mps=5.0, window_s=600.0, min_history_s=400.0), history_s=900.0)
    with pytest.raises(ValueError):
        WindShiftDetector(WindShiftSpec(step_mps=5.0, nis_ratio=0.5), history_s=900.0)


LAT = 45.0  # the synthetic map's Eotvos latitude (SeqGravConfig.lat_deg_if_local)


def _fly(step_mps: float, seed: int = 3, t_step: float = 900.0, t_end: float = 1500.0, stated_mgal: float = 25.0):
    """Northbound at 22 m/s across the synthetic map; the reference is the truth plus the held wind's error, zero
    until ``t_step`` and 5 m/s east after it; 1 Hz readings with 1 mGal white noise, Eotvos-corrected with the
    reference's velocity, stated at ``stated_mgal`` (as the air-data stage states them in an outage: the gusts the held
    wind does not know, correlated over the gravimeter's window, companion.gravity.air_data_stage). Returns (t,
    position error (m), velocity error estimate east (m/s)) rows and the shifts' times."""
    rng = np.random.default_rng(seed)
    cfg = SeqGravConfig(n_particles=300, ins=InsErrorSpec(air_data=True, wind_walk_mps_rts=0.1, init_vel_sigma_mps=1.0),
                        wind_shift=WindShiftSpec(step_mps=step_mps))
    f = SequentialGravityFilter(MAP, cfg, np.random.default_rng(seed))
    v_true = np.array([22.0, 0.0])
    truth = np.array([-30_000.0, 5_000.0])
    ref = truth.copy()
    rows = []
    for t in np.arange(0.0, t_end):
        dv = np.array([0.0, 5.0]) if t >= t_step else np.zeros(2)
        truth = truth + v_true
        ref = ref + v_true + dv
        g = float(MAP.interp_ne(truth[0:1], truth[1:2])[0]) + rng.normal(0.0, 1.0)
        g += float(eotvos_from_ne_mgal(v_true, LAT) - eotvos_from_ne_mgal(v_true + dv, LAT))
        anchored = t < 300  # GNSS: pinned to the reference, the readings at their own noise
        e = f.feed(float(t), g, ref, v_true + dv, 1.0 if anchored else stated_mgal,
                   ref_cov_ne_m2=np.eye(2) * 4.0 if anchored else None, lat_deg=LAT)
        if e is not None and t >= 300:
            rows.append((t, float(np.hypot(*(e.pos_ne_m - truth))), float(e.vel_err_ne_mps[1])))
    return np.array(rows), list(f.wind_shift.shifts_t_s)


def test_a_wind_shift_east_is_taken_by_the_velocity_not_the_position():
    """Three seeds: with the detector the step is seen at once and the east velocity error takes it within a minute;
    without it the filter, which states the readings as the stage does, takes part of the step as position."""
    jump_on = jump_off = err_on = err_off = 0.0
    for seed in (3, 4, 5):
        on, shifts = _fly(5.0, seed=seed)
        off, none = _fly(0.0, seed=seed)
        assert none == [] and len(shifts) == 1 and 900.0 <= shifts[0] <= 905.0  # seen at once, once
        at = on[:, 0] == 960.0
        assert abs(float(on[at, 2][0]) - 5.0) < 0.3, seed  # the velocity error took the step within a minute
        first = (on[:, 0] > 900.0) & (on[:, 0] <= 960.0)
        after = on[:, 0] >= 960.0
        jump_on, jump_off = jump_on + on[first, 1].max(), jump_off + off[first, 1].max()
        err_on, err_off = err_on + np.median(on[after, 1]), err_off + np.median(off[after, 1])
        print(f"seed {seed}: the minute after the step, largest error {on[first, 1].max():.0f} m with the detector, "
              f"{off[first, 1].max():.0f} m without; median after it {np.median(on[after, 1]):.0f} / "
              f"{np.median(off[after, 1]):.0f} m; east velocity error at +60 s {float(on[at, 2][0]):.2f} / "
              f"{float(off[at, 2][0]):.2f} m/s")
    assert jump_on < 0.5 * jump_off
    assert err_on < 0.6 * err_off
