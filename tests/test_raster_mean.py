"""RasterMean: a satellite DEM read from a file (GeoTIFF, rasterio dataset, DataArray) as the GP
prior mean, with the linear-mean protocol.

Reference values: a plane and a plane plus a Gaussian bump, evaluated analytically at every
cell centre of each raster (UTM 8N and EPSG:4326) — so the expected mean at any point is
the analytic surface, and the only error is RasterMean's own (resampling, interpolation).
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
import xarray as xr
from pyproj import Transformer
from rasterio.transform import from_origin

from terrain import InputError, NotFittedError, RasterMean
from terrain.errors import CRSMismatchError
from terrain.grid import Grid
from terrain.prior import TriangulatedMean, as_mean_function, coarse_dem

W, N, RES, NCELL = 500_000.0, 6_500_000.0, 30.0, 200  # a 6 km UTM 8N tile at 30 m
INNER = (W + 1000.0, N - 5000.0, W + 5000.0, N - 1000.0)


def plane(x, y):
    return 1000.0 + 0.05 * (x - W) - 0.02 * (y - N)


def bumpy(x, y):
    return plane(x, y) + 15.0 * np.exp(-((x - W - 3000) ** 2 + (y - N + 3000) ** 2) / 1.28e6)


def centres(transform, shape):
    x = transform.c + transform.a * (np.arange(shape[1]) + 0.5)
    y = transform.f + transform.e * (np.arange(shape[0]) + 0.5)
    return np.meshgrid(x, y)


def write_tif(path, values, transform, crs, nodata=None):
    profile = {"driver": "GTiff", "count": 1, "dtype": "float64", "crs": crs, "nodata": nodata}
    with rasterio.open(
        path, "w", height=values.shape[0], width=values.shape[1], transform=transform, **profile
    ) as ds:
        ds.write(values, 1)
    return path


def utm_tif(tmp_path, f=plane, name="utm.tif", nodata=None, values=None):
    t = from_origin(W, N, RES, RES)
    z = f(*centres(t, (NCELL, NCELL))) if values is None else values
    return write_tif(tmp_path / name, z, t, "EPSG:32608", nodata)


def geo_tif(tmp_path, f=plane, name="geo.tif"):
    """The same surface on a lon/lat raster over the UTM tile, ~0.0004 deg cells (24 x 46 m),
    each cell the analytic surface at its centre's UTM coordinates."""
    to_geo = Transformer.from_crs(32608, 4326, always_xy=True)
    lon, lat = to_geo.transform([W, W + 6000.0], [N - 6000.0, N])
    d = 0.0004116798403144907
    t = from_origin(lon[0], lat[1], d, d)
    shape = (int((lat[1] - lat[0]) / d), int((lon[1] - lon[0]) / d))
    lo, la = centres(t, shape)
    x, y = Transformer.from_crs(4326, 32608, always_xy=True).transform(lo, la)
    return write_tif(tmp_path / name, f(x, y), t, "EPSG:4326")


def points(n=400, seed=0):
    return np.random.default_rng(seed).uniform(INNER[:2], INNER[2:], (n, 2))


def utm_array(f=plane):
    g = Grid.from_bounds((W, N - NCELL * RES, W + NCELL * RES, N), RES)
    return g.data_array(f(*g.xy().T).reshape(g.shape), "elevation")


# -- reading: file, dataset, DataArray; CRSs -----------------------------------------------


@pytest.mark.parametrize("resampling", ["bilinear", "cubic"])
def test_utm_and_geographic_files_agree(tmp_path, resampling):
    # Measured (these fixtures, 400 points): plane 5e-13 m (UTM) and 1.5e-7 m (EPSG:4326,
    # bilinear); plane + 15 m bump (sigma 800 m): UTM vs EPSG:4326 differ by 6.2 mm (bilinear)
    # and 4.1 mm (cubic) — the resampling tolerance at 24-46 m cells on a smooth glacier.
    xy = points()
    for f, tol_truth, tol_pair in ((plane, 1e-6, 1e-6), (bumpy, 0.015, 0.01)):
        u = RasterMean(utm_tif(tmp_path, f), offset="none", crs=32608, resampling=resampling)
        g = RasterMean(geo_tif(tmp_path, f), offset="none", crs=32608, resampling=resampling)
        a, b, truth = u(xy), g(xy), f(*xy.T)
        assert np.abs(a - truth).max() < tol_truth
        assert np.abs(b - truth).max() < tol_truth
        assert np.abs(a - b).max() < tol_pair
    assert g.describe()["source_crs"] == "EPSG:4326"
    assert 20.0 < g.describe()["resolution_m"][0] < 30.0  # ~ the source's 24 m E-W cells


