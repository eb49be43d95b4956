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


def test_frames_are_the_tlog_frames_without_the_second_imu():
    from pymavlink import mavutil

    from replay.live.wake_cost import circuit_frames

    frames = circuit_frames()
    mav = mavutil.mavlink.MAVLink(None)
    mav.robust_parsing = True
    types = [m.get_type() for _, f in frames for m in (mav.parse_buffer(f) or [])]
    assert len(types) == len(frames)  # one whole, valid frame each
    assert "BAD_DATA" not in types and "SCALED_IMU2" not in types
    assert {"RAW_IMU", "GPS_RAW_INT", "ATTITUDE"} <= set(types)
    times = [t for t, _ in frames]
    assert times == sorted(times)


def test_the_link_work_is_the_same_under_every_pacing():
    from replay.live.wake_cost import LINK_PACINGS, circuit_frames, run_link_paced

    frames = circuit_frames()
    runs = {p: run_link_paced(frames, 1440, 36, p) for p in LINK_PACINGS}
    ref = runs["back to back"][1]
    assert len(ref) >= 1440  # the decoder made events of the frames
    for p, (cpu_s_per_frame, events) in runs.items():
        assert cpu_s_per_frame > 0, p
        assert events == ref, p
    with pytest.raises(ValueError, match="unknown pacing"):
        run_link_paced(frames, 0, 10, "real time, 10 Hz batches")


def test_pacing_table_refuses_runs_that_did_different_work():
    from replay.live.wake_cost import pacing_table

    def same(inputs, warmup, n, pacing):
        return 2e-6 if pacing == "back to back" else 6e-6, list(inputs[warmup:warmup + n])

    table, med = pacing_table(same, list(range(10)), 2, 5, 2, ("back to back", "paced"), "frame")
    assert med == {"back to back": 2e-6, "paced": 6e-6}
    assert "| paced | 5 | 6 | 6, 6 | 3.0 |" in table

    def different(inputs, warmup, n, pacing):
        return 1e-6, [pacing]

    with pytest.raises(AssertionError, match="changed the outputs"):
        pacing_table(different, list(range(10)), 0, 5, 1, ("back to back", "paced"), "frame")
