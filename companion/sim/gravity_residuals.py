"""Real sensor-minus-map residuals from the GMT example 3 ship and satellite tracks (MANIFEST sec. 4)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from companion.gravity.data import shared_gravity_dir

R_EARTH_M = 6371000.0


def _xyz(lon_deg, lat_deg):
    lo, la = np.radians(lon_deg), np.radians(lat_deg)
    return R_EARTH_M * np.column_stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])


@lru_cache(maxsize=2)
def ship_minus_satellite_mgal(gravity_dir: str | None = None, max_dist_m: float = 2000.0) -> np.ndarray:
    """Ship minus satellite anomaly, in ship-track order, for ship points within max_dist_m of a
    satellite point (inverse-distance interpolation of the 2 nearest satellite points)."""
    d = Path(gravity_dir) if gravity_dir else shared_gravity_dir()
    ship = np.loadtxt(d / "tracks" / "ship_03.txt")
    sat = np.loadtxt(d / "tracks" / "sat_03.txt")
    tree = cKDTree(_xyz(sat[:, 0], sat[:, 1]))
    dist, idx = tree.query(_xyz(ship[:, 0], ship[:, 1]), k=2)
    w = 1.0 / np.maximum(dist, 1.0)
    sat_g = (w * sat[idx, 2]).sum(axis=1) / w.sum(axis=1)
    keep = dist[:, 0] <= max_dist_m
    return (ship[keep, 2] - sat_g[keep]).astype(float)
