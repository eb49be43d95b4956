"""Assemble BENCHMARKS.md from the measured tables under replay/results/ (each written by its benchmark).

    .venv/bin/python -m replay.collect_benchmarks

Every section keeps the command that produced it; this script only concatenates, shifts headings one
level down and makes image links relative to the repository root. It measures nothing itself.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

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
    parts = [
        "# Benchmarks\n",
        "Measured numbers only. Each section below was produced by the command it names (run from the "
        "repository root on this project's 2-core machine) and copied here by "
        "`python -m replay.collect_benchmarks`. Real data come from `../shared`.\n",
    ]
    parts += [f"- [{_title(p)}](#{_anchor(_title(p))})" for p in files]
    parts.append("")
    for p in files:
        text = p.read_text()
        text = re.sub(r"^(#+) ", lambda m: "#" + m.group(1) + " ", text, flags=re.M)
        text = re.sub(r"\]\((?!https?:|replay/|/|#)([^)]+\.png)\)", r"](replay/results/\1)", text)
        parts.append(text.rstrip() + "\n")
    pngs = sorted(RESULTS.glob("*.png"))
    if pngs:
        parts.append("## Plots\n")
        parts += [f"- [{p.stem}](replay/results/{p.name})" for p in pngs]
        parts.append("")
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


def _anchor(title: str) -> str:
    return re.sub(r"[^a-z0-9 _-]", "", title.lower()).replace(" ", "-")


if __name__ == "__main__":
    main()
