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


def test_lattice_matches_exact_variance(fitted, monkeypatch):
    import terrain.gp

    grid, gp = fitted
    # R&W Alg. 2.1 on every cell (not the long-halo tiles a grid this big would take)
    monkeypatch.setattr(terrain.gp, "predict_long_halo", lambda *a, **k: None)
    m_ref, s_ref = gp.predict(grid.xy(), return_std=True)
    assert gp.predict_route_ == "exact"
    monkeypatch.undo()
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


def test_a_lattice_that_misses_the_variance_is_rejected_and_said():
    """A rough kernel with a long scale (Matern 3/2, l = 300 m, as fitted on the glacier
    DEM's 900-sample survey: l = 381 m) has sigma dipping within metres of the data, far
    below l / 4: the spline from a 75-cell lattice was 190 % off there (session 11), so the
    check rejects it and every cell is predicted exactly; the route says both."""
    from terrain import Matern

    rng = np.random.default_rng(3)
    grid = Grid.from_bounds((0, 0, 240, 180), 1.0)
    xy = np.column_stack([rng.uniform(0, 240, 600), np.repeat(np.linspace(15, 165, 4), 150)])
    z = np.sin(xy[:, 0] / 20) * 3 + rng.normal(0, 0.05, len(xy))
    samples = ElevationSamples(xy, z, 0.05**2, crs=grid.crs)
    gp = TerrainGP(
        kernel=Matern(40.0, 300.0, nu=1.5), optimize=False, nugget=1e-4, nugget_bounds="fixed"
    ).fit(samples)
    assert gp.method_ == "exact"  # below 1,000 samples
    assert variance_step(gp, grid, flops=0.0) == 75.0
    _, lattice_std = predict_coarse_variance(gp, grid, 75.0, check=True)
    assert lattice_std is None and gp.lattice_check_["max_rel_error"] > 0.5
    fine = Grid.from_bounds((0, 0, 240, 180), 0.5, grid.crs)
    ds = gp.predict_grid(fine)  # 600^2 x 172,800 cells > 4e10: the lattice is tried
    assert "rejected" in gp.predict_route_
    _, s_ref = gp.predict(fine.xy(), return_std=True)
    np.testing.assert_allclose(ds["elevation_std"].values.ravel(), s_ref, rtol=1e-12)


def test_an_accepted_lattice_states_its_check(fitted):
    grid, gp = fitted
    gp.predict_grid(grid)
    assert "checked at" in gp.predict_route_ and "rejected" not in gp.predict_route_
    assert gp.lattice_check_["max_rel_error"] < 0.10
