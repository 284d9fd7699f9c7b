"""A satellite DEM read as the mean or as data, chosen by held-out survey samples
(``terrain.dem_choice``, ``glacimap reconstruct --prior-as auto``).

References: the truth is known here (a bumpy surface made in this file), so each reading's
map is scored against it independently of the chooser, which sees only the survey. Two DEMs
of the same ground: one with white noise per cell (its cells, averaged by the GP, beat the
DEM as an exact mean) and one with a smooth error of 2 m over 150 m (a mean's residual field
learns it on the lines; as independent cells it misleads the gaps). The chooser must pick
the reading the truth prefers in both, and they differ, so a chooser stuck on one answer
fails.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from _rasters import write_geotiff
from typer.testing import CliRunner

from terrain import ElevationSamples, Grid, InputError, RasterMean, TerrainGP
from terrain.dem_as_data import dem_as_data
from terrain.dem_choice import choose_dem_reading
from toolkit.cli import app

UTM = "EPSG:32608"
W0, N0, SIDE = 500_000.0, 6_600_400.0, 400.0
runner = CliRunner()


def _truth(x, y):
    u, v = x - W0, y - N0
    return 900.0 + 0.03 * u + 4.0 * np.sin(u / 23.0) * np.cos(v / 31.0) + 2.0 * np.sin(v / 17.0)


def _grid(cell):
    n = int(SIDE / cell)
    return Grid(W0, N0 + SIDE, (cell, cell), (n, n), UTM)


def _dem(error, seed=0):
    """The truth averaged over 20 m cells (4 x 4 points each) plus ``error``'s noise."""
    g = _grid(20.0)
    xx, yy = np.meshgrid(g.x, g.y)
    off = np.array([-7.5, -2.5, 2.5, 7.5])
    v = np.mean([_truth(xx + a, yy + b) for a in off for b in off], axis=0)
    rng = np.random.default_rng(seed)
    if error == "white":
        v = v + rng.normal(0.0, 1.5, g.shape)
    else:  # smooth: a squared-exponential field of 2 m and 150 m
        p = np.column_stack([xx.ravel(), yy.ravel()])
        d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
        cov = 4.0 * np.exp(-0.5 * d2 / 150.0**2) + 1e-6 * np.eye(len(p))
        v = v + (np.linalg.cholesky(cov) @ rng.normal(size=len(p))).reshape(g.shape)
    return g.data_array(v + 3.0, "elevation")  # +3 m: the DEM's datum offset


def _survey(seed=1):
    """Four north-south lines, 100 m apart, a fix every 2 m (+- 1 m of steering)."""
    rng = np.random.default_rng(seed)
    y = np.arange(N0 + 2.0, N0 + SIDE - 2.0, 2.0)
    xy = np.vstack(
        [np.column_stack([np.full(y.size, x), y]) for x in W0 + 50.0 + 100.0 * np.arange(4)]
    )
    xy[:, 0] += rng.normal(0.0, 1.0, len(xy))
    return ElevationSamples(xy, _truth(*xy.T) + rng.normal(0.0, 0.02, len(xy)), 0.02**2, crs=UTM)


def _truth_rmse(gp, grid):
    xx, yy = np.meshgrid(grid.x, grid.y)
    return float(np.sqrt(np.mean((gp.predict_grid(grid).elevation.values - _truth(xx, yy)) ** 2)))


@pytest.mark.parametrize("error", ["white", "smooth"])
def test_the_reading_chosen_is_the_one_the_truth_prefers(error):
    dem, s, grid = _dem(error), _survey(), _grid(4.0)
    pick = choose_dem_reading(
        TerrainGP(mean=RasterMean(dem), seed=0), TerrainGP(seed=0), dem, s, grid
    )
    truth = {
        "mean": _truth_rmse(TerrainGP(mean=RasterMean(dem), seed=0).fit(s), grid),
        "data": _truth_rmse(TerrainGP(seed=0).fit(dem_as_data(dem, s, grid.bounds)[0]), grid),
    }
    better = min(truth, key=truth.get)
    assert pick.choice == better, (pick.note(), truth)
    # the white DEM's cells beat it as a mean; the smooth error's DEM is better as a mean
    assert better == {"white": "data", "smooth": "mean"}[error], truth
    assert max(truth.values()) > 1.2 * min(truth.values())  # a clear case, not a tie
    scores = pick.scores
    assert set(scores) == {"mean", "data"} and pick.n_heldout == s.n and pick.n_folds == 5
    for r in ("mean", "data"):
        assert len(scores[r]["fold_rmse_m"]) == 5 and np.isfinite(scores[r]["heldout_nlpd"])
        assert 0.0 <= scores[r]["heldout_coverage_68"] <= scores[r]["heldout_coverage_95"] <= 1
    assert f"read as {better} (auto)" in pick.note()
    assert json.loads(json.dumps(pick.to_dict()))["choice"] == better


def test_the_choice_does_not_follow_the_rows_order():
    dem, s, grid = _dem("white"), _survey(), _grid(8.0)
    perm = np.random.default_rng(5).permutation(s.n)
    shuffled = ElevationSamples(s.xy[perm], s.z[perm], s.z_var[perm], crs=UTM)
    a, b = (
        choose_dem_reading(
            TerrainGP(mean=RasterMean(dem), seed=0), TerrainGP(seed=0), dem, x, grid, n_folds=3
        )
        for x in (s, shuffled)
    )
    assert a.to_dict() == b.to_dict()


