"""Heights above a national vertical datum (``terrain.vertical_crs``), through PROJ's own
operation and grid.

No national geoid grid is on this machine, so the test writes one under the file name PROJ's
database gives NN2000's geoid (``no_kv_HREF2018B_NN2000_EUREF89.tif``), holding a known
linear field ``N = 30 + 0.2 lon + 0.1 lat`` (m) over Norway, and puts its folder on PROJ's
search path. PROJ interpolates the grid bilinearly, so it must give the field back to float32
rounding at any position (the reference value is the field itself); the rest of the chain
(which grid, which operation, the sign of ``h = H + N``) is PROJ's.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import rasterio
from _rasters import write_array
from pyproj import Transformer
from rasterio.transform import from_origin
from typer.testing import CliRunner

from terrain import InputError
from terrain import vertical_datum as vd
from toolkit.certify import certify
from toolkit.cli import app

GRID = "no_kv_HREF2018B_NN2000_EUREF89.tif"  # PROJ's name for NN2000's geoid (HREF2018B)


def field_n(lon, lat):
    """The grid's undulation, m: the reference value."""
    return 30.0 + 0.2 * np.asarray(lon) + 0.1 * np.asarray(lat)


@pytest.fixture(scope="module")
def nn2000_grid(tmp_path_factory):
    import pyproj.datadir

    folder = tmp_path_factory.mktemp("proj")
    res, lon0, lat0 = 0.25, -5.0, 80.0  # cell centres -5..45 E, 80..50 N
    lon = lon0 + res * np.arange(201)
    lat = lat0 - res * np.arange(121)
    with rasterio.open(
        folder / GRID, "w", driver="GTiff", width=lon.size, height=lat.size, count=1,
        dtype="float32", crs="EPSG:4258",
        transform=from_origin(lon0 - res / 2, lat0 + res / 2, res, res),
    ) as ds:  # fmt: skip
        ds.write(field_n(lon[None, :], lat[:, None]).astype("float32"), 1)
        ds.set_band_description(1, "geoid_undulation")
    before = pyproj.datadir.get_data_dir()
    pyproj.datadir.append_data_dir(str(folder))
    yield folder
    pyproj.datadir.set_data_dir(before)


def test_a_national_datum_is_named_by_its_vertical_crs():
    assert vd.height_datum_option("epsg:5941", "--h") == "EPSG:5941"
    assert vd.height_datum_option("EPSG:5773", "--h") == "egm96"  # the world geoids keep theirs
    assert vd.height_datum_option("EPSG:4326+5941", "--h") == "EPSG:5941"
    assert vd.datum_words("EPSG:5941") == "NN2000 height (EPSG:5941)"
    assert vd.height_words("EPSG:5941") == "orthometric height above NN2000 height (EPSG:5941)"
    assert vd.split_vertical("EPSG:25833+5941")[1] == "EPSG:5941"
    with pytest.raises(InputError, match="--h: expected a vertical CRS.*UTM zone 33N is not one"):
        vd.height_datum_option("EPSG:32633", "--h")
    with pytest.raises(InputError, match="--h: expected heights in metres.*NAVD88 height \\(ft\\)"):
        vd.height_datum_option("EPSG:8228", "--h")
    with pytest.raises(InputError, match="--h: expected ellipsoidal / egm96 / egm2008 or a vert"):
        vd.height_datum_option("EPSG:99999999", "--h")


def test_a_missing_grid_a_ballpark_and_a_site_abroad_are_refused():
    lon, lat = np.array([-135.3]), np.array([58.4])  # Juneau, Alaska
    with pytest.raises(InputError, match="--x:.*NAVD88 height.*us_noaa_g2012ba0.tif.*projsync"):
        vd.geoid_height(lon, lat, "EPSG:5703", "--x")  # no US grid here
    with pytest.raises(InputError, match="relates to the WGS 84 ellipsoid by a geoid model"):
        vd.geoid_height(np.array([24.0]), np.array([57.0]), "EPSG:5705", "--x")  # Baltic 1977
    with pytest.raises(InputError, match="inside its area of use \\(Norway"):
        vd.geoid_height(lon, lat, "EPSG:5941", "--x")


def test_proj_carries_nn2000_heights_with_the_grid_it_names(nn2000_grid):
    lon, lat = np.array([7.31, 10.0, 15.26, 20.1]), np.array([61.62, 60.0, 68.1, 69.9])
    n = vd.geoid_height(lon, lat, "EPSG:5941", "--x")
    np.testing.assert_allclose(n, field_n(lon, lat), atol=2e-5)  # float32 grid, bilinear
    h = vd.ellipsoidal_height(np.full(4, 1000.0), lon, lat, "epsg:5941", "--x")
    np.testing.assert_allclose(h, 1000.0 + field_n(lon, lat), atol=2e-5)


def test_field_gps_heights_above_nn2000_are_carried_to_the_ellipsoid(nn2000_grid):
    from factorgraph.field.fixes import GPSFixes, project_fixes

    lon, lat = np.array([7.30, 7.31]), np.array([61.62, 61.63])  # Jostedalsbreen
    fixes = GPSFixes(
        np.array([0.0, 1.0]), lat, lon, np.array([1200.0, 1201.0]), np.zeros((2, 3)),
        np.array(["single", "single"]),
    )  # fmt: skip
    ell = project_fixes(fixes, "EPSG:4979", "EPSG:32632")
    nn = project_fixes(fixes, "EPSG:4326+5941", "EPSG:32632")
    np.testing.assert_allclose(nn[:, 2] - ell[:, 2], field_n(lon, lat), atol=2e-5)
    with pytest.raises(InputError, match="expected heights in metres"):
        project_fixes(fixes, "EPSG:4326+8228", "EPSG:32632")  # NAVD88 in feet


