"""``glacimap plan`` and ``glacimap sweep`` over the public survey API."""

import json

from typer.testing import CliRunner

from toolkit.cli import app

runner = CliRunner()


def test_plan_writes_json_and_png(tmp_path):
    res = runner.invoke(
        app, ["plan", "--pattern", "piecewise_continuous", "--swaths", "3", "--out", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["pattern"] == "piecewise_continuous" and plan["params"]["n_swaths"] == 3
    assert 0 < plan["metrics"]["centeredness_alpha"] < 1
    assert (tmp_path / "plan.png").read_bytes()[:4] == b"\x89PNG"


def test_plan_bad_pattern_and_swaths(tmp_path):
    res = runner.invoke(app, ["plan", "--pattern", "spiral", "--out", str(tmp_path)])
    assert res.exit_code != 0 and "spiral" in str(res.exception)
    res = runner.invoke(app, ["plan", "--swaths", "0", "--out", str(tmp_path)])
    assert res.exit_code != 0 and "n_swaths" in str(res.exception)
    assert not (tmp_path / "plan.json").exists()


def test_sweep_cli_small_prints_minimum_swaths(tmp_path):
    res = runner.invoke(
        app,
        [
            "sweep",
            "--terrains",
            "2",
            "--swaths",
            "1,3",
            "--resolution",
            "30",
            "--spacing",
            "30",
            "--workers",
            "1",
            "--out",
            str(tmp_path),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "Minimum swaths" in res.output and "tasks/s" in res.output
    for name in (
        "results.sqlite",
        "summary.json",
        "fig10_rmse_vs_swaths.png",
        "fig11_class_limit.png",
    ):
        assert (tmp_path / name).exists()
    res = runner.invoke(
        app, ["sweep", "--terrains", "2", "--swaths", "1-x", "--out", str(tmp_path / "bad")]
    )
    assert res.exit_code != 0 and "--swaths" in str(res.exception)


def _write_geotiff(path, values, crs, transform):
    import rasterio

    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=values.shape[0],
        width=values.shape[1],
        count=1,
        dtype="float32",
        crs=crs,
        transform=transform,
        nodata=-9999.0,
    ) as ds:
        ds.write(values.astype("float32"), 1)


def test_plan_reads_geotiff_prior_in_its_crs_and_in_4326(tmp_path):
    """Issue 17: `plan --prior DEM.tif` printed a traceback (only NetCDF3 was read)."""
    import numpy as np
    from affine import Affine
    from rasterio.warp import Resampling, calculate_default_transform, reproject

    from terrain import Grid, default_site

    dem = default_site(resolution=10.0)
    g = Grid.from_dataarray(dem)
    w, s, e, n = g.bounds
    t = Affine(10.0, 0, w, 0, -10.0, n)
    _write_geotiff(tmp_path / "utm.tif", dem.values, g.crs.to_wkt(), t)
    t4326, nx, ny = calculate_default_transform(g.crs, "EPSG:4326", g.nx, g.ny, *g.bounds)
    geo = np.full((ny, nx), -9999.0, np.float32)
    reproject(
        dem.values.astype("float32"),
        geo,
        src_transform=t,
        src_crs=g.crs,
        dst_transform=t4326,
        dst_crs="EPSG:4326",
        resampling=Resampling.bilinear,
        dst_nodata=-9999.0,
    )
    _write_geotiff(tmp_path / "geo.tif", geo, "EPSG:4326", t4326)
    for name in ("utm.tif", "geo.tif"):
        out = tmp_path / name.replace(".tif", "")
        res = runner.invoke(app, ["plan", "--prior", str(tmp_path / name), "--out", str(out)])
        assert res.exit_code == 0, (name, res.output, res.exception)
        plan = json.loads((out / "plan.json").read_text())
        xy = np.array(plan["samples"])
        # the plan lies on the DEM's site: the UTM zone 8N footprint of the default site
        # (a 4326 DEM is planned in the UTM zone of its centre, which is the site's own)
        assert len(xy) > 100
        tol = 0.0 if name == "utm.tif" else 15.0  # the 4326 raster's cells reach ~10 m beyond
        assert w - tol <= xy[:, 0].min() and xy[:, 0].max() <= e + tol
        assert s - tol <= xy[:, 1].min() and xy[:, 1].max() <= n + tol
        assert "UTM zone 8N" in plan["crs"]


def test_plan_reads_netcdf_prior_and_refuses_other_files_in_one_line(tmp_path):
    from terrain import default_site

    dem = default_site(resolution=10.0)
    dem.to_dataset(name="elevation").to_netcdf(tmp_path / "dem.nc")  # netCDF4 / HDF5
    res = runner.invoke(app, ["plan", "--prior", str(tmp_path / "dem.nc"), "--out", str(tmp_path)])
    assert res.exit_code == 0, (res.output, res.exception)
    (tmp_path / "notes.csv").write_text("a,b\n1,2\n")
    res = runner.invoke(
        app, ["plan", "--prior", str(tmp_path / "notes.csv"), "--out", str(tmp_path / "bad")]
    )
    msg = str(res.exception)
    assert res.exit_code != 0 and "--prior" in msg and "notes.csv" in msg and "Fix" in msg
    assert not (tmp_path / "bad" / "plan.json").exists()
