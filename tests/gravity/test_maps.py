"""Gravity maps: loading, bilinear interpolation, masks, statistics."""

import numpy as np
import pytest

from companion.gravity.data import AK_GULF, LOCAL_1KM, TASMAN
from companion.gravity.maps import (GravityMap, LocalGravityMap, MapFormatError, bilinear, load_grid,
                                     map_statistics, tasman_land_mask)

from tests.conftest import SHARED_GRAVITY as GDIR
from tests.conftest import require


@pytest.fixture
def needs_data():
    require(GDIR)


def _plane(x, y):
    return 3.0 + 0.7 * x - 1.3 * y


@pytest.mark.parametrize("regular_y", [True, False])
def test_bilinear_exact_on_planar_field(regular_y):
    xa = np.linspace(-5, 5, 11)
    ya = np.linspace(0, 4, 9) if regular_y else np.array([0.0, 0.1, 0.5, 0.6, 1.7, 2.0, 3.3, 4.0])
    g = _plane(xa[None, :], ya[:, None])
    rng = np.random.default_rng(0)
    x = rng.uniform(-5, 5, (7, 13))
    y = rng.uniform(0, 4, (7, 13))
    out = bilinear(xa, ya, g, x, y)
    assert out.shape == (7, 13)
    np.testing.assert_allclose(out, _plane(x, y), atol=1e-12)
    # nodes and the far edges are inside; anything beyond is NaN
    np.testing.assert_allclose(bilinear(xa, ya, g, xa[-1], ya[-1]), _plane(xa[-1], ya[-1]))
    assert np.isnan(bilinear(xa, ya, g, 5.01, 1.0)) and np.isnan(bilinear(xa, ya, g, 0.0, -0.01))
    assert np.isnan(bilinear(xa, ya, g, np.nan, 1.0))


def test_bilinear_bilinear_field_and_mask():
    xa, ya = np.arange(4.0), np.arange(3.0)
    f = lambda x, y: 2 + x * y - x  # noqa: E731  bilinear, also reproduced exactly
    g = f(xa[None, :], ya[:, None])
    np.testing.assert_allclose(bilinear(xa, ya, g, [0.25, 2.5], [1.75, 0.5]), f(np.array([0.25, 2.5]), np.array([1.75, 0.5])))
    m = GravityMap(g, xa, ya, "local_m").with_mask(~((np.arange(3)[:, None] == 1) & (np.arange(4)[None, :] == 1)))
    assert np.isnan(m.interp(0.5, 0.5)) and np.isnan(m.interp(1.5, 1.5))  # cells touching the masked node
    assert np.isfinite(m.interp(2.5, 0.5))


def test_map_type_validation_and_units():
    with pytest.raises(MapFormatError):
        GravityMap(np.zeros((3, 4)), np.arange(3.0), np.arange(3.0), "local_m")
    with pytest.raises(MapFormatError):
        GravityMap(np.zeros((2, 2)), np.array([1.0, 0.0]), np.arange(2.0), "local_m")
    m = GravityMap(np.zeros((2, 2)), np.arange(2.0), np.arange(2.0), "local_m")
    assert m.east_m is m.x
    with pytest.raises(AttributeError):
        _ = m.lat_deg


def test_local_view_geographic_roundtrip():
    lon = np.linspace(10, 11, 31)
    lat = np.linspace(40, 41, 31)
    g = _plane(lon[None, :], lat[:, None])
    lm = LocalGravityMap.around(GravityMap(g, lon, lat, "geographic_deg"), 40.5, 10.5)
    n, e = lm.xy_to_ne(np.array([10.2, 10.9]), np.array([40.1, 40.8]))
    np.testing.assert_allclose(lm.interp_ne(n, e), _plane(np.array([10.2, 10.9]), np.array([40.1, 40.8])), atol=1e-9)
    mn, me = lm.metres_per_deg()
    assert 110_900 < mn < 111_200 and 84_000 < me < 85_000


