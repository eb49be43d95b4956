"""Compute time per match point / filter step with the papers' parameters, one core, no other benchmark running.

    nice -n 10 .venv/bin/python -m replay.gravity.speed [--papers gao-wu|li-liu]

gao-wu: KNN / MSD / ICCP (Gao 2022: R 0.055 deg, step 0.003 deg, window 20, K 17, 15 rotations) on the AK strong
area; RPCM / TERCOM on a 512 x 512 map with a 300 x 15 pattern (Wu 2015 sec. 3.1).
li-liu: RVBMP-2 (n 13, o 7, T 6) per correction (target <= 100 ms); GF-PF step (100 particles, 20 iterations,
target <= 20 ms), median over repeated calls on the benchmark maps.
interp: the maps' bilinear interpolation (companion.gravity.maps.bilinear) against the maintained libraries
(scipy.interpolate.RegularGridInterpolator, xarray.DataArray.interp): CPU time per call and the largest difference
of the values, on the real AK grid, at the query sizes the matchers and filters use.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from companion.gravity import IccpMatcher, KnnMatcher, MatchWindow, MsdSequenceMatcher
from companion.gravity.gradient import LIU_COMPONENTS
from companion.gravity.particle import FieldSampler, GravityParticleFilter, PfConfig
from replay.gravity import li as LI
from replay.gravity import liu as LIU
from replay.gravity.areas import AREAS, area_map
from replay.harness.results import md_table, results_file, write_section

RESULTS_MD = results_file("gravity_speed")
TITLE = "Gravity-aided navigation: speed of the matchers and filters"


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


def gao_wu(argv) -> str:
    from replay.gravity.wu import speed_test

    seq = time_sequence_matchers()
    pat = speed_test()
    load = os.getloadavg()[0]
    cmd = "nice -n 10 .venv/bin/python -m replay.gravity.speed " + " ".join(argv)
    lines = ["## Speed per match point (one core)\n", f"Command: `{cmd.strip()}` (1-min load average at the end: {load:.2f} on 2 cores)\n",
             "| method | parameters | median ms | p95 ms | target | paper |", "|---|---|---|---|---|---|"]
    for k in ("KNN", "MSD", "ICCP"):
        tgt = "<= 50 ms" if k == "KNN" else ""
        paper = "5.87 s (KNN, 2.5 GHz, VS2010)" if k == "KNN" else ""
        lines.append(f"| {k} | Gao: R 0.055 deg, step 0.003 deg, window 20, K 17, 15 rotations | {seq[k][0]:.1f} | {seq[k][1]:.1f} | {tgt} | {paper} |")
    lines.append(f"| RPCM-MSD | 512 x 512 map, {pat['msd_cells'][0]} x {pat['msd_cells'][1]} pattern (FFT) | {pat['msd'][0]:.1f} | max {pat['msd'][1]:.1f} | <= 50 ms | |")
    lines.append(f"| RPCM-MAD | 512 x 512 map, {pat['mad_cells'][0]} x {pat['mad_cells'][1]} pattern (direct) | {pat['mad'][0]:.1f} | max {pat['mad'][1]:.1f} | <= 50 ms | |")
    text = "\n".join(lines) + "\n"
    return text



def viterbi_ms(o: int, cell_m: float, alpha: float, subcell: str = "cell", reps: int = 40) -> float:
    rng = np.random.default_rng(0)
    t, true, z, vmeas = LI.simulate("chain", 1.0, rng, "field", cell_m)
    m = LI._matcher(dict(kind="viterbi", n=13, o=o, alpha=alpha, cell_m=cell_m, subcell=subcell), "chain", 1.0, 6)
    times = []
    for r in range(reps):
        k = 6 * r + 6
        ins = true[k - 6:k] + rng.normal(0, 1500.0, 2)
        win = MatchWindow.of(t[k - 6:k], ins, vmeas[k - 6:k], z[k - 6:k])
        times.append(m.match(win).compute_time_s)
    return 1e3 * float(np.median(times))


def pf_ms(optimizer: str, reps: int = 200) -> float:
    gm = LIU.gradient_map("fine")
    s = FieldSampler.from_gradient_map(gm, LIU_COMPONENTS)
    rng = np.random.default_rng(0)
    pf = GravityParticleFilter(s, PfConfig(optimizer=optimizer), rng, 0.0, np.radians(56.0))
    tr = LIU.trajectory()
    times = []
    for k in range(1, reps + 1):
        i = 10 * k
        y = s(tr.pos_ne_m[i:i + 1, 0], tr.pos_ne_m[i:i + 1, 1])[0] + rng.normal(0, 1.0, 5)
        times.append(pf.step(tr.t_s[i], tr.pos_ne_m[i] + 500.0, tr.vel_ne_mps[i], y).compute_time_s)
    return 1e3 * float(np.median(times))


def li_liu(argv) -> str:
    rows = []
    for o, cell, alpha, sub in ((7, LI.NATIVE_CELL_M, 0.1, "cell"), (7, LI.NATIVE_CELL_M / 2, 0.1, "cell"),
                                (7, LI.NATIVE_CELL_M / 2, 0.0, "cell"), (7, LI.NATIVE_CELL_M / 2, 0.1, "interp")):
        rows.append([f"RVBMP-2 n13 o{o} T6 alpha {alpha} cell {cell:.0f} m sub-cells {sub}", "ms / correction", viterbi_ms(o, cell, alpha, sub), 100.0])
    for opt in ("gf", "pso", "apo"):
        rows.append([f"{opt.upper()}-PF 100 particles 20 iterations (5 gradient components)", "ms / step", pf_ms(opt), 20.0 if opt == "gf" else float("nan")])
    load = os.getloadavg()[0]
    return ("## Speed (median, one process; machine shared, load average at the end "
                  f"{load:.1f} on {os.cpu_count()} cores)\n\n`nice -n 10 .venv/bin/python -m replay.gravity.speed {' '.join(argv)}`\n\n"
            + md_table(["what", "unit", "measured", "target"], rows))



def interp(argv) -> str:
    """CPU time per call of the three bilinear interpolations on the AK grid (same points, same values)."""
    import time

    import xarray as xr
    from scipy.interpolate import RegularGridInterpolator

    from companion.gravity.data import AK_GULF, shared_gravity_dir
    from companion.gravity.maps import bilinear, load_grid

    gmap = load_grid(shared_gravity_dir() / AK_GULF)
    xa, ya, g = gmap.x, gmap.y, gmap.anomaly_mgal
    rgi = RegularGridInterpolator((ya, xa), g, method="linear", bounds_error=False, fill_value=np.nan)
    da = xr.DataArray(g, coords={"y": ya, "x": xa}, dims=("y", "x"))
    rng = np.random.default_rng(5)
    rows = []
    for n, use in ((1, "one reading"), (20, "a matcher window"), (1000, "particle filter / Viterbi candidates"),
                   (100_000, "grid resampling")):
        x, y = rng.uniform(xa[0], xa[-1], n), rng.uniform(ya[0], ya[-1], n)
        ours = bilinear(xa, ya, g, x, y)
        calls = {"ours": lambda: bilinear(xa, ya, g, x, y), "scipy": lambda: rgi(np.column_stack([y, x])),
                 "xarray": lambda: da.interp(x=xr.DataArray(x, dims="p"), y=xr.DataArray(y, dims="p")).values}
        diff = max(float(np.nanmax(np.abs(ours - f()))) for k, f in calls.items() if k != "ours")
        us = {}
        for k, f in calls.items():
            reps = max(5, min(2000, 200_000 // n))
            t0 = time.process_time()
            for _ in range(reps):
                f()
            us[k] = (time.process_time() - t0) / reps * 1e6
        rows.append([f"{n:,} ({use})", us["ours"], us["scipy"], us["xarray"], f"{us['scipy'] / us['ours']:.2f}",
                     f"{diff:.1e}"])
    load = os.getloadavg()[0]
    return ("## Bilinear interpolation: ours against scipy and xarray (CPU time per call, one process; "
            f"load average at the end {load:.1f} on {os.cpu_count()} cores)\n\n"
            f"`nice -n 10 .venv/bin/python -m replay.gravity.speed {' '.join(argv)}` (AK grid {g.shape[0]} x "
            f"{g.shape[1]}, random points inside it; the values agree to the last column's mGal, NaN outside alike)\n\n"
            + md_table(["points per call", "ours us", "scipy RegularGridInterpolator us", "xarray interp us",
                        "scipy / ours", "max |difference| mGal"], rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--papers", choices=("gao-wu", "li-liu", "interp", "all"), default="all")
    ap.add_argument("--no-write", action="store_true")
    argv = list(sys.argv[1:] if argv is None else argv)
    a = ap.parse_args(argv)
    for key, run in (("gao-wu", gao_wu), ("li-liu", li_liu), ("interp", interp)):
        if a.papers in (key, "all"):
            text = run([f"--papers {key}"] if a.papers == "all" else argv)
            print(text)
            if not a.no_write:
                write_section(RESULTS_MD, key, text, TITLE)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
