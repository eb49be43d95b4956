"""Speed targets on one core: RVBMP-2 (n 13, o 7, T 6) per correction <= 100 ms; GF-PF step (100 particles,
20 iterations) <= 20 ms. Median over repeated calls on the benchmark maps.

    nice -n 10 .venv/bin/python -m replay.gravity2.speed
"""

from __future__ import annotations

import os
import time

import numpy as np

from companion.matching.base import MatchWindow
from companion.matching.gradient import LIU_COMPONENTS
from companion.matching.particle import FieldSampler, GravityParticleFilter, PfConfig
from replay.gravity2 import li_viterbi as LI
from replay.gravity2 import liu_pf as LIU
from replay.gravity2.common import md_table, write_section


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


def main():
    t0 = time.time()
    rows = []
    for o, cell, alpha, sub in ((7, LI.NATIVE_CELL_M, 0.1, "cell"), (7, LI.NATIVE_CELL_M / 2, 0.1, "cell"),
                                (7, LI.NATIVE_CELL_M / 2, 0.0, "cell"), (7, LI.NATIVE_CELL_M / 2, 0.1, "interp")):
        rows.append([f"RVBMP-2 n13 o{o} T6 alpha {alpha} cell {cell:.0f} m sub-cells {sub}", "ms / correction", viterbi_ms(o, cell, alpha, sub), 100.0])
    for opt in ("gf", "pso", "apo"):
        rows.append([f"{opt.upper()}-PF 100 particles 20 iterations (5 gradient components)", "ms / step", pf_ms(opt), 20.0 if opt == "gf" else float("nan")])
    load = os.getloadavg()[0]
    write_section("speed", "## Speed (median, one process; machine shared, load average at the end "
                  f"{load:.1f} on {os.cpu_count()} cores)\n\n`nice -n 10 .venv/bin/python -m replay.gravity2.speed`\n\n"
                  + md_table(["what", "unit", "measured", "target"], rows))
    for r in rows:
        print(r)
    print(f"{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
