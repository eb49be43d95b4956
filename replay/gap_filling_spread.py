"""The blockage benchmark's figures with their spread over windows (replay.gap_filling; replay.harness.resample)."""

from __future__ import annotations

import numpy as np

from replay.harness.resample import Window, h_rmse, ratio_to_best, spread

#: the issue's pooled targets for the full filter's H RMSE (GNSS at 1 Hz), m
POOLED_TARGET_M = {8.0: 3.0, 15.0: 8.0, 30.0: 30.0}
#: the per-log target: the full filter within this factor of the best baseline
PER_LOG_TARGET = 1.1


def _fmt(s, digits: int = 2) -> tuple[str, str]:
    loo = "-" if np.isnan(s.loo_min) else f"{s.loo_min:.{digits}f}-{s.loo_max:.{digits}f}"
    return loo, f"{s.lo:.{digits}f}-{s.hi:.{digits}f}"


def spread_tables(per_window: dict[tuple[str, float], list[Window]], modes: dict[str, str], lengths,
                  rng: np.random.Generator, n_boot: int = 2000) -> list[str]:
    md = ["### How far each figure rests on single blockages", "",
          "Each figure recomputed with one blockage left out in turn (the range), and on "
          f"{n_boot} resamples of the blockages drawn with replacement (90 % percentile interval; blockages, not "
          "points, are resampled: a blockage's points share one trajectory). With two or three blockages there are "
          "only 3 or 10 distinct resamples: the interval is coarse, and it is what these data can say. "
          "replay/harness/resample.py.", "",
          "Pooled over the INS logs, KNN+INS+KF H RMSE m:", "",
          "| L s | blockages | H RMSE m | one left out | 90 % interval | target | resamples meeting it |",
          "|---:|---:|---:|---|---|---:|---:|"]
    stat_full = lambda ws: h_rmse(ws, "knn_ins_kf")  # noqa: E731
    for L in lengths:
        ws = [w for (n, l), v in sorted(per_window.items()) if l == L and modes.get(n) == "ins" for w in v]
        if not ws:
            continue
        s = spread(ws, stat_full, rng, n_boot)
        target = POOLED_TARGET_M.get(L)
        loo, ci = _fmt(s)
        md.append(f"| {L:g} | {len(ws)} | {s.value:.2f} | {loo} | {ci} | "
                  + (f"{target:g} | {100 * s.share_at_most(target):.0f} % |" if target else "- | - |"))
    md += ["", f"Per log, ratio KNN+INS+KF / best baseline (target <= {PER_LOG_TARGET:g}; the best baseline chosen "
           "again on each resample):", "",
           "| log | mode | L s | blockages | ratio | one left out | 90 % interval | resamples <= "
           f"{PER_LOG_TARGET:g} |", "|---|---|---:|---:|---:|---|---|---:|"]
    for (n, L), ws in sorted(per_window.items()):
        if "knn_ins_kf" not in ws[0]:
            continue
        s = spread(ws, ratio_to_best, rng, n_boot)
        loo, ci = _fmt(s)
        md.append(f"| {n[:40]} | {modes.get(n, '?')} | {L:g} | {len(ws)} | {s.value:.2f} | {loo} | {ci} | "
                  f"{100 * s.share_at_most(PER_LOG_TARGET):.0f} % |")
    return md + [""]
