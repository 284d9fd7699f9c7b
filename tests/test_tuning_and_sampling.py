import numpy as np
import pytest

from terrain import ElevationSamples, Grid, InputError, tune_paper_grid
from terrain.gp import TerrainGP
from terrain.kernels import SquaredExponential
from terrain.metrics import rmse
from terrain.sampling import LandmarkNoise, sample_along_path, sample_dem
from terrain.synthetic import random_terrain


@pytest.fixture(scope="module")
def site():
    grid = Grid.from_bounds((0, 0, 200, 200), 4.0)
    return random_terrain(grid, relief=10.0, seed=3)


def test_paper_grid_search_picks_the_brute_force_minimum(site):
    rng = np.random.default_rng(0)
    xy = rng.uniform(10, 190, (150, 2))
    samples = ElevationSamples(xy, sample_dem(site, xy), 0.01)
    alphas, gammas = [1.0, 10.0], [100.0, 315.0, 3000.0]
    res = tune_paper_grid(samples, site, alphas, gammas, reading="squared_lengthscale")
    # Brute force, written independently: the same RMSE for every pair.
    table = np.array(
        [
            [
                rmse(
                    TerrainGP(
                        SquaredExponential(a, np.sqrt(g)),
                        nugget=0.0,
                        nugget_bounds="fixed",
                        optimize=False,
                    )
                    .fit(samples)
                    .predict(Grid.from_dataarray(site).xy()),
                    site.values.ravel(),
                )
                for g in gammas
            ]
            for a in alphas
        ]
    )
    np.testing.assert_allclose(res.rmse_table, table, rtol=1e-10)
    i, j = np.unravel_index(np.argmin(table), table.shape)
    assert (res.alpha, res.gamma) == (alphas[i], gammas[j])
    assert res.kernel.lengthscale == pytest.approx(np.sqrt(gammas[j]))


def test_sample_dem_is_bilinear_and_rejects_outside(site):
    grid = Grid.from_dataarray(site)
    # At a cell centre the bilinear value is the cell value itself.
    np.testing.assert_allclose(sample_dem(site, grid.xy()[:50]), site.values.ravel()[:50])
    with pytest.raises(InputError, match="outside"):
        sample_dem(site, np.array([[-50.0, 10.0]]))


def test_path_samples_respect_ranges_and_noise(site):
    noise = LandmarkNoise(min_range=5.0, max_range=30.0)
    path = np.array([[20.0, 100.0], [180.0, 100.0]])
    s, rejected = sample_along_path(site, path, 500, noise=noise, seed=1)
    d = np.abs(s.xy[:, 1] - 100.0)  # distance from the straight path
    assert s.n == 500 and rejected >= 0
    assert d.min() >= 5.0 - 1e-9 and d.max() <= 30.0 + 1e-9
    np.testing.assert_allclose(s.extra["range_m"], d, atol=1e-9)
    zscore = (s.z - s.extra["true_z"]) / np.sqrt(s.z_var)
    assert abs(zscore.mean()) < 0.15 and 0.9 < zscore.std() < 1.1
    s2, _ = sample_along_path(site, path, 500, noise=noise, seed=1)
    np.testing.assert_array_equal(s.z, s2.z)  # seeded: bit-identical
