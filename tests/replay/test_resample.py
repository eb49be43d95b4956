"""The spread of a blockage figure over its windows (replay/harness/resample.py), against hand-computed truth."""

import numpy as np
import pytest

from replay.harness.resample import h_rmse, ratio_to_best, spread


def _window(full_m: float, hold_m: float, ins_m: float, n: int = 4) -> dict[str, np.ndarray]:
    """Every point of the window off by these horizontal distances (north only)."""
    e = lambda d: np.tile([d, 0.0, 0.5], (n, 1))  # noqa: E731 - the vertical error never counts
    return {"knn_ins_kf": e(full_m), "hold": e(hold_m), "ins_alone": e(ins_m)}


def test_h_rmse_pools_points_and_ignores_height():
    ws = [_window(3.0, 0, 0, n=1), _window(4.0, 0, 0, n=3)]
    assert h_rmse(ws, "knn_ins_kf") == pytest.approx(np.sqrt((9 + 3 * 16) / 4))


def test_ratio_takes_the_best_baseline_of_these_windows():
    ws = [_window(2.0, 1.0, 4.0), _window(2.0, 3.0, 4.0)]
    assert ratio_to_best(ws) == pytest.approx(2.0 / np.sqrt(5.0))  # hold's RMSE sqrt((1 + 9) / 2) beats INS's 4
    assert ratio_to_best(ws[1:]) == pytest.approx(2.0 / 3.0)
    with pytest.raises(ValueError):
        ratio_to_best([{"knn_ins_kf": np.zeros((1, 3))}])


def test_identical_windows_have_no_spread():
    ws = [_window(1.3, 1.0, 2.0) for _ in range(3)]
    s = spread(ws, ratio_to_best, np.random.default_rng(1), n_boot=200)
    assert s.value == s.loo_min == s.loo_max == s.lo == s.hi == pytest.approx(1.3)
    assert s.share_at_most(1.1) == 0.0


def test_one_deciding_window_shows_in_the_leave_one_out_range_and_the_interval():
    # two windows where the filter beats hold 2:1, one where it is 4x worse: that window decides the ratio
    ws = [_window(1.0, 2.0, 9.0), _window(1.0, 2.0, 9.0), _window(8.0, 2.0, 9.0)]
    s = spread(ws, ratio_to_best, np.random.default_rng(2), n_boot=4000)
    assert s.value == pytest.approx(np.sqrt(66 / 3) / 2.0)
    assert s.loo_min == pytest.approx(0.5)  # the bad window left out
    assert s.loo_max == pytest.approx(np.sqrt(65 / 2) / 2.0)
    # resamples with no bad window (P = 8/27) give 0.5, the 5th percentile; all three bad (1/27 < 5 %) lie above the
    # 95th, which falls among those with two (6/27): sqrt((2 * 64 + 1) / 3) / 2
    assert s.lo == pytest.approx(0.5) and s.hi == pytest.approx(np.sqrt(129 / 3) / 2.0)
    # P(no bad window among 3 draws) = (2/3)^3 = 0.296: the share of resamples at ratio 0.5
    assert s.share_at_most(0.5) == pytest.approx((2 / 3) ** 3, abs=0.03)


def test_seeded_and_checked():
    ws = [_window(1.0 + i, 2.0, 3.0) for i in range(4)]
    a = spread(ws, ratio_to_best, np.random.default_rng(7), n_boot=300)
    b = spread(ws, ratio_to_best, np.random.default_rng(7), n_boot=300)
    assert np.array_equal(a.samples, b.samples)
    one = spread(ws[:1], ratio_to_best, np.random.default_rng(7), n_boot=10)
    assert np.isnan(one.loo_min) and one.lo == one.hi == one.value
    with pytest.raises(ValueError):
        spread([], ratio_to_best, np.random.default_rng(0))
    with pytest.raises(ValueError):
        spread(ws, ratio_to_best, np.random.default_rng(0), level=1.0)


def test_spread_tables_report_each_length_and_log_against_its_target():
    from replay.gap_filling_spread import spread_tables

    per_window = {("logA.bin", 8.0): [_window(2.0, 4.0, 5.0), _window(4.0, 4.0, 5.0)],
                  ("logB.tlog", 8.0): [{"knn_ins_kf": np.tile([1.0, 0.0, 0.0], (3, 1)),
                                        "hold": np.tile([2.0, 0.0, 0.0], (3, 1))}]}
    md = spread_tables(per_window, {"logA.bin": "ins", "logB.tlog": "kinematic"}, [8.0], np.random.default_rng(0),
                       n_boot=50)
    pooled = next(line for line in md if line.startswith("| 8 | 2 |"))  # INS logs only: logA's two blockages
    cells = [c.strip() for c in pooled.strip("|").split("|")]
    assert cells[2] == f"{np.sqrt(10.0):.2f}" and cells[3] == "2.00-4.00" and cells[5] == "3"
    row_a = next(line for line in md if line.startswith("| logA.bin | ins | 8 | 2 |"))
    assert f"| {np.sqrt(10.0) / 4.0:.2f} |" in row_a  # hold's 4 m is the best baseline on both windows
    row_b = next(line for line in md if line.startswith("| logB.tlog | kinematic | 8 | 1 |"))
    assert "| 0.50 | - | 0.50-0.50 | 100 % |" in row_b
