"""The output folder of ``glacimap run``, read back by a real GIS stack, and the run's bad input.

One small seeded run per module (the default site, a 300 m x 300 m corner surveyed with two
lawnmower swaths, a 5 m grid: about 10 s on 2 cores) through the command line. GDAL's own
tools (``gdalinfo``/``ogrinfo`` and the COG / GeoPackage validators in the system Python),
open3d and pyvista are the readers; the helpers are those of ``tests/test_export.py`` and
``tests/test_report.py``.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import shapely
import xarray as xr
from _scenarios import SMALL_BOUNDS, small_run
from test_export import _gdal_py, needs_gdal
from test_report import _parse
from typer.testing import CliRunner

from terrain import InputError, default_site
from terrain.sampling import sample_dem
from toolkit.cli import app

runner = CliRunner()
BOUNDS = SMALL_BOUNDS
SCENARIO = small_run(n_boot=500)
PRODUCTS = {
    "certificate.json",
    "contours.geojson",
    "contours.gpkg",
    "elevation.tif",
    "field",  # the simulated survey as field files (glacimap process reads them)
    "landmarks.csv",
    "samples.csv",
    "trajectory.csv",
    "mesh.ply",
    "mesh.png",
    "mesh.vtp",
    "product.nc",
    "report.html",
    "summary.json",
    "survey.gpkg",
}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("run")
    (root / "small.toml").write_text(SCENARIO)
    out = root / "out"
    res = runner.invoke(app, ["run", "--config", str(root / "small.toml"), "--out", str(out)])
    assert res.exit_code == 0, (res.output, res.exception)
    return out


@pytest.fixture(scope="module")
def product(run):
    with xr.open_dataset(run / "product.nc") as ds:
        return ds.load()


@pytest.fixture(scope="module")
def cert(run):
    return json.loads((run / "certificate.json").read_text())


def _validate_gpkg(path):
    _gdal_py(
        "from osgeo_utils.samples.validate_gpkg import check\n"
        f"check({str(path)!r}, extra_checks=True, warning_as_error=True)"
    )


def test_folder_holds_the_products_and_nothing_else(run):
    assert {p.name for p in run.iterdir()} == PRODUCTS  # no temporaries, no staging folder


@needs_gdal
def test_cog_read_by_gdalinfo_and_validator(run, product):
    import rasterio

    path = run / "elevation.tif"
    info = json.loads(subprocess.check_output(["gdalinfo", "-json", str(path)]))
    names = [b["description"] for b in info["bands"]]
    assert names == ["elevation", "elevation_std", "elevation_std_relative"]
    assert {str(b["noDataValue"]).lower() for b in info["bands"]} == {"nan"}
    assert {b["unit"] for b in info["bands"]} == {"m"}
    assert info["stac"]["proj:epsg"] == 32608
    assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"
    assert info["metadata"][""]["seed"] == "0"
    # 5 m cells over the site bounds: west, 5 m, north (GDAL order)
    assert info["geoTransform"] == [BOUNDS[0], 5.0, 0.0, BOUNDS[3], 0.0, -5.0]
    assert info["size"] == [product.sizes["x"], product.sizes["y"]] == [60, 60]
    out = _gdal_py(
        "from osgeo_utils.samples.validate_cloud_optimized_geotiff import validate\n"
        f"w, e, _ = validate({str(path)!r}, full_check=True)\n"
        "print(repr((w, e)))"
    )
    assert out.strip() == "([], [])", out
    with rasterio.open(path) as src:
        data = src.read()
    names = ("elevation", "elevation_std", "elevation_std_relative")
    expected = np.stack([product[n].values for n in names])
    np.testing.assert_array_equal(data, expected.astype(np.float32))


@needs_gdal
def test_contours_read_by_ogrinfo_and_validator(run, product, cert):
    from pyogrio.raw import read

    path = run / "contours.gpkg"
    text = subprocess.check_output(["ogrinfo", "-so", "-al", str(path)], text=True)
    assert "Layer name: contour" in text and "Geometry: Line String" in text
    assert "elev: Real" in text and "mean_std: Real" in text
    assert 'ID["EPSG",32608]' in text
    flat = " ".join(text.split())  # each field and its unit, and the interval, stated
    assert "fields=elev = contour elevation, m (ellipsoidal height" in flat
    assert f"contour_interval_m={cert['contour_interval']['certified_m']:g}" in flat
    _validate_gpkg(path)
    _, _, wkb, (elev, index, mean_std) = read(path, layer="contour")
    assert len(wkb) > 0
    interval = cert["contour_interval"]["certified_m"]
    np.testing.assert_allclose(elev / interval, np.round(elev / interval))  # on the interval
    np.testing.assert_array_equal(index.astype(bool), np.round(elev / interval) % 5 == 0)
    z, std = product.elevation.values, product.elevation_std.values
    assert (elev > np.nanmin(z)).all() and (elev < np.nanmax(z)).all()
    assert (mean_std >= np.nanmin(std) - 1e-9).all() and (mean_std <= np.nanmax(std) + 1e-9).all()
    geo = json.loads((run / "contours.geojson").read_text())
    assert len(geo["features"]) == len(wkb)


def test_certificate_states_expected_accuracy_and_floors(cert):
    """Without the truth a user still learns what the run expects (the marginals' RMSE) and
    the best any estimator could expect (the frame floor on the estimated path); a
    consistent posterior cannot claim to beat that floor once the 12-min traverse has told
    it more about the heading than its 5-degree start prior does (measured: expected 1.86 m,
    frame floor 1.74 m, mean-bias floor 1.39 m)."""
    loc = cert["localization"]
    pred, frame, issue = (
        loc[k] for k in ("predicted_horizontal_rmse_m", "frame_floor_m", "horizontal_floor_m")
    )
    assert pred >= frame > issue > 0  # heading and scale cost on top of the mean bias
    assert frame < 2 * issue


@needs_gdal
def test_survey_layers_read_by_ogrinfo_and_validator(run, cert):
    from pyogrio.raw import read

    path = run / "survey.gpkg"
    text = subprocess.check_output(["ogrinfo", "-so", "-al", str(path)], text=True)
    assert "Layer name: trajectory" in text and "Layer name: landmarks" in text
    assert "kind: String" in text and "z_std: Real" in text and "kept: Integer(Boolean)" in text
    # the layers state their fields' units, the vertical datum and what made them (they said
    # nothing: a GIS user could not tell z_std's unit nor which survey they came from)
    flat = " ".join(text.split())
    assert "fields=trajectory: kind = 'estimated'" in flat and "sigma_max = largest" in flat
    assert "vertical_datum=ellipsoidal height above the WGS 84 ellipsoid" in flat
    roles = [f["role"] for f in cert["inputs"]["files"]]
    assert f'"role": "{roles[0]}"' in flat and "seed=0" in flat
    _validate_gpkg(path)
    loc = cert["localization"]
    _, _, wkb, (kind,) = read(path, layer="trajectory")
    assert kind.tolist() == ["estimated", "true"]
    lines = shapely.from_wkb(wkb)
    assert [len(shapely.get_coordinates(g)) for g in lines] == [loc["keyframes"]] * 2
    meta, _, wkb, fields = read(path, layer="landmarks")
    cols = dict(zip(meta["fields"], fields, strict=True))
    assert len(wkb) == loc["landmarks_in_graph"]
    assert int(cols["kept"].sum()) == loc["landmarks_selected"] > 0  # the selected landmarks
    # kept by the elevation rule; horizontally a 12-min survey under a 2.5 m GPS bias, with
    # the odometry's scale and heading drift estimated, is good to 1-2 m (measured 99th
    # percentile 1.90 m). Tracks triangulated at 1-3 deg parallax add a few landmarks long
    # along their (near-horizontal) viewing ray that the slope-aware elevation rule still
    # keeps (measured: 1 of 958, 6.5 m horizontally, z 1-sigma 0.16 m)
    kept_sigma = cols["sigma_max"][cols["kept"].astype(bool)]
    assert (cols["z_std"] > 0).all() and np.percentile(kept_sigma, 99) <= 3.0
    assert kept_sigma.max() <= 10.0 and (kept_sigma > 3.0).mean() < 0.01
    xyz = shapely.get_coordinates(shapely.from_wkb(wkb), include_z=True)
    w, s, e, n = BOUNDS
    inside = (xyz[:, 0] > w - 50) & (xyz[:, 0] < e + 50) & (xyz[:, 1] > s - 50)
    assert (inside & (xyz[:, 1] < n + 50)).all()  # camera range around the site


def test_mesh_read_by_open3d_and_pyvista(run, product):
    import open3d as o3d
    import pyvista as pv

    z, std = product.elevation.values.ravel(), product.elevation_std.values.ravel()
    keep = np.isfinite(z)
    m = o3d.io.read_triangle_mesh(str(run / "mesh.ply"))
    v = np.asarray(m.vertices)
    assert len(v) == keep.sum() and len(np.asarray(m.triangles)) == 2 * 59 * 59
    xx, yy = np.meshgrid(product.x.values, product.y.values)
    origin = np.array([BOUNDS[0], BOUNDS[1], 0.0])  # west, south, 0 m
    expected = np.column_stack([xx.ravel()[keep], yy.ravel()[keep], z[keep]]) - origin
    np.testing.assert_allclose(v, expected, atol=1e-4)
    quality = o3d.t.io.read_point_cloud(str(run / "mesh.ply")).point["quality"].numpy().ravel()
    np.testing.assert_array_equal(quality, std[keep].astype(np.float32))
    poly = pv.read(run / "mesh.vtp")
    np.testing.assert_array_equal(poly["elevation"], z[keep])
    np.testing.assert_array_equal(poly["elevation_std"], std[keep])
    # the map's own 1-sigma too: the data gaps a 3D viewer can colour (the total hides them)
    rel = product.elevation_std_relative.values.ravel()
    np.testing.assert_array_equal(poly["elevation_std_relative"], rel[keep])
    assert poly.field_data["seed"][0] == "0" and poly.field_data["crs"][0] == "EPSG:32608"


def test_certificate_has_accuracy_verdicts_seed_and_versions(run, cert):
    from importlib.metadata import version

    acc = cert["accuracy"]
    lo, hi = acc["rmse_ci95_m"]
    assert 0 < lo <= acc["rmse_m"] <= hi
    assert cert["checkpoints"]["n_used"] == 100
    standards = {v["standard"] for v in cert["verdicts"]}
    assert {"paper", "asprs1990", "asprs2023", "nssda", "nmas"} <= standards
    assert all(v["passed"] in (True, False, None) for v in cert["verdicts"])
    assert cert["seed"] == 0 and cert["scenario"]["seed"] == 0
    assert cert["scenario"]["site"]["bounds"] == list(BOUNDS)
    sw = cert["software"]
    assert sw["numpy"] == np.__version__ and sw["gtsam"] == version("gtsam")
    assert "glacimap" in sw
    summary = json.loads((run / "summary.json").read_text())
    assert summary["certificate"]["accuracy"] == acc and summary["seed"] == 0


def test_report_is_self_contained(run, cert):
    page = _parse(run / "report.html")
    html = (run / "report.html").read_text(encoding="utf-8")
    assert page.imgs and all(i["src"].startswith("data:image/png;base64,") for i in page.imgs)
    for tag in ("img", "script", "iframe", "source", "audio", "video", "embed"):
        assert f'<{tag} src="http' not in html
    assert 'src="http' not in html and "src='http" not in html
    assert "<script" not in html and "<link" not in html and "@import" not in html
    assert "url(http" not in html
    assert f"{cert['accuracy']['rmse_m']:.4g}" in html


# -- bad input to glacimap run ------------------------------------------------------------------
def _bad(args, exc_type=InputError):
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code != 0, res.output
    assert isinstance(res.exception, exc_type), repr(res.exception)
    return str(res.exception)


def test_missing_scenario_file(tmp_path):
    out = tmp_path / "out"
    msg = _bad(["run", "--config", tmp_path / "nope.toml", "--out", out])
    assert "--config" in msg and "nope.toml" in msg
    assert not out.exists()


def test_malformed_toml(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[site\nbounds = [1, 2")
    out = tmp_path / "out"
    msg = _bad(["run", "--config", bad, "--out", out])
    assert "--config" in msg and "valid TOML" in msg
    assert not out.exists()


@pytest.mark.parametrize(
    "text, field, hint",
    [
        ("[plan]\nn_swath = 2\n", "plan.n_swath", "did you mean 'n_swaths'"),
        ("[localize]\ngps_modle = 'bias'\n", "localize.gps_modle", "did you mean 'gps_model'"),
        ("[sensors.gps]\nrate_hx = 1.0\n", "sensors.gps.rate_hx", "did you mean 'rate_hz'"),
        ("sede = 1\n", "sede", "did you mean 'seed'"),
        ("[plan]\nn_swaths = 'four'\n", "plan.n_swaths", "expected a int"),
    ],
)
def test_unknown_key_or_wrong_type(tmp_path, text, field, hint):
    cfg = tmp_path / "s.toml"
    cfg.write_text(text)
    out = tmp_path / "out"
    msg = _bad(["run", "--config", cfg, "--out", out])
    assert msg.startswith(field) and hint in msg
    assert not out.exists()


def test_unwritable_output_folder(tmp_path):
    (tmp_path / "a_file").write_text("")  # a path under a regular file (blocks root too)
    msg = _bad(["run", "--out", tmp_path / "a_file" / "out"])
    assert "--out" in msg and "a_file" in msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_shell_exit_code_and_one_line_message(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "toolkit", "run", "--config", "missing.toml", "--out", "o"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.startswith("error: --config") and "missing.toml" in res.stderr
    assert list(tmp_path.iterdir()) == []


def test_failure_while_exporting_leaves_no_products(tmp_path, monkeypatch):
    import toolkit.export

    calls = []

    def broken(*args, **kwargs):
        calls.append(sorted(p.name for p in args[1].parent.iterdir()))
        raise OSError("disk full")

    monkeypatch.setattr(toolkit.export, "write_mesh", broken)
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(
        "[site]\nbounds = [526020.0, 6475020.0, 526180.0, 6475120.0]\n"
        "[plan]\nn_swaths = 1\n[reconstruct]\nresolution_m = 8.0\n"
        "[certify]\nn_checkpoints = 50\nn_boot = 100\n"
    )
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("kept")  # what was there before stays
    res = runner.invoke(app, ["run", "--config", str(cfg), "--out", str(out)])
    assert isinstance(res.exception, OSError) and "disk full" in str(res.exception)
    # certificate, product.nc, COG and contours were written (staged) before the mesh failed
    assert {"certificate.json", "elevation.tif", "contours.gpkg"} <= set(calls[0])
    assert [p.name for p in out.iterdir()] == ["notes.txt"]  # none of them is left


# -- bad input to glacimap certify, on the run's own GeoTIFF --------------------------------------
def _checkpoints_csv(path, header="x,y,z", crs=None, n=20):
    rng = np.random.default_rng(1)
    w, s, e, n_ = BOUNDS
    xy = np.column_stack([rng.uniform(w + 10, e - 10, n), rng.uniform(s + 10, n_ - 10, n)])
    z = sample_dem(default_site(2.0), xy)
    rows = [header + (",crs" if crs else "")]
    for (x, y), zz in zip(xy, z, strict=True):
        cells = [f"{x:.3f}", f"{y:.3f}", f"{zz:.3f}"][: len(header.split(","))]
        rows.append(",".join(cells + ([crs] if crs else [])))
    path.write_text("\n".join(rows) + "\n")
    return path


def test_certify_bad_inputs_leave_the_folder_empty(run, tmp_path):
    import rasterio

    tif = run / "elevation.tif"
    dest = tmp_path / "cert"
    dest.mkdir()
    target = dest / "certificate.json"
    # positive control: good checkpoints are certified and written
    good = _checkpoints_csv(tmp_path / "good.csv")
    res = runner.invoke(app, ["certify", str(tif), str(good), "--out", str(target)])
    assert res.exit_code == 0, (res.output, res.exception)
    target.unlink()
    missing = _checkpoints_csv(tmp_path / "missing.csv", header="x,y")
    msg = _bad(["certify", tif, missing, "--out", target])
    assert "missing.csv columns" in msg and "missing z" in msg
    other = _checkpoints_csv(tmp_path / "utm7.csv", crs="EPSG:32607")
    # another CRS is reprojected (issue 17), so zone-8 coordinates labelled zone 7 land
    # hundreds of km away: every checkpoint is outside the DEM, named with the fix
    msg = _bad(["certify", tif, other, "--out", target])
    assert "20 outside the DEM" in msg and "check the CRS" in msg
    with rasterio.open(tif) as src:  # the same raster without its CRS
        profile = {**src.profile, "crs": None, "driver": "GTiff"}
        profile.pop("layout", None)
        data = src.read()
    bare = tmp_path / "bare.tif"
    with rasterio.open(bare, "w", **profile) as dst:
        dst.write(data)
    msg = _bad(["certify", bare, good, "--out", target])
    assert msg.startswith("DEM crs") and "gdal_edit" in msg
    assert list(dest.iterdir()) == []


@needs_gdal
def test_contours_of_a_map_no_level_crosses(tmp_path):
    """A small survey's map can lie between two certified contour levels: the run still writes
    a valid, empty contour layer (it failed with 'geometry_type' before)."""
    from pyogrio.raw import read

    from terrain import Grid
    from terrain.product import terrain_dataset
    from toolkit.export import write_contours

    grid = Grid.from_bounds(BOUNDS, 10.0)
    xx, _ = np.meshgrid(grid.x, grid.y)
    z = 101.0 + 3.0 * (xx - BOUNDS[0]) / 300.0  # 101..104 m: no multiple of 5 m inside
    ds = terrain_dataset(grid, z, np.full(grid.shape, 0.3), {"seed": 0})
    res = write_contours(ds, tmp_path / "c.gpkg", 5.0, tmp_path / "c.geojson")
    assert res["lines"] == 0 and res["levels"] == 0
    text = subprocess.check_output(["ogrinfo", "-so", "-al", str(tmp_path / "c.gpkg")], text=True)
    assert "Feature Count: 0" in text and "Geometry: Line String" in text
    assert "elev: Real" in text and "mean_std: Real" in text
    _validate_gpkg(tmp_path / "c.gpkg")
    assert len(read(tmp_path / "c.gpkg", layer="contour")[2]) == 0
    assert json.loads((tmp_path / "c.geojson").read_text())["features"] == []


def test_point_tables_state_their_crs(run):
    """trajectory.csv and landmarks.csv gave x, y without a CRS (samples.csv had a crs
    column): a GIS import (QGIS delimited text, pandas + pyproj) had to guess it."""
    import pandas as pd

    for name in ("trajectory.csv", "landmarks.csv", "samples.csv"):
        table = pd.read_csv(run / name)
        assert table["crs"].unique().tolist() == ["EPSG:32608"], name
