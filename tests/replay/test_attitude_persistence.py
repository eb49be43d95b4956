"""The attitude-persistence measures (replay/attitude_persistence.py) on simulated flights, autopilot error known."""

import numpy as np

from companion.events import Attitude
from companion.sim.circle import SimNoise, simulate_circle_flight
from replay.attitude_persistence import change_vs_gyros, innovation_autocorrelation
from tests.helpers import tilted_in_ned


def test_white_autopilot_error_is_flat_its_innovations_white_and_the_gyro_bias_found():
    ev = simulate_circle_flight(60.0, np.random.default_rng(1)).events  # attitude = truth + white 1.7 deg
    bias, rms = change_vs_gyros(ev, lags_s=(0.1, 1.0, 5.0))
    assert max(rms) / min(rms) < 1.15, rms
    # white 1.7 deg on every 10 Hz sample over 60 s: the bias found within 0.1 deg/s of the simulator's
    assert np.allclose(bias, SimNoise().gyro_bias_radps, atol=np.radians(0.1)), np.degrees(bias)
    n, r = innovation_autocorrelation(ev, lags_s=(0.1, 1.0))
    assert n > 400 and max(abs(x) for x in r) < 0.15, r


def test_a_wandering_autopilot_error_shows_as_its_own_increments():
    """The autopilot's level reference tilted about north by a 1 deg/sqrt(s) random walk (no white part), the
    simulator's gyro bias removed: the mismatch over a lag is the walk's own increment over it (about north: per tilt
    axis, half its square) plus the gyros' noise integrated over it (the same flight without the walk); it grows with
    the lag, where a white error stays flat."""
    noise = SimNoise(att_std_tilt_rad=0.0, att_std_yaw_rad=0.0)
    sim = simulate_circle_flight(60.0, np.random.default_rng(2), noise=noise)
    atts = [e for e in sim.events if isinstance(e, Attitude)]  # 10 Hz
    walk = np.cumsum(np.random.default_rng(3).normal(0.0, np.radians(1.0) * np.sqrt(0.1), len(atts)))
    by_id = dict(zip((id(e) for e in atts), walk))
    ev = [tilted_in_ned(e, by_id[id(e)]) if isinstance(e, Attitude) else e for e in sim.events]
    bias = np.array(noise.gyro_bias_radps)
    lags = (1.0, 5.0)
    _b, gyro_only = change_vs_gyros(sim.events, lags_s=lags, bias_radps=bias)
    _b, rms = change_vs_gyros(ev, lags_s=lags, bias_radps=bias)
    for lag, g, r in zip(lags, gyro_only, rms):
        n = int(round(lag * 10))
        expected = np.sqrt(np.mean((walk[n:] - walk[:-n]) ** 2) / 2 + g**2)
        assert abs(r / expected - 1) < 0.1, (lag, r, expected)
    assert rms[1] / rms[0] > 1.8
