"""The one reorder buffer: time order, then type priority, then arrival order."""

from __future__ import annotations

from companion.events import Attitude, GnssFix, ImuSample
from companion.nav.reorder import ReorderBuffer


def _imu(t):
    return ImuSample(t, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0)


def test_priority_orders_equal_times_and_flush_releases_the_rest():
    buf = ReorderBuffer(0.5, {ImuSample: 0, Attitude: 1, GnssFix: 2}, default_priority=3)
    att = Attitude(1.0, 0.0, 0.0, 0.0)
    out = buf.push(att) + buf.push(_imu(1.0)) + buf.push(_imu(0.9)) + buf.push(_imu(1.6))
    assert [(type(e).__name__, e.t_s) for e in out] == [("ImuSample", 0.9), ("ImuSample", 1.0), ("Attitude", 1.0)]
    assert [e.t_s for e in buf.flush()] == [1.6] and buf.newest_s == 1.6


def test_zero_horizon_passes_through_and_tracks_the_newest():
    buf = ReorderBuffer(0.0)
    assert buf.push(_imu(2.0)) and buf.push(_imu(1.0))[0].t_s == 1.0 and buf.newest_s == 2.0 and buf.late == 0
