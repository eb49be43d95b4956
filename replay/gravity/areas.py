"""Shared pieces of the gravity benchmarks: areas and long tracks on the real grids, track plots."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from companion.gravity.data import AK_GULF, TASMAN, shared_gravity_dir
from companion.gravity.maps import GravityMap, LocalGravityMap, load_grid, tasman_land_mask



@dataclass(frozen=True)
class Area:
    name: str
    grid: str
    lon_deg: tuple[float, float]
    lat_deg: tuple[float, float]
    note: str


# Sub-areas from MANIFEST.md (strong-feature and flat areas of both geographic grids)
AREAS = {
    "AK-strong": Area("AK-strong", AK_GULF, (-146.0, -142.0), (55.0, 57.0), "Kodiak-Bowie seamounts"),
    "AK-flat": Area("AK-flat", AK_GULF, (-142.5, -139.5), (52.55, 55.0), "abyssal plain"),
    "Tasman-strong": Area("Tasman-strong", TASMAN, (155.0, 159.95), (-34.0, -28.0), "Tasmantid seamounts"),
    "Tasman-flat": Area("Tasman-flat", TASMAN, (151.5, 155.5), (-45.5, -41.5), "abyssal plain SE of Tasmania"),
}


@lru_cache(maxsize=4)
def load_marine(grid: str) -> GravityMap:
    """A real grid with land masked (Tasman) so no track uses land fill."""
    m = load_grid(shared_gravity_dir() / grid)
    if grid == TASMAN:
        m = m.with_mask(tasman_land_mask(m), "land (approximate polygon)")
    return m


def area_map(area: Area) -> LocalGravityMap:
    """Whole grid in a local frame centred on the area (matchers may look beyond the area)."""
    m = load_marine(area.grid)
    return LocalGravityMap.around(m, float(np.mean(area.lat_deg)), float(np.mean(area.lon_deg)))


def area_box_ne(lmap: LocalGravityMap, area: Area) -> tuple[float, float, float, float]:
    lon = np.array([area.lon_deg[0], area.lon_deg[1], area.lon_deg[0], area.lon_deg[1]])
    lat = np.array([area.lat_deg[0], area.lat_deg[0], area.lat_deg[1], area.lat_deg[1]])
    n, e = lmap.xy_to_ne(lon, lat)
    return float(n.min()), float(n.max()), float(e.min()), float(e.max())


# Long marine track in the Tasman Sea along the Tasmantid seamount chain / Tasman Basin (land masked).
TASMAN_START = (-44.0, 156.3)  # lat, lon of the track start
TASMAN_FRAME = (-38.0, 156.5)  # LocalFrame origin


@lru_cache(maxsize=2)
def tasman_map() -> LocalGravityMap:
    return LocalGravityMap.around(load_marine(TASMAN), *TASMAN_FRAME)


def start_ne(lmap: LocalGravityMap, lat_lon=TASMAN_START) -> np.ndarray:
    n, e = lmap.xy_to_ne(np.array(lat_lon[1]), np.array(lat_lon[0]))
    return np.array([float(n), float(e)])


def plot_tracks(path: Path, lmap: LocalGravityMap, tracks: dict[str, np.ndarray], title: str, pad_m: float = 15_000.0,
                points: dict[str, np.ndarray] | None = None) -> None:
    """Map (resampled around the tracks) with true / INS / matched tracks, NE metres -> km."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    allp = np.vstack([t for t in tracks.values()] + ([p for p in points.values()] if points else []))
    allp = allp[np.all(np.isfinite(allp), axis=1)]
    n0, e0 = allp.min(axis=0) - pad_m
    n1, e1 = allp.max(axis=0) + pad_m
    cell = max((n1 - n0), (e1 - e0)) / 300
    g, na, ea = lmap.regular_ne(cell, (n0, n1), (e0, e1))
    aspect = (n1 - n0) / (e1 - e0)
    fig, ax = plt.subplots(figsize=(9, float(np.clip(7.5 * aspect, 3.5, 9)) + 0.8))
    im = ax.pcolormesh(ea / 1e3, na / 1e3, g, cmap="viridis", shading="auto")
    fig.colorbar(im, ax=ax, label="free-air anomaly (mGal)", shrink=0.8)
    styles = {"true": ("w-", 2.0), "INS": ("r--", 1.5)}
    for name, tr in tracks.items():
        st, lw = styles.get(name, ("-", 1.2))
        ax.plot(tr[:, 1] / 1e3, tr[:, 0] / 1e3, st, lw=lw, label=name)
    for name, p in (points or {}).items():
        ax.plot(p[:, 1] / 1e3, p[:, 0] / 1e3, "o", ms=3.5, label=name)
    ax.set_xlabel("east (km)")
    ax.set_ylabel("north (km)")
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="best", facecolor="0.6", framealpha=0.85)  # grey: the white truth line shows in it
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
