"""Gravity-gradient tensor from an anomaly grid by the standard wavenumber-domain (FFT) method.

Frame: x = north, y = east, z = down (NED); T is the disturbing potential, the anomaly is dg = dT/dz (positive
= stronger downward pull), and G_ij = d2T / di dj in Eotvos (1 E = 1e-9 s^-2; 1 mGal/km = 10 E).

For a field harmonic above the map plane, T(k, z) = T(k, 0) exp(|k| z) (z down), so d/dz <-> |k| and
T^ = dg^ / |k|, which gives (k = wavenumber vector, rad/m; Blakely 1995, Potential Theory, ch. 12):

    G_xx = -kx^2/|k| dg^,  G_xy = -kx ky/|k| dg^,  G_yy = -ky^2/|k| dg^,
    G_xz = i kx dg^,       G_yz = i ky dg^,        G_zz = |k| dg^.

G_xx + G_yy + G_zz = 0 holds exactly in the wavenumber domain (Laplace). Optionally the field is
upward-continued to `height_m` above the plane (factor exp(-|k| h)).

Approximations, documented: flat Earth (a local tangent plane, fine for maps of a few hundred km); the
anomaly is treated as a field on a plane (free-air anomaly at sea level, no terrain); the grid is resampled
bilinearly to a regular NE metric grid first; the FFT assumes periodicity, so the grid is de-meaned and
extended by mirror reflection (even extension: no jump at the edges, a kink only) and results within about
one feature width of the edges are degraded; the DC term (k = 0) is dropped; wavelengths shorter than two
cells are absent, so gradients of an altimetry grid (effective resolution coarser than its spacing) are
smoother than a real gradiometer would see. Liu et al. 2019 forward-model their maps the same way ("by
forward modeling of free air gravity anomaly data"), at 30" resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from companion.gravity.maps import LocalGravityMap, bilinear

MGAL_PER_M_TO_EOTVOS = 1e-5 / 1e-9  # 1 mGal/m = 1e4 E
COMPONENTS = ("xx", "xy", "xz", "yy", "yz", "zz")
LIU_COMPONENTS = ("xx", "xy", "xz", "yy", "yz")  # the five independent components Liu et al. use


def gradient_tensor_fft(g_mgal: np.ndarray, cell_n_m: float, cell_e_m: float, height_m: float = 0.0,
                        pad: str = "mirror") -> dict[str, np.ndarray]:
    """Six tensor components (Eotvos) of a regular anomaly grid g[north, east] (mGal). NaNs are not allowed."""
    g = np.asarray(g_mgal, float)
    if g.ndim != 2 or min(g.shape) < 4:
        raise ValueError("need a 2-D grid of at least 4 x 4 cells")
    if not np.all(np.isfinite(g)):
        raise ValueError("grid has NaN cells: fill or crop them before the FFT")
    if not (cell_n_m > 0 and cell_e_m > 0):
        raise ValueError("cell sizes must be > 0")
    ny, nx = g.shape
    g0 = g - g.mean()
    if pad == "mirror":
        ext = np.block([[g0, g0[:, ::-1]], [g0[::-1, :], g0[::-1, ::-1]]])
    elif pad == "none":
        ext = g0
    else:
        raise ValueError("pad must be 'mirror' or 'none'")
    my, mx = ext.shape
    kx = 2 * np.pi * np.fft.fftfreq(my, d=cell_n_m)[:, None]  # north wavenumber (rows)
    ky = 2 * np.pi * np.fft.fftfreq(mx, d=cell_e_m)[None, :]  # east wavenumber (cols)
    k = np.hypot(kx, ky)
    G = np.fft.fft2(ext)
    if height_m:
        G = G * np.exp(-k * height_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_k = np.where(k > 0, 1.0 / k, 0.0)
    ops = {
        "xx": -kx**2 * inv_k,
        "xy": -kx * ky * inv_k,
        "yy": -ky**2 * inv_k,
        "xz": 1j * kx,
        "yz": 1j * ky,
        "zz": k,
    }
    out = {}
    for name in COMPONENTS:
        field = np.fft.ifft2(G * ops[name])
        out[name] = np.real(field[:ny, :nx]) * MGAL_PER_M_TO_EOTVOS
    return out


@dataclass(frozen=True)
class GradientMap:
    """Tensor components on a regular NE grid; bilinear interpolation of any subset of components."""

    north_m: np.ndarray
    east_m: np.ndarray
    comps: dict  # name -> (nn, ne) array, Eotvos
    source_cell_m: float

    @classmethod
    def from_local_map(cls, lmap: LocalGravityMap, cell_m: float, region_ne_m: tuple[float, float, float, float],
                       height_m: float = 0.0) -> "GradientMap":
        """Resample `region_ne_m` of the map to cell_m and derive the tensor. NaN (masked) cells are filled with
        the mean of the valid cells before the FFT and set back to NaN afterwards."""
        g, n_ax, e_ax = lmap.regular_ne(cell_m, region_ne_m[:2], region_ne_m[2:])
        valid = np.isfinite(g)
        if valid.mean() < 0.5:
            raise ValueError("less than half of the region has map data")
        filled = np.where(valid, g, np.nanmean(g))
        comps = gradient_tensor_fft(filled, cell_m, cell_m, height_m)
        comps = {k: np.where(valid, v, np.nan) for k, v in comps.items()}
        comps["anomaly"] = g
        return cls(n_ax, e_ax, comps, float(cell_m))

    def subsample(self, step: int) -> "GradientMap":
        """Every step-th node (Liu et al. make their 1' maps from 30" maps by interval point extraction)."""
        return GradientMap(self.north_m[::step], self.east_m[::step], {k: v[::step, ::step] for k, v in self.comps.items()},
                           self.source_cell_m * step)

    def stack(self, names=LIU_COMPONENTS) -> np.ndarray:
        return np.stack([self.comps[n] for n in names], axis=-1)

    def interp_ne(self, north_m, east_m, names=LIU_COMPONENTS) -> np.ndarray:
        """(..., len(names)) values at NE points; NaN off-grid."""
        return np.stack([bilinear(self.east_m, self.north_m, self.comps[n], east_m, north_m) for n in names], axis=-1)

    def statistics(self, names=LIU_COMPONENTS) -> dict[str, tuple[float, float, float, float]]:
        """min, max, mean, std per component (as Liu et al. Table 1)."""
        return {n: (float(np.nanmin(self.comps[n])), float(np.nanmax(self.comps[n])), float(np.nanmean(self.comps[n])),
                    float(np.nanstd(self.comps[n]))) for n in names}