def test_bad_settings_are_input_errors():
    dem, s = _dem("white"), _survey()
    gps = (TerrainGP(mean=RasterMean(dem), seed=0), TerrainGP(seed=0))
    with pytest.raises(InputError, match="n_folds"):
        choose_dem_reading(*gps, dem, s, _grid(8.0), n_folds=1)
    with pytest.raises(InputError, match="targets.*Grid"):
        choose_dem_reading(*gps, dem, s, np.zeros((3, 2)))


def test_cli_prior_as_auto_records_the_choice(tmp_path):
    dem, s = _dem("white"), _survey()
    tif = write_geotiff(dem, tmp_path / "dem.tif")
    csv = tmp_path / "s.csv"
    pd.DataFrame({"x": s.xy[:, 0], "y": s.xy[:, 1], "z": s.z, "z_var": s.z_var, "crs": UTM}).to_csv(
        csv, index=False
    )
    never, cfg = tmp_path / "never", tmp_path / "bad.toml"
    cfg.write_text('[prior]\nas = "sometimes"\n')
    refused = {  # the option or setting named, before any work
        "--prior-as": ["--prior-as", "auto"],  # nothing to read
        '"auto"': ["--prior", str(tif), "--prior-as", "maybe"],
        "prior.as": ["--config", str(cfg)],
    }
    for field, bad in refused.items():
        r = runner.invoke(app, ["reconstruct", str(csv), *bad, "--out", str(never)])
        assert isinstance(r.exception, InputError) and field in str(r.exception), field
    assert not never.exists()
    out = tmp_path / "m"
    args = ["reconstruct", str(csv), "--prior", str(tif), "--prior-as", "auto", "--resolution", "8"]
    r = runner.invoke(app, [*args, "--out", str(out)])
    assert r.exit_code == 0, r.output
    attrs = xr.open_dataset(out / "product.nc").attrs
    record = json.loads(attrs["prior_reading"])
    assert record["choice"] == "data" and "read as data (auto)" in r.output
    assert "cells as samples" in attrs["prior_as_data"]  # the chosen reading was applied
    assert attrs["mean_function"].startswith("ConstantMean")
    assert record["scores"]["data"]["heldout_rmse_m"] < record["scores"]["mean"]["heldout_rmse_m"]
    # the choice's own fit is the map's: the same bits as asking for the data reading
    r = runner.invoke(app, [*args[:-4], "--prior-as", "data", *args[-2:], "--out", str(out / "d")])
    assert r.exit_code == 0, r.output
    with xr.open_dataset(out / "product.nc") as a, xr.open_dataset(out / "d" / "product.nc") as b:
        for band in ("elevation", "elevation_std", "elevation_std_relative"):
            np.testing.assert_array_equal(a[band].values, b[band].values)


def test_process_chooses_the_reading_and_certifies_it(tmp_path):
    # The example field folder with a 10 m prior DEM of its truth + 1.5 m datum offset +
    # 0.3 m noise per cell (as tests/test_dem_as_data.py): "auto" from the settings picks a
    # reading, applies it, and the certificate and console state the choice and its scores.
    from pathlib import Path

    from toolkit.config import load_scenario
    from toolkit.field_survey import simulated_prior
    from toolkit.pipeline import make_site

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    truth = make_site(load_scenario(example / "scenario.toml"))
    dem = simulated_prior(truth, 10.0, 1.5, 0.3, np.random.default_rng(0))
    tif = write_geotiff(dem, tmp_path / "dem.tif")
    cfg = tmp_path / "auto.toml"
    cfg.write_text('[prior]\nas = "auto"\n')
    out = tmp_path / "out"
    r = runner.invoke(
        app, ["process", str(example), "--prior", str(tif), "--config", str(cfg), "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    attrs = xr.open_dataset(out / "product.nc").attrs
    # the landmarks' rover-clock times + survey.json's clock offset (1782936000 s: 2026-07-01
    # 20:00 UTC) date the map (glacimap change reads it for a mass-balance rate)
    assert attrs["survey_date"] == "2026-07-01"
    cert = json.loads((out / "certificate.json").read_text())
    record = cert["reconstruction"]["prior_reading"]
    assert record == json.loads(attrs["prior_reading"])
    scores = {k: v["heldout_rmse_m"] for k, v in record["scores"].items()}
    assert record["choice"] == min(scores, key=scores.get)
    as_data = record["choice"] == "data"
    assert ("prior_as_data" in attrs) == as_data  # the chosen reading is the one applied
    assert attrs["mean_function"].startswith("ConstantMean") == as_data
    assert "prior DEM read as (auto)" in r.output
    from toolkit.report import write_report  # the HTML certificate (it needs no checkpoints)

    html = write_report(
        tmp_path / "report.html", product=out / "product.nc", certificate=out / "certificate.json"
    ).read_text()
    assert 'id="prior-reading"' in html and f"Read as <b>{record['choice']}</b>" in html


def test_too_few_samples_to_hold_out_leave_the_mean_and_say_why():
    # Four samples cannot fill five folds' blocks: the choice falls back to the default
    # reading (the mean) with the reason, rather than failing the run.
    from toolkit.config import load_scenario
    from toolkit.prior_reading import choose_reading

    dem, s = _dem("white"), _survey()
    few = s.subset(np.isin(np.arange(s.n), [0, 150, 400, 600]))
    why = choose_reading(dem, RasterMean(dem), few, _grid(8.0), load_scenario(None), 0)
    assert isinstance(why, str) and "read as the mean" in why and "4 samples for 5" in why
