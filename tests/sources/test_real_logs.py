"""Every real log in ../shared/data/logs ingests; counts, rates and gaps match its MANIFEST."""

from __future__ import annotations

import numpy as np
import pytest

from companion.events import Attitude, GnssFix, ImuSample
from companion.sources import read_events
from companion.stats import StreamStats
from tests.conftest import LOG171, LOG_AC313, LOG_AC402, LOG_ERLE, LOG_TLOG, require

# (log, duration_s, gnss_hz, {imu_index: hz}) as the MANIFEST states them
EXPECTED = [
    (LOG171, 242.6, 5.0, {0: 50.0, 1: 50.0, 2: 50.0}),
    (LOG_AC313, 332.5, 5.0, {0: 50.0, 1: 50.0}),
    (LOG_ERLE, 112.0, 5.56, {0: 50.0}),
    (LOG_AC402, 199.2, 5.0, {}),
    (LOG_TLOG, 1393.8, 1.25, {0: 1.25, 1: 1.25, 2: 1.25}),
]

_cache: dict = {}


def stats_for(path):
    if path not in _cache:
        evs = read_events(require(path))
        st = StreamStats()
        for e in evs:
            st.add(e)
        _cache[path] = (evs, st)
    return _cache[path]


@pytest.mark.parametrize("path,duration_s,gnss_hz,imu_hz", EXPECTED, ids=lambda v: getattr(v, "stem", None))
def test_counts_and_rates_match_manifest(path, duration_s, gnss_hz, imu_hz):
    evs, st = stats_for(path)
    assert st.duration_s == pytest.approx(duration_s, abs=0.6)
    assert st.gnss_rate_hz == pytest.approx(gnss_hz, rel=0.03)
    rates = st.imu_rates_hz()
    assert set(rates) == set(imu_hz)
    for i, hz in imu_hz.items():
        assert rates[i] == pytest.approx(hz, rel=0.05)
    t = np.array([e.t_s for e in evs])
    assert np.all(np.diff(t) >= 0), "events come out in time order"
    assert any(isinstance(e, GnssFix) and e.has_position for e in evs)


def test_ac313_gps_time_of_week_and_boot_time():
    evs, st = stats_for(LOG_AC313)
    fix = next(e for e in evs if isinstance(e, GnssFix))
    # first GPS row: TimeMS = 3880600 is GPS time of week, T = 313001 ms is boot time
    assert fix.t_s == pytest.approx(313.001)
    assert fix.gps_tow_s == pytest.approx(3880.6) and fix.gps_week == 1815
    assert fix.lat_deg == pytest.approx(30.1557346) and fix.alt_msl_m == pytest.approx(297.88)
    assert st.gaps() == []  # MANIFEST: no gaps, always 3D fix


def test_log171_no_fix_at_start_and_arming_pause():
    evs, st = stats_for(LOG171)
    gaps = st.gaps()
    first = gaps[0]
    assert first.kind == "gnss" and first.duration_s == pytest.approx(33.7, abs=1.0)  # "no fix for the first 33 s"
    stream = [g for g in gaps if g.kind == "stream"]
    assert len(stream) == 1 and stream[0].duration_s == pytest.approx(2.0, abs=0.2)  # "all messages stop 2.1 s"
    nofix = [e for e in evs if isinstance(e, GnssFix) and not e.has_position]
    assert len(nofix) == 161  # "161 rows with Status=1"
    assert all(e.lat_deg is None for e in nofix)


def test_erle_inflight_gps_loss_is_reported_as_gap():
    evs, st = stats_for(LOG_ERLE)
    gnss_gaps = [g for g in st.gaps() if g.kind == "gnss"]
    assert len(gnss_gaps) == 1
    g = gnss_gaps[0]
    assert g.start_s - st.first_s == pytest.approx(77.7, abs=1.5)
    assert g.end_s == st.last_s and g.duration_s > 30.0
    # rows keep arriving during the loss with Status 0/1 and Lat=Lng=0: clean no-position events
    during = [e for e in evs if isinstance(e, GnssFix) and e.t_s > g.start_s]
    assert during and all(not e.has_position and e.fix_type <= 1 for e in during)


def test_ac402_has_no_imu_and_says_so():
    evs, st = stats_for(LOG_AC402)
    assert not any(isinstance(e, (ImuSample, Attitude)) for e in evs)
    assert any("no IMU" in w for w in st.warnings())
    gps2 = [e for e in evs if isinstance(e, GnssFix) and e.instance == 1]
    assert len(gps2) == 983
    fix = next(e for e in evs if isinstance(e, GnssFix) and e.instance == 0)
    # AC 4.x: TimeUS boot time, GPA accuracies merged into the fix
    assert fix.t_s == pytest.approx(5.763299)
    assert (fix.h_acc_m, fix.v_acc_m, fix.speed_acc_mps, fix.vdop) == pytest.approx((4.63, 6.53, 0.65, 1.47))
    assert fix.gps_week == 2095 and fix.gps_tow_s == pytest.approx(220768.4)


def test_tlog_boot_time_and_glitch_messages():
    evs, st = stats_for(LOG_TLOG)
    fixes = [e for e in evs if isinstance(e, GnssFix)]
    assert fixes[0].t_s == pytest.approx(96.668)  # GPS_RAW_INT.time_usec is boot time
    assert all(f.vel_d_mps is None for f in fixes)  # GPS_RAW_INT has no vertical speed
    texts = [e.text for e in evs if type(e).__name__ == "StatusText"]
    assert any("GPS Glitch" in t for t in texts)
