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


@dataclass(frozen=True)
class MapView:
    """How the navigator's states reach a map and back: through a `Placement` of the navigator's local frame (a
    replayed flight laid on a chosen map area), or with ``geographic=True`` (a vehicle over the map's own area)
    through latitude/longitude, exact over hundreds of kilometres where two tangent planes differ by kilometres."""

    lmap: LocalGravityMap
    placement: Placement = Placement()
    geographic: bool = False

    def __post_init__(self):
        if self.geographic and self.lmap.frame is None:
            raise ValueError("geographic matching needs a geographic map")

    def state(self, s, frame) -> np.ndarray:
        """(north, east, v_north, v_east) of a navigator state (companion.nav.outputs.FusedState) in map metres
        (velocity: map metres per second); ``frame`` is the navigator's companion.nav.frame.LocalFrame."""
        if self.geographic:
            ne = np.array(self.lmap.xy_to_ne(s.lon_deg, s.lat_deg), float)
            n1, e1, _ = frame.to_ned_m(s.lat_deg, s.lon_deg, s.alt_msl_m)
            lat2, lon2, _ = frame.to_geodetic(np.array([n1 + s.vel_n_mps, e1 + s.vel_e_mps, 0.0]))
            vel = np.array(self.lmap.xy_to_ne(float(lon2), float(lat2)), float) - ne  # 1 s of motion on the map
            return np.concatenate([ne, vel])
        n, e, _ = frame.to_ned_m(s.lat_deg, s.lon_deg, s.alt_msl_m)
        pl = self.placement
        return np.concatenate([pl.to_map(np.array([n, e])), pl.to_map(np.array([s.vel_n_mps, s.vel_e_mps])) - pl.to_map(np.zeros(2))])

    def to_geodetic(self, map_ne, frame) -> tuple[float, float, np.ndarray]:
        """lat, lon and the navigator-frame NE of a map position."""
        map_ne = np.asarray(map_ne, float)
        if self.geographic:
            lon, lat = self.lmap.ne_to_xy(map_ne[0], map_ne[1])
            ne = np.asarray(frame.to_ned_m(float(lat), float(lon), 0.0)[:2], float)
            return float(lat), float(lon), ne
        ne = self.placement.to_flight(map_ne)
        lat, lon, _ = frame.to_geodetic(np.array([ne[0], ne[1], 0.0]))
        return float(lat), float(lon), ne

    def describe(self) -> str:
        pl = self.placement
        return ("geographic (lat/lon on the map's own area)" if self.geographic else
                f"origin_ne_m={tuple(round(v, 1) for v in pl.origin_ne_m)} rot={pl.rotation_deg:g}")
