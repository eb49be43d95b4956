"""Gravity anomaly maps: loading, bilinear interpolation, masks, statistics.

A `GravityMap` is a 2-D grid of anomaly values (mGal) on either
  * geographic axes: columns = longitude (deg), rows = latitude (deg); rows may be non-uniform
    (rectilinear, e.g. the Mercator-row Tasman grid), or
  * local metric axes: columns = east (m), rows = north (m), no geodetic reference.
Matchers work in metres: `LocalGravityMap` wraps a map with a `LocalFrame` (geographic maps) so every
matcher sees one `interp_ne(north_m, east_m)`; for a local map north/east are the map's own y/x.

Values are float64 with NaN where no usable data (masked cells); interpolation touching a NaN node
or falling outside the node hull returns NaN, which matchers turn into a failed result.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from companion.nav.frame import LocalFrame, radii_m

Axes = Literal["geographic_deg", "local_m"]


class MapFormatError(ValueError):
    """A grid file is missing, malformed or of an unsupported layout."""


def _axis_is_regular(a: np.ndarray, rtol: float = 1e-6) -> bool:
    if a.size < 3:
        return True
    d = np.diff(a)
    return bool(np.all(np.abs(d - d.mean()) <= rtol * max(abs(d.mean()), 1e-300) + 1e-9))


@dataclass(frozen=True)
class GravityMap:
    """Anomaly grid. x = column axis (lon_deg or east_m), y = row axis (lat_deg or north_m), both increasing."""

    anomaly_mgal: np.ndarray  # (ny, nx) float64, NaN where masked
    x: np.ndarray  # (nx,) lon_deg for geographic, east_m for local
    y: np.ndarray  # (ny,) lat_deg for geographic, north_m for local
    axes: Axes
    name: str = ""
    source: str = ""
    registration: str = "pixel"  # 'pixel' (values are cell centres) or 'gridline' (nodes)
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        g = np.asarray(self.anomaly_mgal, dtype=float)
        x = np.asarray(self.x, dtype=float)
        y = np.asarray(self.y, dtype=float)
        if g.ndim != 2 or g.shape != (y.size, x.size):
            raise MapFormatError(f"map shape {g.shape} does not match axes (ny={y.size}, nx={x.size})")
        if x.size < 2 or y.size < 2:
            raise MapFormatError("map needs at least 2 x 2 nodes")
        if not (np.all(np.diff(x) > 0) and np.all(np.diff(y) > 0)):
            raise MapFormatError("map axes must be strictly increasing")
        if self.axes not in ("geographic_deg", "local_m"):
            raise MapFormatError(f"unknown axes kind {self.axes!r}")
        object.__setattr__(self, "anomaly_mgal", g)
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)

    # unit-named views
    @property
    def lon_deg(self) -> np.ndarray:
        self._need("geographic_deg")
        return self.x

    @property
    def lat_deg(self) -> np.ndarray:
        self._need("geographic_deg")
        return self.y

    @property
    def east_m(self) -> np.ndarray:
        self._need("local_m")
        return self.x

    @property
    def north_m(self) -> np.ndarray:
        self._need("local_m")
        return self.y

    def _need(self, kind: str) -> None:
        if self.axes != kind:
            raise AttributeError(f"map {self.name!r} has {self.axes} axes, not {kind}")

    @property
    def shape(self) -> tuple[int, int]:
        return self.anomaly_mgal.shape

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.anomaly_mgal)

    @property
    def is_regular(self) -> bool:
        return _axis_is_regular(self.x) and _axis_is_regular(self.y)

    def cell_size_m(self) -> tuple[float, float]:
        """Median (north, east) node spacing on the ground in metres."""
        if self.axes == "local_m":
            return float(np.median(np.diff(self.y))), float(np.median(np.diff(self.x)))
        lat_c = np.radians(np.median(self.y))
        rm, rn = radii_m(lat_c)
        dn = float(np.radians(np.median(np.diff(self.y))) * rm)
        de = float(np.radians(np.median(np.diff(self.x))) * rn * np.cos(lat_c))
        return dn, de

    # ---- interpolation -------------------------------------------------------------------------
    def interp(self, x, y) -> np.ndarray:
        """Bilinear interpolation (Gao et al. 2022 eq. 3) at column coords x and row coords y.

        Vectorised over any broadcastable shape; NaN outside the node hull or next to a masked node.
        """
        return bilinear(self.x, self.y, self.anomaly_mgal, x, y)

    def with_mask(self, valid: np.ndarray, reason: str = "") -> "GravityMap":
        """Copy with cells where `valid` is False set to NaN."""
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != self.shape:
            raise ValueError(f"mask shape {valid.shape} != map shape {self.shape}")
        g = np.where(valid, self.anomaly_mgal, np.nan)
        meta = dict(self.meta)
        if reason:
            meta["mask"] = reason
        return replace(self, anomaly_mgal=g, meta=meta)

    def crop(self, x_min, x_max, y_min, y_max) -> "GravityMap":
        ix = (self.x >= x_min) & (self.x <= x_max)
        iy = (self.y >= y_min) & (self.y <= y_max)
        if ix.sum() < 2 or iy.sum() < 2:
            raise ValueError("crop leaves fewer than 2 x 2 nodes")
        return replace(self, anomaly_mgal=self.anomaly_mgal[np.ix_(iy, ix)], x=self.x[ix], y=self.y[iy])


def bilinear(xa: np.ndarray, ya: np.ndarray, g: np.ndarray, x, y) -> np.ndarray:
    """Bilinear interpolation on a rectilinear grid g[ya, xa] (Gao et al. 2022 eq. 3), NaN outside.

    The same values as scipy's RegularGridInterpolator (tests/gravity/test_maps.py). Kept for its speed where the
    volume is: CPU time per call on the AK grid (replay/results/gravity_speed.md, "interp") 3.3x less than scipy's
    at 100,000 points, equal at 1,000 (particle filters, Viterbi candidates), 50 us more at 1-20 points (a reading,
    a window: negligible at 1 Hz); xarray's interp is 10-40x slower at every size.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    x, y = np.broadcast_arrays(x, y)
    nx, ny = xa.size, ya.size
    if _axis_is_regular(xa):
        fx = (x - xa[0]) / ((xa[-1] - xa[0]) / (nx - 1))
    else:
        i = np.clip(np.searchsorted(xa, x, side="right") - 1, 0, nx - 2)
        fx = i + (x - xa[i]) / (xa[i + 1] - xa[i])
    if _axis_is_regular(ya):
        fy = (y - ya[0]) / ((ya[-1] - ya[0]) / (ny - 1))
    else:
        j = np.clip(np.searchsorted(ya, y, side="right") - 1, 0, ny - 2)
        fy = j + (y - ya[j]) / (ya[j + 1] - ya[j])
    eps = 1e-9
    inside = (fx >= -eps) & (fx <= nx - 1 + eps) & (fy >= -eps) & (fy <= ny - 1 + eps)
    fx = np.where(inside, np.clip(fx, 0, nx - 1), 0.0)
    fy = np.where(inside, np.clip(fy, 0, ny - 1), 0.0)
    i0 = np.minimum(fx.astype(np.intp), nx - 2)
    j0 = np.minimum(fy.astype(np.intp), ny - 2)
    tx = fx - i0
    ty = fy - j0
    g00 = g[j0, i0]
    g01 = g[j0, i0 + 1]
    g10 = g[j0 + 1, i0]
    g11 = g[j0 + 1, i0 + 1]
    # eq. 3: weights (x1 - x)(y1 - y), (x - x0)(y1 - y), (x1 - x)(y - y0), (x - x0)(y - y0) over the cell area
    out = (1 - ty) * ((1 - tx) * g00 + tx * g01) + ty * ((1 - tx) * g10 + tx * g11)
    return np.where(inside, out, np.nan)


