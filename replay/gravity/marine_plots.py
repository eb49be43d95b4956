"""Plots of the marine benchmark (replay.gravity.marine): error against time after the GNSS cut, and accuracy against
the filter map's cell size beside the papers' results."""

from __future__ import annotations

import numpy as np


def error_plot(path, groups: dict[str, list[dict]], title: str) -> None:
    """Horizontal error after the cut per group: the median run (with its 2 x h_acc band) and the mean of the runs, aided
    and INS alone."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(groups)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n + 0.6), sharex=True, squeeze=False)
    for ax, (name, runs) in zip(axes[:, 0], groups.items()):
        means = [r["err_m"].mean() for r in runs]
        r = runs[int(np.argsort(means)[len(means) // 2])]  # the median run
        t = r["t_s"] / 3600.0
        ax.fill_between(t, 0.0, 2e-3 * r["h_acc_m"], color="tab:blue", alpha=0.18, lw=0, label="2 x reported h_acc (median run)")
        ax.plot(t, 1e-3 * r["ins_err_m"], color="tab:red", lw=1.0, label="INS alone (median run)")
        ax.plot(t, 1e-3 * r["err_m"], color="tab:blue", lw=1.0, label=f"sequential filter (median run, seed {r['seed']})")
        L = min(x["t_s"].size for x in runs)
        ax.plot(t[:L], 1e-3 * np.mean([x["err_m"][:L] for x in runs], axis=0), color="tab:blue", lw=1.6, ls="--",
                label=f"filter, mean of {len(runs)} runs")
        ax.plot(t[:L], 1e-3 * np.mean([x["ins_err_m"][:L] for x in runs], axis=0), color="tab:red", lw=1.6, ls="--",
                label=f"INS, mean of {len(runs)} runs")
        ax.set_ylabel("horizontal error (km)")
        ax.set_title(name, fontsize=9, loc="left")
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0.0)
    axes[0, 0].legend(fontsize=7, ncol=3, loc="upper left")
    axes[-1, 0].set_xlabel("hours after the GNSS cut")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def resolution_plot(path, rows: list[tuple[str, float, dict]]) -> None:
    """Aided and INS-alone mean error against the filter map's cell size, with the papers' points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for name, cell_km, sm in rows:
        ax.errorbar(cell_km, sm["mean"] / 1e3, yerr=[[0.0], [(sm["p95"] - sm["mean"]) / 1e3]], fmt="o", color="tab:blue",
                    capsize=3)
        ax.plot(cell_km, sm["ins_mean"] / 1e3, "x", color="tab:red", ms=8)
        ax.annotate(name, (cell_km, sm["mean"] / 1e3), textcoords="offset points", xytext=(6, -10), fontsize=7)
    for label, cell_km, err_km, dy in PAPER_POINTS:
        ax.plot(cell_km, err_km, "s", color="0.4", ms=5)
        ax.annotate(label, (cell_km, err_km), textcoords="offset points", xytext=(5, dy), fontsize=6, color="0.3")
    ax.plot([], [], "o", color="tab:blue", label="sequential filter: mean (bar to p95)")
    ax.plot([], [], "x", color="tab:red", label="INS alone: mean")
    ax.plot([], [], "s", color="0.4", label="papers (their maps, sensors and tracks)")
    ax.set_xlabel("filter map cell (km)")
    ax.set_ylabel("horizontal error after the cut (km)")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("Accuracy vs map cell size, ship 8 m/s, 2 h 40 min after the GNSS cut", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: (label, cell km, error km, label offset in points) of the papers' results in replay.gravity.marine.PAPERS, for
#: the resolution plot
PAPER_POINTS = [("Gao T2", 1.85, 0.150, 4), ("Gao T4", 1.85, 0.494, -7), ("Gao T6", 1.85, 0.554, 3),
                ("Li T3", 0.55, 0.72, 3), ("Li T2", 1.1, 0.92, 3), ("Wu", 3.7, 0.37, 3), ("Liu 30\"", 0.9, 0.048, 3),
                ("Liu 1'", 1.85, 0.141, -9)]
