"""Assemble BENCHMARKS.md from the measured tables under replay/results/ (each written by its benchmark), with a
one-page summary at the top (replay/benchmark_summary.py).

    .venv/bin/python -m replay.collect_benchmarks

Every section keeps the command that produced it; this script only concatenates, shifts headings one
level down, makes image links relative to the repository root and reads each section's headline into the summary.
It measures nothing itself.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from replay import benchmark_summary

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "replay" / "results"
ORDER = ["install.md", "ingest.md", "gap_filling.md", "live.md", "gravity_summary.md", "gravity_speed.md", "gravity_gao.md",
         "gravity_wu.md", "gravity_li.md", "gravity_liu.md", "gravity_marine.md", "gravity_live_aircraft.md",
         "gravity_live_drone.md", "gravity_live_ship.md", "gravity_live_ship_sequential.md",
         "gravity_live_ship_sequential_vel.md",
         "gravity_live_ship_s8_pos.md", "gravity_live_ship_s8_vel.md"]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m replay.collect_benchmarks", description=__doc__.split("\n\n")[0],
                                 epilog="It writes BENCHMARKS.md in the repository root (replacing it).")
    ap.add_argument("--check", action="store_true", help="only say whether BENCHMARKS.md is up to date (exit 1 if not)")
    args = ap.parse_args(argv)
    files = [RESULTS / n for n in ORDER if (RESULTS / n).exists()]
    files += sorted(p for p in RESULTS.glob("*.md") if p not in files)
    head = [
        "# Benchmarks\n",
        "Measured numbers only. Each section below was produced by the command it names (run from the "
        "repository root on this project's 2-core machine) and copied here by "
        "`python -m replay.collect_benchmarks`, which also writes the summary from them. Real data come from "
        "`../shared`.\n",
    ]
    body = []
    for p in files:
        text = p.read_text()
        text = re.sub(r"^(#+) ", lambda m: "#" + m.group(1) + " ", text, flags=re.M)
        text = re.sub(r"\]\((?!https?:|replay/|/|#)([^)]+\.png)\)", r"](replay/results/\1)", text)
        body.append(text.rstrip() + "\n")
    pngs = sorted(RESULTS.glob("*.png"))
    if pngs:
        body.append("## Plots\n")
        body += [f"- [{p.stem}](replay/results/{p.name})" for p in pngs]
        body.append("")
    # each section's anchor: its first heading's, counted over the whole document (the summary's own heading first)
    seen: dict[str, int] = {}
    benchmark_summary.anchors("# Benchmarks\n## Summary\n", seen)
    anchor = {p: benchmark_summary.anchors(part, seen)[0] for p, part in zip(files, body)}
    summary = benchmark_summary.summary(files, _title, anchor.__getitem__, lambda p: _plots(p, files, pngs))
    parts = head + [summary] + body
    text = "\n".join(parts)
    if args.check:
        current = (ROOT / "BENCHMARKS.md").read_text() if (ROOT / "BENCHMARKS.md").exists() else ""
        print("BENCHMARKS.md is " + ("up to date" if current == text else "out of date"))
        raise SystemExit(0 if current == text else 1)
    (ROOT / "BENCHMARKS.md").write_text(text)
    print(f"BENCHMARKS.md: {len(files)} sections from {', '.join(p.name for p in files)}")


def _title(p: Path) -> str:
    for line in p.read_text().splitlines():
        if line.startswith("# "):
            return line[2:].strip()
    return p.stem


def _plots(p: Path, files: list[Path], pngs: list[Path]) -> list[Path]:
    """The plots of a results file: those named after it and not after a longer-named one."""
    def owner(png: Path) -> Path | None:
        names = [f for f in files if png.stem == f.stem or png.stem.startswith(f.stem + "_")]
        return max(names, key=lambda f: len(f.stem)) if names else None
    return [q for q in pngs if owner(q) == p]


if __name__ == "__main__":
    main()