def test_malformed_files_give_clear_errors(tmp_path):
    import xarray as xr

    with pytest.raises(MapFormatError, match="not found"):
        load_grid(tmp_path / "missing.nc")
    bad = tmp_path / "bad.nc"
    bad.write_text("this is not netCDF\n")
    with pytest.raises(MapFormatError, match="not a readable netCDF"):
        load_grid(bad)
    three_d = tmp_path / "cube.nc"
    xr.Dataset({"z": (("t", "lat", "lon"), np.zeros((2, 3, 4)))},
               coords={"lat": np.arange(3.0), "lon": np.arange(4.0)}).to_netcdf(three_d)
    with pytest.raises(MapFormatError, match="2-D"):
        load_grid(three_d)
    nonmono = tmp_path / "nonmono.nc"
    xr.Dataset({"z": (("lat", "lon"), np.zeros((3, 4)))},
               coords={"lat": [0.0, 2.0, 1.0], "lon": np.arange(4.0)}).to_netcdf(nonmono)
    with pytest.raises(MapFormatError, match="monotonic"):
        load_grid(nonmono)
    other_units = tmp_path / "metres.nc"
    ds = xr.Dataset({"z": (("lat", "lon"), np.zeros((3, 4)), {"units": "m"})},
                    coords={"lat": np.arange(3.0), "lon": np.arange(4.0)})
    ds.to_netcdf(other_units)
    with pytest.raises(MapFormatError, match="units"):
        load_grid(other_units)


def test_descending_axis_is_flipped(tmp_path):
    import xarray as xr

    p = tmp_path / "desc.nc"
    lat = np.array([2.0, 1.0, 0.0])
    lon = np.arange(4.0)
    g = _plane(lon[None, :], lat[:, None])
    xr.Dataset({"z": (("lat", "lon"), g, {"units": "mGal"})}, coords={"lat": lat, "lon": lon}).to_netcdf(p)
    m = load_grid(p)
    assert m.axes == "geographic_deg" and np.all(np.diff(m.lat_deg) > 0)
    np.testing.assert_allclose(m.interp(1.5, 0.25), _plane(1.5, 0.25))


@pytest.mark.usefixtures("needs_data")
def test_real_grids_load_with_manifest_statistics():
    ak = load_grid(GDIR / AK_GULF)
    assert ak.axes == "geographic_deg" and ak.shape == (165, 420) and ak.is_regular
    st = map_statistics(ak)
    assert st.std_mgal == pytest.approx(23.6, abs=0.1)
    assert st.grad_mean_mgal_per_km == pytest.approx(1.01, abs=0.02)
    tas = load_grid(GDIR / TASMAN)
    assert tas.shape == (964, 450) and not tas.is_regular  # Mercator rows
    steps = np.diff(tas.lat_deg) * 60
    assert steps[0] == pytest.approx(1.29, abs=0.01) and steps[-1] == pytest.approx(1.81, abs=0.01)
    assert map_statistics(tas.crop(155, 160, -34, -28)).grad_mean_mgal_per_km == pytest.approx(1.60, abs=0.03)
    loc = load_grid(GDIR / LOCAL_1KM)
    assert loc.axes == "local_m" and loc.cell_size_m() == (1000.0, 1000.0)
    assert loc.north_m[0] == -78_000 and loc.east_m[-1] == 75_000


@pytest.mark.usefixtures("needs_data")
def test_tasman_land_mask():
    tas = load_grid(GDIR / TASMAN)
    sea = tasman_land_mask(tas)
    m = tas.with_mask(sea, "land")
    assert np.isnan(m.interp(147.0, -42.0))  # Tasmania
    assert np.isnan(m.interp(146.0, -30.0))  # NSW inland
    assert np.isfinite(m.interp(157.0, -31.0)) and np.isfinite(m.interp(153.5, -43.5))  # Tasman Sea
    assert 0.15 < 1 - sea.mean() < 0.4


def test_bilinear_agrees_with_scipy():
    """The same values as scipy's RegularGridInterpolator (linear), inside and (NaN) outside, on a regular and on an
    irregular grid; replay.gravity.speed --papers interp measures why ours is kept (faster on large batches)."""
    from scipy.interpolate import RegularGridInterpolator

    rng = np.random.default_rng(4)
    for xa, ya in ((np.linspace(-3.0, 5.0, 41), np.linspace(10.0, 12.0, 23)),
                   (np.cumsum(rng.uniform(0.1, 1.0, 30)), np.cumsum(rng.uniform(0.1, 1.0, 17)))):
        g = rng.normal(0.0, 20.0, (ya.size, xa.size))
        x = rng.uniform(xa[0] - 0.5, xa[-1] + 0.5, 5000)
        y = rng.uniform(ya[0] - 0.5, ya[-1] + 0.5, 5000)
        ref = RegularGridInterpolator((ya, xa), g, bounds_error=False, fill_value=np.nan)(np.column_stack([y, x]))
        ours = bilinear(xa, ya, g, x, y)
        assert np.array_equal(np.isnan(ours), np.isnan(ref)) and np.isnan(ref).sum() > 100
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9, equal_nan=True)
