"""Checkpoints as surveyors write them (issue 17): header aliases with a did-you-mean, any CRS
reprojected with pyproj, one sign for bias and z-scores, and a bias that dominates the error
said in words in the certificate JSON, the command line and the HTML report."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Transformer
from typer.testing import CliRunner

from terrain import Grid, InputError, random_terrain
from terrain.product import terrain_dataset
from toolkit.certify import bias_assessment, certify, read_checkpoints
from toolkit.certify_io import COLUMN_ALIASES
from toolkit.cli import app
from toolkit.report import write_report

BOUNDS = (526000.0, 6475000.0, 526600.0, 6475600.0)  # 600 m x 600 m, UTM 8N
CRS = "EPSG:32608"


@pytest.fixture(scope="module")
def site():
    grid = Grid.from_bounds(BOUNDS, 10.0, crs=CRS)
    truth = random_terrain(grid, relief=25.0, seed=1).values
    rng = np.random.default_rng(5)
    flat = rng.choice(grid.size, 40, replace=False)
    rows, cols = np.unravel_index(flat, grid.shape)
    xy = np.column_stack([grid.x[cols], grid.y[rows]])
    return grid, truth, xy, truth[rows, cols]


def _product(grid, z, std=0.3):
    return terrain_dataset(grid, z, np.broadcast_to(std, grid.shape).copy(), {"seed": 3})


def _write(path, header, columns):
    lines = [",".join(header)]
    lines += [
        ",".join(c[i] if isinstance(c[i], str) else repr(float(c[i])) for c in columns)
        for i in range(len(columns[0]))
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_easting_northing_elevation_headers_are_read(site, tmp_path):
    grid, truth, xy, z = site
    ref = certify(
        _product(grid, truth + 0.3),
        _write(tmp_path / "a.csv", ["x", "y", "z"], [xy[:, 0], xy[:, 1], z]),
        crs=CRS,
    )
    ids = [f"CP{i}" for i in range(len(z))]
    p = _write(
        tmp_path / "b.csv",
        ["Point ID", "Easting (m)", "NORTHING", "elevation_m", "sigma_z"],
        [ids, xy[:, 0], xy[:, 1], z, np.full(len(z), 0.02)],
    )
    cps = read_checkpoints(p, crs=CRS)
    assert cps.columns == {
        "x": "Easting (m)",
        "y": "NORTHING",
        "z": "elevation_m",
        "z_std": "sigma_z",
    }
    assert cps.ignored_columns == ("Point ID",)  # listed, not silently dropped
    cert = certify(_product(grid, truth + 0.3), p, crs=CRS)
    assert cert["accuracy"]["rmse_m"] == ref["accuracy"]["rmse_m"]
    assert cert["checkpoints"]["ignored_columns"] == ["Point ID"]
    assert cert["checkpoints"]["columns"]["z"] == "elevation_m"
    for canon in ("x", "y", "z"):  # every documented alias reads
        for alias in COLUMN_ALIASES[canon]:
            header = {"x": "x", "y": "y", "z": "z", canon: alias}
            q = _write(
                tmp_path / "c.csv", [header[k] for k in "xyz"], [xy[:3, 0], xy[:3, 1], z[:3]]
            )
            assert read_checkpoints(q, crs=CRS).columns[canon] == alias


def test_unknown_and_doubled_headers_are_named_with_a_fix(site, tmp_path):
    _, _, xy, z = site
    p = _write(tmp_path / "a.csv", ["easting", "northing", "elevaton"], [xy[:, 0], xy[:, 1], z])
    with pytest.raises(InputError) as exc:
        read_checkpoints(p, crs=CRS)
    msg = str(exc.value)
    assert "missing z" in msg and "'elevaton'" in msg and "did you mean 'elevation'" in msg
    p = _write(tmp_path / "b.csv", ["x", "y", "z", "height"], [xy[:, 0], xy[:, 1], z, z])
    with pytest.raises(InputError, match="one column for z") as exc:
        read_checkpoints(p, crs=CRS)
    assert "'z'" in str(exc.value) and "'height'" in str(exc.value)


def test_checkpoints_in_4326_are_reprojected_not_refused(site, tmp_path):
    grid, truth, xy, z = site
    ref = certify(_product(grid, truth + 0.3), {"x": xy[:, 0], "y": xy[:, 1], "z": z}, crs=CRS)
    lon, lat = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(xy[:, 0], xy[:, 1])
    lon, lat = np.append(lon, -134.7), np.append(lat, 95.0)  # a latitude beyond the pole
    p = _write(
        tmp_path / "geo.csv",
        ["lon", "lat", "h", "crs"],
        [lon, lat, np.append(z, 100.0), ["EPSG:4326"] * (len(z) + 1)],
    )
    cert = certify(_product(grid, truth + 0.3), p)
    acc = cert["accuracy"]
    # pyproj's round trip UTM -> 4326 -> UTM is ~1e-9 m; the DEM is linear between centres
    assert acc["rmse_m"] == pytest.approx(ref["accuracy"]["rmse_m"], abs=1e-6)
    assert acc["n"] == 40
    moved = cert["checkpoints"]["reprojected"]
    assert moved["from"] == "EPSG:4326" and "32608" in moved["to"]
    assert cert["checkpoints"]["dropped"]["not_projectable"]["count"] == 1
    assert cert["checkpoints"]["dropped"]["not_projectable"]["rows"] == [40]
    # UTM zone 7 coordinates (another projected CRS) land on the same points too
    e7, n7 = Transformer.from_crs(CRS, "EPSG:32607", always_xy=True).transform(xy[:, 0], xy[:, 1])
    c7 = certify(_product(grid, truth + 0.3), {"x": e7, "y": n7, "z": z}, crs="EPSG:32607")
    assert c7["accuracy"]["rmse_m"] == pytest.approx(ref["accuracy"]["rmse_m"], abs=1e-6)


def test_one_sign_for_bias_and_z_scores(site):
    """A map 0.3 m too high with a 0.3 m 1-sigma: bias +0.3 m and z = (map - cp) / s = +1
    at every checkpoint (hand computation). Before, bias was +0.3 and z_mean -1."""
    grid, truth, xy, z = site
    cert = certify(
        _product(grid, truth + 0.3, 0.3), {"x": xy[:, 0], "y": xy[:, 1], "z": z}, crs=CRS
    )
    assert cert["accuracy"]["bias_m"] == pytest.approx(0.3, abs=1e-12)
    assert cert["calibration"]["z_mean"] == pytest.approx(1.0, abs=1e-12)
    assert cert["calibration"]["z_std"] == pytest.approx(0.0, abs=1e-9)
    assert "map - checkpoint" in cert["calibration"]["z_definition"]
    assert cert["accuracy"]["error_definition"].startswith("map minus checkpoint")


def test_bias_assessment_by_hand():
    # errors 0.46 + e with e = +-0.32 alternating (mean 0): bias 0.46, SD 0.32 (1/n),
    # RMSE = sqrt(0.46^2 + 0.32^2) = 0.5604; |bias| / RMSE = 0.8209
    err = 0.46 + 0.32 * np.tile([1.0, -1.0], 20)
    b = bias_assessment(err)
    assert b["bias_m"] == pytest.approx(0.46)
    assert b["rmse_without_bias_m"] == pytest.approx(0.32)
    assert b["fraction_of_rmse"] == pytest.approx(0.46 / np.hypot(0.46, 0.32))
    assert b["share_of_mse"] == pytest.approx(0.46**2 / (0.46**2 + 0.32**2))
    # t = 0.46 / (s / sqrt(40)), s = 0.32 sqrt(40 / 39)
    assert b["t_statistic"] == pytest.approx(0.46 / (0.32 * np.sqrt(40 / 39) / np.sqrt(40)))
    assert b["significant"] and b["dominant"] and b["exceeds_asprs_mean_error"]
    assert "dominates" in b["message"] and "0.46 m above" in b["message"]
    assert "82 % of the RMSE" in b["message"] and "0.32 m" in b["message"]
    # 200 points, bias 0.06 m: t = 0.06 / (0.32 / sqrt(200)) = 2.65, significant, 18 % of RMSE
    small = bias_assessment(0.06 + 0.32 * np.tile([1.0, -1.0], 100))
    assert small["significant"] and not small["exceeds_asprs_mean_error"]
    assert not small["dominant"] and small["message"] is None
    noise = bias_assessment(0.05 + 0.32 * np.tile([1.0, -1.0], 20))  # t = 0.97: chance
    assert not noise["significant"] and noise["message"] is None
    mid = bias_assessment(-0.15 + 0.32 * np.tile([1.0, -1.0], 20))  # 42 %: large, not dominant
    assert mid["exceeds_asprs_mean_error"] and not mid["dominant"]
    assert "systematic bias" in mid["message"] and "below" in mid["message"]
    assert bias_assessment(0.32 * np.tile([1.0, -1.0], 20))["message"] is None


def test_dominant_bias_is_flagged_in_json_cli_and_html(site, tmp_path):
    grid, truth, xy, z = site
    # checkpoints 0.46 m below the map plus +-0.32 m: the 0.46 m of a 0.56 m RMSE
    cz = z - 0.46 + 0.32 * np.tile([1.0, -1.0], 20)
    table = {"x": xy[:, 0], "y": xy[:, 1], "z": cz}
    product = _product(grid, truth)
    cert = certify(product, table, crs=CRS)
    assert cert["accuracy"]["bias_assessment"]["dominant"]
    assert len(cert["warnings"]) == 1 and "dominates" in cert["warnings"][0]
    assert all(any("of RMSE" in n for n in v["notes"]) for v in cert["verdicts"])
    html = write_report(tmp_path / "r.html", product=product, certificate=cert).read_text()
    assert 'id="bias-warning"' in html and "dominates the error" in html
    # 40 checkpoints: the standard error comes from their errors' variogram (spatial route)
    ba = cert["accuracy"]["bias_assessment"]
    assert ba["standard_error_method"].startswith("spatial") and ba["error_variogram"]
    assert 'id="bias-se"' in html and "standard error of the bias" in html
    p = _write(tmp_path / "cp.csv", ["x", "y", "z"], [xy[:, 0], xy[:, 1], cz])
    product.to_netcdf(tmp_path / "dem.nc")
    res = CliRunner().invoke(app, ["certify", str(tmp_path / "dem.nc"), str(p), "--crs", CRS])
    assert res.exit_code == 0, (res.output, res.exception)
    assert "warning:" in res.output and "dominates" in res.output
    unbiased = certify(
        product, {"x": xy[:, 0], "y": xy[:, 1], "z": z + 0.32 * np.tile([1.0, -1.0], 20)}, crs=CRS
    )
    assert unbiased["warnings"] == [] and not unbiased["accuracy"]["bias_assessment"]["dominant"]


def test_truth_metrics_use_the_certificate_sign():
    """A map 0.5 m above the truth with sigma 0.25 m: mean error +0.5 m and z mean +2 (hand
    computation), the sign of the checkpoint block's bias (DEM - checkpoint) and of
    calibration.z_mean; terrain.evaluate standardizes truth - map and would say -2."""
    from terrain import evaluate
    from toolkit.pipeline import _against_truth

    truth = np.linspace(100.0, 110.0, 50).reshape(5, 10)
    row = _against_truth(truth + 0.5, np.full(truth.shape, 0.25), truth)
    assert row["mean_error"] == pytest.approx(0.5) and row["z_mean"] == pytest.approx(2.0)
    assert evaluate(truth + 0.5, truth, np.full(truth.shape, 0.25))["z_mean"] == pytest.approx(-2)
    assert "z_mean" not in _against_truth(truth + 0.5, None, truth)  # no sigma: no z
