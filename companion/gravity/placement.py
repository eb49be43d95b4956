"""Where a flight's local track lies on a gravity map (a replayed drone log flies near (0, 0) of its own frame; the
map area it is pretended to fly over is elsewhere)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.gravity.maps import LocalGravityMap


@dataclass(frozen=True)
class Placement:
    """Lays a flight's local NE track (metres from its own origin) onto map NE metres:
    map_ne = origin_ne_m + R(rotation_deg) @ flight_ne (rotation clockwise, as a heading change)."""

    origin_ne_m: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0

    def _r(self) -> np.ndarray:
        c, s = math.cos(math.radians(self.rotation_deg)), math.sin(math.radians(self.rotation_deg))
        return np.array([[c, -s], [s, c]])

    def to_map(self, flight_ne_m) -> np.ndarray:
        return np.asarray(self.origin_ne_m, float) + np.asarray(flight_ne_m, float) @ self._r().T

    def to_flight(self, map_ne_m) -> np.ndarray:
        return (np.asarray(map_ne_m, float) - np.asarray(self.origin_ne_m, float)) @ self._r()

    @classmethod
    def at_lat_lon(cls, lmap: LocalGravityMap, lat_deg: float, lon_deg: float, rotation_deg: float = 0.0) -> "Placement":
        """Start the flight at a chosen point of a geographic map."""
        n, e = lmap.xy_to_ne(np.array(lon_deg), np.array(lat_deg))
        return cls((float(n), float(e)), rotation_deg)
