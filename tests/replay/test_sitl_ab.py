"""The real-autopilot A/B harness on a real ArduCopter SITL: one lap of a 60 m square, then GPS1 denied for 20 s while
the laps go on; ArduPilot alone (A) and with the real `companion run` process as GPS2 in its recommended takeover set-up
(B). Needs a SITL binary named by COMPANION_SITL_BIN (built outside this repository); skipped otherwise. About 6 minutes
of wall time (SITL at speedup 1)."""

from __future__ import annotations

import math

import pytest

from replay.live import sitl, sitl_core as core
from tests.conftest import sitl_binary

pytestmark = pytest.mark.slow

SCENARIO = "lap-deny-20-short"


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    bin_ = sitl_binary("COMPANION_SITL_BIN", "ArduCopter", "copter")
    a = sitl.parse_args(["--sitl-bin", bin_, "--scenarios", SCENARIO])
    work = tmp_path_factory.mktemp("sitl_ab")
    found = sitl.probe(a, work)
    sc = core.SCENARIOS[SCENARIO]
    return {arm: sitl.fly(sc, arm, a, work, found) for arm in ("A", "B")}


@pytest.mark.timeout(1200)
def test_both_arms_arm_fly_and_are_measured(flights):
    for arm, r in flights.items():
        assert r.armed, f"arm {arm} did not arm: {r.refusals} {r.notes}"
        assert not any(n.startswith("harness:") for n in r.notes), r.notes  # every parameter held, every wait met
        mean, mx, n = r.phases["route"]
        assert n > 100 and math.isfinite(mean) and mx < 2.0, (arm, r.phases)  # the EKF on GPS1 within metres
    b = flights["B"]
    assert b.sent_fix.get(3, 0) > 50, b.sent_fix  # the companion sent 3D fixes (while disarmed, and in the outage)
    assert math.isfinite(b.own_healthy_mean) and b.own_healthy_mean < 2.0, b.own_healthy_mean


@pytest.mark.timeout(1200)
def test_takeover_after_a_lap_reaches_ekf3_and_keeps_it_bounded(flights):
    a, b = flights["A"], flights["B"]
    assert b.takeover.startswith("takeover"), (b.takeover, b.trust)
    assert b.gps2_fix_denial.get(3, 0) > 20, b.gps2_fix_denial  # the autopilot saw GPS2's fixes during the denial
    assert not math.isfinite(b.left_guided_s), b.events  # no failsafe: the vehicle kept flying its laps
    denial = [e for o, e in b.marks_err if o <= core.SCENARIOS[SCENARIO].deny_s and math.isfinite(e)]
    assert denial and max(denial) < 5.0, b.marks_err  # EKF3 on the companion's fixes stays within metres of truth
    # ArduPilot alone, default parameters, loses its position: EKF failsafe and LAND within the denial
    assert math.isfinite(a.left_guided_s) and a.left_guided_s < core.SCENARIOS[SCENARIO].deny_s, a.events


@pytest.mark.timeout(1200)
def test_companion_does_no_harm_before_the_loss(flights):
    """Healthy flight: mean EKF error with the companion <= 1.1x ArduPilot alone, or within one 1e-7 deg step."""
    a, b = flights["A"].phases["route"][0], flights["B"].phases["route"][0]
    assert b <= 1.1 * a or b - a < 0.011, f"route mean EKF error: {b:.3f} m with the companion vs {a:.3f} m alone"
