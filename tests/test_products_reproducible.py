"""Products as a GIS colleague receives them (issues 16/17 QA pass): they name their inputs
by file name and SHA-256, are the same bytes for the same inputs and seed whatever folder
they were written to, state the installed version, and product.nc names its variables with
CF standard names. Unit tests of each cause, then one slow end-to-end check of two runs."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from _scenarios import small_run
from typer.testing import CliRunner

from terrain import Grid, InputError, random_terrain
from terrain.product import VERTICAL_DATUM, terrain_dataset
from toolkit.cli import app
from toolkit.export import VectorLayer, cf_standard_name, write_netcdf, write_vector_layers
from toolkit.provenance import (
    GPKG_LAST_CHANGE_DEFAULT,
    TIMING_KEYS,
    file_sha256,
    input_record,
    split_timings,
)

runner = CliRunner()
CRS = "EPSG:32608"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --- glacimap --version ---------------------------------------------------------------------


def test_version_flag_prints_the_installed_version():
    import toolkit

    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0, res.output
    assert res.output.strip() == f"glacimap {version('glacimap')}"
    # the version certificates record (toolkit.certify.software_versions) is the same one
    assert toolkit.__version__ == version("glacimap")


# --- GeoPackage bytes do not depend on the wall clock ----------------------------------------


def _layers():
    return {"pts": VectorLayer.points(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), k=[1, 2])}


def test_geopackage_bytes_do_not_depend_on_the_clock(tmp_path, monkeypatch):
    """GDAL stamps gpkg_contents.last_change with the wall clock (ms): two writes of the same
    layers differed. Now the stamp is fixed, and GDAL's setting is restored afterwards."""
    from pyogrio import get_gdal_config_option

    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    a, b = tmp_path / "a.gpkg", tmp_path / "b.gpkg"
    write_vector_layers(a, _layers(), CRS)
    time.sleep(0.05)  # a different millisecond on the clock
    write_vector_layers(b, _layers(), CRS)
    assert _sha(a) == _sha(b)
    with sqlite3.connect(a) as db:
        stamp = db.execute("select last_change from gpkg_contents").fetchone()[0]
    assert stamp == GPKG_LAST_CHANGE_DEFAULT
    assert get_gdal_config_option("OGR_CURRENT_DATE") is None


