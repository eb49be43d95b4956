"""The kinematic filter alone (companion.nav.kinematic): on a constant-velocity track its velocity converges to the
truth from position fixes alone, the gate refuses an outlier, and a reset takes the fix."""

import math

import numpy as np
import pytest

from companion.nav.config import NavigatorConfig
from companion.nav.gnss_lag import GnssLatency
from companion.nav.kinematic import KinematicFilter
from companion.nav.measurements import PositionMeasurement
from companion.nav.outputs import MeasurementUpdate

V = np.array([3.0, -4.0, 0.5])


def _track(hold_cv: bool, n=30, seed=1):
    c = NavigatorConfig(kinematic_hold_cv=hold_cv)
    out = []
    kin = KinematicFilter(c, GnssLatency(0.0, 0.0), out.append, 0.0, (0.0, 0.0, 0.0), None)
    rng = np.random.default_rng(seed)
    for k in range(1, n + 1):
        z = V * k + rng.normal(0, 0.01, 3)
        assert kin.apply(PositionMeasurement(float(k), "gnss_pos", tuple(z), 0.1, 0.1, gate_chi2=16.27))[0]
    return kin, out


@pytest.mark.parametrize("hold_cv", [False, True])
def test_velocity_converges_on_a_constant_velocity_track(hold_cv):
    kin, out = _track(hold_cv)
    x = kin.state()[0]
    assert x[3:6] == pytest.approx(V, abs=0.1)
    assert x[0:3] == pytest.approx(V * 30, abs=0.2)
    assert len(out) == 30 and all(isinstance(o, MeasurementUpdate) and o.filter == "kinematic" for o in out)
    kin.predict(35.0)
    x = kin.state()[0]
    if not hold_cv:  # extrapolated at the learnt velocity
        assert x[0:3] == pytest.approx(V * 35, abs=0.8)
    else:  # the mixture of hold (where it was) and constant velocity
        assert 30 * V[0] < x[0] < 35 * V[0] + 0.5 and 35 * V[1] - 0.5 < x[1] < 30 * V[1]


def test_gate_refuses_an_outlier_and_reset_takes_the_fix():
    kin, out = _track(False)
    x0 = kin.state()[0].copy()
    m = PositionMeasurement(31.0, "gnss_pos", (500.0, 0.0, 0.0), 0.5, 0.5, gate_chi2=16.27)
    ok, y, nis = kin.apply(m)
    assert not ok and nis > 16.27 and not out[-1].accepted
    assert kin.state()[0][0] == pytest.approx(x0[0] + x0[3], abs=1e-9)  # predicted, not updated
    kin.reset_to_fix(m, (1.0, 2.0, math.nan))
    x = kin.state()[0]
    assert x[0:3] == pytest.approx([500.0, 0.0, 0.0]) and x[3:5] == pytest.approx([1.0, 2.0])
    assert kin.state()[1][0, 0] == pytest.approx(0.25)


def test_trajectory_record_is_its_dead_reckoning():
    kin, _ = _track(False)
    p, v, p_free, v_free = kin.trajectory_record()
    assert v == pytest.approx(list(kin.state()[0][3:6])) and p_free == (0.0, 0.0, 0.0) and v_free == (0.0, 0.0, 0.0)
