"""The Eq 1 random-field truth (terrain.gaussian_field): its covariance is Eq 1's."""

from __future__ import annotations

import numpy as np
import pytest

from terrain import Grid, gaussian_field_terrain, se_random_field
from terrain.errors import InputError


@pytest.fixture(scope="module")
def field():
    grid = Grid.from_bounds((0.0, 0.0, 600.0, 600.0), 2.0)
    return grid, se_random_field(grid, 0.18, 15.0, seed=7)


def test_marginal_variance_and_mean(field):
    # ~(600 / 15)^2 = 1,600 correlation areas: the sample variance's relative sd is about
    # sqrt(2 / 1600) = 3.5 %, so 12 % is > 3 sd; the mean's sd is about sqrt(0.18 / 1600).
    _, f = field
    assert abs(f.var() / 0.18 - 1.0) < 0.12
    assert abs(f.mean()) < 4 * np.sqrt(0.18 / 1600)


@pytest.mark.parametrize("lag_cells", [4, 8, 15])  # 8, 16, 30 m on the 2 m grid
def test_correlation_is_eq1(field, lag_cells):
    # Eq 1 by hand: rho(r) = exp(-r^2 / (2 * 15^2)); 8 m: 0.867, 16 m: 0.566, 30 m: 0.135.
    # GSTools' own "Gaussian" model (rescale sqrt(pi)/2) would give 0.814, 0.410, 0.043.
    _, f = field
    r = 2.0 * lag_cells
    rho = np.exp(-(r**2) / (2 * 15.0**2))
    a = f - f.mean()
    both = (a[:, :-lag_cells] * a[:, lag_cells:]).mean() + (a[:-lag_cells] * a[lag_cells:]).mean()
    est = 0.5 * both / a.var()
    assert abs(est - rho) < 0.06


def test_same_seed_same_bytes_and_different_seed_differs():
    grid = Grid.from_bounds((0.0, 0.0, 100.0, 80.0), 2.0)
    a = gaussian_field_terrain(grid, seed=3)
    b = gaussian_field_terrain(grid, seed=3)
    c = gaussian_field_terrain(grid, seed=4)
    assert a.values.tobytes() == b.values.tobytes()
    assert not np.allclose(a.values, c.values)
    assert a.attrs["field_length_scale_m"] == 15.0 and a.attrs["seed"] == 3
    assert a.shape == grid.shape and np.all(np.isfinite(a.values))


@pytest.mark.parametrize(
    "kw, name",
    [
        ({"variance": 0.0}, "variance"),
        ({"length_scale": -1.0}, "length_scale"),
        ({"length_scale": float("nan")}, "length_scale"),
        ({"mode_no": 0}, "mode_no"),
    ],
)
def test_bad_parameters_name_the_field(kw, name):
    grid = Grid.from_bounds((0.0, 0.0, 20.0, 20.0), 2.0)
    args = {"variance": 0.18, "length_scale": 15.0, **kw}
    with pytest.raises(InputError, match=name):
        se_random_field(grid, **args)


def test_site_dem_covers_beyond_the_map():
    from terrain import Grid, gaussian_field_site

    truth, dem = gaussian_field_site(200.0, 5.0, margin=50.0, dem_cell=50.0, seed=2)
    assert Grid.from_dataarray(truth).bounds == (0.0, 0.0, 200.0, 200.0)
    assert Grid.from_dataarray(dem).bounds == (-50.0, -50.0, 250.0, 250.0)
    assert dem.shape == (6, 6) and truth.shape == (40, 40)
    # the map is the inner part of the surface the DEM averages: DEM cell (1, 1) is the
    # map's north-west 50 m block (10 x 10 cells at 5 m), by hand
    assert np.isclose(float(dem.values[1, 1]), truth.values[:10, :10].mean(), atol=1e-9)
    assert np.isclose(float(dem.values[4, 4]), truth.values[30:, 30:].mean(), atol=1e-9)


def test_site_rejects_a_margin_below_one_cell():
    from terrain import gaussian_field_site

    with pytest.raises(InputError, match="margin"):
        gaussian_field_site(200.0, 4.0, margin=2.0)