def test_geopackage_stamp_follows_source_date_epoch(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")  # 2023-11-14T22:13:20Z
    out = write_vector_layers(tmp_path / "c.gpkg", _layers(), CRS)
    with sqlite3.connect(out) as db:
        stamp = db.execute("select last_change from gpkg_contents").fetchone()[0]
    assert stamp == "2023-11-14T22:13:20.000Z"
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    with pytest.raises(InputError, match="SOURCE_DATE_EPOCH"):
        write_vector_layers(tmp_path / "d.gpkg", _layers(), CRS)
    assert not (tmp_path / "d.gpkg").exists()  # nothing written on error


# --- inputs by name and SHA-256; timings out of the certificate ------------------------------


def test_input_record_names_files_and_folders_by_name_and_hash(tmp_path):
    log = tmp_path / "deep" / "rover"
    (log / "sub").mkdir(parents=True)
    (log / "gps.nmea").write_text("$GPGGA\n")
    (log / "sub" / "odometry.csv").write_text("t,d\n")
    rec = input_record("log", log)
    assert rec["name"] == "rover" and rec["n_files"] == 2
    assert rec["files"] == {
        "gps.nmea": file_sha256(log / "gps.nmea"),
        "sub/odometry.csv": file_sha256(log / "sub" / "odometry.csv"),
    }
    # the folder digest: sha256 over "<relative path> <sha256>\n" lines in sorted order
    lines = "".join(f"{k} {v}\n" for k, v in sorted(rec["files"].items()))
    assert rec["sha256"] == hashlib.sha256(lines.encode()).hexdigest()
    assert str(tmp_path) not in json.dumps(rec)  # never the absolute path
    prior = tmp_path / "dem.tif"
    prior.write_bytes(b"\x00\x01")
    assert input_record("prior", str(prior)) == {
        "role": "prior",
        "name": "dem.tif",
        "sha256": hashlib.sha256(b"\x00\x01").hexdigest(),
    }
    assert input_record("control", None) is None
    # an object read earlier keeps its own name and hash (toolkit.Checkpoints)
    from toolkit import Checkpoints

    cps = Checkpoints(np.zeros((1, 2)), np.zeros(1), source="cp.csv", sha256="ab")
    assert input_record("checkpoints", cps) == {
        "role": "checkpoints",
        "name": "cp.csv",
        "sha256": "ab",
    }


def test_split_timings_keeps_counts_and_moves_seconds():
    summary = {
        "keyframes": 10,
        "step_median_s": 0.1,
        "step_p95_s": 0.2,
        "marginals_s": 1.0,
        "view_gate": {"views_cut": 3, "seconds": 0.5},
    }
    kept, times = split_timings(summary)
    assert kept == {"keyframes": 10, "view_gate": {"views_cut": 3}}
    assert times == {
        "step_median_s": 0.1,
        "step_p95_s": 0.2,
        "marginals_s": 1.0,
        "view_gate_s": 0.5,
    }
    assert set(TIMING_KEYS) <= set(times)


def test_prior_dem_is_labelled_by_file_name(tmp_path):
    """The product's mean_function named the prior by its absolute path: the bytes of every
    product depended on the output folder (glacimap run writes the DEM inside it)."""
    import rioxarray  # noqa: F401  (the .rio accessor)

    from toolkit.config import load_scenario
    from toolkit.processing import prior_mean

    grid = Grid.from_bounds((526000.0, 6475000.0, 526600.0, 6475600.0), 50.0, crs=CRS)
    dem = random_terrain(grid, relief=25.0, seed=3)
    path = tmp_path / "folder" / "prior.tif"
    path.parent.mkdir()
    dem.rio.write_crs(CRS).rio.to_raster(path)
    mean = prior_mean(path, load_scenario(None))
    assert repr(mean).startswith("RasterMean('prior.tif'")
    assert str(tmp_path) not in repr(mean)
    assert mean.source.path == str(path)  # still read from where it is
    # a RasterMean the caller built: a relabelled copy, the caller's object untouched
    from terrain import RasterMean

    own = RasterMean(path)
    used = prior_mean(own, load_scenario(None))
    assert used is not own and repr(used).startswith("RasterMean('prior.tif'")
    assert str(path) in repr(own)


# --- product.nc with CF standard names -------------------------------------------------------


@pytest.mark.parametrize(
    ("datum", "name"),
    [
        (VERTICAL_DATUM, "height_above_reference_ellipsoid"),
        ("orthometric height, EGM2008 geoid", "height_above_geoid"),
        ("heights above the geoid (NAVD88)", "height_above_geoid"),
        ("not stated by the product", None),
        (None, None),
    ],
)
def test_cf_standard_name_follows_the_vertical_datum(datum, name):
    assert cf_standard_name(datum) == name


def test_product_nc_has_cf_standard_names(tmp_path):
    grid = Grid.from_bounds((526000.0, 6475000.0, 526600.0, 6475600.0), 20.0, crs=CRS)
    z = random_terrain(grid, relief=25.0, seed=1).values
    ds = terrain_dataset(grid, z, np.full(grid.shape, 0.3), {"seed": 1})
    out = write_netcdf(ds, tmp_path / "product.nc")
    back = xr.open_dataset(out)
    assert back["elevation"].attrs["standard_name"] == "height_above_reference_ellipsoid"
    assert (
        back["elevation_std"].attrs["standard_name"]
        == "height_above_reference_ellipsoid standard_error"
    )
    assert back["elevation"].attrs["ancillary_variables"].split()[0] == "elevation_std"
    assert back["elevation"].attrs["units"] == "m"
    assert "standard_name" not in ds["elevation"].attrs  # the caller's Dataset untouched
    with pytest.raises(InputError, match="product"):
        write_netcdf(ds.drop_vars("elevation_std"), tmp_path / "bad.nc")
    assert not (tmp_path / "bad.nc").exists()


# --- the notebook user's objects --------------------------------------------------------------


def test_process_result_repr_is_one_readable_line():
    from toolkit.pipeline import RunResult
    from toolkit.processing import ProcessResult

    cert = {
        "accuracy": {"n": 400, "rmse_m": 0.5921, "bias_m": 0.4712},
        "heldout_calibration": {"map_coverage_68": 0.729, "map_coverage_95": 0.965},
    }
    res = ProcessResult(
        out=Path("out/x"),
        settings={"huge": list(range(1000))},
        timings={"localize": 12.0, "reconstruct": 7.5},
        summary={"seed": 0, "certificate": cert},
        products=["certificate.json", "elevation.tif"],
        objects={"grid": object()},
    )
    text = repr(res)
    assert "\n" not in text and len(text) < 300, text
    for part in ("seed=0", "0.592 m", "+0.471 m", "72.9/96.5 %", "2 files", "19.5 s"):
        assert part in text, (part, text)
    run = RunResult(out=Path("out/x"), settings={}, summary={"seed": 0, "rmse_m": 0.594})
    assert "RMSE vs truth 0.594 m" in repr(run)


# --- two runs, two folders, the same bytes ---------------------------------------------------

SCENARIO = small_run(n_boot=500)


@pytest.mark.slow
def test_same_seed_same_bytes_in_two_folders(tmp_path):
    """Every product of ``glacimap run`` is byte-identical across two runs into different
    folders; only summary.json (wall-clock timings, by design) differs."""
    cfg = tmp_path / "s.toml"
    cfg.write_text(SCENARIO)
    for name in ("a", "b"):
        res = runner.invoke(app, ["run", "--config", str(cfg), "--out", str(tmp_path / name)])
        assert res.exit_code == 0, res.output
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*"))
    files = [f for f in files if (tmp_path / "a" / f).is_file()]
    differ = [str(f) for f in files if _sha(tmp_path / "a" / f) != _sha(tmp_path / "b" / f)]
    assert differ == ["summary.json"]
    cert = json.loads((tmp_path / "a" / "certificate.json").read_text())
    roles = {r["role"]: r for r in cert["inputs"]["files"]}
    assert roles["prior"]["sha256"] == _sha(tmp_path / "a" / "field" / "prior.tif")
    assert roles["checkpoints"]["sha256"] == _sha(tmp_path / "a" / "field" / "checkpoints.csv")
    assert roles["log"]["name"] == "rover" and roles["log"]["n_files"] >= 5
    assert not set(TIMING_KEYS) & set(cert["localization"])
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert set(TIMING_KEYS) <= set(summary["localization_timings_s"])
    tags = xr.open_dataset(tmp_path / "a" / "product.nc").attrs
    assert json.loads(tags["inputs"]) == [
        {k: r[k] for k in ("role", "name", "sha256")} for r in cert["inputs"]["files"]
    ]
    assert str(tmp_path) not in (tmp_path / "a" / "certificate.json").read_text()


def test_certificate_says_what_an_in_memory_dem_hash_is_of(tmp_path):
    """run/process certify the map in memory: the certificate's dem.sha256 is of its arrays,
    not of elevation.tif. It said 'dataset Dataset, sha256 ...' only, which a reader checking
    the file's hash would find wrong. The report also lists the input files and hashes."""
    from toolkit.certify import certify
    from toolkit.report import write_report

    grid = Grid.from_bounds((526000.0, 6475000.0, 526600.0, 6475600.0), 20.0, crs=CRS)
    z = random_terrain(grid, relief=25.0, seed=1).values
    ds = terrain_dataset(grid, z, np.full(grid.shape, 0.3), {"seed": 1})
    rng = np.random.default_rng(0)
    xy = rng.uniform([526050.0, 6475050.0], [526550.0, 6475550.0], (60, 2))
    table = {"x": xy[:, 0], "y": xy[:, 1], "z": np.full(60, float(np.nanmean(z)))}
    cert = certify(ds, table, crs=CRS, seed=0, n_boot=200)
    assert "not a file" in cert["dem"]["sha256_of"] and "elevation_std" in cert["dem"]["sha256_of"]
    cert["inputs"] = {"files": [{"role": "prior", "name": "dem.tif", "sha256": "ab" * 32}]}
    html = write_report(tmp_path / "r.html", product=ds, certificate=cert).read_text()
    assert "not a file" in html
    assert "input: prior</th><td>dem.tif, sha256 <code>" + "ab" * 32 in html


def test_uncertified_contour_interval_includes_the_shared_offset():
    """Without checkpoints the interval was 3 x the held-out RMSE, which only compares the
    map with its own samples: the example field folder (consumer GPS, shared vertical offset
    1-sigma 1.35 m, held-out RMSE 0.032 m) got 0.1 m contours. ASPRS 1990 Class 1:
    CI = 3 RMSE_z, with RMSE_z what a checkpoint would see."""
    from toolkit.products import contour_interval

    cert: dict = {}
    assert contour_interval(cert, 0.0317, 1.35) == 5.0  # 3 x 1.3504 = 4.05 -> 5 m
    assert cert["contour_interval"]["certified_m"] is None
    assert cert["contour_interval"]["expected_rmse_m"] == pytest.approx(np.hypot(0.0317, 1.35))
    assert contour_interval({}, 0.0317, 0.0) == 0.1  # no shared offset: the held-out RMSE
    assert contour_interval({"contour_interval": {"certified_m": 2.0}}, 0.03, 1.35) == 2.0
