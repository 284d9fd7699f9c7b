"""A satellite DEM's cells as samples of the ground (``terrain.dem_as_data``,
``glacimap reconstruct --prior-as data``).

References: a DEM made here from a plane (so a cell's value is the plane at its centre) plus
a known datum offset and seeded white noise; its cell centres counted and placed by hand,
and projected from EPSG:4326 by ``pyproj`` directly; the offset and noise recovered within
their sampling error.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from _rasters import write_geotiff
from pyproj import Transformer
from typer.testing import CliRunner

from terrain import ElevationSamples, Grid, InputError
from terrain.dem_as_data import dem_as_data
from toolkit.cli import app

UTM = "EPSG:32608"
W0, N0 = 500_000.0, 6_600_300.0
runner = CliRunner()


def _plane(x, y):
    return 1000.0 + 0.04 * (x - W0) - 0.03 * (y - N0)


def _dem(offset=2.0, noise=0.5, cell=30.0, n=12, seed=0):
    g = Grid(W0 - 30.0, N0 + 30.0, (cell, cell), (n, n), UTM)
    xx, yy = np.meshgrid(g.x, g.y)
    v = _plane(xx, yy) + offset + np.random.default_rng(seed).normal(0.0, noise, g.shape)
    return g, g.data_array(v, "elevation")


def _survey(n=3000, seed=1):
    rng = np.random.default_rng(seed)
    xy = rng.uniform([W0, N0 - 300.0], [W0 + 300.0, N0], (n, 2))
    return ElevationSamples(xy, _plane(*xy.T) + rng.normal(0, 0.02, n), 0.02**2, crs=UTM)


def test_cells_become_samples_with_the_offset_and_noise_measured_on_the_survey():
    g, dem = _dem()
    s = _survey()
    bounds = (W0, N0 - 300.0, W0 + 300.0, N0)
    out, rec = dem_as_data(dem, s, bounds)
    # cell centres at W0 - 15 + 30 k: 10 columns and 10 rows fall inside the 300 m square
    assert rec.n_cells == 100 and rec.n_nodata == 0 and rec.n_compared == s.n
    assert out.n == s.n + 100
    np.testing.assert_allclose(out.xy[: s.n], s.xy)
    np.testing.assert_allclose(out.z[: s.n], s.z)
    # a plane's cell value is the plane at its centre: the survey sees a + noise + the
    # plane's change across a cell (sd 0.05 * 30 / sqrt(12) per axis)
    assert rec.offset_m == pytest.approx(2.0, abs=0.1)
    within = np.hypot(0.04, 0.03) * 30.0 / np.sqrt(12.0)
    assert rec.sd_m == pytest.approx(np.hypot(0.5, within), rel=0.15)
    cx, cy = out.xy[s.n :].T
    np.testing.assert_allclose(np.sort(np.unique(cx)), W0 + 15.0 + 30.0 * np.arange(10))
    # a cell sample is the DEM minus the offset: the plane plus that cell's noise
    np.testing.assert_allclose(out.z[s.n :] - _plane(cx, cy), 2.0 - rec.offset_m, atol=2.0)
    np.testing.assert_allclose(out.z_var[s.n :], rec.sd_m**2)
    assert "100 cells as samples" in rec.note()


def test_a_dem_in_degrees_is_read_on_its_own_cells_and_nodata_counted():
    to_ll = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True)
    lon0, lat0 = to_ll.transform(W0 - 50.0, N0 + 50.0)
    step = 1 / 3600
    lon = lon0 + (np.arange(30) + 0.5) * step
    lat = lat0 - (np.arange(20) + 0.5) * step
    LL, LA = np.meshgrid(lon, lat)
    x, y = Transformer.from_crs("EPSG:4326", UTM, always_xy=True).transform(LL, LA)
    v = _plane(x, y) - 3.0
    v[:3, :3] = np.nan  # a hole
    dem = xr.DataArray(v, dims=("y", "x"), coords={"y": lat, "x": lon}, attrs={"crs": "EPSG:4326"})
    s = _survey(800)
    bounds = (W0, N0 - 300.0, W0 + 300.0, N0)
    out, rec = dem_as_data(dem, s, bounds)
    inside = (x >= W0) & (x <= W0 + 300) & (y >= N0 - 300) & (y <= N0)
    assert rec.n_cells == int((inside & np.isfinite(v)).sum())
    assert rec.n_nodata == int((inside & ~np.isfinite(v)).sum())
    got = out.xy[s.n :]
    want = np.column_stack([x[inside & np.isfinite(v)], y[inside & np.isfinite(v)]])
    np.testing.assert_allclose(np.sort(got, axis=0), np.sort(want, axis=0), atol=1e-6)
    assert rec.offset_m == pytest.approx(-3.0, abs=0.1)


def test_a_dem_away_from_the_survey_is_an_error():
    g, dem = _dem()
    far = ElevationSamples(
        np.array([[W0 + 5000.0, N0], [W0 + 5010.0, N0]]), [1.0, 2.0], 0.0, crs=UTM
    )
    with pytest.raises(InputError, match="prior DEM.*under the survey"):
        dem_as_data(dem, far, (W0, N0 - 300.0, W0 + 300.0, N0))


def test_cli_prior_as_data(tmp_path):
    g, dem = _dem(n=14)
    tif = write_geotiff(dem, tmp_path / "dem.tif")
    s = _survey(600)
    csv = tmp_path / "s.csv"
    pd.DataFrame({"x": s.xy[:, 0], "y": s.xy[:, 1], "z": s.z, "crs": UTM}).to_csv(csv, index=False)
    r = runner.invoke(
        app, ["reconstruct", str(csv), "--prior-as", "data", "--out", str(tmp_path / "a")]
    )
    assert isinstance(r.exception, InputError) and "--prior-as" in str(r.exception)
    assert not (tmp_path / "a").exists()
    r = runner.invoke(
        app, ["reconstruct", str(csv), "--prior", str(tif), "--prior-as", "data", "--resolution",
              "10", "--out", str(tmp_path / "m")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    ds = xr.open_dataset(tmp_path / "m" / "product.nc")
    assert "cells as samples" in ds.attrs["prior_as_data"]
    assert ds.attrs["mean_function"].startswith("ConstantMean")
    xx, yy = np.meshgrid(ds["x"].values, ds["y"].values)
    err = ds["elevation"].values - _plane(xx, yy)
    assert float(np.sqrt(np.mean(err**2))) < 0.5  # the survey's plane, not the DEM's +2 m
    summary = json.loads((tmp_path / "m" / "reconstruct_summary.json").read_text())
    n_cells = int(re.search(r"(\d+) cells as samples", ds.attrs["prior_as_data"]).group(1))
    assert summary["samples"] == 600 + n_cells and n_cells >= 81  # the cells inside the map


def test_process_reads_the_prior_as_data_from_the_option_or_the_settings(tmp_path):
    # The example field folder (the default site's corner, EPSG:32608) with a 10 m prior DEM
    # of its truth + 1.5 m datum offset + 0.3 m noise per cell: the cells join the landmarks
    # (their offset measured near +1.5 m), the mean is constant, and the certificate says so.
    # "data" without a DEM, or an unknown value, is refused before any work.
    from pathlib import Path

    from toolkit.config import load_scenario
    from toolkit.field_survey import simulated_prior
    from toolkit.pipeline import make_site

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    truth = make_site(load_scenario(example / "scenario.toml"))
    dem = simulated_prior(truth, 10.0, 1.5, 0.3, np.random.default_rng(0))
    tif = tmp_path / "dem.tif"
    write_geotiff(dem, tif)
    never = tmp_path / "never"
    for args in (["--prior-as", "data"], ["--prior", str(tif), "--prior-as", "dem"]):
        r = runner.invoke(app, ["process", str(example), *args, "--out", str(never)])
        assert isinstance(r.exception, InputError) and "--prior-as" in str(r.exception)
    cfg = tmp_path / "as_data.toml"
    cfg.write_text('[prior]\nas = "data"\n')
    r = runner.invoke(app, ["process", str(example), "--config", str(cfg), "--out", str(never)])
    assert isinstance(r.exception, InputError) and "[prior] as" in str(r.exception)
    assert not never.exists()
    out = tmp_path / "out"
    r = runner.invoke(
        app, ["process", str(example), "--prior", str(tif), "--config", str(cfg), "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    attrs = xr.open_dataset(out / "product.nc").attrs
    assert attrs["mean_function"].startswith("ConstantMean")
    offset = float(re.search(r"datum offset ([+-][\d.]+) m", attrs["prior_as_data"]).group(1))
    assert abs(offset - 1.5) < 0.5  # the landmarks carry the survey's own GPS offset too
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["reconstruction"]["prior_as_data"] == attrs["prior_as_data"]
    assert "prior DEM" in r.output and "cells as samples" in r.output