@pytest.fixture()
def norwegian_site(tmp_path, nn2000_grid):
    """A flat 100 m DEM in NN2000 heights (EPSG:25833+5941) and GNSS checkpoints on the
    ellipsoid (100 m + N)."""
    dem = write_array(tmp_path / "dem_nn2000.tif", np.full((50, 50), 100.0),
                      from_origin(500000, 6800500, 10, 10), "EPSG:25833+5941")  # fmt: skip
    xy = np.array([[500100, 6800100], [500200, 6800200], [500300, 6800300],
                   [500150, 6800400], [500250, 6800050], [500420, 6800440]], float)  # fmt: skip
    lon, lat = Transformer.from_crs("EPSG:25833", "EPSG:4326", always_xy=True).transform(*xy.T)
    n = field_n(lon, lat)
    cps = tmp_path / "cps_4979.csv"  # lon, lat, h: a 3-D geographic CRS states ellipsoidal
    pd.DataFrame({"lon": lon, "lat": lat, "h": 100.0 + n, "crs": "EPSG:4979"}).to_csv(
        cps, index=False
    )
    return dem, cps, n


def test_a_national_dem_is_certified_against_ellipsoidal_checkpoints(norwegian_site, tmp_path):
    dem, cps, n = norwegian_site
    c = certify(dem, cps, n_boot=50)
    h = c["checkpoints"]["heights"]
    assert (h["dem"], h["checkpoints"]) == ("EPSG:5941", "ellipsoidal")
    assert h["shift_m"] == pytest.approx(-n.mean(), abs=1e-4)
    assert c["accuracy"]["rmse_m"] == pytest.approx(0.0, abs=1e-4)  # against |N| ~ 40 m as stored
    r = CliRunner().invoke(
        app, ["certify", str(dem), str(cps), "--n-boot", "50", "--out", str(tmp_path / "c.json")]
    )
    assert r.exit_code == 0, r.output
    assert (
        "checkpoint heights above the WGS 84 ellipsoid carried to the DEM's (NN2000 height "
        "(EPSG:5941))" in " ".join(r.output.split())
    )


def test_a_map_is_carried_to_nn2000_and_back(nn2000_grid):
    # A glacimap map (ellipsoidal) on a Norwegian UTM lattice: above NN2000 its elevation is
    # the map's less N at each cell, its 1-sigma kept; back on the ellipsoid it is itself.
    from terrain import Grid
    from terrain.product import terrain_dataset

    g = Grid(west=400000.0, north=6830000.0, resolution=50.0, shape=(30, 40), crs="EPSG:25833")
    z = np.full(g.shape, 1500.0)
    ds = terrain_dataset(g, z, np.full(g.shape, 0.3), {"seed": 3})
    nn, note = vd.product_in_datum(ds, "EPSG:5941")
    xx, yy = np.meshgrid(g.x, g.y)
    lon, lat = Transformer.from_crs(g.crs, "EPSG:4326", always_xy=True).transform(xx, yy)
    np.testing.assert_allclose(nn["elevation"].values, z - field_n(lon, lat), atol=2e-5)
    np.testing.assert_array_equal(nn["elevation_std"].values, ds["elevation_std"].values)
    assert nn.attrs["height_datum"] == "EPSG:5941"
    assert "orthometric height above NN2000 height (EPSG:5941)" in nn.attrs["vertical_datum"]
    assert "to NN2000 height (EPSG:5941)" in note
    back, _ = vd.product_in_datum(nn, "ellipsoidal")
    np.testing.assert_allclose(back["elevation"].values, z, atol=1e-9)


def test_change_carries_a_national_dem_to_the_maps_datum(nn2000_grid, tmp_path):
    # BEFORE: a glacimap map (ellipsoidal) of a Norwegian glacier; AFTER: the same ground,
    # unchanged, as a national DEM in NN2000 heights (H = h - N, N ~ 39 m here), its compound
    # CRS saying so. Carried to the ellipsoid the change reads ~0 (not ~-39 m of thinning).
    import json

    import pyogrio
    import shapely
    from shapely.geometry import box

    from terrain import Grid
    from terrain.product import terrain_dataset

    g = Grid(west=420000.0, north=6835000.0, resolution=20.0, shape=(60, 80), crs="EPSG:25833")
    xx, yy = np.meshgrid(g.x, g.y)
    z = 1200.0 + 0.05 * (xx - 420000.0) + 20.0 * np.sin((yy - 6834000.0) / 150.0)
    terrain_dataset(g, z, np.full(g.shape, 0.05), {"seed": 1}).to_netcdf(
        tmp_path / "b.nc", engine="scipy"
    )
    lon, lat = Transformer.from_crs(g.crs, "EPSG:4326", always_xy=True).transform(xx, yy)
    n = field_n(lon, lat)
    write_array(tmp_path / "a.tif", z - n, g.transform, "EPSG:25833+5941")
    outline = tmp_path / "glacier.gpkg"
    pyogrio.raw.write(
        outline, np.array([shapely.to_wkb(box(420400, 6834200, 421200, 6834700))], object),
        [], [], geometry_type="Polygon", crs="EPSG:25833",
    )  # fmt: skip
    out = tmp_path / "out"
    r = CliRunner().invoke(
        app, ["change", str(tmp_path / "b.nc"), str(tmp_path / "a.tif"), "--outline",
              str(outline), "--no-coregister", "--out", str(out)],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    vol = json.loads((out / "volume.json").read_text())
    assert abs(vol["mean_dh_m"]) < 1e-3, vol["mean_dh_m"]
    assert any(
        "above NN2000 height (EPSG:5941) carried to BEFORE's (the WGS 84 ellipsoid)" in t
        for t in vol["notes"]
    )
