"""``[site] kind = "dem"``: a scenario's true DEM read from a GeoTIFF (toolkit/site_dem.py).

Small GeoTIFFs are written in each test (UTM and lon/lat, with nodata); the surfaces are
analytic so that the resampled truth has a reference value: GDAL's cubic convolution (Keys,
a = -0.5) reproduces polynomials up to degree 2 exactly (Keys 1981, IEEE TASSP 29(6), eq. 26
ff.), so a quadratic DEM comes back exactly away from the raster edge.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin
from typer.testing import CliRunner

from terrain import InputError
from toolkit.cli import app
from toolkit.config import load_scenario
from toolkit.pipeline import make_plan, make_site, simulate_log

W0, N0, CELL = 500_000.0, 7_000_000.0, 30.0  # UTM 33N window of 64 x 64 cells at 30 m


def _quadratic(x, y):
    """Reference surface (m): a tilted plane plus a quadratic valley."""
    return 1000.0 + 0.05 * (x - W0) + 2e-4 * (y - N0 + 960.0) ** 2


def _write(path: Path, z, transform, crs="EPSG:32633", nodata=-9999.0) -> Path:
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=z.shape[0],
        width=z.shape[1],
        count=1,
        dtype="float64",
        crs=crs,
        transform=transform,
        nodata=nodata,
    ) as ds:
        ds.write(np.where(np.isfinite(z), z, nodata), 1)
    return path


def _utm_dem(path: Path, hole=None) -> Path:
    x = W0 + CELL * (np.arange(64) + 0.5)
    y = N0 - CELL * (np.arange(64) + 0.5)
    z = _quadratic(*np.meshgrid(x, y))
    if hole is not None:
        z[hole] = np.nan
    return _write(path, z, from_origin(W0, N0, CELL, CELL))


def _scenario(tmp_path: Path, **site) -> Path:
    lines = ["[site]"] + [f"{k} = {json.dumps(v)}" for k, v in {"kind": "dem", **site}.items()]
    path = tmp_path / "scenario.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_utm_dem_is_resampled_exactly_where_cubic_is_exact(tmp_path):
    _utm_dem(tmp_path / "dem.tif")
    bounds = [W0 + 300.0, N0 - 1500.0, W0 + 1500.0, N0 - 300.0]
    scen = load_scenario(_scenario(tmp_path, dem="dem.tif", bounds=bounds))
    site = make_site(scen)
    assert site.shape == (600, 600)  # 1200 m at the default 2 m
    assert scen["site"]["crs"] == "EPSG:32633"  # the DEM's own projected CRS
    xx, yy = np.meshgrid(site.x.values, site.y.values)
    np.testing.assert_allclose(site.values, _quadratic(xx, yy), atol=1e-6, rtol=0)
    prov = json.loads(site.attrs["site_dem"])
    assert prov["resampling"] == "cubic" and prov["site_crs_from"] == "the DEM's own CRS"
    assert prov["nodata_cells_filled"] == 0 and prov["dem_cell_m"] == pytest.approx(30.0)


def test_relative_path_is_read_from_the_scenario_folder_and_extent_is_the_default(tmp_path):
    sub = tmp_path / "data"
    sub.mkdir()
    _utm_dem(sub / "dem.tif")
    scen = load_scenario(_scenario(sub, dem="dem.tif", truth_resolution_m=8.0))
    assert Path(scen["site"]["dem"]) == (sub / "dem.tif").resolve()
    # bounds omitted: the DEM's valid extent, snapped to whole truth cells (1920 m = 240 x 8)
    assert scen["site"]["bounds"] == [W0, N0 - 1920.0, W0 + 1920.0, N0]
    assert make_site(scen).shape == (240, 240)


def test_lonlat_dem_takes_the_utm_zone_of_its_centre_and_says_so(tmp_path):
    # 0.004 deg cells around lon 10.5, lat 46.0: UTM 32N (6 deg zones: 6-12 E)
    lon = 10.4 + 0.004 * (np.arange(50) + 0.5)
    lat = 46.1 - 0.004 * (np.arange(50) + 0.5)
    z = 2000.0 + 2000.0 * (lon[None, :] - 10.5) + 500.0 * (lat[:, None] - 46.0)
    tif = _write(tmp_path / "ll.tif", z, from_origin(10.4, 46.1, 0.004, 0.004), "EPSG:4326")
    scen = load_scenario(_scenario(tmp_path, dem=str(tif), truth_resolution_m=20.0))
    assert scen["site"]["crs"] == "EPSG:32632"
    site = make_site(scen)
    prov = json.loads(site.attrs["site_dem"])
    assert prov["site_crs_from"] == "the UTM zone of the DEM's centre (WGS 84)"
    assert prov["dem_crs"] == "EPSG:4326" and np.isfinite(site.values).all()
    # the inscribed box of the lon/lat extent: inside 0.2 deg x 0.2 deg (~15.5 x 22.2 km)
    w, s, e, n = scen["site"]["bounds"]
    assert 14_000 < e - w < 15_600 and 21_000 < n - s < 22_300
    # linear in lon/lat, so cubic is exact: the truth at each cell centre is the plane at
    # that centre's lon/lat (pyproj), more than half a DEM cell (300 m) from its edge
    from pyproj import Transformer

    xx, yy = np.meshgrid(site.x.values[20:-20:50], site.y.values[20:-20:50])
    lo, la = Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True).transform(xx, yy)
    want = 2000.0 + 2000.0 * (lo - 10.5) + 500.0 * (la - 46.0)
    np.testing.assert_allclose(site.values[20:-20:50, 20:-20:50], want, atol=1e-3)


def test_nodata_inside_the_site_is_counted_then_refused_above_the_share(tmp_path):
    hole = (slice(30, 33), slice(30, 33))  # 3 x 3 DEM cells = 90 m x 90 m of nodata
    _utm_dem(tmp_path / "dem.tif", hole)
    bounds = [W0 + 600.0, N0 - 1200.0, W0 + 1200.0, N0 - 600.0]  # 600 m: the hole inside
    site = make_site(load_scenario(_scenario(tmp_path, dem="dem.tif", bounds=bounds)))
    prov = json.loads(site.attrs["site_dem"])
    # 90 m x 90 m at 2 m = 2025 cells, plus the cubic kernel's reach into the hole's rim
    assert 2025 <= prov["nodata_cells_filled"] <= 60 * 60
    assert prov["nodata_fraction"] == pytest.approx(prov["nodata_cells_filled"] / 300**2)
    assert np.isfinite(site.values).all() and prov["max_fill_distance_m"] > 0
    small = [W0 + 840.0, N0 - 1080.0, W0 + 1080.0, N0 - 840.0]  # 240 m: hole > 5 %
    with pytest.raises(InputError, match=r"site\.bounds.*max_nodata_fraction"):
        load_scenario(_scenario(tmp_path, dem="dem.tif", bounds=small))  # at load: no work
    loose = load_scenario(_scenario(tmp_path, dem="dem.tif", bounds=small, max_nodata_fraction=0.5))
    assert json.loads(make_site(loose).attrs["site_dem"])["nodata_cells_filled"] > 0.05 * 120**2


def test_ragged_dem_without_bounds_takes_its_largest_valid_rectangle(tmp_path):
    x = W0 + CELL * (np.arange(64) + 0.5)
    y = N0 - CELL * (np.arange(64) + 0.5)
    z = _quadratic(*np.meshgrid(x, y))
    z[:, :20] = np.nan  # nodata west of column 20
    z[40:, :] = np.nan  # and south of row 40
    z[:5, 20:30] = np.nan  # a notch in the north-west corner
    _write(tmp_path / "dem.tif", z, from_origin(W0, N0, CELL, CELL))
    scen = load_scenario(_scenario(tmp_path, dem="dem.tif", truth_resolution_m=10.0))
    # the valid cells' bounding box is rows 0-40, columns 20-64; the notch makes it 3 %
    # nodata (< 5 %), so the box itself is the site
    assert scen["site"]["bounds"] == [W0 + 600.0, N0 - 1200.0, W0 + 1920.0, N0]
    z[:20, 20:40] = np.nan  # a big notch: 20 x 20 of 40 x 44 (23 %): the largest rectangle,
    # columns 40-64 x rows 0-40 (960 cells) rather than rows 20-40 x columns 20-64 (880)
    _write(tmp_path / "dem.tif", z, from_origin(W0, N0, CELL, CELL))
    scen = load_scenario(_scenario(tmp_path, dem="dem.tif", truth_resolution_m=10.0))
    assert scen["site"]["bounds"] == [W0 + 1200.0, N0 - 1200.0, W0 + 1920.0, N0]
    assert json.loads(make_site(scen).attrs["site_dem"])["nodata_cells_filled"] == 0


@pytest.mark.parametrize(
    ("site", "field"),
    [
        ({"dem": "missing.tif"}, r"site\.dem: expected an existing DEM"),
        ({"dem": ""}, r"site\.dem"),
        ({"dem": "nocrs.tif"}, r"site\.dem: .*CRS"),
        ({"dem": "blank.tif"}, r"site\.dem: .*nodata"),
        ({"dem": "dem.tif", "bounds": [W0 - 500.0, N0 - 600.0, W0 + 100.0, N0]}, r"site\.bounds"),
        ({"dem": "dem.tif", "bounds": [W0 + 600.0, N0, W0, N0 - 600.0]}, r"site\.bounds"),
        ({"dem": "dem.tif", "truth_resolution_m": 200.0}, r"site\.truth_resolution_m"),
        ({"dem": "dem.tif", "truth_resolution_m": 0.25}, r"site\.bounds: .*truth cells"),
        ({"dem": "dem.tif", "crs": "EPSG:4326"}, r"site\.crs"),
        ({"dem": "dem.tif", "max_nodata_fraction": 1.5}, r"site\.max_nodata_fraction"),
        ({"dem": "dem.tif", "kind": "lidar"}, r"site\.kind"),
    ],
)
def test_each_bad_input_names_its_field(tmp_path, site, field):
    _utm_dem(tmp_path / "dem.tif")
    z = np.ones((20, 20))
    with rasterio.open(
        tmp_path / "nocrs.tif", "w", driver="GTiff", height=20, width=20, count=1,
        dtype="float64", transform=from_origin(0, 600, 30, 30),
    ) as ds:  # fmt: skip
        ds.write(z, 1)
    _write(tmp_path / "blank.tif", np.full((20, 20), np.nan), from_origin(W0, N0, CELL, CELL))
    with pytest.raises(InputError, match=field):
        load_scenario(_scenario(tmp_path, **site))


@pytest.mark.parametrize("hole", [False, True])
def test_cli_refuses_a_bad_dem_site_and_writes_nothing(tmp_path, hole):
    if hole:  # bounds inside the DEM, 25 % of them nodata
        _utm_dem(tmp_path / "dem.tif", (slice(0, 10), slice(0, 10)))
        bad = _scenario(tmp_path, dem="dem.tif", bounds=[W0, N0 - 600.0, W0 + 600.0, N0])
    else:  # bounds outside the DEM
        _utm_dem(tmp_path / "dem.tif")
        bad = _scenario(tmp_path, dem="dem.tif", bounds=[W0 - 900.0, N0 - 600.0, W0, N0])
    for cmd in (["run"], ["simulate", "--camera", "images"]):
        out = tmp_path / f"out_{cmd[0]}"
        res = CliRunner().invoke(app, [*cmd, "--config", str(bad), "--out", str(out)])
        assert isinstance(res.exception, InputError), res.output
        assert str(res.exception).startswith("site.bounds")
        assert not out.exists()


def test_a_survey_is_simulated_over_the_dem_site(tmp_path):
    _utm_dem(tmp_path / "dem.tif")
    bounds = [W0 + 600.0, N0 - 720.0, W0 + 720.0, N0 - 600.0]  # 120 m, 1 swath
    scen = load_scenario(
        _scenario(tmp_path, dem="dem.tif", bounds=bounds), {"plan": {"n_swaths": 1}}
    )
    truth = make_site(scen)
    plan = make_plan(scen, truth)
    log = simulate_log(scen, truth, plan)
    assert log.n_keyframes > 40 and log.obs_k.size > 0
    # the rover drives on the DEM: true heights within the site's elevation range
    z = log.truth["xyz"][:, 2]
    assert np.isfinite(z).all()
    assert float(truth.min()) - 2.0 <= z.min() and z.max() <= float(truth.max()) + 2.0


def test_samples_csv_with_a_wkt_crs_column_is_read(tmp_path):
    # a DEM whose CRS has no EPSG code (olinda_dem_utm25s.tif: UTM 25S on GRS80 with a
    # TOWGS84 clause) makes localize write the WKT, commas and all, quoted in samples.csv
    from pyproj import CRS

    from toolkit.samples_io import read_samples

    wkt = CRS.from_proj4("+proj=utm +zone=25 +south +ellps=GRS80 +towgs84=0,0,0 +units=m").to_wkt()
    assert CRS.from_wkt(wkt).to_epsg() is None and "," in wkt
    quoted = '"' + wkt.replace('"', '""') + '"'
    rows = [f"{290000 + i},{9115000 + 2 * i},{10 + i},0.04,0.2,1.1,{quoted}" for i in range(5)]
    path = tmp_path / "samples.csv"
    path.write_text("x,y,z,z_var,track_z_std_m,shared_offset_std_m,crs\n" + "\n".join(rows) + "\n")
    table = read_samples(path)
    np.testing.assert_allclose(table.samples.z, 10.0 + np.arange(5))
    np.testing.assert_allclose(table.samples.z_var, 0.04)
    assert table.shared_z_std == 1.1 and CRS.from_user_input(table.samples.crs).equals(wkt)


def test_kernel_search_folds_samples_on_two_lines():
    # found on a real-DEM site (benchmarks/vision_dem.py, olinda_site_240): 113 landmarks of
    # a 2-swath survey crashed TerrainGP's kernel search, whose first CV blocks (4 x the
    # median gap, 100 m) held the two swaths in fewer blocks than folds; blocks now shrink
    from terrain.candidate_cv import cv_folds

    y = np.random.default_rng(0).uniform(0.0, 199.0, 60)
    xy = np.column_stack([np.r_[np.zeros(30), np.full(30, 99.0)], y])
    fold, block = cv_folds(xy, None, 2.0, np.random.default_rng(0))
    assert block < 100.0 and np.bincount(fold).size == 5 and np.bincount(fold).min() >= 6


def test_south_up_and_feet_dems(tmp_path):
    # rows running south -> north (transform e > 0) give the same truth as north-up
    x = W0 + CELL * (np.arange(64) + 0.5)
    y = N0 - 1920.0 + CELL * (np.arange(64) + 0.5)  # ascending
    z = _quadratic(*np.meshgrid(x, y))
    _write(tmp_path / "up.tif", z, rasterio.Affine(CELL, 0, W0, 0, CELL, N0 - 1920.0))
    bounds = [W0 + 300.0, N0 - 1500.0, W0 + 1500.0, N0 - 300.0]
    site = make_site(load_scenario(_scenario(tmp_path, dem="up.tif", bounds=bounds)))
    xx, yy = np.meshgrid(site.x.values, site.y.values)
    np.testing.assert_allclose(site.values, _quadratic(xx, yy), atol=1e-6, rtol=0)
    # a projected CRS in US survey feet (NAD83 / Colorado Central ftUS): not the site CRS
    ft = 3.28083333
    _write(
        tmp_path / "ft.tif",
        np.full((40, 40), 3000.0),
        from_origin(3_000_000.0, 1_700_000.0, 100.0, 100.0),
        "EPSG:2232",
    )
    scen = load_scenario(_scenario(tmp_path, dem="ft.tif", truth_resolution_m=20.0))
    assert scen["site"]["crs"].startswith("EPSG:326")  # UTM of the centre, in metres
    w, s, e, n = scen["site"]["bounds"]
    assert 4000.0 / ft * 0.95 < e - w < 4000.0 / ft  # 4000 ft of DEM, inner box
    prov = json.loads(make_site(scen).attrs["site_dem"])
    assert "UTM zone of the DEM's centre" in prov["site_crs_from"]
    assert "foot" in prov["site_crs_from"]


def test_raster_prior_cells_cover_the_map_not_only_the_samples():
    # found with glacimap run on a tilted real-DEM site (lux, 240 m, 27 m relief): the prior's
    # 8 x 8 coarse cells were laid over the samples' bounding box (its first bind), so the mean
    # was flat beyond it and the map 3.4 m off at the unsurveyed west edge (RMSE 1.19 m vs
    # 0.30 m once the cells cover the map grid)
    from terrain import ElevationSamples, Grid, RasterMean
    from toolkit.stages import reconstruct_stage

    grid = Grid.from_bounds((W0, N0 - 240.0, W0 + 240.0, N0), 4.0, "EPSG:32633")
    coarse = Grid.from_bounds((W0 - 80.0, N0 - 320.0, W0 + 320.0, N0 + 80.0), 80.0, "EPSG:32633")
    plane = coarse.data_array(0.1 * (coarse.xy()[:, 0] - W0).reshape(coarse.shape), "elevation")
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(W0 + 60, W0 + 180, 300), rng.uniform(N0 - 230, N0 - 10, 300)])
    samples = ElevationSamples(xy, 0.1 * (xy[:, 0] - W0), np.full(300, 0.01), crs="EPSG:32633")
    settings = load_scenario(overrides={"reconstruct": {"max_fit_samples": 300}})
    rec = reconstruct_stage(samples, grid, RasterMean(plane, cells=(8, 8)), settings, 0,
                            heldout_folds=0)  # fmt: skip
    west = rec.product["elevation"].values[:, :5]  # x < 20 m: 40 m beyond the samples
    truth = 0.1 * (grid.x[:5] - W0)
    assert float(np.abs(west - truth).max()) < 0.2  # 5.1 m with the cells over the samples


def test_a_local_crs_without_a_name_is_labelled_by_its_proj_form():
    """A GeoTIFF's WKT of a local transverse Mercator has no EPSG code and the name
    "unknown": the summary states its PROJ form instead (was: "site CRS unknown")."""
    from pyproj import CRS

    from toolkit.site_dem import _label

    local = CRS.from_wkt(
        CRS("+proj=tmerc +lat_0=0 +lon_0=0 +k=1 +x_0=0 +y_0=0 +ellps=WGS84").to_wkt()
    )
    assert local.name == "unknown" and local.to_epsg() is None
    assert _label(local).startswith("+proj=tmerc")
    assert _label(CRS("EPSG:32608")) == "EPSG:32608"