def test_geographic_written_by_rasterio_warp(tmp_path):
    # The EPSG:4326 file made by rasterio.warp.reproject (bilinear, GDAL's approximate
    # transformer at 0.125 px, kernel widened where it downsamples): that file itself is off
    # the plane by up to 4.5 cm (measured); RasterMean reading it: 4.0 cm, held to 5 cm.
    from rasterio.warp import Resampling, calculate_default_transform, reproject

    src = utm_tif(tmp_path)
    with rasterio.open(src) as ds:
        t, w, h = calculate_default_transform(ds.crs, "EPSG:4326", ds.width, ds.height, *ds.bounds)
        out = np.full((h, w), -9999.0)
        reproject(
            rasterio.band(ds, 1), out, dst_transform=t, dst_crs="EPSG:4326",
            resampling=Resampling.bilinear, dst_nodata=-9999.0,
        )  # fmt: skip
    geo = write_tif(tmp_path / "warped.tif", out, t, "EPSG:4326", nodata=-9999.0)
    xy = points()
    a = RasterMean(geo, offset="none", crs=32608)(xy)
    assert np.abs(a - plane(*xy.T)).max() < 0.05


def test_y_ascending_equals_descending_and_spatial_ref():
    da = utm_array(bumpy)
    xy = points()
    ref = RasterMean(da, offset="none", crs=32608)(xy)
    np.testing.assert_array_equal(RasterMean(da.sortby("y"), offset="none", crs=32608)(xy), ref)
    bare = da.copy()
    bare.attrs = {"units": "m"}
    sr = bare.assign_coords(spatial_ref=xr.DataArray(0, attrs={"crs_wkt": da.attrs["crs_wkt"]}))
    m = RasterMean(sr.sortby("y"), offset="none", crs=32608)
    np.testing.assert_array_equal(m(xy), ref)
    assert m.describe()["source"] == "DataArray"


def test_dataset_object_and_path(tmp_path):
    path = utm_tif(tmp_path, bumpy)
    xy = points()
    ref = RasterMean(utm_array(bumpy), offset="none", crs=32608)(xy)
    with rasterio.open(path) as ds:
        np.testing.assert_allclose(RasterMean(ds, offset="none", crs=32608)(xy), ref, atol=1e-9)
    for src in (path, str(path)):
        m = RasterMean(src, offset="none", crs=32608)
        np.testing.assert_allclose(m(xy), ref, atol=1e-9)
    assert m.describe()["source"] == str(path)
    assert isinstance(as_mean_function(Path(path)), RasterMean)


def test_rebinding_outside_keeps_values_and_pickles():
    m = RasterMean(utm_array(bumpy), offset="none")
    m.bind("EPSG:32608", (W + 2000, N - 3000, W + 2500, N - 2500))
    inner = np.array([[W + 2200.0, N - 2700.0], [W + 2400.0, N - 2900.0]])
    before = m(inner)
    far = np.array([[W + 100.0, N - 5900.0]])  # outside the bound area, inside the DEM
    np.testing.assert_allclose(m(far), bumpy(*far.T), atol=0.02)
    assert m.describe()["bound_bounds"][0] < W + 100.0
    np.testing.assert_array_equal(m(inner), before)  # same lattice: same values
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(m))(inner), before)


# -- nodata, coverage, bad input -------------------------------------------------------------


