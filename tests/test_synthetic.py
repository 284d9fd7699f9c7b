"""Synthetic terrains: exact relief, reproducibility, resolution independence, the default site."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import uniform_filter

from terrain.errors import InputError
from terrain.grid import DEFAULT_CRS, Grid
from terrain.synthetic import (
    DEFAULT_SITE_BOUNDS,
    TerrainFeatures,
    default_site,
    default_site_function,
    random_terrain,
    terrain_function,
)

SITE = (0.0, 0.0, 600.0, 600.0)


def grid(res: float = 4.0, bounds: tuple[float, float, float, float] = SITE) -> Grid:
    return Grid.from_bounds(bounds, res)


@pytest.mark.parametrize("features", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 7])
@pytest.mark.parametrize("relief", [25.0, 0.5, 300.0])
def test_relief_is_exact(seed: int, relief: float, features: bool) -> None:
    z = random_terrain(grid(), relief=relief, seed=seed, features=features).values
    assert abs((z.max() - z.min()) - relief) < 1e-9
    assert abs(z.min() - 100.0) < 1e-9  # default base


def test_relief_exact_on_odd_grids_and_base() -> None:
    g = Grid(526000.0, 6475600.0, (3.0, 5.0), (37, 91))
    da = random_terrain(g, relief=12.5, seed=3, features=True, base=-40.0)
    assert da.shape == (37, 91) and da.dims == ("y", "x") and da.name == "elevation"
    assert abs(float(da.max() - da.min()) - 12.5) < 1e-9
    assert abs(float(da.min()) + 40.0) < 1e-9


def test_same_seed_bit_identical_and_seeds_differ() -> None:
    g = grid()
    a = random_terrain(g, seed=11, features=True).values
    b = random_terrain(g, seed=11, features=True).values
    c = random_terrain(g, seed=12, features=True).values
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    gen = random_terrain(g, seed=np.random.default_rng(11), features=True).values
    assert np.array_equal(a, gen)  # a Generator seeded alike draws the same parameters


def test_seed_none_is_recorded_and_reproducible() -> None:
    g = grid(8.0)
    da = random_terrain(g, seed=None)
    assert isinstance(da.attrs["seed"], int)
    assert np.array_equal(da.values, random_terrain(g, seed=da.attrs["seed"]).values)


def test_attrs() -> None:
    da = random_terrain(grid(), relief=20.0, seed=5, features=True)
    for key in ("seed", "relief", "generator", "generator_version", "features_added", "base"):
        assert key in da.attrs
    assert da.attrs["seed"] == 5 and da.attrs["relief"] == 20.0
    assert da.attrs["features_added"] == 1
    assert da.attrs["features"] == "dunes,crevasses,melt_pools"
    assert random_terrain(grid(), seed=5).attrs["features_added"] == 0
    assert Grid.from_dataarray(da) == grid()


def test_same_continuous_surface_at_two_resolutions() -> None:
    fine, coarse = grid(2.0), grid(6.0)  # 6 m centres (3, 9, ...) are also 2 m centres
    f_fine = terrain_function(fine, seed=4, features=True)
    f_coarse = terrain_function(coarse, seed=4, features=True)
    pts = np.random.default_rng(0).uniform(-100.0, 700.0, (500, 2))  # off-grid points too
    assert np.array_equal(f_fine.raw(pts), f_coarse.raw(pts))  # identical before rescale
    a = random_terrain(fine, seed=4, features=True).values[1::3, 1::3]
    b = random_terrain(coarse, seed=4, features=True).values
    assert np.abs(a - b).max() < 0.02 * 25.0  # only the exact-relief rescale differs


def test_function_matches_raster_everywhere() -> None:
    # The separable / windowed grid evaluation equals the point-wise one, overlapping
    # crevasse and pool windows included.
    feats = TerrainFeatures(crevasses=(8, 8), melt_pools=(6, 6))
    for seed in range(4):
        g = grid(3.0)
        tf = terrain_function(g, seed=seed, features=feats)
        raster = random_terrain(g, seed=seed, features=feats).values
        assert np.abs(tf(g.xy()).reshape(g.shape) - raster).max() < 1e-9


def test_features_add_short_scale_energy() -> None:
    def high_pass_energy(z: np.ndarray) -> float:
        return float(np.mean((z - uniform_filter(z, size=31, mode="nearest")) ** 2))

    g = grid(2.0)
    plain = random_terrain(g, seed=2).values
    rough = random_terrain(g, seed=2, features=True).values
    assert high_pass_energy(rough) > 10 * high_pass_energy(plain)
    # Only short scales change: the trend is the same up to the small rescale.
    smooth = uniform_filter(rough - plain, size=61, mode="nearest")
    assert np.abs(smooth).max() < 2.0


def test_features_only_some() -> None:
    feats = TerrainFeatures(dunes=False, crevasses=(0, 0), melt_pools=(1, 1))
    da = random_terrain(grid(), seed=1, features=feats)
    assert da.attrs["features"] == "melt_pools" and da.attrs["n_melt_pools"] == 1


def test_slope_and_direction() -> None:
    g = grid(4.0)
    z = random_terrain(g, seed=0, slope=0.03, downhill_azimuth=90.0).values  # falls to east
    gx, gy = _plane_gradient(g, z)
    assert gx < -0.01 and abs(gy) < abs(gx)


def _plane_gradient(g: Grid, z: np.ndarray) -> tuple[float, float]:
    xy = g.xy()
    design = np.column_stack([xy - xy.mean(0), np.ones(len(xy))])
    coef = np.linalg.lstsq(design, z.ravel(), rcond=None)[0]
    return float(coef[0]), float(coef[1])


def test_default_site() -> None:
    site = default_site()
    g = Grid.from_dataarray(site)
    assert site.shape == (300, 300) and site.name == "elevation"
    assert g.bounds == DEFAULT_SITE_BOUNDS == (526000.0, 6475000.0, 526600.0, 6475600.0)
    assert g.crs.equals(DEFAULT_CRS) and g.crs.to_epsg() == 32608
    assert abs(float(site.max() - site.min()) - 25.0) < 1e-9
    gx, gy = _plane_gradient(g, site.values)
    assert gx > 0.01 and gy > 0.01  # rises to the north-east: falls toward the south-west
    assert np.hypot(gx, gy) * 600 > 12.0  # the plane dominates the 25 m of relief
    assert site.attrs["features_added"] == 1 and site.attrs["n_crevasses"] == 2
    assert np.array_equal(site.values, default_site().values)
    coarse = default_site(6.0)
    assert coarse.shape == (100, 100)
    assert np.abs(site.values[1::3, 1::3] - coarse.values).max() < 0.5
    tf = default_site_function()
    assert np.abs(tf(g.xy()).reshape(g.shape) - site.values).max() < 1e-9


@pytest.mark.parametrize("relief", [0.0, -1.0, np.nan, np.inf, "steep", None])
def test_bad_relief(relief: object) -> None:
    with pytest.raises(InputError, match="relief"):
        random_terrain(grid(), relief=relief)  # type: ignore[arg-type]


def test_other_bad_inputs() -> None:
    with pytest.raises(InputError, match="features"):
        random_terrain(grid(), features="dunes")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="slope"):
        random_terrain(grid(), slope=-0.1)
    with pytest.raises(InputError, match="slope"):
        random_terrain(grid(), relief=5.0, slope=0.05)  # plane alone drops 42 m > 5 m
    with pytest.raises(InputError, match="seed"):
        random_terrain(grid(), seed=-3)
    with pytest.raises(InputError, match="crevasse_width"):
        TerrainFeatures(crevasse_width=(5.0, 2.0))
    with pytest.raises(InputError, match="grid.shape"):
        random_terrain(Grid(0.0, 10.0, (10.0, 10.0), (1, 1)))
    with pytest.raises(InputError, match="xy"):
        terrain_function(grid())(np.zeros((3, 3)))


def test_large_grid_is_cheap() -> None:
    # Separable evaluation: 2000 x 2000 cells stay well under a second or two.
    da = random_terrain(grid(0.3), seed=1, features=True)
    assert da.shape == (2000, 2000)
    assert abs(float(da.max() - da.min()) - 25.0) < 1e-9
