"""Gravity aiding on a real ArduRover SITL motorboat (replay.live.sitl_gravity --vehicle rover), short: a survey over
the Tasman grid with GNSS for a few minutes, then GPS1 denied for a few minutes at speed-up; the companion arm only.
ArduRover alone has no way to know where it is without GNSS and its EKF failsafe holds the boat within seconds
(replay/results/sitl_gravity_boat_*.md). Checks that the boat's water-speed log and the gravimeter reach the companion,
that EKF3 takes the companion's fixes from the loss on (no EKF failsafe, no mode change: the boat keeps its mission)
and stays within what they claim. Needs an ArduRover SITL binary named by COMPANION_SITL_ROVER_BIN (built outside
this repository); skipped otherwise."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from companion.record.inspect import iter_payloads
from replay.live import sitl_core as core
from replay.live import sitl_gravity
from tests.conftest import TASMAN_MAP, require, sitl_binary

pytestmark = pytest.mark.slow

HEALTHY_MIN, DENIAL_MIN = 4.0, 5.0


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    bin_ = sitl_binary("COMPANION_SITL_ROVER_BIN", "ArduRover", "rover")
    out = tmp_path_factory.mktemp("sitl_gravity_boat")
    rc = sitl_gravity.main(["--sitl-bin", bin_, "--vehicle", "rover", "--map", str(require(TASMAN_MAP)),
                            "--origin=-31.0,156.0", "--arms", "companion", "--healthy-min", str(HEALTHY_MIN),
                            "--denial-min", str(DENIAL_MIN), "--back-min", "1", "--speedup", "4", "--outdir", str(out)])
    summary = json.loads((out / "summary.json").read_text())
    log = core.FlightLog.from_dict(json.loads((out / "companion" / "log.json").read_text()))
    return rc, summary, log, out


@pytest.mark.timeout(2400)
def test_log_and_gravimeter_reach_the_companion(flight):
    rc, summary, log, out = flight
    b = summary["arms"]["companion"]
    assert not b["notes"], b["notes"]  # every parameter held (EK3_GPS_CHECK among them), every wait met
    assert b["kept_up"], (b["companion_lag"], b["truth_max_gap_s"])
    flown_s = log.marks["end"] - log.marks["route"]
    text = (out / "companion" / "companion.out").read_text()
    m = re.search(r"gravity +(\d+) readings", text)
    assert m and int(m.group(1)) > 0.8 * flown_s, (m and m.group(0), flown_s)
    speeds = [1 for _ in iter_payloads(out / "companion" / "companion.mcap", "/input/water_speed")]
    assert len(speeds) > 1.6 * flown_s  # 2 Hz, routed by the autopilot like the gravimeter's


@pytest.mark.timeout(2400)
def test_ekf3_takes_the_fixes_from_the_loss_and_the_boat_keeps_its_mission(flight):
    rc, summary, log, out = flight
    b = summary["arms"]["companion"]
    assert b["failsafes"] == [], b["failsafes"]  # no EKF failsafe, no HOLD: alone holds within 6 s of the loss
    on, off = log.marks["deny_on"], log.marks["deny_off"]
    gps2 = [f for t, f, _s in log.gps[2] if on + 2.0 <= t < off]
    assert gps2 and np.mean(np.array(gps2) >= 3) > 0.95, gps2[:20]  # 3D from the loss on
    assert b["fixes_in_denial"] > 100 and b["within_2hacc_frac"] >= 0.9, b
    assert b["max_m"] <= 2.0 * b["last_hacc_m"] + 50.0, b  # EKF3 within what the fixes claim, its lag on top
    assert b["cross_track_max_m"] < 200.0, b  # on its lines