def test_nodata_counted_and_filled(tmp_path):
    z = plane(*centres(from_origin(W, N, RES, RES), (NCELL, NCELL)))
    z[100:103, 100:104] = -9999.0  # a 3 x 4 hole at (W + 3000..3120, N - 3000..3090)
    m = RasterMean(utm_tif(tmp_path, values=z, nodata=-9999.0), offset="none", crs=32608)
    m.bind(32608, INNER)
    assert m.n_nodata_ == 12 and m.describe()["n_nodata"] == 12
    assert "n_nodata=12" in repr(m)
    assert 0 < m.describe()["max_fill_m"] <= 60.0
    assert np.all(np.isfinite(m(points())))
    assert np.all(np.abs(m(points()) - plane(*points().T)) < 1e-9 + (0.05 + 0.02) * 60)
    # the same hole as NaN in a DataArray, and as a nodata= value
    da = utm_array()
    da.values[100:103, 100:104] = np.nan
    assert RasterMean(da, offset="none").bind(32608, INNER).n_nodata_ == 12
    da.values[100:103, 100:104] = -32768.0
    assert RasterMean(da, offset="none", nodata=-32768).bind(32608, INNER).n_nodata_ == 12


def test_all_nodata_raises(tmp_path):
    path = utm_tif(tmp_path, values=np.full((NCELL, NCELL), -9999.0), nodata=-9999.0)
    with pytest.raises(InputError, match="source nodata.*Fix: check the nodata"):
        RasterMean(path, crs=32608).bind(32608, INNER)


def test_not_covering_the_map_names_both_bounds():
    m = RasterMean(utm_array(), crs=32608)
    with pytest.raises(InputError, match=r"footprint \(500000.0, 6494000.0, 506000.0, 6500000.0\)"):
        m.bind(32608, (W + 5000, N - 4000, W + 7000, N - 2000))
    with pytest.raises(InputError, match=r"map bounds \(505000.0, 6496000.0, 507000.0"):
        m.bind(32608, (W + 5000, N - 4000, W + 7000, N - 2000))


def test_bad_inputs():
    da = utm_array()
    bare = da.copy()
    bare.attrs = {}
    with pytest.raises(InputError, match=r"source\.crs: .*Fix: pass source_crs="):
        RasterMean(bare)
    assert RasterMean(bare, source_crs=32608).source.crs.to_epsg() == 32608
    with pytest.raises(InputError, match="resampling: expected one of .*'average'"):
        RasterMean(da, resampling="lanczos")
    with pytest.raises(InputError, match="offset"):
        RasterMean(da, offset="auto")
    with pytest.raises(InputError, match="x coordinates: expected regularly spaced"):
        RasterMean(da.isel(x=[0, 1, 2, 4, 5]))
    with pytest.raises(InputError, match="RasterMean.crs"):
        RasterMean(da).fit(points(5), np.zeros(5))
    with pytest.raises(NotFittedError, match="not bound"):
        RasterMean(da, offset="none")(points(5))
    m = RasterMean(da, crs=32608)
    with pytest.raises(CRSMismatchError):
        m.bind(32607, INNER)


# -- the linear-mean protocol ----------------------------------------------------------------


def test_ols_fit_recovers_offset_and_scale():
    # z = 3 + 1.01 * DEM exactly (noise free; a plane DEM, which bilinear reproduces to
    # 1e-11 m): least squares gives a = 3, b = 1.01 and a zero residual, hence a zero
    # covariance (s^2 = RSS / (n - 2) = 0), by hand.
    da = utm_array(plane)
    xy = points()
    z = 3.0 + 1.01 * plane(*xy.T)
    m = RasterMean(da, crs=32608)
    assert m.n_coef == 2 and m.coef_names == ("offset_m", "scale")
    with pytest.raises(NotFittedError, match="offset='fit'"):
        m(xy)
    fitted = m.fit(xy, z)
    np.testing.assert_allclose(fitted.coef_, [3.0, 1.01], rtol=0, atol=1e-6)
    np.testing.assert_allclose(fitted.coef_cov_, 0.0, atol=1e-12)
    np.testing.assert_allclose(fitted(xy), z, atol=1e-6)
    h = fitted.basis(xy)
    assert h.shape == (len(xy), 2) and np.all(h[:, 0] == 1.0)
    coefs = fitted.describe()["coefficients"]
    assert set(coefs) == {"offset_m", "scale"} and abs(coefs["scale"]["value"] - 1.01) < 1e-6
    assert "offset_m=3" in repr(fitted) and "+-" in repr(fitted)
    assert m.coef_ is None  # fit returns a copy
    # the GP's route: coefficients from elsewhere (GLS) with their covariance
    given = m.with_coefficients([2.0, 1.0], np.diag([0.25, 1e-4]))
    np.testing.assert_allclose(given(xy), 2.0 + m.dem(xy))
    assert given.describe()["coefficients"]["offset_m"] == {"value": 2.0, "sd": 0.5}


