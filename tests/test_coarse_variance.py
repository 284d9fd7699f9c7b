"""Exact mean + lattice variance: the route ``predict_grid`` takes for big exact-GP grids."""

import numpy as np
import pytest

from terrain import ElevationSamples, Grid, SquaredExponential, TerrainGP
from terrain.coarse_variance import coarse_step, predict_coarse_variance, variance_step


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(3)
    grid = Grid.from_bounds((0, 0, 240, 180), 1.0)
    # Rover-like data: 6 tracks plus scattered points, so the variance has dips and gaps.
    t = rng.uniform(0, 240, 900)
    tracks = np.column_stack([t, np.repeat(np.linspace(15, 165, 6), 150)])
    xy = np.vstack([tracks, rng.uniform([0, 0], [240, 180], (200, 2))])
    z = np.sin(xy[:, 0] / 20) * 3 + xy[:, 1] / 30 + rng.normal(0, 0.1, len(xy))
    samples = ElevationSamples(xy, z, 0.1**2, crs=grid.crs)
    kernel = SquaredExponential(1.0, 15.0) + SquaredExponential(4.0, 300.0)
    # local_amplitude=False: 1,100 samples would take per-tile amplitudes (tiled) by default
    gp = TerrainGP(
        kernel=kernel, optimize=False, nugget=1e-4, nugget_bounds="fixed", local_amplitude=False
    )
    return grid, gp.fit(samples)


def test_lattice_matches_exact_variance(fitted):
    grid, gp = fitted
    m_ref, s_ref = gp.predict(grid.xy(), return_std=True)  # R&W Alg. 2.1 on every cell
    step = coarse_step(15.0, 1.0)
    assert step == 3.75  # l / 4 / resolution
    mean, std = predict_coarse_variance(gp, grid, step)
    np.testing.assert_allclose(mean.ravel(), m_ref, rtol=0, atol=1e-9)  # the mean is exact
    s_ref = s_ref.reshape(grid.shape)
    rel = std / s_ref - 1
    # Measured here: 0.5 % rms; the largest relative errors sit in the narrow variance valleys
    # on the dense tracks, where sigma is smallest: bound them in metres.
    assert np.sqrt(np.mean(rel**2)) < 0.01
    assert np.abs(std - s_ref).max() < 0.01
    for corner in ((0, 0), (0, -1), (-1, 0), (-1, -1)):  # lattice nodes: exact there
        np.testing.assert_allclose(std[corner], s_ref[corner], rtol=1e-9)


def test_route_choice(fitted):
    grid, gp = fitted
    assert variance_step(gp, grid, flops=1e20) == 1  # cheap enough: every cell exactly
    assert variance_step(gp, grid, flops=0.0) == 3.75
    fine = Grid.from_bounds((0, 0, 240, 180), 8.0)
    assert variance_step(gp, fine, flops=0.0) == 1  # l/4 under two cells: no gain
    ds = gp.predict_grid(grid)
    assert ds["elevation_std"].shape == grid.shape
