"""Results files of the benchmarks: replay/results/<name>.md, each made of sections a benchmark rewrites.

A section is the block between ``<!-- BEGIN key -->`` and ``<!-- END key -->``; rerunning a benchmark replaces its
own section and leaves the others. `python -m replay.collect_benchmarks` assembles BENCHMARKS.md from the files.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
RESULTS_DIR = REPO / "replay" / "results"


def results_file(name: str) -> Path:
    """replay/results/<name>.md"""
    return RESULTS_DIR / f"{name}.md"


def write_section(path: Path, key: str, text: str, title: str) -> None:
    """Replace (or append) the block between <!-- BEGIN key --> and <!-- END key --> in a results file; a new file
    starts with ``# title``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.read_text() if path.exists() else f"# {title}\n\n"
    block = f"<!-- BEGIN {key} -->\n{text.rstrip()}\n<!-- END {key} -->\n"
    pat = re.compile(rf"<!-- BEGIN {re.escape(key)} -->.*?<!-- END {re.escape(key)} -->\n", re.S)
    new = pat.sub(lambda _: block, old) if pat.search(old) else old.rstrip() + "\n\n" + block
    path.write_text(new)


def md_table(header: list[str], rows: list[list]) -> str:
    def f(v):
        if isinstance(v, float):
            return "nan" if not np.isfinite(v) else f"{v:.3f}" if abs(v) < 100 else f"{v:.1f}"
        return str(v)

    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(f(v) for v in r) + " |" for r in rows]
    return "\n".join(out)


def publish(text: str, path: Path, key: str, title: str, *, write: bool = True) -> None:
    """Print a benchmark's section and (unless told not to) write it into its results file."""
    print(text)
    if write:
        write_section(path, key, text, title)


def save_curves(path: Path, plot_curves, xlabel: str, ylabel: str, title: str) -> None:
    """A time-series figure: ``plot_curves(ax)`` draws the curves; labels, legend, grid, saved at 110 dpi."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4))
    plot_curves(ax)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)  # beside, never on, the data
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