# ---- loading -------------------------------------------------------------------------------------
_LON_NAMES = ("lon", "longitude", "x")
_LAT_NAMES = ("lat", "latitude", "y")


def load_grid(path: str | Path, variable: str | None = None, name: str | None = None) -> GravityMap:
    """Load a 2-D netCDF grid (GMT / COARDS / CF) with xarray.

    Geographic axes are recognised from units 'degrees_east/north' or names lon/lat; other axes named
    x/y are taken as local metres. Descending axes are flipped. Raises MapFormatError on anything else.
    """
    from companion.extras import require

    xr = require("xarray", "gravity", "a netCDF gravity map")
    require("netCDF4", "gravity", "a netCDF gravity map")  # xarray's reader for the files (else: "no engine")
    path = Path(path)
    if not path.is_file():
        raise MapFormatError(f"gravity grid not found: {path}")
    try:
        ds = xr.open_dataset(path, decode_times=False)
    except Exception as exc:  # netCDF4/h5 raise many types for non-netCDF bytes
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise MapFormatError(f"{path.name}: not a readable netCDF file ({type(exc).__name__}: {first})") from exc
    with ds:
        if variable is None:
            cands = [v for v in ds.data_vars if ds[v].ndim == 2]
            if len(cands) != 1:
                raise MapFormatError(f"{path.name}: expected exactly one 2-D data variable, found {cands}; pass variable=")
            variable = cands[0]
        if variable not in ds.data_vars:
            raise MapFormatError(f"{path.name}: no variable {variable!r}")
        da = ds[variable]
        if da.ndim != 2:
            raise MapFormatError(f"{path.name}:{variable} is {da.ndim}-D, expected 2-D")
        ydim, xdim = da.dims
        if xdim not in ds.coords or ydim not in ds.coords:
            raise MapFormatError(f"{path.name}: dims {da.dims} have no coordinate variables")
        xa = np.array(ds[xdim].values, dtype=float)
        ya = np.array(ds[ydim].values, dtype=float)
        xu = str(ds[xdim].attrs.get("units", "")).lower()
        yu = str(ds[ydim].attrs.get("units", "")).lower()
        geographic = xu.startswith("degrees_e") or yu.startswith("degrees_n") or (xdim in ("lon", "longitude") and ydim in ("lat", "latitude"))
        if not geographic and not (xdim.lower() in _LON_NAMES and ydim.lower() in _LAT_NAMES):
            raise MapFormatError(f"{path.name}: unsupported axes {da.dims} (units {xu!r}, {yu!r})")
        if not geographic and (xu.startswith("deg") or yu.startswith("deg")):
            raise MapFormatError(f"{path.name}: mixed degree/metre axes")
        units = str(da.attrs.get("units", "mGal"))
        if units.lower() not in ("mgal", "milligal"):
            raise MapFormatError(f"{path.name}:{variable} has units {units!r}, expected mGal")
        g = np.asarray(da.values, dtype=float)
        attrs = dict(ds.attrs)
    if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ya))):
        raise MapFormatError(f"{path.name}: non-finite coordinates")
    for axis, a in ((1, xa), (0, ya)):
        d = np.diff(a)
        if np.all(d < 0):
            g = np.flip(g, axis=axis)
            a[:] = a[::-1].copy()
        elif not np.all(d > 0):
            raise MapFormatError(f"{path.name}: axis {axis} is not monotonic")
    node_offset = attrs.get("node_offset", None)
    reg = "pixel" if str(node_offset) == "1" else "gridline"
    return GravityMap(
        anomaly_mgal=g,
        x=xa,
        y=ya,
        axes="geographic_deg" if geographic else "local_m",
        name=name or path.stem,
        source=str(path),
        registration=reg,
        meta={"variable": variable, "title": str(attrs.get("title", ""))},
    )


