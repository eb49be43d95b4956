"""The spread of a blockage figure over its windows (replay/harness/resample.py), against hand-computed truth."""

import numpy as np
import pytest

from replay.harness.resample import best_baseline, h_rmse, ratio_to_best, spread


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
    assert best_baseline(ws) == ("hold", pytest.approx(np.sqrt(5.0)))
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


def test_deciding_tables_show_the_blockages_behind_each_missed_target():
    from replay.gap_filling_spread import deciding_tables

    def win(full_m, hold_m, t0):
        return _window(full_m, hold_m, 9.0) | {"_window": np.array([t0, t0 + 8.0, 1.5, 0.25])}

    # logA misses both targets: pooled RMSE sqrt((25 + 1) / 2) = 3.6 > 3 m, and 1.9 x hold's; logB meets its ratio
    per_window = {("logA.bin", 8.0): [win(5.0, 1.0, 100.0), win(1.0, 2.5, 130.0)],
                  ("logB.tlog", 8.0): [win(1.0, 2.0, 50.0)]}
    md = deciding_tables(per_window, {"logA.bin": "ins", "logB.tlog": "kinematic"}, [8.0])
    pooled = [line for line in md if line.startswith("| pooled 8 s")]
    assert [line.split("|")[2].strip() for line in pooled] == ["100.0-108.0", "130.0-138.0"]  # largest first
    assert pooled[0].endswith(f"| {100 * 25 / 26:.0f} % |") and "| 1.5 -> 0.2 |" in pooled[0]
    ratio = [line for line in md if line.startswith("| logA.bin 8 s vs hold")]
    # the full filter's squared error minus hold's: +24 and -5.25 per point, so 128 % and -28 % of the excess
    assert [line.rsplit("|", 2)[1].strip() for line in ratio] == ["128 %", "-28 %"]
    assert "| 5.00 |" in ratio[0] and not any("logB" in line for line in md)
    assert deciding_tables({("logB.tlog", 8.0): per_window[("logB.tlog", 8.0)]}, {"logB.tlog": "kinematic"},
                           [8.0])[-2] == "All targets met: no blockage to show."
