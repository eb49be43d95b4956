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
