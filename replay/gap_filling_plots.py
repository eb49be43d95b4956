"""Plots of the gap-filling benchmark (replay/gap_filling.py): the pooled RMSE per blockage length and one 8 s
blockage drawn on the map with every method."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import FusedState, PredictorPoint
from replay.harness.blockages import (METHOD_LABEL, METHODS, LogData, choose_windows, decimate_mask, drop_fixes, free_ins,
                                      in_windows, series, stats)
from replay.harness.baselines import constant_velocity, hold_last_fix, withhold_aiding


def example(outdir: Path, ins_logs: list[LogData], dec, cfg: NavigatorConfig) -> None:
    """The 8 s blockage example: the middle window of the longest INS log."""
    if ins_logs:
        lg = max(ins_logs, key=lambda x: x.duration_s)
        wins = choose_windows(lg, 8.0, 0.0)
        if wins:
            plot_example(outdir / "gap_filling_example_8s.png", lg, wins[len(wins) // 2], dec, cfg)


def plot_example(path: Path, log: LogData, window: tuple[float, float], dec, cfg: NavigatorConfig) -> None:
    """North/east track of one 8 s blockage: truth fixes and every method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a, b = window
    keep = decimate_mask(log.fix_t, dec) & ~in_windows(log.fix_t, [window])
    events = drop_fixes(log.events, set(log.fix_t[~keep].tolist()))
    full = run_navigator(events, cfg)
    alone = run_navigator(withhold_aiding(events, [window]), free_ins(cfg))
    tq = np.arange(a, b, 0.1)
    m = (log.fix_t >= a - 3) & (log.fix_t < b + 2)
    avail = keep
    fig, ax = plt.subplots(figsize=(9.5, 6))
    ax.plot(log.fix_ned[m, 1], log.fix_ned[m, 0], "k.", ms=4, label="GNSS fixes (truth inside the blockage)")
    ax.plot(hold_last_fix(log.fix_t[avail], log.fix_ned[avail], tq)[:, 1],
            hold_last_fix(log.fix_t[avail], log.fix_ned[avail], tq)[:, 0], "s", ms=6, label="hold last fix")
    cv = constant_velocity(log.fix_t[avail], log.fix_ned[avail], log.fix_vel[avail], tq)
    ax.plot(cv[:, 1], cv[:, 0], "-", label="constant velocity")
    pt, pn = series(full, log.frame, PredictorPoint)
    sel = (pt >= a) & (pt < b)
    ax.plot(pn[sel, 1], pn[sel, 0], "-", label="KNN predictor")
    at, an = series(alone, log.frame, FusedState)
    sel = (at >= a) & (at < b)
    ax.plot(an[sel, 1], an[sel, 0], "-", label="INS alone")
    ft, fn = series(full, log.frame, FusedState)
    # the fused track, drawn in two pieces: its correction at the first fix after the blockage is a jump of the
    # estimate, not a path the vehicle flew (dotted)
    later = log.fix_t[keep & (log.fix_t >= b)]
    t_fix = float(later.min()) if later.size else b  # the first fix the navigator gets after the blockage
    inside, after = (ft >= a - 3) & (ft < t_fix), (ft >= t_fix) & (ft < b + 2)
    line = ax.plot(fn[inside, 1], fn[inside, 0], "-", lw=2.5, label="KNN + INS + Kalman")[0]
    if inside.any() and after.any():
        i, j = np.flatnonzero(inside)[-1], np.flatnonzero(after)[0]
        ax.plot(fn[[i, j], 1], fn[[i, j], 0], ":", lw=1.2, color=line.get_color(),
                label="its correction at the first fix after")
        ax.plot(fn[after, 1], fn[after, 0], "-", lw=2.5, color=line.get_color())
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)  # beside the track
    ax.set_title(f"{log.name}\n8 s blockage at t = {a:.1f} s (GNSS {dec or 'native'} Hz)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_rmse(outdir: Path, pooled, lengths) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    outdir.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for m in METHODS:
        xs = [L for L in lengths if L in pooled and m in pooled[L]]
        ys = [stats(np.concatenate(pooled[L][m]))["h_rmse"] for L in xs]
        if xs:
            ax.plot(xs, ys, "o-", label=METHOD_LABEL[m].strip("*"), lw=2.5 if m == "knn_ins_kf" else 1.2)
    ax.set_xlabel("GNSS blockage length (s)")
    ax.set_ylabel("horizontal RMSE (m)")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)  # beside the data
    ax.set_title("Gap filling on the shared ArduCopter logs (INS mode, pooled)")
    fig.tight_layout()
    fig.savefig(outdir / "gap_filling_rmse.png", dpi=120)
    plt.close(fig)