# ---- masks ---------------------------------------------------------------------------------------
# Approximate coastline of eastern Australia + Tasmania (lon, lat), padded ~0.2 deg seaward. The Tasman
# grid holds smooth land fill there (MANIFEST); this polygon is coarse and meant only to keep marine
# tests off land.
_TASMAN_LAND_POLYS = (
    # mainland (SE corner to the grid's north edge)
    [(144.0, -38.0), (145.5, -38.7), (146.5, -39.3), (147.5, -38.1), (149.9, -37.7), (150.4, -36.5),
     (150.5, -35.2), (151.0, -34.4), (151.6, -33.3), (152.4, -32.4), (153.2, -31.0), (153.4, -30.0),
     (153.8, -28.6), (153.6, -27.0), (153.4, -25.9), (153.3, -24.0), (144.0, -24.0)],
    # Tasmania
    [(144.4, -40.5), (148.6, -40.5), (148.6, -43.8), (146.8, -43.9), (144.4, -42.2)],
)


def tasman_land_mask(gmap: GravityMap) -> np.ndarray:
    """True for marine cells, False over the approximate land polygons (eastern Australia, Tasmania)."""
    from companion.extras import require

    MPath = require("matplotlib.path", "plots", "the Tasman land mask").Path

    lon, lat = np.meshgrid(gmap.lon_deg, gmap.lat_deg)
    pts = np.column_stack([lon.ravel(), lat.ravel()])
    land = np.zeros(pts.shape[0], dtype=bool)
    for poly in _TASMAN_LAND_POLYS:
        land |= MPath(np.asarray(poly)).contains_points(pts)
    return ~land.reshape(lon.shape)