def test_fixed_offsets():
    da = utm_array()
    xy = points()
    base = RasterMean(da, offset="none", crs=32608)
    assert base.n_coef == 0
    shifted = RasterMean(da, offset=-2.5, crs=32608)
    np.testing.assert_allclose(shifted(xy), base(xy) - 2.5)
    assert shifted.fit(xy, base(xy)) is shifted
    with pytest.raises(InputError, match="n_coef"):
        base.basis(xy)


def test_cells_equal_triangulated_coarse_dem():
    grid = Grid.from_bounds(INNER, 2.0)
    m = RasterMean(utm_array(bumpy), offset="none", cells=(8, 8)).for_grid(grid)
    ref = TriangulatedMean(coarse_dem(m.bound_dem, cells=(8, 8)))
    xy = np.vstack([points(), [[W, N], [W + 9000.0, N + 50.0]]])  # inside and far outside
    np.testing.assert_allclose(m(xy), ref(xy), rtol=0, atol=1e-9)
    assert Grid.from_dataarray(m.bound_dem).bounds == pytest.approx(grid.bounds)
    assert m.describe()["cells"] == [8, 8]


def test_cells_read_as_area_means():
    from terrain import PycnophylacticMean

    grid = Grid.from_bounds(INNER, 2.0)
    m = RasterMean(utm_array(bumpy), offset="none", cells=(8, 8), coarse="area-means")
    m = m.for_grid(grid)
    ref = PycnophylacticMean(coarse_dem(m.bound_dem, cells=(8, 8)))
    xy = np.vstack([points(), [[W, N], [W + 9000.0, N + 50.0]]])  # inside and far outside
    np.testing.assert_allclose(m(xy), ref(xy), rtol=0, atol=1e-9)
    assert m.describe()["coarse"] == "area-means" and "coarse='area-means'" in repr(m)
    mesh = RasterMean(utm_array(bumpy), offset="none", cells=(8, 8)).for_grid(grid)
    assert np.abs(mesh(xy) - m(xy)).max() > 0.01  # not the mesh
    with pytest.raises(InputError, match="coarse"):
        RasterMean(utm_array(bumpy), cells=(8, 8), coarse="triangles")


def test_describe_is_json_safe(tmp_path):
    import json

    m = RasterMean(geo_tif(tmp_path), crs=32608).fit(points(), plane(*points().T))
    d = json.loads(json.dumps(m.describe()))
    assert d["map_crs"] == "EPSG:32608" and d["resampling"] == "bilinear"
    assert len(d["footprint_map"]) == 4 and d["n_nodata"] == 0


# -- real DEMs (Debian packages; skipped with the reason when they cannot be fetched) ------


def _real(name):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import real_dems

    try:
        return real_dems.load(name)
    except real_dems.RealDataUnavailable as exc:
        pytest.skip(f"real DEM {name!r} unavailable: {exc}")


