"""The long-denial benchmark's drawn survey start (replay.live.long_denial.draw_origin): over features by the marine
benchmark's rule, and the same for the same seed."""

import numpy as np

from companion.gravity.data import TASMAN
from tests.conftest import SHARED_GRAVITY, require


def test_drawn_origin_sees_the_required_signal_and_is_deterministic():
    require(SHARED_GRAVITY / TASMAN)
    from companion.gravity.maps import LocalGravityMap, load_grid
    from companion.sim.cruise import survey_waypoints
    from replay.live.long_denial import draw_origin

    args = dict(speed_mps=8.0, hours=3.0, line_km=40.0, spacing_km=5.0, cut_s=1200.0, min_track_std_mgal=15.0)
    lat, lon, std = draw_origin(7, **args)
    assert (lat, lon, std) == draw_origin(7, **args)
    assert draw_origin(8, **args)[:2] != (lat, lon)
    assert std >= 15.0
    # checked independently: the survey's path sampled on the grid from that start (a frame at the start itself)
    lmap = LocalGravityMap.around(load_grid(SHARED_GRAVITY / TASMAN), lat, lon)
    wps = np.array([(0.0, 0.0)] + survey_waypoints(8.0 * 3 * 3600.0, 40e3, 5e3, 0.0))
    seg = [p0 + np.outer(np.arange(0.0, np.hypot(*(p1 - p0)), 100.0) / np.hypot(*(p1 - p0)), p1 - p0)
           for p0, p1 in zip(wps[:-1], wps[1:])]  # every 100 m of track
    path = np.concatenate(seg)
    g = lmap.interp_ne(path[:, 0], path[:, 1])
    assert np.all(np.isfinite(g))
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    after = g[travelled >= 1200.0 * 8.0]
    assert abs(np.std(after) - std) < 0.1 * std
