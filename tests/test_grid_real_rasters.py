"""Grid.from_dataarray and north_up on rasters as real files store them: y ascending (NetCDF),
Datasets, a rioxarray ``spatial_ref`` coordinate, irregular spacing; and the callers that pair
a DEM's values with its grid (coarse_dem, TriangulatedMean, sample_dem).

Reference: every y-ascending array is the y-descending one flipped with ``sortby``, so each
result must equal the north-up result exactly.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from terrain import InputError, TriangulatedMean, coarse_dem, sample_dem
from terrain.grid import Grid, dataarray_crs, north_up


def north_dem() -> xr.DataArray:
    g = Grid.from_bounds((526000.0, 6475000.0, 526600.0, 6475400.0), (20.0, 25.0))
    xy = g.xy()
    z = 100 + 0.02 * (xy[:, 0] - 526000) + 1e-4 * (xy[:, 1] - 6475000) ** 2
    return g.data_array(z.reshape(g.shape), "elevation")


def test_y_ascending_gives_the_same_grid_and_north_up_flips_back():
    da = north_dem()
    asc = da.sortby("y")
    assert asc.y.values[0] < asc.y.values[-1]
    assert Grid.from_dataarray(asc) == Grid.from_dataarray(da)
    assert north_up(da) is da  # already north-up: nothing copied
    flipped = north_up(asc)
    np.testing.assert_array_equal(flipped.values, da.values)
    np.testing.assert_array_equal(flipped.y.values, da.y.values)
    # x descending too (rare, but a sort fixes it the same way)
    both = da.sortby("x", ascending=False).sortby("y")
    assert Grid.from_dataarray(both) == Grid.from_dataarray(da)
    np.testing.assert_array_equal(north_up(both).values, da.values)


def test_dataset_and_crs_sources():
    da = north_dem()
    wkt = da.attrs["crs_wkt"]
    ds = da.to_dataset()
    ds.attrs = dict(da.attrs)
    assert Grid.from_dataarray(ds.sortby("y")) == Grid.from_dataarray(da)
    # attrs["crs"] alone
    only_crs = da.copy()
    only_crs.attrs = {"crs": "EPSG:32608"}
    assert Grid.from_dataarray(only_crs).crs.to_epsg() == 32608
    # a rioxarray / CF spatial_ref coordinate, with either attribute name
    for key in ("crs_wkt", "spatial_ref"):
        bare = da.copy()
        bare.attrs = {}
        ref = bare.assign_coords(spatial_ref=xr.DataArray(0, attrs={key: wkt}))
        assert Grid.from_dataarray(ref.sortby("y")) == Grid.from_dataarray(da)
        assert dataarray_crs(ref).to_epsg() == 32608
    bare = da.copy()
    bare.attrs = {}
    assert dataarray_crs(bare) is None
    with pytest.raises(InputError, match=r"attrs\['crs_wkt'\]"):  # message kept as before
        Grid.from_dataarray(bare)


def test_rioxarray_crs_when_installed():
    rioxarray = pytest.importorskip("rioxarray", reason="rioxarray is optional")
    assert rioxarray
    da = north_dem()
    bare = da.copy()
    bare.attrs = {}
    bare = bare.drop_vars("spatial_ref", errors="ignore").rio.write_crs("EPSG:32608")
    assert Grid.from_dataarray(bare).crs.to_epsg() == 32608


def test_irregular_spacing_is_a_clear_error():
    da = north_dem()
    x = da.x.values.copy()
    x[5:] += 7.0  # one gap of 27 m among 20 m cells
    with pytest.raises(
        InputError, match=r"x coordinates: expected regularly spaced.*got 'spacing 20 then 27"
    ):
        Grid.from_dataarray(da.assign_coords(x=x))
    y = da.y.values.copy()
    y[3] -= 2.0
    with pytest.raises(InputError, match="y coordinates: expected regularly spaced"):
        Grid.from_dataarray(da.assign_coords(y=y))
    # float noise far below a cell is still a raster
    jitter = da.x.values + np.linspace(0, 1e-6, da.x.size)
    assert Grid.from_dataarray(da.assign_coords(x=jitter)).resolution[0] == pytest.approx(20.0)
    with pytest.raises(InputError, match="coordinate 'x'"):
        Grid.from_dataarray(da.rename({"x": "lon"}))


def test_callers_accept_y_ascending():
    da = north_dem()
    asc = da.sortby("y")
    xr.testing.assert_identical(coarse_dem(asc, (4, 6)), coarse_dem(da, (4, 6)))
    dem = coarse_dem(da, (4, 6))
    xy = np.random.default_rng(0).uniform([525950, 6474950], [526650, 6475450], (200, 2))
    np.testing.assert_array_equal(TriangulatedMean(dem.sortby("y"))(xy), TriangulatedMean(dem)(xy))
    inside = np.random.default_rng(1).uniform([526010, 6475013], [526590, 6475387], (200, 2))
    np.testing.assert_array_equal(sample_dem(asc, inside), sample_dem(da, inside))


def test_real_dem_both_orders():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import real_dems

    try:
        dem = real_dems.load("olinda")  # real UTM 25S SRTM-like DEM, 111 x 111 at ~90 m
    except real_dems.RealDataUnavailable as exc:
        pytest.skip(f"real DEM 'olinda' unavailable: {exc}")
    g = Grid.from_dataarray(dem)
    assert Grid.from_dataarray(dem.sortby("y")) == g
    assert "Zone 25, Southern" in g.crs.name and g.resolution[0] == pytest.approx(90, abs=0.1)
    w, s, e, n = g.bounds
    xy = np.random.default_rng(2).uniform([w + 100, s + 100], [e - 100, n - 100], (300, 2))
    np.testing.assert_array_equal(sample_dem(dem.sortby("y"), xy), sample_dem(dem, xy))
    np.testing.assert_array_equal(
        coarse_dem(dem.sortby("y"), (8, 8)).values, coarse_dem(dem, (8, 8)).values
    )


@pytest.mark.parametrize(
    "name, shape, lon, lat",
    [
        # matplotlib sample_data/jacksboro_fault_dem.npz: 344 x 403 at 3" from -84.41375 E,
        # rows from 36.73292 N southward (the file's own xmin/dx/ymin/dy)
        ("jacksboro", (344, 403), (-84.41375, -84.41375 + 403 * 3 / 3600), 36.73292),
        # matplotlib sample_data/topobathy.npz: 91 x 120, longitudes 234.02-237.98 (0-360 E)
        ("topobathy", (91, 120), (234.0167 - 360, 237.9834 - 360), 49.98418),
    ],
)
def test_matplotlib_real_dems(name, shape, lon, lat):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import real_dems

    dem = real_dems.load(name)  # ships with matplotlib: never skipped
    assert dem.shape == shape and np.isfinite(dem.values).all()
    assert dem.attrs["crs_wkt"] == "EPSG:4326"  # degrees: a Grid refuses it, RasterMean warps
    x, y = dem.x.values, dem.y.values
    assert x[0] == pytest.approx(lon[0], abs=0.02) and x[-1] == pytest.approx(lon[1], abs=0.02)
    assert y[0] == pytest.approx(lat, abs=0.02) and np.all(np.diff(y) < 0)  # north-up
    site = real_dems.glacier_site(name)  # a 600 m site at 2 m, 25 m relief
    assert site.shape == (300, 300)
    assert float(site.max() - site.min()) == pytest.approx(25.0)


@pytest.mark.parametrize(
    "name, shape, cell, lo, hi",
    [
        # R's datasets::volcano: 87 x 61 at 10 m, range(volcano) = 94 195 (R's ?volcano)
        ("volcano", (87, 61), 10.0, 94.0, 195.0),
        # spatstat.data::bei.extra$elev: 101 x 201 pixels of 5 m over 1000 m x 500 m;
        # range 119.81-159.48 m as R's summary(bei.extra$elev) prints it
        ("bei", (101, 201), 5.0, 119.81, 159.48),
    ],
)
def test_lazyload_real_dems(name, shape, cell, lo, hi):
    """The R lazy-load databases (zlib: spatstat.data; raw xz: R's own datasets) decode to
    north-up DEMs of the documented size, cell and range."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import real_dems

    try:
        dem = real_dems.load(name)
    except real_dems.RealDataUnavailable as exc:
        pytest.skip(f"real DEM {name!r} unavailable: {exc}")
    assert dem.shape == shape and np.isfinite(dem.values).all()
    assert float(dem.min()) == pytest.approx(lo) and float(dem.max()) == pytest.approx(hi)
    assert np.all(np.diff(dem.x.values) == cell) and np.all(np.diff(dem.y.values) == -cell)
    if name == "volcano":
        # volcano[1, 1] = 100 and volcano[1, 61] = 103 (R), rows south -> north, columns
        # east -> west: the first row is the south edge, so they land bottom right and left
        assert dem.values[-1, -1] == 100.0 and dem.values[-1, 0] == 103.0
    site = real_dems.glacier_site(name)
    assert site.shape == (300, 300)


@pytest.mark.parametrize(
    "name, shape, cell, crs, nan_cells",
    [
        # spatstat.data::gorillas.extra$elevation: an "im" of 149 x 181 integer pixels,
        # xstep 30.70954977 m (the object's own header), UTM 32N (spatstat's ?gorillas);
        # R's NA_integer_ outside the sanctuary's polygon: 5,927 cells (counted here)
        ("gorillas", (149, 181), 30.70954977, "EPSG:32632", 5927),
        # spatstat.data::clmfires.extra$clmcov200$elevation: 200 x 200 pixels, xstep
        # 2.00000006 km (header), no NA; km read as metres x 1000
        ("clm", (200, 200), 2000.00006325, None, 0),
    ],
)
def test_spatstat_covariate_dems(name, shape, cell, crs, nan_cells):
    """DEMs stored among factor images (gorillas.extra) decode; R's integer NA becomes NaN
    (counted, never an elevation of -2,147,483,648 m); km coordinates become metres."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import real_dems

    try:
        dem = real_dems.load(name)
    except real_dems.RealDataUnavailable as exc:
        pytest.skip(f"real DEM {name!r} unavailable: {exc}")
    assert dem.shape == shape
    assert int(np.isnan(dem.values).sum()) == nan_cells
    assert float(np.nanmin(dem.values)) > 0.0  # no NA sentinel left
    assert np.diff(dem.x.values) == pytest.approx(cell) and np.diff(dem.y.values) == pytest.approx(
        -cell
    )
    assert dem.attrs["crs_wkt"] == (crs or real_dems.LOCAL_TM)
    site = real_dems.glacier_site(name)  # its windows avoid the NA cells
    assert site.shape == (300, 300) and np.isfinite(site.values).all()


@pytest.mark.parametrize(
    "lon, lat, epsg",
    [
        (-134.5, 58.4, 32608),  # Juneau, the paper's site: UTM 8N
        (-34.85, -8.0, 32725),  # Olinda: UTM 25S (the stars DEM's own CRS)
        (6.1, 49.6, 32632),  # Luxembourg: UTM 32N
        (0.0, 85.0, None),  # beyond 84 N: polar stereographic, no UTM zone
        (0.0, -81.0, None),  # beyond 80 S
    ],
)
def test_utm_crs_of_a_point(lon, lat, epsg):
    from terrain.grid import utm_crs

    got = utm_crs(lon, lat)
    assert (got.to_epsg() if got is not None else None) == epsg
