"""The live-pacing benchmark (replay.live.wake_cost): every pacing gives the navigator the same work."""

import pytest

from replay.live.wake_cost import PACINGS, circuit_events, run_paced


@pytest.fixture(scope="module")
def events():
    return circuit_events()


def test_every_pacing_gives_the_same_outputs(events):
    # 0.5 s of flight after 20 s: the filter is initialised and producing outputs at 10 Hz
    warmup, n = 1440, 36
    runs = {p: run_paced(events, warmup, n, p) for p in PACINGS}
    ref = runs["back to back"][1]
    assert len(ref) > warmup // 10  # outputs were made (ticks, updates)
    for p, (cpu_per_event, outs) in runs.items():
        assert cpu_per_event > 0, p
        assert outs == ref, p


def test_batches_end_on_the_grid_whatever_the_rounding(events):
    # event times on the 0.1 s grid (0.02 s IMU steps sum with rounding): each batch must still move on
    grid = events[1440:1500]
    _, outs = run_paced(grid, 0, len(grid), "real time, 10 Hz batches")
    _, ref = run_paced(grid, 0, len(grid), "back to back")
    assert outs == ref


def test_bad_arguments(events):
    with pytest.raises(ValueError, match="unknown pacing"):
        run_paced(events, 0, 10, "as fast as it can")
    with pytest.raises(ValueError, match="no events"):
        run_paced(events[:5], 5, 10, "back to back")
