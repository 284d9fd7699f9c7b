"""The real-terrain benchmark's options of session 21: ``--noise-sd`` (the survey's
signal-to-noise ratio, drawn into the samples and stated in their ``z_var``) and ``--survey
west-half`` (the rover only in the west half; the cells far from every sample scored apart);
of session 34: ``--tracks`` and ``--scattered`` (the survey's shape).

Reference: the noise is ``track_samples``' N(0, sd^2) on top of the truth it stores in
``extra["true_z"]``; 3,000 draws estimate sd to ~1.3 % (sd / sqrt(2 n)), so the checks below
allow 5 %. Far cells: distances checked against a brute-force minimum over the samples.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def real_terrain():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    sys.path.insert(0, str(ROOT / "scripts"))
    import real_terrain

    return real_terrain


@pytest.mark.parametrize("sd", [0.05, 0.5])
def test_the_samples_carry_the_noise_asked_for(real_terrain, sd):
    site = dict(real_terrain.parse_site("jacksboro"), noise_sd=sd)  # matplotlib's DEM
    _, _, samples = real_terrain._data(site, 3000)
    err = samples.z - samples.extra["true_z"]
    assert np.std(err) == pytest.approx(sd, rel=0.05)
    assert np.all(samples.z_var == pytest.approx(sd**2))


def test_the_default_is_every_earlier_result(real_terrain):
    _, _, samples = real_terrain._data(real_terrain.parse_site("jacksboro"), 3000)
    assert real_terrain.NOISE_SD == 0.2
    assert np.all(samples.z_var == pytest.approx(0.04))


def test_the_option_is_recorded_in_the_results(real_terrain, tmp_path):
    out = tmp_path / "r.json"
    real_terrain.main(
        ["--sites", "jacksboro", "--sizes", "3000", "--methods", "delaunay", "--noise-sd", "0.1"]
        + ["--tracks", "6", "--scattered", "0.05", "--out", str(out)]
    )
    payload = json.loads(out.read_text())
    assert payload["results"][0]["rmse_hull"] > 0.0
    settings = payload["settings"]
    assert settings["noise_sd_m"] == 0.1
    assert settings["sites"][0]["noise_sd"] == 0.1
    assert (settings["tracks"], settings["scattered"]) == (6, 0.05)
    assert (settings["sites"][0]["tracks"], settings["sites"][0]["scattered"]) == (6, 0.05)


def test_the_survey_shape_options_reach_the_samples(real_terrain):
    """``track_samples`` puts round(scattered * n) samples uniformly over the site, the rest
    within a few lateral_sd (8 m) + 6 m of its wavy track lines: with 4 tracks on 600 m the
    lines are 150 m apart, so no track sample lies 40 m or more from every line centre."""
    site = dict(real_terrain.parse_site("jacksboro"), tracks=4, scattered=0.02)
    truth, grid, samples = real_terrain._data(site, 3000)
    w, _, e, _ = grid.bounds
    centres = w + (e - w) / 4 * (np.arange(4) + 0.5)
    off = np.min(np.abs(samples.xy[:, 0, None] - centres[None, :]), axis=1)
    assert np.sum(off >= 40.0) <= 60  # only the 60 scattered ones can be that far
    _, _, default = real_terrain._data(real_terrain.parse_site("jacksboro"), 3000)
    assert (real_terrain.TRACKS, real_terrain.SCATTERED) == (8, 0.1)
    d_centres = w + (e - w) / 8 * (np.arange(8) + 0.5)
    d_off = np.min(np.abs(default.xy[:, 0, None] - d_centres[None, :]), axis=1)
    assert np.sum(d_off >= 20.0) > 100  # 300 scattered: many between the 8 lines


@pytest.mark.parametrize(("option", "value"), [("--tracks", "0"), ("--scattered", "1.5")])
def test_a_survey_shape_out_of_range_is_refused(real_terrain, tmp_path, capsys, option, value):
    out = tmp_path / "r.json"
    with pytest.raises(SystemExit):
        real_terrain.main(["--sites", "jacksboro", option, value, "--out", str(out)])
    assert option in capsys.readouterr().err
    assert not out.exists()


def test_a_west_half_survey_keeps_the_west_samples_only(real_terrain):
    site = dict(real_terrain.parse_site("jacksboro"), survey="west-half")
    truth, grid, samples = real_terrain._data(site, 3000)
    _, _, whole = real_terrain._data(real_terrain.parse_site("jacksboro"), 3000)
    mid = grid.xy()[:, 0].mean()
    assert np.all(samples.xy[:, 0] < mid)
    assert samples.n == int(np.sum(whole.xy[:, 0] < mid))  # none lost beside the cut


def test_far_cells_are_those_beyond_far_m_of_every_sample(real_terrain):
    site = dict(real_terrain.parse_site("jacksboro"), survey="west-half")
    truth, grid, samples = real_terrain._data(site, 3000)
    pred = truth.values + 0.5  # a map 0.5 m high everywhere, sigma 0.4 m: |z| = 1.25
    std = np.full(grid.shape, 0.4)
    m = real_terrain._metrics(pred, std, truth, samples, grid)
    q = grid.xy()
    d = np.array([np.min(np.hypot(*(samples.xy - p).T)) for p in q[::97]])
    far_share = np.mean(d >= real_terrain.FAR_M)  # every 97th cell, brute force
    assert m["far_fraction"] == pytest.approx(far_share, abs=0.02)
    assert 0.3 < m["far_fraction"] < 0.5  # the east half, less 50 m
    assert m["rmse_far"] == pytest.approx(0.5)
    assert m["cov68_far"] == 0.0 and m["cov95_far"] == 100.0
    whole = real_terrain._data(real_terrain.parse_site("jacksboro"), 3000)[2]
    assert real_terrain._metrics(pred, std, truth, whole, grid)["rmse_far"] is None


def test_the_rescaled_coverage_is_the_truths_under_sigma_times_sqrt_kappa(real_terrain):
    # Hand computation: errors N(0, 0.5^2) against a stated 1-sigma of 1 m read 95.4 % at
    # 68 (P(|z| < 2)); kappa = 0.25 rescales the sigma to 0.5 m, the errors' own, so the
    # coverages become the normal's 68.3 and 95.0 % (to ~0.3 points with 200,000 cells).
    rng = np.random.default_rng(0)
    truth = np.zeros((400, 500))
    pred = rng.normal(0.0, 0.5, truth.shape)
    std = np.ones_like(truth)
    pred[0, :10] = np.nan  # undefined cells are left out, as in the benchmark's coverages
    out = real_terrain.rescaled_coverage(pred, std, truth, 0.25)
    assert out["cov68_rescaled"] == pytest.approx(68.27, abs=0.4)
    assert out["cov95_rescaled"] == pytest.approx(95.0, abs=0.3)
    assert real_terrain.rescaled_coverage(pred, std, truth, 1.0)["cov68_rescaled"] > 95.0
    assert real_terrain.rescaled_coverage(pred, std, truth, None) == {}


def test_the_rescaled_verdict_needs_both_levels_in_band(real_terrain):
    row = {"cov68_rescaled": 70.0, "cov95_rescaled": 95.0}
    assert real_terrain._rescaled_verdict(row)["rescaled_ok"] == "PASS"
    assert real_terrain._rescaled_verdict({**row, "cov95_rescaled": 91.0})["rescaled_ok"] == "MISS"
    assert real_terrain._rescaled_verdict({**row, "cov68_rescaled": 77.0})["rescaled_ok"] == "MISS"
    assert real_terrain._rescaled_verdict({}) == {}


def _write_dem(path: Path, da, *, south_up: bool = False, nodata_cells: int = 0) -> Path:
    """``da`` (north-up, cell centres) as a GeoTIFF with rasterio; rows stored south -> north
    (a positive y pixel size) when ``south_up``; the first ``nodata_cells`` cells of the last
    row set to nodata."""
    import rasterio
    from rasterio.transform import Affine

    z = np.asarray(da.values, float).copy()
    dx = float(da.x[1] - da.x[0])
    dy = float(da.y[0] - da.y[1])
    west, north = float(da.x[0]) - dx / 2, float(da.y[0]) + dy / 2
    z[-1, :nodata_cells] = -9999.0
    if south_up:
        z, t = z[::-1], Affine(dx, 0.0, west, 0.0, dy, north - dy * z.shape[0])
    else:
        t = Affine(dx, 0.0, west, 0.0, -dy, north)
    profile = dict(driver="GTiff", width=z.shape[1], height=z.shape[0], count=1)
    with rasterio.open(path, "w", **profile, dtype="float64", transform=t, nodata=-9999.0) as ds:
        ds.write(z, 1)
    return path


@pytest.mark.parametrize("south_up", [False, True])
def test_a_dem_file_of_ones_own_makes_the_same_site_as_the_named_dem(
    real_terrain, tmp_path, south_up
):
    # Reference: the named DEM (matplotlib's jacksboro) written to a GeoTIFF and read back
    # by rasterio gives the same site, bit for bit, whichever way its rows are stored; the
    # nodata cells of the file's southern row are NaN and the windows keep clear of them.
    import real_dems

    dem = real_dems.load("jacksboro")
    path = _write_dem(tmp_path / "my dem.tif", dem, south_up=south_up, nodata_cells=5)
    read = real_dems.load_file(path)
    np.testing.assert_allclose(read.y.values, dem.y.values, rtol=0, atol=1e-9)  # degrees
    assert np.isnan(read.values[-1, :5]).all()
    np.testing.assert_array_equal(read.values[:-1], dem.values[:-1])
    site = real_terrain.parse_site(f"{path}:1:30")
    assert (site["label"], site["window"], site["nodes"]) == ("my dem:1:30", 1, 30)
    mine = real_dems.glacier_site(site["name"], window=1, nodes=30)
    named = real_dems.glacier_site("jacksboro", window=1, nodes=30)
    np.testing.assert_array_equal(mine.values, named.values)
    assert "my dem.tif" in mine.attrs["source"]


def test_a_site_that_is_no_dem_is_refused_by_name(real_terrain, tmp_path):
    import argparse

    with pytest.raises(argparse.ArgumentTypeError, match="neither a real DEM"):
        real_terrain.parse_site(str(tmp_path / "missing.tif"))
    with pytest.raises(argparse.ArgumentTypeError, match="integers"):
        real_terrain.parse_site("olinda:first")


def test_the_ground_features_are_what_they_say(real_terrain):
    # Reference: hand computation on the site's own grid. The scarp is a logistic step of
    # 24 % of the relief: 6 m on the 25 m site, half of it on its line, and the tracks cross
    # it (east-west); the lake is flat at the 35th percentile over 35 % of the cells; the
    # terraces never rise more than 30 % of a 2.5 m bench between two cells on one bench.
    import real_dems

    site = real_terrain.parse_site("jacksboro")
    plain = real_dems.glacier_site("jacksboro")
    assert real_terrain._data(site, 300)[0].equals(plain)  # "none": every earlier result
    scarp = real_terrain._data(dict(site, feature="scarp"), 300)[0]
    step = scarp.values - plain.values
    assert step.max() == pytest.approx(6.0, abs=1e-3) and step.min() == pytest.approx(0, abs=1e-3)
    x = plain.x.values - plain.x.values.mean()
    y = plain.y.values - plain.y.values.mean()
    col, row = np.argmin(np.abs(x)), np.argmin(np.abs(y))  # the cells nearest the centre
    across = y[row] - 40.0 * np.sin(x[col] / 90.0)  # the line's own formula, by hand
    assert step[row, col] == pytest.approx(6.0 / (1.0 + np.exp(-across / 1.5)), abs=1e-3)
    assert np.all(np.diff(step[::-1, col]) >= -1e-12)  # rising northward along a track
    along = real_dems.add_feature(plain, "scarp-along").values - plain.values
    assert np.all(np.diff(along[np.argmin(np.abs(y))]) >= -1e-12)  # rising eastward
    lake = real_dems.add_feature(plain, "lake").values
    level = np.percentile(plain.values, 35.0)
    assert lake.min() == level and np.mean(lake == level) == pytest.approx(0.35, abs=0.005)
    terr = real_dems.add_feature(plain, "terraces")
    bench = np.floor((terr.values - terr.values.min()) / 2.5 + 1e-9)
    same = bench[:, 1:] == bench[:, :-1]
    assert np.abs(np.diff(terr.values, axis=1))[same].max() <= 0.3 * 2.5 + 1e-9
    assert "feature terraces" in terr.attrs["source"]
    with pytest.raises(ValueError, match="feature"):
        real_dems.add_feature(plain, "crevasse")