def test_real_utm25s_dem_as_file_and_array(tmp_path):
    dem = _real("olinda")  # 111 x 111 cells at ~90 m, UTM 25S
    g = Grid.from_dataarray(dem)
    path = write_tif(tmp_path / "olinda.tif", dem.values, g.transform, g.crs.to_wkt())
    w, s, e, n = g.bounds
    xy = np.random.default_rng(1).uniform([w + 1000, s + 1000], [e - 1000, n - 1000], (300, 2))
    a = RasterMean(path, offset="none", crs=g.crs)(xy)
    b = RasterMean(dem.sortby("y"), offset="none", crs=g.crs)(xy)
    np.testing.assert_allclose(a, b, atol=1e-9)
    # same CRS and lattice: bilinear on the source cells, as scipy's reference does
    from terrain.sampling import sample_dem

    np.testing.assert_allclose(a, sample_dem(dem, xy), atol=1e-6)


def test_real_geographic_dem_into_utm():
    dem = _real("rm")  # Rocky Mountains at 2.5 arc-minutes, EPSG:4326
    crs = "EPSG:32613"  # UTM 13N covers -108..-102 deg
    to_map = Transformer.from_crs(4326, crs, always_xy=True)
    cx, cy = to_map.transform(-105.5, 40.0)
    m = RasterMean(dem, offset="none", crs=crs, resampling="bilinear")
    xy = np.array([[cx, cy], [cx + 20000.0, cy - 15000.0]])
    got = m(xy)
    # Reference: bilinear in lon/lat on the source cells at the points' lon/lat
    from scipy.interpolate import RegularGridInterpolator

    lon, lat = Transformer.from_crs(crs, 4326, always_xy=True).transform(xy[:, 0], xy[:, 1])
    d = dem.sortby("y")
    ref = RegularGridInterpolator((d.y.values, d.x.values), d.values)(np.column_stack([lat, lon]))
    # two bilinear steps (source -> ~3.5 km lattice -> point) on rough real terrain
    assert np.abs(got - ref).max() < 0.02 * (dem.values.max() - dem.values.min())
    assert 3000 < m.describe()["resolution_m"][0] < 4700


def test_gp_map_from_a_geographic_prior_equals_the_map_from_the_utm_prior(tmp_path):
    """The issue's check at the map level: the same DEM as a UTM 8N GeoTIFF and as an
    EPSG:4326 GeoTIFF, each the GP's prior mean (offset and scale fitted by GLS) for the same
    300 samples. The GP is linear in the mean, so the maps differ by at most the priors'
    resampling difference (6.2 mm bilinear at these cells, measured above) — measured here:
    3.6 mm max over a 60 x 60 grid, 1-sigma within 3e-7 m (the basis enters the variance
    only through R = h* - H K^-1 k*, which the mm shifts barely move)."""
    from terrain import ElevationSamples, SquaredExponential, TerrainGP

    rng = np.random.default_rng(3)
    xy = points(300, seed=3)
    z = bumpy(*xy.T) + 2.0 + rng.normal(0.0, 0.1, len(xy))  # a 2 m datum offset to fit
    samples = ElevationSamples(xy, z, 0.01, crs="EPSG:32608")
    grid = Grid.from_bounds(INNER, (INNER[2] - INNER[0]) / 60)
    maps = []
    for path in (utm_tif(tmp_path, bumpy), geo_tif(tmp_path, bumpy)):
        gp = TerrainGP(
            SquaredExponential(1.0, 300.0),
            mean=RasterMean(path, offset="fit"),
            optimize=False,
            method="exact",
        )
        maps.append(gp.fit(samples).predict_grid(grid))
    a, b = maps
    assert np.abs(a.elevation.values - b.elevation.values).max() < 0.01
    assert np.abs(a.elevation_std.values - b.elevation_std.values).max() < 1e-3
    truth = bumpy(*grid.xy().T).reshape(grid.shape) + 2.0
    assert np.abs(a.elevation.values - truth).max() < 0.5  # the map itself is right


# -- heights as stored: band scale / offset, feet, NetCDF, nodata under cells= --------------


