"""GIS and mesh exports, read back by the real GIS stack (GDAL CLI + validators, open3d, VTK).

GDAL's own tools are the reference: ``gdalinfo``/``ogrinfo`` (apt gdal-bin) and the COG /
GeoPackage validators from ``osgeo_utils`` run in the *system* Python (apt python3-gdal),
independent of the rasterio / pyogrio wheels that wrote the files.
"""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest
import shapely
import typer
from pyproj import Transformer
from typer.testing import CliRunner

from terrain import Grid, InputError, random_terrain
from terrain.product import terrain_dataset
from toolkit.cli.export import FILES, export_command
from toolkit.export import VectorLayer, write_cog, write_contours, write_mesh, write_vector_layers

SYS_PY = "/usr/bin/python3"
BOUNDS = (526000.0, 6475000.0, 526600.0, 6475600.0)  # the default site, UTM 8N
NAN_ROWS, NAN_COLS = slice(10, 13), slice(20, 25)  # a 3 x 5 hole of NaN cells

needs_gdal = pytest.mark.skipif(
    shutil.which("gdalinfo") is None or shutil.which("ogrinfo") is None,
    reason="GDAL command-line tools (apt gdal-bin) not installed",
)


def _gdal_py(code: str) -> str:
    """Run ``code`` in the system Python that has python3-gdal (osgeo_utils)."""
    probe = subprocess.run([SYS_PY, "-c", "import osgeo_utils"], capture_output=True)
    if probe.returncode:
        pytest.skip("system python3-gdal (osgeo_utils) not installed")
    res = subprocess.run([SYS_PY, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return res.stdout


@pytest.fixture(scope="module")
def grid():
    return Grid.from_bounds(BOUNDS, 10.0)  # 60 x 60 cells


@pytest.fixture(scope="module")
def product(grid):
    """Random glacier surface; 1-sigma rising eastwards (0.1 + 0.005 m per column); a hole."""
    z = random_terrain(grid, relief=25.0, seed=1).values.copy()
    std = np.broadcast_to(0.1 + 0.005 * np.arange(grid.nx), grid.shape).copy()
    z[NAN_ROWS, NAN_COLS] = np.nan
    std[NAN_ROWS, NAN_COLS] = np.nan
    return terrain_dataset(grid, z, std, {"seed": 7, "method": "unit test"})


@pytest.fixture(scope="module")
def plane(grid):
    """z = 100 + 0.05 (x - west) rises eastwards; std = 0.2 + 0.001 (y - south)."""
    xx, yy = np.meshgrid(grid.x, grid.y)
    return terrain_dataset(
        grid, 100.0 + 0.05 * (xx - BOUNDS[0]), 0.2 + 0.001 * (yy - BOUNDS[1]), {"seed": 1}
    )


# -- Cloud-Optimized GeoTIFF -------------------------------------------------------------------
@needs_gdal
def test_cog_read_by_gdalinfo_and_validator(product, grid, tmp_path):
    path = write_cog(product, tmp_path / "dem.tif")
    info = json.loads(subprocess.check_output(["gdalinfo", "-json", str(path)]))
    assert [b["description"] for b in info["bands"]] == ["elevation", "elevation_std"]
    assert {b["type"] for b in info["bands"]} == {"Float32"}
    assert {b["unit"] for b in info["bands"]} == {"m"}
    assert {str(b["noDataValue"]).lower() for b in info["bands"]} == {"nan"}
    assert all(len(b["overviews"]) >= 1 for b in info["bands"])
    assert info["stac"]["proj:epsg"] == 32608
    # GDAL order (x0, dx, 0, y0, 0, -dy) from the grid: west, 10 m, north.
    assert info["geoTransform"] == [BOUNDS[0], 10.0, 0.0, BOUNDS[3], 0.0, -10.0]
    assert info["size"] == [grid.nx, grid.ny]
    assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"
    assert info["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"] == "DEFLATE"
    assert info["metadata"][""]["seed"] == "7" and info["metadata"][""]["method"] == "unit test"
    out = _gdal_py(
        "from osgeo_utils.samples.validate_cloud_optimized_geotiff import validate\n"
        f"w, e, _ = validate({str(path)!r}, full_check=True)\n"
        "print(repr((w, e)))"
    )
    assert out.strip() == "([], [])", out  # (warnings, errors) of GDAL's COG validator


def test_cog_values_round_trip(product, tmp_path):
    import rasterio

    path = write_cog(product, tmp_path / "dem.tif")
    with rasterio.open(path) as src:
        data = src.read()
    expected = np.stack([product.elevation.values, product.elevation_std.values])
    np.testing.assert_array_equal(np.isnan(data), np.isnan(expected))  # NaN cells -> nodata
    np.testing.assert_array_equal(data, expected.astype(np.float32))


# -- contours --------------------------------------------------------------------------------
@needs_gdal
def test_contours_read_by_ogrinfo_and_gpkg_validator(product, tmp_path):
    res = write_contours(product, tmp_path / "c.gpkg", 2.0)
    assert res["lines"] > 0 and res["interval"] == 2.0
    text = subprocess.check_output(["ogrinfo", "-so", "-al", str(tmp_path / "c.gpkg")], text=True)
    assert "Layer name: contour" in text and "Geometry: Line String" in text
    assert "elev: Real" in text and "mean_std: Real" in text
    assert f"Feature Count: {res['lines']}" in text
    assert 'ID["EPSG",32608]' in text and "seed=7" in text
    _gdal_py(
        "from osgeo_utils.samples.validate_gpkg import check\n"
        f"check({str(tmp_path / 'c.gpkg')!r}, extra_checks=True, warning_as_error=True)"
    )


def test_contours_of_a_plane_match_hand_computation(plane, tmp_path):
    from pyogrio.raw import read

    res = write_contours(plane, tmp_path / "c.gpkg", 5.0)
    # Centres span x = west + 5 ... west + 595 m: z from 100.25 to 129.75, so levels 105 ... 125
    # (5 levels), each one straight south-north line at x = west + (level - 100) / 0.05.
    assert (res["lines"], res["levels"]) == (5, 5)
    meta, _, wkb, fields = read(tmp_path / "c.gpkg", layer="contour")
    assert meta["fields"].tolist() == ["elev", "index", "mean_std"]
    elev, index, mean_std = fields
    np.testing.assert_array_equal(np.sort(elev), [105.0, 110.0, 115.0, 120.0, 125.0])
    # index contours every 5 intervals of 5 m from 0 m: 125 m only
    np.testing.assert_array_equal(index.astype(bool), elev == 125.0)
    for line, level in zip(shapely.from_wkb(wkb), elev, strict=True):
        xy = shapely.get_coordinates(line)
        np.testing.assert_allclose(xy[:, 0], BOUNDS[0] + (level - 100.0) / 0.05, atol=1e-6)
        np.testing.assert_allclose([xy[:, 1].min(), xy[:, 1].max()], [BOUNDS[1] + 5, BOUNDS[3] - 5])
    # std is linear in y: its mean over y = south+5 ... north-5 is its value at mid-height,
    # 0.2 + 0.001 * 300 = 0.5 m.
    np.testing.assert_allclose(mean_std, 0.5, rtol=1e-9)


@needs_gdal
def test_contours_geojson_is_rfc7946_lonlat(plane, tmp_path):
    write_contours(plane, tmp_path / "c.gpkg", 5.0, geojson_path=tmp_path / "c.geojson")
    text = subprocess.check_output(["ogrinfo", "-al", str(tmp_path / "c.geojson")], text=True)
    assert 'ID["EPSG",4326]' in text and "Feature Count: 5" in text
    doc = json.loads((tmp_path / "c.geojson").read_text())
    assert "crs" not in doc  # RFC 7946: no crs member, WGS 84 lon/lat implied
    coords = np.array([c for f in doc["features"] for c in f["geometry"]["coordinates"]])
    # UTM zone 8N spans 138 W - 132 W; the site lies near 58.4 N (Mendenhall Glacier).
    assert (-138 < coords[:, 0]).all() and (coords[:, 0] < -132).all()
    assert (58 < coords[:, 1]).all() and (coords[:, 1] < 59).all()
    # Reference: pyproj's inverse of the first vertex lands back on the planned line.
    f0 = doc["features"][0]
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32608", always_xy=True)
    x, _ = to_utm.transform(*f0["geometry"]["coordinates"][0])
    assert x == pytest.approx(BOUNDS[0] + (f0["properties"]["elev"] - 100) / 0.05, abs=0.02)


# -- generic vector layers -------------------------------------------------------------------
@needs_gdal
def test_vector_layers_trajectory_and_landmarks(tmp_path):
    from pyogrio.raw import read

    rng = np.random.default_rng(0)
    true = np.column_stack([np.linspace(526010, 526590, 50), np.full(50, 6475300.0)])
    est = true + rng.normal(0, 0.3, true.shape)
    xyz = np.column_stack([526000 + rng.uniform(0, 600, (20, 2)), rng.uniform(90, 120, 20)])
    z_std = rng.uniform(0.05, 0.4, 20)
    layers = {
        "trajectory": VectorLayer.lines([est, true], kind=["estimated", "true"]),
        "landmarks": VectorLayer.points(xyz, z_std=z_std, n_obs=np.arange(20)),
    }
    path = write_vector_layers(tmp_path / "survey.gpkg", layers, "EPSG:32608")
    text = subprocess.check_output(["ogrinfo", "-so", "-al", str(path)], text=True)
    assert "Layer name: trajectory" in text and "Layer name: landmarks" in text
    assert "Feature Count: 2" in text and "Feature Count: 20" in text
    assert "kind: String" in text and "z_std: Real" in text and "n_obs: Integer" in text
    assert "Geometry: 3D Point" in text
    _gdal_py(
        "from osgeo_utils.samples.validate_gpkg import check\n"
        f"check({str(path)!r}, extra_checks=True, warning_as_error=True)"
    )
    _, _, wkb, (z_std_back, _) = read(path, layer="landmarks")
    np.testing.assert_array_equal(
        shapely.get_coordinates(shapely.from_wkb(wkb), include_z=True), xyz
    )
    np.testing.assert_array_equal(z_std_back, z_std)
    _, _, wkb, (kind,) = read(path, layer="trajectory")
    np.testing.assert_array_equal(shapely.get_coordinates(shapely.from_wkb(wkb[0])), est)
    assert kind.tolist() == ["estimated", "true"]


def test_vector_layer_rejects_mixed_geometry_and_bad_fields():
    with pytest.raises(InputError, match="geometry"):
        VectorLayer([shapely.Point(0, 0), shapely.LineString([(0, 0), (1, 1)])])
    with pytest.raises(InputError, match="field 'z'"):
        VectorLayer.points(np.zeros((3, 2)), z=np.zeros(2))


# -- mesh ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def mesh_files(product, tmp_path_factory):
    d = tmp_path_factory.mktemp("mesh")
    res = write_mesh(product, d / "m.ply", d / "m.vtp", d / "m.png", window_size=(640, 480))
    return d, res


def test_mesh_counts_from_hand_computation(mesh_files):
    _, res = mesh_files
    # 60 x 60 centres -> 59 x 59 quads; the 3 x 5 NaN hole touches (3+1) x (5+1) = 24 quads.
    assert res["dropped_cells"] == 24
    assert res["triangles"] == 2 * (59 * 59 - 24)
    assert res["vertices"] == 60 * 60 - 15  # every finite centre is still a quad corner
    assert res["origin"] == [BOUNDS[0], BOUNDS[1], 0.0]  # default: west, south, 0 m


def test_ply_read_by_open3d_with_quality(mesh_files, product, grid):
    import open3d as o3d

    d, res = mesh_files
    m = o3d.io.read_triangle_mesh(str(d / "m.ply"))
    v = np.asarray(m.vertices)
    keep = np.isfinite(product.elevation.values).ravel()
    expected = np.column_stack(
        [grid.xy()[keep] - res["origin"][:2], product.elevation.values.ravel()[keep]]
    )
    np.testing.assert_allclose(v, expected, atol=1e-4)  # float32 relative to the origin
    assert np.asarray(m.triangles).shape == (res["triangles"], 3)
    m.compute_triangle_normals()
    assert (np.asarray(m.triangle_normals)[:, 2] > 0).all()  # counter-clockwise from above
    # open3d's tensor reader keeps extra vertex properties: quality == elevation_std.
    pts = o3d.t.io.read_point_cloud(str(d / "m.ply")).point
    quality = pts["quality"].numpy().ravel()
    std = product.elevation_std.values.ravel()[keep]
    np.testing.assert_array_equal(quality, std.astype(np.float32))
    header = (d / "m.ply").read_bytes().split(b"end_header")[0].decode()
    assert f"comment origin {BOUNDS[0]!r} {BOUNDS[1]!r} 0.0" in header
    assert "comment crs EPSG:32608" in header and "property float quality" in header


def test_vtp_read_by_pyvista(mesh_files, product):
    import pyvista as pv

    d, res = mesh_files
    poly = pv.read(d / "m.vtp")
    keep = np.isfinite(product.elevation.values).ravel()
    np.testing.assert_array_equal(poly["elevation"], product.elevation.values.ravel()[keep])
    np.testing.assert_array_equal(poly["elevation_std"], product.elevation_std.values.ravel()[keep])
    np.testing.assert_array_equal(poly.field_data["origin"], res["origin"])
    assert poly.field_data["crs"][0] == "EPSG:32608" and poly.field_data["seed"][0] == "7"
    assert poly.n_cells == res["triangles"]
    np.testing.assert_allclose(poly.points[:, 2], poly["elevation"], atol=1e-4)  # z origin 0


def test_png_is_a_nontrivial_image(mesh_files):
    from PIL import Image

    d, _ = mesh_files
    with Image.open(d / "m.png") as im:
        assert im.format == "PNG" and im.size == (640, 480)
        pixels = np.asarray(im.convert("RGB")).reshape(-1, 3)
    assert len(np.unique(pixels, axis=0)) > 50  # a colour ramp, not a blank frame


# -- bad input and atomicity -----------------------------------------------------------------
def _bad_products(product):
    no_crs = product.copy()
    no_crs.attrs = {k: v for k, v in product.attrs.items() if k not in ("crs", "crs_wkt")}
    return {
        "elevation_std": product.drop_vars("elevation_std"),
        "dims": product.transpose("x", "y"),
        "crs": no_crs,
    }


@pytest.mark.parametrize("which", ["elevation_std", "dims", "crs"])
def test_bad_products_raise_and_leave_nothing(product, tmp_path, which):
    bad = _bad_products(product)[which]
    for call in (
        lambda: write_cog(bad, tmp_path / "a.tif"),
        lambda: write_contours(bad, tmp_path / "c.gpkg", 1.0),
        lambda: write_mesh(bad, tmp_path / "m.ply", tmp_path / "m.vtp"),
    ):
        with pytest.raises(InputError, match=which) as err:
            call()
        assert "Fix:" in str(err.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("interval", [0.0, -1.0, float("nan")])
def test_bad_interval(product, tmp_path, interval):
    with pytest.raises(InputError, match="interval_m"):
        write_contours(product, tmp_path / "c.gpkg", interval, tmp_path / "c.geojson")
    assert list(tmp_path.iterdir()) == []


def test_unwritable_or_wrong_target(product, tmp_path):
    with pytest.raises(InputError, match="existing folder"):
        write_cog(product, tmp_path / "missing" / "a.tif")
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="existing folder"):
        write_contours(product, tmp_path / "file" / "c.gpkg", 1.0)
    with pytest.raises(InputError, match="ending in .ply"):
        write_mesh(product, ply_path=tmp_path / "m.obj")
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_failure_mid_write_leaves_no_partial_file(product, tmp_path, monkeypatch):
    import toolkit.export.mesh as mesh_module

    def broken(path, *args, **kwargs):
        path.write_bytes(b"\x89PNG half")  # a partial file, then the writer dies
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(mesh_module, "_render_png", broken)
    with pytest.raises(RuntimeError, match="crashed"):
        write_mesh(product, tmp_path / "m.ply", png_path=tmp_path / "m.png")
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]  # complete PLY, no PNG, no .tmp


# -- command line ----------------------------------------------------------------------------
def _app():
    app = typer.Typer()
    app.command()(export_command)
    return app


def test_cli_exports_every_product(product, tmp_path):
    nc = tmp_path / "reconstruction.nc"
    product.to_netcdf(nc, engine="scipy")  # as glacimap reconstruct writes it
    res = CliRunner().invoke(_app(), [str(nc), "--out", str(tmp_path / "out"), "--interval", "2"])
    assert res.exit_code == 0, res.output
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == sorted(FILES.values())
    summary = json.loads((tmp_path / "out" / FILES["summary"]).read_text())
    assert summary["seed"] == 7 and summary["mesh"]["dropped_cells"] == 24
    assert summary["contours"]["interval"] == 2.0 and summary["contours"]["lines"] > 0
    assert "index contours, every 10 m" in res.output  # 5 intervals of 2 m
    assert f"heights: {summary['contours']['vertical_datum']}" in " ".join(res.output.split())


def test_cli_bad_interval_writes_nothing(product, tmp_path):
    nc = tmp_path / "reconstruction.nc"
    product.to_netcdf(nc, engine="scipy")
    out = tmp_path / "out"
    res = CliRunner().invoke(_app(), [str(nc), "--out", str(out), "--interval", "0"])
    assert res.exit_code != 0 and "--interval" in str(res.exception)
    assert not out.exists()


@pytest.mark.parametrize(
    "cert, interval, said",
    [
        ({"contour_interval": {"certified_m": 5.0, "how": "ASPRS 1990"}}, 5.0, "certified"),
        ({"contour_interval": {"certified_m": None, "uncertified_m": 2.0}}, 2.0, "not certified"),
        (None, 1.0, "no certificate.json"),  # nothing beside the product: 1 m, said so
    ],
)
def test_cli_interval_defaults_to_the_certificates(product, tmp_path, cert, interval, said):
    """Without --interval the contours follow the certificate beside the product (a 0.1 m
    default would draw the map's noise as terrain); without one, 1 m and a sentence."""
    nc = tmp_path / "product.nc"
    product.to_netcdf(nc, engine="scipy")
    if cert is not None:
        (tmp_path / "certificate.json").write_text(json.dumps(cert))
    res = CliRunner().invoke(_app(), [str(nc), "--out", str(tmp_path / "out"), "--no-mesh"])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "out" / FILES["summary"]).read_text())
    assert summary["contours"]["interval"] == interval
    assert said in summary["contour_interval_basis"]
    assert said in " ".join(res.output.split())
