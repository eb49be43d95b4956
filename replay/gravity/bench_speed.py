"""Compute time per match point with the papers' parameters, one core, no other benchmark running.

    nice -n 10 .venv/bin/python -m replay.gravity.bench_speed

KNN / MSD / ICCP (Gao 2022: R 0.055 deg, step 0.003 deg, window 20, K 17, 15 rotations) on the AK
strong area; RPCM / TERCOM on a 512 x 512 map with a 300 x 15 pattern (Wu 2015 sec. 3.1).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from companion.matching import IccpMatcher, KnnMatcher, MatchWindow, MsdSequenceMatcher
from replay.gravity.common import AREAS, area_map, write_section


def time_sequence_matchers(n_windows: int = 40, seed: int = 11) -> dict[str, tuple[float, float]]:
    lmap = area_map(AREAS["AK-strong"])
    rng = np.random.default_rng(seed)
    ms = {"KNN": KnnMatcher(lmap, k=17), "MSD": MsdSequenceMatcher(lmap), "ICCP": IccpMatcher(lmap)}
    times = {k: [] for k in ms}
    for _ in range(n_windows):
        h = np.radians(rng.uniform(0, 360))
        start = rng.uniform(-40_000, 40_000, 2)
        true = start + np.outer(np.arange(20) * 1750.0, [np.cos(h), np.sin(h)])
        g = lmap.interp_ne(true[:, 0], true[:, 1]) + rng.normal(0, 3, 20)
        win = MatchWindow.of(np.arange(20) * 336.0, true + rng.normal(0, 3000, 2), np.tile([5 * np.cos(h), 5 * np.sin(h)], (20, 1)), g)
        for k, m in ms.items():
            r = m.match(win)
            if r.ok:
                times[k].append(r.compute_time_s)
    return {k: (1e3 * float(np.median(v)), 1e3 * float(np.percentile(v, 95))) for k, v in times.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args(argv)
    from replay.gravity.bench_wu import speed_test

    seq = time_sequence_matchers()
    pat = speed_test()
    load = os.getloadavg()[0]
    cmd = "nice -n 10 .venv/bin/python -m replay.gravity.bench_speed " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = ["## Speed per match point (one core)\n", f"Command: `{cmd.strip()}` (1-min load average at the end: {load:.2f} on 2 cores)\n",
             "| method | parameters | median ms | p95 ms | target | paper |", "|---|---|---|---|---|---|"]
    for k in ("KNN", "MSD", "ICCP"):
        tgt = "<= 50 ms" if k == "KNN" else ""
        paper = "5.87 s (KNN, 2.5 GHz, VS2010)" if k == "KNN" else ""
        lines.append(f"| {k} | Gao: R 0.055 deg, step 0.003 deg, window 20, K 17, 15 rotations | {seq[k][0]:.1f} | {seq[k][1]:.1f} | {tgt} | {paper} |")
    lines.append(f"| RPCM-MSD | 512 x 512 map, {pat['msd_cells'][0]} x {pat['msd_cells'][1]} pattern (FFT) | {pat['msd'][0]:.1f} | max {pat['msd'][1]:.1f} | <= 50 ms | |")
    lines.append(f"| RPCM-MAD | 512 x 512 map, {pat['mad_cells'][0]} x {pat['mad_cells'][1]} pattern (direct) | {pat['mad'][0]:.1f} | max {pat['mad'][1]:.1f} | <= 50 ms | |")
    text = "\n".join(lines) + "\n"
    print(text)
    if not a.no_write:
        write_section("speed", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
