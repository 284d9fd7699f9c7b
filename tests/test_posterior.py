"""Bayesian hyperparameters with emcee: recovery, seeding, diagnostics, mixture maps."""

import warnings

import numpy as np
import pytest

from terrain import ElevationSamples, Grid, InputError, Matern, coarse_dem, random_terrain
from terrain.posterior import (
    HyperPosterior,
    ShortChainWarning,
    mixture_mean_std,
    sample_hyperparameters,
)

TRUE_VARIANCE, TRUE_LENGTHSCALE, NOISE_SD = 4.0, 80.0, 0.1  # m^2, m, m


def _gp_samples(n=150, seed=1, kernel=None, side=300.0):
    """``n`` noisy draws of a known zero-mean Matern GP at uniform random points."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, side, (n, 2))
    kernel = kernel or Matern(TRUE_VARIANCE, TRUE_LENGTHSCALE, nu=2.5)
    f = np.linalg.cholesky(kernel(xy) + 1e-8 * np.eye(n)) @ rng.normal(size=n)
    return xy, f + rng.normal(0.0, NOISE_SD, n)


def _quiet_sample(*args, **kwargs) -> HyperPosterior:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ShortChainWarning)
        return sample_hyperparameters(*args, **kwargs)


@pytest.fixture(scope="module")
def recovered():
    xy, z = _gp_samples()
    samples = ElevationSamples(xy, z + 50.0, NOISE_SD**2)
    post = _quiet_sample(samples, Matern(1.0, 20.0, nu=2.5), n_walkers=16, n_steps=700, seed=0)
    return samples, post


def test_posterior_recovers_known_kernel(recovered):
    _, post = recovered
    assert post.param_names == ["variance", "lengthscale", "nugget", "offset"]
    assert post.chain.shape == (700 - 175, 16, 4)
    flat = post.natural(post.chain.reshape(-1, 4))
    for i, truth in ((0, TRUE_VARIANCE), (1, TRUE_LENGTHSCALE)):
        lo, med, hi = np.percentile(flat[:, i], [2.5, 50, 97.5])
        assert truth / 2 < med < truth * 2, (post.param_names[i], med)
        assert lo < truth < hi, (post.param_names[i], lo, hi)
    summary = post.summary()
    assert set(summary["parameters"]) == set(post.param_names)
    assert summary["ess"] > 100 and 0.1 < summary["acceptance_fraction"] < 0.9
    assert np.all(post.tau > 0) and post.ess == pytest.approx(16 * 525 / post.tau.max())


def test_same_seed_same_chain_other_seed_other_chain():
    xy, z = _gp_samples(n=60, seed=3)
    samples = ElevationSamples(xy, z, 0.01)
    kernel = Matern(1.0, 30.0, nu=2.5)
    a, b, c = (_quiet_sample(samples, kernel, n_walkers=10, n_steps=40, seed=s) for s in (7, 7, 8))
    np.testing.assert_array_equal(a.chain, b.chain)
    np.testing.assert_array_equal(a.log_prob, b.log_prob)
    assert not np.array_equal(a.chain, c.chain)


def test_short_chain_warns():
    xy, z = _gp_samples(n=60, seed=4)
    with pytest.warns(ShortChainWarning, match="n_steps >="):
        sample_hyperparameters(
            ElevationSamples(xy, z, 0.01), Matern(1.0, 30.0, nu=2.5), n_walkers=10, n_steps=30
        )


def test_mixture_law_of_total_variance_by_hand():
    mean, std = mixture_mean_std(np.array([[1.0, 0.0], [3.0, 0.0]]), np.array([[1.0, 2.0]] * 2))
    np.testing.assert_allclose(mean, [2.0, 0.0])
    # E[var] = (1 + 1) / 2 = 1 and Var[mean] = ((1 - 2)^2 + (3 - 2)^2) / 2 = 1 -> sqrt(2)
    np.testing.assert_allclose(std, [np.sqrt(2.0), 2.0])


def test_predict_grid_is_the_mixture_of_its_draws(recovered):
    samples, post = recovered
    grid = Grid.from_bounds((0.0, 0.0, 300.0, 300.0), 30.0)
    ds = post.predict_grid(samples, grid, n_draws=2)
    assert ds.attrs["method"] == "posterior-averaged GP (emcee)" and ds.attrs["n_draws"] == 2
    parts = [post.gp(t, samples).predict_grid(grid) for t in post.draws(2, post.seed)]
    m = [p["elevation"].values for p in parts]
    v = [p["elevation_std"].values ** 2 for p in parts]
    hand_mean = (m[0] + m[1]) / 2
    hand_std = np.sqrt((v[0] + v[1]) / 2 + ((m[0] - m[1]) / 2) ** 2)
    np.testing.assert_allclose(ds["elevation"].values, hand_mean)
    np.testing.assert_allclose(ds["elevation_std"].values, hand_std)


def test_offset_and_scale_of_a_dem_prior_are_recovered():
    grid = Grid.from_bounds((0.0, 0.0, 400.0, 400.0), 10.0)
    coarse = coarse_dem(random_terrain(grid, relief=30.0, seed=5), cells=(8, 8))
    xy, f = _gp_samples(n=150, seed=6, kernel=Matern(0.25, 40.0, nu=2.5), side=400.0)
    xy = np.clip(xy, 5.0, 395.0)
    from terrain.prior import TriangulatedMean

    z = 3.0 + 0.5 * TriangulatedMean(coarse)(xy) + f
    post = _quiet_sample(
        ElevationSamples(xy, z, NOISE_SD**2, crs=grid.crs),
        Matern(1.0, 30.0, nu=2.5),
        coarse,
        n_walkers=16,
        n_steps=500,
        seed=0,
    )
    assert post.param_names[-2:] == ["offset", "scale"]
    flat = post.chain.reshape(-1, 5)
    for i, truth in ((3, 3.0), (4, 0.5)):
        lo, hi = np.percentile(flat[:, i], [2.5, 97.5])
        assert lo < truth < hi, (post.param_names[i], lo, hi)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"n_walkers": 6}, "n_walkers"),
        ({"n_steps": 0}, "n_steps"),
        ({"priors": {"ls": (0, 1)}}, "priors"),
    ],
)
def test_bad_input_names_the_field(kwargs, field):
    xy, z = _gp_samples(n=20, seed=2)
    with pytest.raises(InputError, match=field):
        sample_hyperparameters(ElevationSamples(xy, z, 0.01), Matern(1.0, 30.0), **kwargs)