# ---- statistics ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class MapStats:
    std_mgal: float
    min_mgal: float
    max_mgal: float
    grad_mean_mgal_per_km: float  # mean |grad g| (MANIFEST "roughness")
    grad_p95_mgal_per_km: float
    roughness_x_mgal: float  # RMS of neighbouring-cell differences along x (matching-area "roughness")
    roughness_y_mgal: float
    n_valid: int


def map_statistics(gmap: GravityMap) -> MapStats:
    """Statistics used to choose matching areas; NaN cells are ignored."""
    g = gmap.anomaly_mgal
    if not np.any(np.isfinite(g)):
        raise ValueError("map has no valid cells")
    if gmap.axes == "geographic_deg":
        lat = np.radians(gmap.y)
        rm, rn = radii_m(lat)
        yk = np.cumsum(np.r_[0.0, np.diff(np.radians(gmap.y)) * rm[1:]]) / 1e3
        xk_scale = (rn * np.cos(lat))[:, None] * np.radians(gmap.x)[None, :] / 1e3  # per row
        gy = np.gradient(g, yk, axis=0)
        gx = np.gradient(g, axis=1) / np.gradient(xk_scale, axis=1)
    else:
        gy = np.gradient(g, gmap.y / 1e3, axis=0)
        gx = np.gradient(g, gmap.x / 1e3, axis=1)
    mag = np.hypot(gx, gy)
    dx = np.diff(g, axis=1)
    dy = np.diff(g, axis=0)
    return MapStats(
        std_mgal=float(np.nanstd(g)),
        min_mgal=float(np.nanmin(g)),
        max_mgal=float(np.nanmax(g)),
        grad_mean_mgal_per_km=float(np.nanmean(mag)),
        grad_p95_mgal_per_km=float(np.nanpercentile(mag, 95)),
        roughness_x_mgal=float(np.sqrt(np.nanmean(dx**2))),
        roughness_y_mgal=float(np.sqrt(np.nanmean(dy**2))),
        n_valid=int(np.isfinite(g).sum()),
    )


# ---- metric view for matchers --------------------------------------------------------------------
METRES_PER_ARCMIN = 1852.0  # Gao et al. 2022 sec. 2.4: 1852 m = 1' near the equator


