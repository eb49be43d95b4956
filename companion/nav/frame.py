"""WGS84 geodesy at the scale of a flight: local NED tangent plane about a reference point.

Pure numpy. Positions in a local frame are metres NED from a reference geodetic point; the mapping uses
the ellipsoid's meridian and prime-vertical radii at the reference latitude, which is exact to first
order and good to centimetres within a few kilometres (errors grow as distance^2 / R).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from companion.constants import EARTH_RATE_RADPS, WGS84_A_M, WGS84_E2, WGS84_F

__all__ = ["LocalFrame", "radii_m", "normal_gravity_mps2", "EARTH_RATE_RADPS", "WGS84_A_M", "WGS84_E2", "WGS84_F"]


def radii_m(lat_rad: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Meridian (north-south) and prime-vertical (east-west) radii of curvature at a latitude."""
    s2 = np.sin(lat_rad) ** 2
    w = np.sqrt(1.0 - WGS84_E2 * s2)
    r_meridian = WGS84_A_M * (1.0 - WGS84_E2) / w**3
    r_normal = WGS84_A_M / w
    return r_meridian, r_normal


def normal_gravity_mps2(lat_rad: float | np.ndarray, height_m: float | np.ndarray = 0.0) -> np.ndarray:
    """Somigliana normal gravity on WGS84 with the free-air height correction (positive down)."""
    s2 = np.sin(lat_rad) ** 2
    g0 = 9.7803253359 * (1.0 + 0.00193185265241 * s2) / np.sqrt(1.0 - WGS84_E2 * s2)
    return g0 - 3.086e-6 * np.asarray(height_m)


@dataclass(frozen=True)
class LocalFrame:
    """NED tangent plane at (ref_lat_deg, ref_lon_deg, ref_alt_m); altitude in the datum of ref_alt_m."""

    ref_lat_deg: float
    ref_lon_deg: float
    ref_alt_m: float

    def _radii(self) -> tuple[float, float]:
        rm, rn = radii_m(np.radians(self.ref_lat_deg))
        return float(rm) + self.ref_alt_m, float(rn) + self.ref_alt_m

    def to_ned_m(self, lat_deg, lon_deg, alt_m) -> np.ndarray:
        """Geodetic -> NED metres. Accepts scalars or arrays; returns shape (..., 3)."""
        rm, rn = self._radii()
        lat = np.asarray(lat_deg, dtype=float)
        lon = np.asarray(lon_deg, dtype=float)
        alt = np.asarray(alt_m, dtype=float)
        dlon = (lon - self.ref_lon_deg + 180.0) % 360.0 - 180.0
        n = np.radians(lat - self.ref_lat_deg) * rm
        e = np.radians(dlon) * rn * np.cos(np.radians(self.ref_lat_deg))
        d = -(alt - self.ref_alt_m)
        return np.stack(np.broadcast_arrays(n, e, d), axis=-1)

    @cached_property
    def _scalar_scale(self) -> tuple[float, float]:
        """(meridian radius, prime-vertical radius x cos latitude), both at the reference height, in floats."""
        rm, rn = (float(x) for x in radii_m(math.radians(self.ref_lat_deg)))
        return rm + self.ref_alt_m, (rn + self.ref_alt_m) * math.cos(math.radians(self.ref_lat_deg))

    def ned_tuple(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        """Geodetic -> NED metres for one point, in plain floats (the navigator's per-sample path; the same mapping
        as `to_ned_m` to within rounding)."""
        rm, rn_cos = self._scalar_scale
        return (
            math.radians(lat_deg - self.ref_lat_deg) * rm,
            math.radians((lon_deg - self.ref_lon_deg + 180.0) % 360.0 - 180.0) * rn_cos,
            -(alt_m - self.ref_alt_m),
        )

    def geodetic_tuple(self, n: float, e: float, d: float) -> tuple[float, float, float]:
        """NED metres -> (lat_deg, lon_deg, alt_m) for one point, in plain floats (inverse of `ned_tuple`)."""
        rm, rn_cos = self._scalar_scale
        lat = self.ref_lat_deg + math.degrees(n / rm)
        lon = (self.ref_lon_deg + math.degrees(e / rn_cos) + 180.0) % 360.0 - 180.0
        return lat, lon, self.ref_alt_m - d

    def to_geodetic(self, ned_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """NED metres -> (lat_deg, lon_deg, alt_m)."""
        rm, rn = self._radii()
        ned = np.asarray(ned_m, dtype=float)
        lat = self.ref_lat_deg + np.degrees(ned[..., 0] / rm)
        lon = self.ref_lon_deg + np.degrees(ned[..., 1] / (rn * np.cos(np.radians(self.ref_lat_deg))))
        lon = (lon + 180.0) % 360.0 - 180.0
        alt = self.ref_alt_m - ned[..., 2]
        return lat, lon, alt
