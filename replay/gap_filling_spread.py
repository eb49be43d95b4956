"""The blockage benchmark's figures with their spread over windows (replay.gap_filling; replay.harness.resample)."""

from __future__ import annotations

import numpy as np

from replay.harness.resample import Window, best_baseline, h_rmse, ratio_to_best, spread

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


#: the methods of a blockage's row in :func:`deciding_tables`, with their column labels
_ROW_METHODS = (("hold", "hold"), ("cv", "CV"), ("knn", "KNN"), ("ins_alone", "INS alone"), ("knn_ins_kf", "full"))


def deciding_tables(per_window: dict[tuple[str, float], list[Window]], modes: dict[str, str], lengths) -> list[str]:
    """The blockages behind each missed target, one row each: where it is (``_window``: start, end, GNSS speed at
    its start and end), every method's H RMSE on it, and its share of the figure's squared error (of the full
    filter's for the pooled RMSE; of full filter minus best baseline for a per-log ratio: the blockages that put
    it above the target)."""
    md = ["### The blockages behind the missed targets", "",
          "Each blockage of a missed figure: start-end (s of the log), GNSS horizontal speed at its last fix before "
          "and first fix after (m/s), every method's H RMSE on it (m), and its share of what decides the figure: of "
          "the full filter's squared error for a pooled RMSE (the five largest), of the full filter's squared error "
          "minus the best baseline's for a per-log ratio (negative: the filter beat it there).", ""]
    head = ("| figure | blockage s | speed m/s | " + " | ".join(lab for _, lab in _ROW_METHODS) + " | share |",
            "|---|---|---|" + "---:|" * (len(_ROW_METHODS) + 1))
    rows: list[str] = []

    def row(fig: str, w: Window, share: float) -> str:
        t0, t1, v0, v1 = (float(x) for x in w["_window"])
        cells = [f"{h_rmse([w], m):.2f}" if m in w else "n/a" for m, _ in _ROW_METHODS]
        return f"| {fig} | {t0:.1f}-{t1:.1f} | {v0:.1f} -> {v1:.1f} | " + " | ".join(cells) + f" | {100 * share:.0f} % |"

    for L in lengths:
        target = POOLED_TARGET_M.get(L)
        ws = [(n, w) for (n, l), v in sorted(per_window.items()) if l == L and modes.get(n) == "ins" for w in v]
        if target is None or not ws or h_rmse([w for _, w in ws], "knn_ins_kf") <= target:
            continue
        sq = np.array([np.sum(w["knn_ins_kf"][:, :2] ** 2) for _, w in ws])
        for i in np.argsort(-sq, kind="stable")[:5]:
            n, w = ws[i]
            rows.append(row(f"pooled {L:g} s ({n[:12]})", w, sq[i] / sq.sum()))
    for (n, L), ws in sorted(per_window.items()):
        if "knn_ins_kf" not in ws[0] or ratio_to_best(ws) <= PER_LOG_TARGET:
            continue
        best = best_baseline(ws)[0]
        d = np.array([np.sum(w["knn_ins_kf"][:, :2] ** 2) - np.sum(w[best][:, :2] ** 2) for w in ws])
        for w, di in zip(ws, d):
            rows.append(row(f"{n[:12]} {L:g} s vs {best}", w, di / d.sum()))
    return md + ["All targets met: no blockage to show.", ""] if not rows else md + [*head, *rows, ""]