@dataclass(frozen=True)
class LocalGravityMap:
    """A map seen in metres (north, east) of a LocalFrame; the common input of every matcher."""

    gmap: GravityMap
    frame: LocalFrame | None = None  # required for geographic maps, must be None for local maps

    def __post_init__(self):
        if self.gmap.axes == "geographic_deg" and self.frame is None:
            raise ValueError("geographic map needs a LocalFrame")
        if self.gmap.axes == "local_m" and self.frame is not None:
            raise ValueError("local metric map takes no LocalFrame")

    @classmethod
    def around(cls, gmap: GravityMap, lat_deg: float | None = None, lon_deg: float | None = None) -> "LocalGravityMap":
        if gmap.axes == "local_m":
            return cls(gmap, None)
        if lat_deg is None:
            lat_deg, lon_deg = float(np.median(gmap.y)), float(np.median(gmap.x))
        return cls(gmap, LocalFrame(lat_deg, lon_deg, 0.0))

    def ne_to_xy(self, north_m, east_m):
        if self.frame is None:
            return np.asarray(east_m, float), np.asarray(north_m, float)
        lat, lon, _ = self.frame.to_geodetic(np.stack(np.broadcast_arrays(np.asarray(north_m, float), np.asarray(east_m, float), 0.0), axis=-1))
        return lon, lat

    def xy_to_ne(self, x, y):
        if self.frame is None:
            return np.asarray(y, float), np.asarray(x, float)
        ned = self.frame.to_ned_m(y, x, 0.0)
        return ned[..., 0], ned[..., 1]

    def lat_deg_at(self, north_m) -> np.ndarray:
        """Latitude of points (for Eotvos); for a local map the frame-less value 0 is not meaningful -> NaN."""
        if self.frame is None:
            return np.full(np.shape(north_m), np.nan)
        rm, _ = self.frame._radii()
        return self.frame.ref_lat_deg + np.degrees(np.asarray(north_m, float) / rm)

    def interp_ne(self, north_m, east_m) -> np.ndarray:
        """Anomaly (mGal) at NE metres; NaN off-map or on masked cells."""
        if self.frame is None:
            return self.gmap.interp(east_m, north_m)
        n = np.asarray(north_m, float)
        e = np.asarray(east_m, float)
        rm, rn = self.frame._radii()
        lat = self.frame.ref_lat_deg + np.degrees(n / rm)
        lon = self.frame.ref_lon_deg + np.degrees(e / (rn * np.cos(np.radians(self.frame.ref_lat_deg))))
        return self.gmap.interp(lon, lat)

    def metres_per_deg(self) -> tuple[float, float]:
        """(north, east) metres per degree at the frame origin; 60 * 1852 m/deg for a local map."""
        if self.frame is None:
            return 60 * METRES_PER_ARCMIN, 60 * METRES_PER_ARCMIN
        rm, rn = self.frame._radii()
        return float(np.radians(1.0) * rm), float(np.radians(1.0) * rn * np.cos(np.radians(self.frame.ref_lat_deg)))

    def cell_size_m(self) -> tuple[float, float]:
        return self.gmap.cell_size_m()

    def bounds_ne(self) -> tuple[float, float, float, float]:
        """(n_min, n_max, e_min, e_max) of the node hull (approximate for geographic maps)."""
        xs = np.array([self.gmap.x[0], self.gmap.x[-1]])
        ys = np.array([self.gmap.y[0], self.gmap.y[-1]])
        X, Y = np.meshgrid(xs, ys)
        n, e = self.xy_to_ne(X, Y)
        return float(n.min()), float(n.max()), float(e.min()), float(e.max())

    def regular_ne(self, cell_m: float, n_range: tuple[float, float], e_range: tuple[float, float]):
        """Resample to a regular NE grid (bilinear) for image correlation. Returns (g[n, e], north_m, east_m)."""
        n_ax = np.arange(n_range[0], n_range[1] + 0.5 * cell_m, cell_m)
        e_ax = np.arange(e_range[0], e_range[1] + 0.5 * cell_m, cell_m)
        N, E = np.meshgrid(n_ax, e_ax, indexing="ij")
        return self.interp_ne(N, E), n_ax, e_ax
