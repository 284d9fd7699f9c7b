"""Accuracy certificate: reference values by hand, verdicts equal to survey.standards, bad input.

Reference values and their origin:
- A DEM offset by +0.3 m from the truth, checked at cell centres: every error is 0.3 m, so
  RMSE = bias = MAE = max = 0.3 m, std = 0, NSSDA Accuracy_z = 1.96 x 0.3 = 0.588 m (hand).
- Bilinear interpolation reproduces an affine surface exactly, so a tilted plane + 0.3 m is
  checked at arbitrary (not cell-centre) points with the same 0.3 m errors (hand).
- Errors (0.1, -0.2, 0.3, -0.4) m: RMSE = sqrt(0.30 / 4) = 0.27386 m, bias = -0.05 m,
  MAE = 0.25 m, std (ddof 1) = sqrt(0.29 / 3) = 0.31091 m (hand).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from survey.standards import verdicts
from terrain import CRSMismatchError, Grid, InputError, random_terrain
from terrain.product import terrain_dataset
from toolkit.certify import (
    Checkpoints,
    bootstrap_rmse_ci,
    certificate_json,
    certify,
    conventional_interval,
    read_checkpoints,
    write_certificate,
)
from toolkit.cli.certify import certify_command

BOUNDS = (526000.0, 6475000.0, 526600.0, 6475600.0)  # 600 m x 600 m, UTM 8N
CRS = "EPSG:32608"


@pytest.fixture(scope="module")
def grid():
    return Grid.from_bounds(BOUNDS, 10.0, crs=CRS)  # 60 x 60 cells


@pytest.fixture(scope="module")
def truth(grid):
    return random_terrain(grid, relief=25.0, seed=1).values


@pytest.fixture(scope="module")
def centres(grid):
    """40 distinct cell centres (row, col) and their coordinates."""
    rng = np.random.default_rng(5)
    flat = rng.choice(grid.size, 40, replace=False)
    rows, cols = np.unravel_index(flat, grid.shape)
    return rows, cols, np.column_stack([grid.x[cols], grid.y[rows]])


def _product(grid, z, std=0.3):
    return terrain_dataset(grid, z, np.broadcast_to(std, grid.shape).copy(), {"seed": 3})


def _csv(path, xy, z, extra=None):
    cols = {"x": xy[:, 0], "y": xy[:, 1], "z": z, **(extra or {})}

    def cell(v):
        return v if isinstance(v, str) else ("" if np.isnan(v) else repr(float(v)))

    lines = [",".join(cols)] + [",".join(cell(c[i]) for c in cols.values()) for i in range(len(z))]
    path.write_text("\n".join(lines) + "\n")
    return path


def _tif(path, grid, bands, crs=CRS, descriptions=("elevation", "elevation_std")):
    import rasterio

    profile = dict(driver="GTiff", width=grid.nx, height=grid.ny, count=len(bands))
    profile.update(dtype="float64", transform=grid.transform, nodata=np.nan)
    if crs is not None:
        profile["crs"] = crs
    with rasterio.open(path, "w", **profile) as dst:
        for i, band in enumerate(bands, start=1):
            dst.write(band, i)
            dst.set_band_description(i, descriptions[i - 1])
    return path


def test_constant_offset_gives_rmse_and_bias_of_the_offset(grid, truth, centres):
    rows, cols, xy = centres
    cert = certify(_product(grid, truth + 0.3), Checkpoints(xy, truth[rows, cols], crs=CRS))
    acc = cert["accuracy"]
    for key in ("rmse_m", "bias_m", "mae_m", "max_abs_error_m", "p95_abs_error_m"):
        assert acc[key] == pytest.approx(0.3, abs=1e-12), key
    assert acc["std_m"] == pytest.approx(0.0, abs=1e-12)
    assert acc["accuracy_95_m"] == pytest.approx(0.588, abs=1e-12)
    assert acc["rmse_ci95_m"] == pytest.approx([0.3, 0.3], abs=1e-12)
    assert acc["n"] == cert["checkpoints"]["n_used"] == 40
    # ASPRS 1990 Class 1 contours: CI = 3 RMSE = 0.9 m, rounded up to the conventional 1 m
    assert cert["contour_interval"]["finest_m"]["asprs1990_class1"] == pytest.approx(0.9)
    assert cert["contour_interval"]["certified_m"] == 1.0


def test_bilinear_sampling_is_exact_on_a_plane(grid):
    plane = 0.02 * (grid.x[None, :] - grid.west) - 0.05 * (grid.y[:, None] - grid.north) + 100
    rng = np.random.default_rng(2)
    w, s, e, n = grid.bounds
    xy = np.column_stack([rng.uniform(w + 5, e - 5, 30), rng.uniform(s + 5, n - 5, 30)])
    z = 0.02 * (xy[:, 0] - grid.west) - 0.05 * (xy[:, 1] - grid.north) + 100
    cert = certify(_product(grid, plane - 0.3), Checkpoints(xy, z, crs=CRS))
    assert cert["accuracy"]["bias_m"] == pytest.approx(-0.3, abs=1e-9)  # DEM is 0.3 m low
    assert cert["accuracy"]["rmse_m"] == pytest.approx(0.3, abs=1e-9)


def test_hand_computed_statistics(grid, truth, centres):
    rows, cols, xy = centres
    e = np.array([0.1, -0.2, 0.3, -0.4])
    dem = truth.copy()
    dem[rows[:4], cols[:4]] += e
    cps = Checkpoints(xy[:4], truth[rows[:4], cols[:4]], crs=CRS)
    acc = certify(_product(grid, dem), cps, contour_interval_m=1.0)["accuracy"]
    assert acc["rmse_m"] == pytest.approx(math.sqrt(0.30 / 4), abs=1e-12)
    assert acc["bias_m"] == pytest.approx(-0.05, abs=1e-12)
    assert acc["mae_m"] == pytest.approx(0.25, abs=1e-12)
    assert acc["max_abs_error_m"] == pytest.approx(0.4, abs=1e-12)
    assert acc["std_m"] == pytest.approx(math.sqrt(0.29 / 3), abs=1e-12)


def test_bootstrap_ci_contains_rmse_and_is_seeded():
    err = np.random.default_rng(0).normal(0.05, 0.3, 200)
    rmse = float(np.sqrt(np.mean(err**2)))
    lo, hi = bootstrap_rmse_ci(err, n_boot=2000, seed=4)
    assert lo < rmse < hi
    # RMSE of 200 N(0.05, 0.3) errors: relative s.e. ~ 1/sqrt(2n) = 5 %, so the 95 % CI is
    # about +-10 % of RMSE; accept 5 %..20 % each side
    assert 0.05 < (hi - lo) / 2 / rmse < 0.2
    assert bootstrap_rmse_ci(err, n_boot=2000, seed=4) == (lo, hi)
    assert bootstrap_rmse_ci(err, n_boot=2000, seed=5) != (lo, hi)


def test_verdicts_match_survey_standards(grid, truth, centres):
    rows, cols, xy = centres
    noise = np.random.default_rng(1).normal(0, 0.12, len(rows))
    cps = Checkpoints(xy, truth[rows, cols] + noise, crs=CRS)
    cert = certify(_product(grid, truth), cps, contour_interval_m=0.6096, checkpoint_rmse_m=0.02)
    rmse = cert["accuracy"]["rmse_m"]
    assert rmse == pytest.approx(np.sqrt(np.mean(noise**2)), abs=1e-12)
    expected = verdicts(rmse, 0.6096, 0.02, n_checkpoints=40, area_km2=0.36)
    assert cert["verdicts"] == json.loads(json.dumps(expected))
    assert cert["contour_interval"]["certified_m"] == 0.6096  # given, 2 ft


@pytest.mark.parametrize(("ci", "expected"), [(0.9, 1.0), (1.0, 1.0), (1.01, 2.0), (0.26, 0.5)])
def test_conventional_interval(ci, expected):
    assert conventional_interval(ci) == expected


def test_calibration_at_checkpoints(grid, truth, centres):
    rows, cols, xy = centres
    std = np.full(grid.shape, 0.1)
    std[rows[:20], cols[:20]] = 0.5
    cps = Checkpoints(xy, truth[rows, cols], crs=CRS)
    cal = certify(_product(grid, truth + 0.3, std), cps)["calibration"]
    # |e| = 0.3: inside +-1 sigma only where sigma = 0.5 (20 of 40); inside +-1.96 sigma
    # where 1.96 sigma >= 0.3, i.e. sigma = 0.5 again (1.96 x 0.1 = 0.196 < 0.3)
    assert cal["n"] == 40
    assert cal["coverage_68"] == pytest.approx(0.5)
    assert cal["coverage_95"] == pytest.approx(0.5)
    # with checkpoint z_std = 0.4: sigma = hypot(0.1, 0.4) = 0.412 >= 0.3 everywhere
    cps_std = Checkpoints(xy, truth[rows, cols], np.full(40, 0.4), crs=CRS)
    assert certify(_product(grid, truth + 0.3, std), cps_std)["calibration"]["coverage_68"] == 1


def test_dropped_checkpoints_are_counted_with_reasons(grid, truth, centres):
    rows, cols, xy = centres
    xy, z = xy.copy(), truth[rows, cols].copy()
    z[[1, 2]] = np.nan  # rows 1, 2: NaN
    xy[3] = (BOUNDS[0] - 50.0, BOUNDS[1] + 100.0)  # row 3: west of the DEM
    dem = truth.copy()
    dem[rows[4], cols[4]] = np.nan  # row 4: on nodata
    cert = certify(_product(grid, dem), Checkpoints(xy, z, crs=CRS))
    cp = cert["checkpoints"]
    assert cp["dropped"]["nan_values"]["rows"] == [1, 2]
    assert cp["dropped"]["outside_dem"]["rows"] == [3]
    assert cp["dropped"]["nodata"]["rows"] == [4]
    assert (cp["n_total"], cp["n_used"], cp["n_dropped"]) == (40, 36, 4)
    assert cert["accuracy"]["rmse_m"] == pytest.approx(0.0, abs=1e-12)


def test_certificate_is_reproducible_bytes(grid, truth, centres, tmp_path):
    rows, cols, xy = centres
    noisy = truth[rows, cols] + np.random.default_rng(3).normal(0, 0.2, len(rows))
    path = _csv(tmp_path / "cps.csv", xy, noisy, {"crs": [CRS] * len(rows)})  # a crs column
    a = write_certificate(certify(_product(grid, truth), path, seed=9), tmp_path / "a.json")
    b = write_certificate(certify(_product(grid, truth), path, seed=9), tmp_path / "b.json")
    assert a.read_bytes() == b.read_bytes()
    cert = json.loads(a.read_text())
    assert "created" not in cert and cert["seed"] == 9
    assert cert["software"]["numpy"] == np.__version__
    assert cert["checkpoints"]["crs"] == CRS
    c = certify(_product(grid, truth), path, seed=10)
    assert c["accuracy"]["rmse_ci95_m"] != cert["accuracy"]["rmse_ci95_m"]
    assert certify(_product(grid, truth), path, created="2024-07-01")["created"] == "2024-07-01"


def test_read_checkpoints_csv_parquet_sidecar(tmp_path, centres, truth):
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows, cols, xy = centres
    z = truth[rows, cols].copy()
    z[0] = np.nan
    p = _csv(tmp_path / "cps.csv", xy, z, {"z_std": np.full(len(z), 0.05)})
    (tmp_path / "cps.crs").write_text(CRS + "\n")
    cps = read_checkpoints(p)
    assert cps.crs.to_epsg() == 32608 and cps.n == 40
    assert cps.nan_rows().tolist() == [True] + [False] * 39  # kept, flagged
    assert np.allclose(cps.z_std, 0.05)
    table = pa.table({"X": xy[:, 0], "Y": xy[:, 1], "Z": z})
    pq.write_table(table, tmp_path / "cps.parquet")
    cpq = read_checkpoints(tmp_path / "cps.parquet", crs=CRS)
    assert np.array_equal(cpq.xy, cps.xy) and np.array_equal(cpq.z, cps.z, equal_nan=True)
    assert cpq.z_std is None
    with pytest.raises(CRSMismatchError):
        read_checkpoints(p, crs="EPSG:32607")  # argument vs the sidecar


def test_missing_z_column_is_named(tmp_path, centres):
    p = tmp_path / "cps.csv"
    p.write_text("x,y,hieght\n526100,6475100,100\n")  # a typo: 'height' is an alias of z
    with pytest.raises(InputError, match="missing z") as exc:
        read_checkpoints(p)
    assert "did you mean 'height'" in str(exc.value)


def test_geotiff_matches_dataset_and_needs_crs(grid, truth, centres, tmp_path):
    rows, cols, xy = centres
    std = np.full(grid.shape, 0.25)
    tif = _tif(tmp_path / "dem.tif", grid, [truth + 0.3, std])
    cps = Checkpoints(xy, truth[rows, cols], crs=CRS)
    from_tif = certify(tif, cps)
    from_ds = certify(_product(grid, truth + 0.3, 0.25), cps)
    assert from_tif["accuracy"] == from_ds["accuracy"]
    assert from_tif["calibration"] == from_ds["calibration"]  # the std band was found
    assert from_tif["dem"]["kind"] == "geotiff" and from_tif["dem"]["has_std_band"]
    bare = _tif(tmp_path / "bare.tif", grid, [truth], crs=None)
    with pytest.raises(InputError, match="CRS"):
        certify(bare, cps)


def _app():
    app = typer.Typer()
    app.command()(certify_command)
    return app


def test_cli_certifies_a_geotiff(grid, truth, centres, tmp_path):
    rows, cols, xy = centres
    tif = _tif(tmp_path / "dem.tif", grid, [truth + 0.3, np.full(grid.shape, 0.2)])
    csv = _csv(tmp_path / "cps.csv", xy, truth[rows, cols])
    out = tmp_path / "cert.json"
    args = [str(tif), str(csv), "--out", str(out), "--crs", CRS, "--seed", "2"]
    res = CliRunner().invoke(_app(), [*args, "--contour-interval", "1"])
    assert res.exit_code == 0, res.output
    assert "RMSE_z 0.300 m" in res.output and "asprs1990" in res.output
    expected = certificate_json(certify(tif, csv, crs=CRS, seed=2, contour_interval_m=1.0))
    assert out.read_text() == expected


def test_cli_bad_input_leaves_no_file(grid, truth, centres, tmp_path):
    rows, cols, xy = centres
    tif = _tif(tmp_path / "dem.tif", grid, [truth])
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n526100,6475100\n")
    out = tmp_path / "cert.json"
    res = CliRunner().invoke(_app(), [str(tif), str(bad), "--out", str(out)])
    assert isinstance(res.exception, InputError) and "missing z" in str(res.exception)
    assert not out.exists()
    csv = _csv(tmp_path / "cps.csv", xy, truth[rows, cols])
    blocked = tmp_path / "a_file" / "cert.json"  # parent is a file: not writable
    (tmp_path / "a_file").write_text("")
    res = CliRunner().invoke(_app(), [str(tif), str(csv), "--out", str(blocked)])
    assert isinstance(res.exception, InputError) and "--out" in str(res.exception)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "bad.csv", "cps.csv", "dem.tif"]


def test_write_certificate_is_atomic(grid, truth, centres, tmp_path, monkeypatch):
    rows, cols, xy = centres
    cert = certify(_product(grid, truth), Checkpoints(xy, truth[rows, cols], crs=CRS))
    target = tmp_path / "cert.json"
    target.write_text("old")

    def fail(self, *args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("pathlib.Path.write_text", fail)
    with pytest.raises(InputError, match="disk full"):
        write_certificate(cert, target)
    monkeypatch.undo()
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["cert.json"]  # no temporary left


def test_tables_of_columns_are_checkpoints(grid, truth, centres):
    import pandas as pd

    rows, cols, xy = centres
    z = truth[rows, cols]
    ref = certify(_product(grid, truth + 0.3), Checkpoints(xy, z, crs=CRS))["accuracy"]
    table = {"x": xy[:, 0], "y": xy[:, 1], "z": z}
    assert certify(_product(grid, truth + 0.3), table)["accuracy"] == ref
    frame = pd.DataFrame({"X": xy[:, 0], "Y": xy[:, 1], "Z": z, "crs": CRS})
    assert certify(_product(grid, truth + 0.3), frame)["accuracy"] == ref
    with pytest.raises(CRSMismatchError):
        certify(_product(grid, truth), frame, crs="EPSG:32607")
    with pytest.raises(InputError, match="missing z"):
        certify(_product(grid, truth), {"x": xy[:, 0], "y": xy[:, 1]})


def test_netcdf_and_dataarray_dems(grid, truth, centres, tmp_path):
    rows, cols, xy = centres
    cps = Checkpoints(xy, truth[rows, cols], crs=CRS)
    product = _product(grid, truth + 0.3)
    product.to_netcdf(tmp_path / "product.nc", engine="scipy")
    from_nc = certify(tmp_path / "product.nc", cps)
    assert from_nc["dem"]["kind"] == "netcdf"
    assert from_nc["accuracy"] == certify(product, cps)["accuracy"]
    bare = certify(product["elevation"].assign_attrs(product.attrs), cps)  # a DataArray
    assert bare["calibration"] is None and not bare["dem"]["has_std_band"]
    assert bare["accuracy"]["rmse_m"] == pytest.approx(0.3, abs=1e-12)


def test_report_of_a_surveyors_own_certified_geotiff(grid, truth, centres, tmp_path):
    """Issue 17: `glacimap report` could not draw a DEM certified with `glacimap certify`
    (it wanted product.nc): it now finds the certified file by the certificate, checks its
    bytes (sha256) and draws it."""
    from toolkit.cli import app

    rows, cols, xy = centres
    tif = _tif(tmp_path / "mine.tif", grid, [truth + 0.3], descriptions=("elevation",))
    csv = _csv(tmp_path / "cps.csv", xy, truth[rows, cols])
    out = tmp_path / "cert"
    out.mkdir()
    res = CliRunner().invoke(
        app, ["certify", str(tif), str(csv), "--crs", CRS, "--out", str(out / "certificate.json")]
    )
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["report", str(out)])
    assert res.exit_code == 0, (res.output, res.exception)
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html
    assert "0.3" in html  # the RMSE of a constant +0.3 m DEM
    # the certificate JSON itself as the argument, the report written elsewhere
    res = CliRunner().invoke(
        app, ["report", str(out / "certificate.json"), "--out", str(tmp_path / "r.html")]
    )
    assert res.exit_code == 0, (res.output, res.exception)
    assert (tmp_path / "r.html").read_text() == html
    # a DEM edited after certification is refused, naming the file and the fix
    _tif(tmp_path / "mine.tif", grid, [truth + 0.5], descriptions=("elevation",))
    (out / "report.html").unlink()
    res = CliRunner().invoke(app, ["report", str(out)])
    assert isinstance(res.exception, InputError), res.output
    assert "mine.tif" in str(res.exception) and "--dem" in str(res.exception)
    assert not (out / "report.html").exists()


def test_the_checkpoints_stated_sigma_is_their_survey_rmse_unless_given(grid, truth, centres):
    # ASPRS 2014 / 2023 add the checkpoint survey's own RMSE: the RMS of the stated z_std
    # (hand value: sqrt((0.03^2 + 0.04^2) / 2) = 0.03536 m) unless --checkpoint-rmse is given.
    rows, cols, xy = centres
    cps = {"x": xy[:, 0], "y": xy[:, 1], "z": truth[rows, cols] + 0.1, "crs": CRS}
    cps["z_std"] = np.where(np.arange(len(rows)) % 2 == 0, 0.03, 0.04)
    cert = certify(_product(grid, truth), cps)
    p = cert["parameters"]
    assert p["checkpoint_rmse_m"] == pytest.approx(np.sqrt((0.03**2 + 0.04**2) / 2))
    assert "stated 1-sigma" in p["checkpoint_rmse_source"]
    rmse = cert["accuracy"]["rmse_m"]
    assert cert["accuracy"]["rmse_with_checkpoint_error_m"] == pytest.approx(
        np.hypot(rmse, p["checkpoint_rmse_m"])
    )
    given = certify(_product(grid, truth), cps, checkpoint_rmse_m=0.0)["parameters"]
    assert given["checkpoint_rmse_m"] == 0.0 and given["checkpoint_rmse_source"].startswith("given")
    del cps["z_std"]
    bare = certify(_product(grid, truth), cps)["parameters"]
    assert bare["checkpoint_rmse_m"] == 0.0 and "not stated" in bare["checkpoint_rmse_source"]
