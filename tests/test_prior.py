"""Satellite prior (coarse DEM, triangulated mean) and the GP mean functions."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from terrain.errors import InputError, NotFittedError
from terrain.grid import DEFAULT_CRS, Grid
from terrain.prior import ConstantMean, TriangulatedMean, as_mean_function, coarse_dem
from terrain.synthetic import default_site


def raster(values: np.ndarray, res: float = 1.0, west: float = 0.0) -> xr.DataArray:
    values = np.asarray(values, dtype=float)
    g = Grid(west, res * values.shape[0], (res, res), values.shape)
    return g.data_array(values, "elevation")


def plane(xy: np.ndarray) -> np.ndarray:
    return 0.02 * (xy[:, 0] - 526000.0) - 0.03 * (xy[:, 1] - 6475000.0) + 110.0


def plane_dem(cells: tuple[int, int] = (8, 8)) -> xr.DataArray:
    g = Grid.from_bounds((526000.0, 6475000.0, 526600.0, 6475600.0), 600.0 / 8).coarsen(cells)
    return g.data_array(plane(g.xy()).reshape(g.shape), "elevation")


# -- coarse_dem ---------------------------------------------------------------------------


def test_coarse_dem_by_hand() -> None:
    truth = raster(np.arange(16).reshape(4, 4))
    # rows (north first):  0  1  2  3 /  4  5  6  7 /  8  9 10 11 / 12 13 14 15
    # NW block: (0 + 1 + 4 + 5) / 4 = 2.5       NE block: (2 + 3 + 6 + 7) / 4 = 4.5
    # SW block: (8 + 9 + 12 + 13) / 4 = 10.5    SE block: (10 + 11 + 14 + 15) / 4 = 12.5
    dem = coarse_dem(truth, cells=(2, 2))
    np.testing.assert_allclose(dem.values, [[2.5, 4.5], [10.5, 12.5]], rtol=0, atol=1e-12)
    g = Grid.from_dataarray(dem)
    assert g.bounds == (0.0, 0.0, 4.0, 4.0) and g.resolution == (2.0, 2.0)
    np.testing.assert_allclose(dem.x, [1.0, 3.0])
    np.testing.assert_allclose(dem.y, [3.0, 1.0])
    assert dem.attrs["cells"] == (2, 2) and dem.attrs["source"] == "block average"
    assert dem.attrs["noise"] == 0.0


def test_coarse_dem_ignores_nan() -> None:
    values = np.arange(16, dtype=float).reshape(4, 4)
    values[0, 0] = np.nan
    dem = coarse_dem(raster(values), cells=(2, 2))
    # NW block without the NaN: (1 + 4 + 5) / 3 = 10/3; the others as above
    np.testing.assert_allclose(dem.values, [[10 / 3, 4.5], [10.5, 12.5]], atol=1e-12)


def test_coarse_dem_all_nan_cell_is_named() -> None:
    values = np.arange(16, dtype=float).reshape(4, 4)
    values[2:, 2:] = np.nan  # the whole south-east block
    with pytest.raises(InputError, match=r"row 1, col 1"):
        coarse_dem(raster(values), cells=(2, 2))
    with pytest.raises(InputError, match="coarse cell"):
        coarse_dem(raster(np.ones((2, 2))), cells=(4, 4))  # more coarse than fine cells


def brute_force(truth: xr.DataArray, cells: tuple[int, int]) -> np.ndarray:
    fine, coarse = Grid.from_dataarray(truth), Grid.from_dataarray(truth).coarsen(cells)
    cw, cn = coarse.west, coarse.north
    (dx, dy), out = coarse.resolution, np.zeros(coarse.shape)
    for r in range(coarse.ny):
        for c in range(coarse.nx):
            picked = []
            for i, y in enumerate(fine.y):
                for j, x in enumerate(fine.x):
                    # half-open cells: [west, east) and (south, north]
                    inside_x = cw + c * dx <= x < cw + (c + 1) * dx
                    inside_y = cn - (r + 1) * dy < y <= cn - r * dy
                    if inside_x and inside_y and np.isfinite(truth.values[i, j]):
                        picked.append(truth.values[i, j])
            out[r, c] = np.mean(picked)
    return out


NON_DIVISIBLE = [((6, 6), (4, 4)), ((7, 5), (3, 2)), ((9, 10), (4, 3))]


@pytest.mark.parametrize(("shape", "cells"), NON_DIVISIBLE)
def test_coarse_dem_non_divisible_matches_brute_force(shape, cells) -> None:
    values = np.random.default_rng(1).normal(100.0, 5.0, shape)
    values[1, 1] = np.nan  # ignored; every coarse cell keeps some finite fine cells
    truth = raster(values)
    dem = coarse_dem(truth, cells=cells)
    assert dem.shape == cells
    np.testing.assert_allclose(dem.values, brute_force(truth, cells), rtol=0, atol=1e-10)


def test_coarse_dem_on_the_site_gives_64_values() -> None:
    truth = default_site(4.0)  # 150 x 150 cells into 8 x 8: not divisible
    dem = coarse_dem(truth)
    assert dem.shape == (8, 8) and np.isfinite(dem.values).all()
    assert Grid.from_dataarray(dem).bounds == Grid.from_dataarray(truth).bounds
    assert abs(float(dem.mean()) - float(truth.mean())) < 0.5  # near-equal block sizes


def test_coarse_dem_noise_is_seeded() -> None:
    truth = default_site(10.0)
    clean = coarse_dem(truth)
    a, b = coarse_dem(truth, noise=2.0, seed=3), coarse_dem(truth, noise=2.0, seed=3)
    assert np.array_equal(a.values, b.values)
    assert not np.array_equal(a.values, coarse_dem(truth, noise=2.0, seed=4).values)
    resid = (a - clean).values
    assert 1.0 < resid.std() < 3.0
    assert a.attrs["noise"] == 2.0 and a.attrs["seed"] == 3
    with pytest.raises(InputError, match="noise"):
        coarse_dem(truth, noise=-1.0)


# -- TriangulatedMean ---------------------------------------------------------------------


def test_triangulated_reproduces_a_plane_inside_hull() -> None:
    mean = TriangulatedMean(plane_dem())
    lo, hi = mean.points.min(0), mean.points.max(0)  # hull = rectangle of cell centres
    xy = np.random.default_rng(2).uniform(lo, hi, (2000, 2))
    np.testing.assert_allclose(mean(xy), plane(xy), rtol=0, atol=1e-9)
    np.testing.assert_allclose(mean(mean.points), mean.values, atol=1e-9)


def test_triangulated_is_finite_and_bounded_everywhere() -> None:
    mean = TriangulatedMean(coarse_dem(default_site(6.0)), extrapolate="nearest")
    xy = np.random.default_rng(3).uniform(-1e6, 1e6, (5000, 2)) + [526300.0, 6475300.0]
    z = mean(xy)
    assert z.shape == (5000,) and np.isfinite(z).all()
    assert mean.values.min() - 1e-9 <= z.min() and z.max() <= mean.values.max() + 1e-9


def test_triangulated_continuous_across_hull() -> None:
    dem = coarse_dem(default_site(6.0), noise=1.0, seed=0)
    mean = TriangulatedMean(dem)
    scale = float(np.ptp(mean.values))
    (x0, y0), (x1, y1) = mean.points.min(0), mean.points.max(0)
    s = np.linspace(0.0, 1.0, 201)
    eps = 1e-6
    sides = [  # (points on the hull edge, outward normal)
        (np.column_stack([x0 + s * (x1 - x0), np.full_like(s, y1)]), (0.0, 1.0)),
        (np.column_stack([x0 + s * (x1 - x0), np.full_like(s, y0)]), (0.0, -1.0)),
        (np.column_stack([np.full_like(s, x0), y0 + s * (y1 - y0)]), (-1.0, 0.0)),
        (np.column_stack([np.full_like(s, x1), y0 + s * (y1 - y0)]), (1.0, 0.0)),
    ]
    for edge, normal in sides:
        inside, outside = mean(edge - eps * np.array(normal)), mean(edge + eps * np.array(normal))
        assert np.abs(inside - outside).max() < 1e-6 * scale


def test_triangulated_far_outside_is_nearest_hull_value() -> None:
    mean = TriangulatedMean(coarse_dem(default_site(6.0)), extrapolate="nearest")
    (_, y0), (x1, y1) = mean.points.min(0), mean.points.max(0)
    ys = np.linspace(y0, y1, 13)
    far_east = np.column_stack([np.full_like(ys, x1 + 5e4), ys])
    on_hull = np.column_stack([np.full_like(ys, x1), ys])
    np.testing.assert_allclose(mean(far_east), mean(on_hull), atol=1e-9)
    # Beyond a corner the nearest hull point is the corner centre itself.
    corner = int(np.argmin(np.hypot(mean.points[:, 0] - x1, mean.points[:, 1] - y0)))
    far_se = np.array([[x1 + 1e4, y0 - 3e4]])
    np.testing.assert_allclose(mean(far_se), mean.values[corner], atol=1e-9)


def test_linear_extrapolation_continues_a_plane_over_the_footprint() -> None:
    # A plane's block means equal the plane at the cell centres; odd reflection continues it,
    # so the padded mesh reproduces the plane over the whole DEM footprint (hand argument).
    dem = plane_dem()
    mean = TriangulatedMean(dem)
    grid = Grid.from_dataarray(dem)
    w, s, e, n = grid.bounds
    xy = np.random.default_rng(0).uniform([w, s], [e, n], (500, 2))
    np.testing.assert_allclose(mean(xy), plane(xy), atol=1e-9)
    # Beyond the padded ring it is bounded and finite (nearest point of the padded mesh).
    far = np.array([[w - 1e5, s - 1e5], [e + 1e5, n]])
    assert np.isfinite(mean(far)).all()
    with pytest.raises(InputError, match="extrapolate"):
        TriangulatedMean(dem, extrapolate="cubic")


def test_triangulated_attributes_and_repr() -> None:
    mean = TriangulatedMean(plane_dem())
    assert mean.crs.equals(DEFAULT_CRS)
    text = repr(mean)
    assert "TriangulatedMean" in text and "(8, 8)" in text and "EPSG:32608" in text
    assert not hasattr(mean, "fit")


def test_triangulated_single_row_dem() -> None:
    dem = plane_dem((1, 8))
    mean = TriangulatedMean(dem)
    xs = np.array([[526000.0 - 100, 0.0], [526300.0, 1.0], [527000.0, 2.0]])
    z = mean(xs)
    assert np.isfinite(z).all()
    assert z[0] == dem.values[0, 0] and z[2] == dem.values[0, -1]


def test_triangulated_rejects_bad_dem() -> None:
    dem = plane_dem()
    dem[2, 3] = np.nan
    with pytest.raises(InputError, match="coarse"):
        TriangulatedMean(dem)
    with pytest.raises(InputError, match="coarse"):
        TriangulatedMean(np.ones((8, 8)))  # type: ignore[arg-type]


# -- ConstantMean and as_mean_function ----------------------------------------------------


def test_constant_mean_fit() -> None:
    xy, z = np.zeros((4, 2)), np.array([1.0, 2.0, 3.0, 10.0])
    unfitted = ConstantMean()
    with pytest.raises(NotFittedError, match="fit"):
        unfitted(xy)
    fitted = unfitted.fit(xy, z)
    assert fitted.value_ == 4.0 and unfitted.value_ is None  # a copy, original untouched
    np.testing.assert_array_equal(fitted(np.ones((3, 2))), [4.0, 4.0, 4.0])
    fixed = ConstantMean(7.5)
    np.testing.assert_array_equal(fixed(xy), np.full(4, 7.5))
    assert fixed.fit(xy, z).value_ == 7.5  # a given value is kept
    with pytest.raises(InputError, match="z"):
        unfitted.fit(xy, np.array([1.0, np.nan, 2.0, 3.0]))
    with pytest.raises(InputError, match="xy"):
        unfitted.fit(np.zeros((3, 2)), z)
    with pytest.raises(InputError, match="value"):
        ConstantMean(np.inf)


def test_as_mean_function_normalises() -> None:
    assert as_mean_function(None) == ConstantMean()
    assert as_mean_function("constant") == ConstantMean()
    assert as_mean_function(3.0)(np.zeros((2, 2))).tolist() == [3.0, 3.0]
    assert isinstance(as_mean_function(plane_dem()), TriangulatedMean)
    tri = TriangulatedMean(plane_dem())
    assert as_mean_function(tri) is tri
    wrapped = as_mean_function(plane)
    xy = np.array([[526100.0, 6475100.0], [526200.0, 6475300.0]])
    np.testing.assert_allclose(wrapped(xy), plane(xy))
    assert wrapped.fit(xy, np.zeros(2)) is wrapped  # nothing to fit


def test_as_mean_function_validates_callables() -> None:
    xy = np.zeros((3, 2))
    with pytest.raises(InputError, match="mean"):
        as_mean_function(lambda p: np.zeros((len(p), 1)))(xy)  # wrong shape
    with pytest.raises(InputError, match="mean"):
        as_mean_function(lambda p: np.full(len(p), np.nan))(xy)
    with pytest.raises(InputError, match="mean"):
        as_mean_function(lambda p: 1.0)(xy)  # a scalar is not one value per point


@pytest.mark.parametrize("bad", ["linear", [1.0, 2.0], object(), True, np.ones((3, 3))])
def test_as_mean_function_rejects(bad: object) -> None:
    with pytest.raises(InputError, match="mean"):
        as_mean_function(bad)
