"""Issue 3's "must show" numbers at full size (slow): 50,000 landmarks on the default site,
600 x 600 cells at 1 m, against the synthetic truth — what benchmarks/gp_scalable.py reports.

Only the targets that hold are asserted; the ones that do not are documented with their
numbers in docs/terrain.md (Calibration)."""

import numpy as np
import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def site():
    from terrain import (
        Grid,
        SquaredExponential,
        TerrainGP,
        TriangulatedMean,
        coarse_dem,
        default_site,
        sample_along_path,
    )
    from toolkit.demo import demo_path

    truth = default_site(1.0)
    grid = Grid.from_dataarray(truth)
    samples, _ = sample_along_path(truth, demo_path(grid, 4), 50_000, seed=0)
    prior = TriangulatedMean(coarse_dem(truth))
    maps = {}
    for amp in (False, True):
        gp = TerrainGP(
            SquaredExponential(0.18, 15.0),
            mean=prior,
            n_restarts=0,
            max_fit_samples=1000,
            local_amplitude=amp,
        ).fit(samples)
        ds = gp.predict_grid(grid)
        maps[amp] = (ds.elevation.values, ds.elevation_std.values)
    return truth.values, grid, samples, maps


def test_rmse_beats_delaunay_by_40_percent(site):
    from scipy.interpolate import LinearNDInterpolator

    truth, grid, samples, maps = site
    off = samples.xy.mean(axis=0)
    dl = LinearNDInterpolator(samples.xy - off, samples.z)(grid.xy() - off).reshape(grid.shape)
    hull = np.isfinite(dl)

    def rmse(m):
        return np.sqrt(np.mean((m[hull] - truth[hull]) ** 2))

    for amp, (mean, _) in maps.items():
        assert rmse(mean) <= 0.6 * rmse(dl), amp  # measured 0.589 / 0.588


def test_95_percent_intervals_and_local_amplitude_gain(site):
    from terrain import evaluate

    truth, _, _, maps = site
    plain = evaluate(maps[False][0], truth, maps[False][1])
    local = evaluate(maps[True][0], truth, maps[True][1])
    for s in (plain, local):
        assert 0.93 <= s["coverage_95"] <= 0.97  # measured 0.960 / 0.960
    # The local amplitude narrows the over-covered 68 % band, shrinks the z spread that the
    # crevasse walls blow up, and improves the log density (measured 0.728 -> 0.721,
    # 1.30 -> 1.08, NLPD -0.81 -> -1.11) without costing RMSE.
    assert local["coverage_68"] < plain["coverage_68"]
    assert abs(local["z_std"] - 1) < abs(plain["z_std"] - 1)
    assert local["nlpd"] < plain["nlpd"] - 0.1
    assert local["rmse"] <= plain["rmse"] * 1.005
