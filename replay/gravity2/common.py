"""Shared pieces of the part II benchmarks: result file sections, the Tasman long-track map."""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

import numpy as np

from companion.matching.data import TASMAN
from companion.matching.maps import LocalGravityMap
from replay.gravity.common import load_marine

REPO = Path(__file__).resolve().parents[2]
RESULTS_DIR = REPO / "replay" / "results"
RESULTS_MD = RESULTS_DIR / "gravity_part2.md"
HEAD = "# Gravity-aided navigation, part II: benchmark results (issue 6)\n\n"

# Long marine track in the Tasman Sea along the Tasmantid seamount chain / Tasman Basin (land masked).
TASMAN_START = (-44.0, 156.3)  # lat, lon of the track start
TASMAN_FRAME = (-38.0, 156.5)  # LocalFrame origin


@lru_cache(maxsize=2)
def tasman_map() -> LocalGravityMap:
    return LocalGravityMap.around(load_marine(TASMAN), *TASMAN_FRAME)


def start_ne(lmap: LocalGravityMap, lat_lon=TASMAN_START) -> np.ndarray:
    n, e = lmap.xy_to_ne(np.array(lat_lon[1]), np.array(lat_lon[0]))
    return np.array([float(n), float(e)])


def write_section(key: str, text: str, path: Path = RESULTS_MD) -> None:
    """Replace (or append) the block between <!-- BEGIN key --> and <!-- END key --> in the results file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    old = path.read_text() if path.exists() else HEAD
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
