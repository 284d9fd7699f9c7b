"""Noise the samples do not state, estimated from the dense windows (session 46).

A DSM's cells or a dense survey without a variance column: the nugget is the noise, and the
2,000-sample fit subset, 13 m apart, cannot tell 0.05 m of noise from ground at its spacing
(0.44.0 fitted 2.7e-3 to 6.6e-3 m² on this site over four seeds, 3.6e-6 to 2.4e-2 m² on
real DEMs' DSMs, for 2.5e-3). The windows of left-out samples measure it
(terrain/unstated_noise.py); origin of the reference value: the noise drawn here.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from terrain import ElevationSamples, Grid, TerrainGP, random_terrain
from terrain.unstated_noise import unstated_noise, window_noise

NOISE_SD = 0.05  # m: the noise drawn below, the reference value


@pytest.fixture(scope="module")
def dense():
    grid = Grid(0.0, 300.0, 2.0, (150, 150), crs="EPSG:32608")
    truth = random_terrain(grid, relief=25.0, seed=4, features=True)
    xy = grid.xy()
    z = truth.values.ravel() + np.random.default_rng(1).normal(0.0, NOISE_SD, xy.shape[0])
    return xy, z


@pytest.mark.parametrize("seed", [0, 2])
def test_the_nugget_of_a_dense_survey_without_stated_noise_is_its_noise(dense, seed):
    xy, z = dense
    gp = TerrainGP(seed=seed).fit(ElevationSamples(xy, z, 0.0, crs="EPSG:32608"))
    assert 0.7 * NOISE_SD**2 <= gp.nugget_ <= 1.4 * NOISE_SD**2
    est = gp.noise_estimate_
    assert est["nugget"] == gp.nugget_  # held in the family's refit
    assert est["evaluations"] >= 3 and 0 < est["samples_scored"] <= 8_000
    # the subset's own nugget and kernel are kept beside it, and reach the product
    assert est["subset_nugget"] > 0 and est["subset_kernel"].startswith(("Matern", "Squared"))
    assert json.loads(gp.provenance()["noise_estimate"])["nugget"] == gp.nugget_


def test_stated_noise_is_not_re_estimated(dense):
    xy, z = dense
    gp = TerrainGP(seed=0).fit(ElevationSamples(xy, z, NOISE_SD**2, crs="EPSG:32608"))
    assert gp.noise_estimate_ is None
    assert gp.provenance()["noise_estimate"] == ""


def test_when_it_applies():
    class Plan:  # stands in for a WindowPlan: only its presence matters here
        pass

    assert unstated_noise(np.zeros(5), Plan(), True)
    assert not unstated_noise(np.zeros(5), None, True)  # no windows: nothing to measure
    assert not unstated_noise(np.zeros(5), Plan(), False)  # nugget held by the user
    assert not unstated_noise(np.array([0.0, 0.01, 0, 0, 0]), Plan(), True)  # one states


def test_window_noise_finds_the_noise_of_white_windows():
    """Windows of pure noise with a negligible kernel: the estimate is their variance
    (hand check: the MLE of a variance is the mean square, within the search's 2 %)."""
    from terrain.kernels import SquaredExponential
    from terrain.window_evidence import WindowPlan

    rng = np.random.default_rng(0)
    r = [rng.normal(0.0, 0.1, 400) for _ in range(4)]
    X = [rng.uniform(-10, 10, (400, 2)) for _ in range(4)]
    plan = WindowPlan(X, r, [np.zeros(400)] * 4, 20.0, 1600, 0, 0, 0)
    est = window_noise(plan, SquaredExponential(1e-12, 5.0), (1e-6, 1.0))
    mle = float(np.mean(np.concatenate(r) ** 2))
    assert est["nugget"] == pytest.approx(mle, rel=0.03)
    assert est["windows"] == 4 and est["samples_scored"] == 1600


def test_reconstruct_states_the_noise_a_dsm_does_not(tmp_path, dense):
    """A DSM's cells state no noise: ``glacimap reconstruct`` measures it, says so, and
    records it in the product."""
    import rasterio
    import xarray as xr
    from rasterio.transform import from_origin
    from typer.testing import CliRunner

    from toolkit.cli import app

    _, z = dense
    band = z.reshape(150, 150)[:100, :100].astype("float32")  # 10,000 cells of 2 m
    dsm = tmp_path / "dsm.tif"
    profile = dict(driver="GTiff", width=100, height=100, count=1, dtype="float32",
                   crs="EPSG:32608", transform=from_origin(0.0, 300.0, 2.0, 2.0))  # fmt: skip
    with rasterio.open(dsm, "w", **profile) as ds:
        ds.write(band, 1)
    out = tmp_path / "map"
    res = CliRunner().invoke(app, ["reconstruct", str(dsm), "--resolution", "4", "--out", str(out)])
    assert res.exit_code == 0, res.output
    noise = json.loads(xr.open_dataset(out / "product.nc").attrs["noise_estimate"])
    assert 0.7 * NOISE_SD**2 <= noise["nugget"] <= 1.4 * NOISE_SD**2
    text = " ".join(res.output.split())
    assert "noise, stated by none" in text
