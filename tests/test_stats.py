"""Stream statistics keep bounded memory for a live service and still find every gap."""

from __future__ import annotations

import pytest

from companion.events import GnssFix, ImuSample
from companion.stats import RATE_WINDOW, StreamStats


def _fix(t, ok=True):
    return GnssFix(t, 3 if ok else 1, 1.0 if ok else None, 2.0 if ok else None, 3.0 if ok else None,
                   None, None, None, None, None, 8, 1.0, None, None, None, None, None, None)


def test_long_stream_bounded_memory_rates_and_gaps():
    st = StreamStats()
    n_imu = 0
    t = 0.0
    for k in range(60_000):  # 100 min at 10 Hz GNSS, 50 Hz IMU
        t = k * 0.1
        lost = 3000.0 <= t < 3012.0
        st.add(_fix(t, ok=not lost))
        for j in range(5):
            st.add(ImuSample(t + j * 0.02, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0))
            n_imu += 1
    assert len(st._fixes.recent) <= RATE_WINDOW and len(st._imu[0].recent) <= RATE_WINDOW
    assert st.gnss_rate_hz == pytest.approx(10.0) and st.imu_rates_hz()[0] == pytest.approx(50.0)
    assert st.counts["ImuSample[0]"] == n_imu
    (gap,) = st.gnss_gaps()
    assert gap.start_s == pytest.approx(2999.9) and gap.end_s == pytest.approx(3012.0)


def test_gnss_gaps_judged_against_the_local_rate():
    """A telemetry stream at 0.4 Hz (before the ground station sets stream rates) then 1.25 Hz has no gap at either
    rate; a fix stream that stops for longer than three local intervals does, at either rate."""
    st = StreamStats()
    t, times = 0.0, []
    for k in range(200):
        t += 2.6 if k < 12 else 0.8  # 0.38 Hz, then 1.25 Hz
        if 120 <= k < 128:  # 8 fixes missing at 1.25 Hz: a 7.2 s gap
            continue
        times.append(t)
    for x in times:
        st.add(_fix(x))
    gaps = st.gnss_gaps()
    assert [round(g.duration_s, 1) for g in gaps] == [7.2]
    # the same slow start with one 9 s interval (more than 3 x 2.6 s): a gap at the slow rate too
    st = StreamStats()
    t = 0.0
    for k in range(60):
        t += 9.0 if k == 6 else (2.6 if k < 12 else 0.8)
        st.add(_fix(t))
    assert [round(g.duration_s, 1) for g in st.gnss_gaps()] == [9.0]


def test_gap_notes_tell_a_lost_fix_from_missing_messages():
    st = StreamStats()
    for k in range(100):
        t = k * 0.2
        if 40 <= k < 60:  # the receiver reports, without a position
            st.add(_fix(t, ok=False))
        elif not 70 <= k < 80:  # nothing arrives (a telemetry drop-out)
            st.add(_fix(t))
    lost, silent = st.gnss_gaps()
    assert lost.note == "no fix (20 rows without position)" and lost.duration_s == pytest.approx(4.2)
    assert silent.note == "no GNSS message (valid fixes around)" and silent.duration_s == pytest.approx(2.2)
    assert all(len(line) <= 80 for line in st.format().splitlines())
