"""DEMs in longitude / latitude (SRTM, Copernicus GLO-30): ``terrain.dem_projection`` and
``glacimap change`` / ``certify`` on them.

References: the ground size of one arcsecond from the WGS 84 radii of curvature (hand
formulas: east ``N cos(lat) dlon``, north ``M dlat``, N and M the prime-vertical and meridian
radii), a 1 deg x 1 deg cell's area from the ellipsoid's band area ``b^2/2 dlon (q(lat2) -
q(lat1))`` (q: the authalic latitude function), the UTM zone by its 6-degree rule, and a
known shift, bias and change laid on an analytic surface before the DEM is warped to degrees
with ``rasterio.warp``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pyogrio
import pytest
import rasterio
import shapely
import xarray as xr
from pyproj import CRS, Transformer
from rasterio.transform import from_origin
from rasterio.warp import Resampling, calculate_default_transform, reproject
from shapely.geometry import Point
from typer.testing import CliRunner

from terrain import Grid, difference
from terrain.dem_projection import Footprint, change_crs, finer, grid_in, raster_footprint
from toolkit.cli import app

A, F = 6378137.0, 1 / 298.257223563  # WGS 84
E2 = F * (2 - F)
UTM = "EPSG:32608"  # 135 W - 132 W: a site at 134 W, 60 N (south-east Alaska's icefields)
LON0, LAT0 = -134.0, 60.0
runner = CliRunner()


def _geographic(values, west, north, step):
    """A DataArray in EPSG:4326 (cell centres in degrees, rows north first)."""
    ny, nx = values.shape
    x = west + (np.arange(nx) + 0.5) * step
    y = north - (np.arange(ny) + 0.5) * step
    return xr.DataArray(
        values, dims=("y", "x"), coords={"y": y, "x": x}, attrs={"crs": "EPSG:4326"}
    )


def test_ground_resolution_of_an_arcsecond_matches_the_radii_of_curvature():
    step = 1 / 3600
    fp = raster_footprint(_geographic(np.zeros((3, 3)), LON0, LAT0 + 1.5 * step, step))
    lat = math.radians(LAT0)
    w = math.sqrt(1 - E2 * math.sin(lat) ** 2)
    east = A / w * math.cos(lat) * math.radians(step)  # prime vertical N cos(lat) dlon
    north = A * (1 - E2) / w**3 * math.radians(step)  # meridian M dlat
    gx, gy = fp.ground_resolution()
    assert gx == pytest.approx(east, rel=1e-6) and gy == pytest.approx(north, rel=1e-6)
    assert gx == pytest.approx(15.50, abs=0.01) and gy == pytest.approx(30.95, abs=0.01)
    assert "deg cells (~15.5 x 30.9 m)" in fp.describe()


def test_area_of_a_degree_cell_on_the_ground():
    fp = Footprint(10.0, 1.0, (1.0, 1.0), (1, 1), CRS.from_epsg(4326))
    e, b2 = math.sqrt(E2), (A * (1 - F)) ** 2

    def q(lat):  # the ellipsoid's band area per radian of longitude is b^2/2 (q2 - q1)
        s = math.sin(math.radians(lat))
        return s / (1 - E2 * s * s) + math.log((1 + e * s) / (1 - e * s)) / (2 * e)

    band = b2 / 2 * math.radians(1.0) * (q(1.0) - q(0.0)) / 1e6
    assert fp.area_km2() == pytest.approx(band, rel=1e-6)  # ~12,309 km^2
    assert Footprint(0.0, 10.0, (2.0, 2.0), (5, 5), CRS.from_epsg(32608)).area_km2() == 1e-4


def test_the_comparison_crs_is_a_projected_input_or_the_local_utm_zone():
    step = 1 / 3600
    geo = _geographic(np.zeros((40, 40)), LON0, LAT0, step)
    g = Grid.from_bounds((400_000, 6_650_000, 400_300, 6_650_300), 10.0, UTM)
    proj = g.data_array(np.zeros(g.shape), "elevation")
    crs, why = change_crs(geo, proj)  # geographic finer (15 x 31 m < 10 x 10? no: coarser)
    assert crs.equals(CRS.from_user_input(UTM)) and "the finer DEM's, after's" in why
    fine = Grid.from_bounds((400_000, 6_650_000, 400_300, 6_650_300), 100.0, UTM)
    crs, why = change_crs(geo, fine.data_array(np.zeros(fine.shape), "elevation"))
    assert crs.equals(CRS.from_user_input(UTM)) and "the finer DEM is geographic" in why
    crs, why = change_crs(geo, geo)
    assert crs.to_epsg() == 32608 and "UTM zone" in why  # 134 W lies in zone 8 (-138..-132)
    polar = _geographic(np.zeros((4, 4)), -40.0, 85.0, 0.01)
    assert change_crs(polar, polar)[0].to_epsg() == 3413
    south = _geographic(np.zeros((4, 4)), 160.0, -82.0, 0.01)
    assert change_crs(south, south)[0].to_epsg() == 3031
    a, b = raster_footprint(geo), raster_footprint(proj)
    assert finer(a, b)[2] == "after"


def test_grid_in_keeps_a_projected_lattice_and_warps_degrees_as_gdal_does():
    fp = Footprint(400_000.0, 6_650_000.0, (10.0, 10.0), (3, 4), CRS.from_user_input(UTM))
    assert grid_in(fp, fp.crs) == Grid(400_000.0, 6_650_000.0, (10.0, 10.0), (3, 4), UTM)
    geo = Footprint(LON0, LAT0, (1 / 3600, 1 / 3600), (100, 100), CRS.from_epsg(4326))
    g = grid_in(geo, CRS.from_user_input(UTM))
    t, w, h = calculate_default_transform("EPSG:4326", UTM, 100, 100, *geo.bounds)
    assert g.shape == (h, w) and g.resolution == (t.a, -t.e) and g.west == t.c


def _surface(x, y):
    """A smooth ridge-and-valley surface in UTM 8N metres (m)."""
    u, v = (x - 400_000.0) / 400.0, (y - 6_650_000.0) / 300.0
    return 800.0 + 40.0 * np.sin(u) * np.cos(v) + 0.02 * (x - 400_000.0)


def _to_degrees(values, grid, step=1 / 3600):
    """``values`` on a UTM grid warped to EPSG:4326 (bilinear), as GDAL would write it."""
    w, s, e, n = grid.bounds
    lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(
        [w, e, w, e], [s, s, n, n]
    )
    west, north = min(lon), max(lat)
    nx = int((max(lon) - west) / step)
    ny = int((north - min(lat)) / step)
    out = np.full((ny, nx), np.nan)
    reproject(
        values, out, src_transform=grid.transform, src_crs=UTM, src_nodata=np.nan,
        dst_transform=from_origin(west, north, step, step), dst_crs="EPSG:4326",
        dst_nodata=np.nan, resampling=Resampling.bilinear,
    )  # fmt: skip
    return out, west, north, step


@pytest.fixture(scope="module")
def two_epochs():
    """Before: 10 m UTM cells. After: the glacier thinned 2 m, the DEM shifted 12 m east and
    -8 m north, +1.5 m, in 1-arcsecond cells of EPSG:4326."""
    g = Grid.from_bounds((400_000, 6_650_000, 403_000, 6_653_000), 10.0, UTM)
    xx, yy = np.meshgrid(g.x, g.y)
    glacier = Point(401_500, 6_651_500).buffer(700)
    inside = shapely.contains_xy(glacier, xx, yy)
    before = _surface(xx, yy)
    after = (
        _surface(xx + 12.0, yy - 8.0) - 2.0 * shapely.contains_xy(glacier, xx + 12, yy - 8) + 1.5
    )
    deg, west, north, step = _to_degrees(after, g)
    return g, before, _geographic(deg, west, north, step), glacier, inside


def test_difference_with_a_dem_in_degrees(two_epochs):
    g, before, after, glacier, inside = two_epochs
    d = difference(g.data_array(before, "elevation"), after, outline=glacier)
    assert Grid.from_dataarray(d) == g  # the finer, projected DEM sets the grid
    note = d.attrs["reprojection"]
    assert "after reprojected from EPSG:4326 to EPSG:32608" in note and "deg cells (~15.5" in note
    co = json.loads(d.attrs["coregistration"])
    assert co["shift_east_m"] == pytest.approx(-12.0, abs=0.5)
    assert co["shift_north_m"] == pytest.approx(8.0, abs=0.5)
    assert co["vertical_bias_m"] == pytest.approx(1.5, abs=0.1)
    dh = d["dh"].values
    core = shapely.contains_xy(glacier.buffer(-60), *np.meshgrid(g.x, g.y))
    assert np.nanmedian(dh[core]) == pytest.approx(-2.0, abs=0.1)
    assert np.nanmedian(np.abs(dh[~inside])) < 0.2  # stable ground after co-registration


def test_two_dems_in_degrees_are_compared_in_their_utm_zone(two_epochs):
    g, before, after, glacier, _ = two_epochs
    deg, west, north, step = _to_degrees(before, g)
    d = difference(_geographic(deg, west, north, step), after, coregister=False)
    assert Grid.from_dataarray(d).crs.to_epsg() == 32608
    assert "compared in EPSG:32608" in d.attrs["reprojection"]
    assert "UTM zone of the DEM's centre" in d.attrs["reprojection"]


def _write_tif(path, values, transform, crs):
    prof = dict(driver="GTiff", height=values.shape[0], width=values.shape[1], count=1,
                dtype="float32", crs=crs, transform=transform, nodata=-9999.0)  # fmt: skip
    with rasterio.open(path, "w", **prof) as dst:
        dst.write(np.where(np.isfinite(values), values, -9999.0).astype("float32"), 1)
    return path


def test_cli_change_and_certify_read_a_geotiff_in_degrees(two_epochs, tmp_path):
    g, before, after, glacier, inside = two_epochs
    b = _write_tif(tmp_path / "before.tif", before, g.transform, UTM)
    fp = raster_footprint(after)
    a = _write_tif(tmp_path / "after.tif", after.values, fp.transform, "EPSG:4326")
    to_deg = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True)
    outline = shapely.transform(glacier, to_deg.transform, interleaved=False)
    pyogrio.raw.write(
        tmp_path / "outline.geojson", np.array([shapely.to_wkb(outline)], dtype=object), [], [],
        geometry_type="Polygon", crs="EPSG:4326",
    )  # fmt: skip
    r = runner.invoke(
        app, ["change", str(b), str(a), "--outline", str(tmp_path / "outline.geojson"),
              "--out", str(tmp_path / "c")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    v = json.loads((tmp_path / "c" / "volume.json").read_text())
    true_v = -2.0 * glacier.area
    assert abs(v["volume_m3"] - true_v) < 2 * v["volume_std_m3"] + 0.02 * abs(true_v)
    assert any("after reprojected from EPSG:4326" in n for n in v["notes"])
    # checkpoints on stable ground, in lon/lat, against the after DEM (still shifted: the
    # RMSE is the shift's; the certificate is about the DEM in its own cells)
    rng = np.random.default_rng(0)
    x = rng.uniform(400_200, 402_800, 200)
    y = rng.uniform(6_650_200, 6_652_800, 200)
    keep = ~shapely.contains_xy(glacier.buffer(100), x, y)
    lon, lat = to_deg.transform(x[keep], y[keep])
    z = _surface(x[keep] + 12.0, y[keep] - 8.0) + 1.5  # the after DEM's own surface
    rows = "\n".join(f"{p:.8f},{q:.8f},{h:.3f}" for p, q, h in zip(lon, lat, z, strict=True))
    (tmp_path / "cps.csv").write_text(
        "lon,lat,h,crs\n" + rows.replace("\n", ",EPSG:4326\n") + ",EPSG:4326\n"
    )
    r = runner.invoke(
        app, ["certify", str(a), str(tmp_path / "cps.csv"), "--out", str(tmp_path / "cert.json")]
    )
    assert r.exit_code == 0, r.output
    cert = json.loads((tmp_path / "cert.json").read_text())
    assert cert["checkpoints"]["n_used"] == int(keep.sum())
    assert cert["accuracy"]["rmse_m"] < 0.3  # bilinear on ~15 x 31 m cells of a smooth surface
    assert cert["dem"]["resolution_m"][0] == pytest.approx(15.5, abs=0.1)
    assert cert["dem"]["area_km2"] == pytest.approx(fp.area_km2(), rel=1e-9)
    assert "EPSG:32608" in cert["dem"]["geographic_note"]