def test_int16_band_scale_and_offset_are_applied(tmp_path):
    # An int16 DEM stored as round((z - 50) / 0.1) with band scale 0.1 and offset 50 (GDAL's
    # convention: value = stored x scale + offset); nodata -32768 masked before scaling.
    t = from_origin(W, N, RES, RES)
    z = plane(*centres(t, (NCELL, NCELL)))
    stored = np.round((z - 50.0) / 0.1).astype(np.int16)
    stored[100:102, 100:102] = -32768
    path = tmp_path / "i16.tif"
    profile = {"driver": "GTiff", "count": 1, "dtype": "int16", "crs": "EPSG:32608"}
    with rasterio.open(
        path, "w", height=NCELL, width=NCELL, transform=t, nodata=-32768, **profile
    ) as ds:
        ds.write(stored, 1)
        ds.scales, ds.offsets = (0.1,), (50.0,)
    m = RasterMean(path, offset="none").bind(32608, INNER)
    np.testing.assert_allclose(m(points()), plane(*points().T), atol=0.05 + 1e-9)  # 0.1 m steps
    assert m.n_nodata_ == 4 and "band scale 0.1 and offset 50" in m.describe()["source_vertical"]


@pytest.mark.parametrize(
    "how, units, factor",
    [("unit", "ft", 0.3048), ("tag", "US survey foot", 1200 / 3937), ("tag", "metre", 1.0)],
)
def test_heights_in_feet_are_converted(tmp_path, how, units, factor):
    t = from_origin(W, N, RES, RES)
    path = write_tif(tmp_path / "ft.tif", plane(*centres(t, (NCELL, NCELL))) / factor, t, 32608)
    with rasterio.open(path, "r+") as ds:
        if how == "unit":
            ds.units = (units,)  # GDAL's band unit type
        else:
            ds.update_tags(1, units=units)
    m = RasterMean(path, offset="none").bind(32608, INNER)
    np.testing.assert_allclose(m(points()), plane(*points().T), rtol=1e-12)
    da = utm_array()
    da = da.copy(data=da.values / factor).assign_attrs(units=units)
    np.testing.assert_allclose(
        RasterMean(da, offset="none").bind(32608, INNER)(points()), plane(*points().T), rtol=1e-12
    )


def test_unknown_height_units_warn_and_read_as_metres():
    da = utm_array().assign_attrs(units="fathoms")
    with pytest.warns(UserWarning, match="fathoms"):
        m = RasterMean(da, offset="none")
    np.testing.assert_allclose(m.bind(32608, INNER)(points()), plane(*points().T), rtol=1e-12)


def test_netcdf_path_without_cf_axis_attributes(tmp_path):
    # x / y without CF axis attributes: GDAL reads such a file with an identity transform
    # (footprint (0, 0, ncols, nrows)); it is opened with xarray instead.
    da = utm_array(bumpy)
    path = tmp_path / "prior.nc"
    da.to_dataset(name="elevation").to_netcdf(path)
    m = RasterMean(path, offset="none").bind(32608, INNER)
    ref = RasterMean(da, offset="none").bind(32608, INNER)
    np.testing.assert_array_equal(m(points()), ref(points()))


def test_nodata_counted_on_source_cells_with_coarse_cells(tmp_path):
    z = plane(*centres(from_origin(W, N, RES, RES), (NCELL, NCELL)))
    z[100:103, 100:104] = -9999.0  # 12 source cells under INNER
    path = utm_tif(tmp_path, values=z, nodata=-9999.0)
    for cells in (None, (8, 8)):
        assert RasterMean(path, offset="none", cells=cells).bind(32608, INNER).n_nodata_ == 12


def test_heights_in_feet_from_a_compound_crs():
    # No units text: the vertical axis of EPSG:32608+8228 (UTM 8N + NAVD88 height in ft,
    # PROJ's unit table: 0.3048 m per foot) says the heights are feet.
    from pyproj import CRS

    da = utm_array()
    da = da.copy(data=da.values / 0.3048)
    da.attrs = {"crs_wkt": CRS("EPSG:32608+8228").to_wkt()}
    m = RasterMean(da, offset="none").bind(32608, INNER)
    np.testing.assert_allclose(m(points()), plane(*points().T), rtol=1e-12)
    assert "vertical unit" in m.describe()["source_vertical"]
