"""A DEM stored south-up (y ascending, as NetCDF files often are) gives the same results as
the same DEM north-up, everywhere a DEM's values are paired with its grid: the simulator's
surface, the certificate's DEM reader, the exporters' product reader, the planner's prior
gradient and the length-scale tuning table. Reference: the north-up DEM itself."""

from __future__ import annotations

import numpy as np
import xarray as xr

from terrain import Grid, random_terrain


def _pair():
    grid = Grid.from_bounds((500_000.0, 6_800_000.0, 500_200.0, 6_800_160.0), 4.0)
    da = random_terrain(grid, relief=10.0, seed=2)
    return da, da.isel(y=slice(None, None, -1))  # same data, rows south first


def test_simulator_surface_reads_a_south_up_dem():
    from factorgraph.simulate import Surface

    north, south = _pair()
    origin = np.array([500_000.0, 6_800_000.0])
    xy = np.random.default_rng(0).uniform([10, 10], [190, 150], (200, 2))
    a, b = Surface(north, origin), Surface(south, origin)
    assert np.array_equal(a.z(xy), b.z(xy)) and a.bounds == b.bounds
    assert np.ptp(a.z(xy)) > 1.0  # the DEM is not flat: a row flip would show


def test_certificate_and_exporters_read_a_south_up_product():
    from toolkit.dem_io import read_dem
    from toolkit.export._product import read_product

    north, south = _pair()

    def product(da):
        return xr.Dataset({"elevation": da, "elevation_std": da * 0 + 0.5}, attrs=dict(da.attrs))

    a, b = read_dem(north), read_dem(south)
    assert np.array_equal(a.elevation, b.elevation) and a.grid == b.grid
    pa, pb = read_product(product(north)), read_product(product(south))
    assert np.array_equal(pa.elevation, pb.elevation)
    assert np.array_equal(pa.elevation, north.values)


def test_planner_prior_gradient_and_tuning_read_a_south_up_dem():
    from survey.piecewise import _prior_gradient
    from terrain import ElevationSamples
    from terrain.tuning import tune_paper_grid

    north, south = _pair()
    grid = Grid.from_dataarray(north)
    bounds = (500_010.0, 6_800_010.0, 500_190.0, 6_800_150.0)
    ga, gxa, gya = _prior_gradient(north, bounds, grid.crs)
    gb, gxb, gyb = _prior_gradient(south, bounds, grid.crs)
    assert ga == gb and np.array_equal(gxa, gxb) and np.array_equal(gya, gyb)
    xy = grid.xy()[::7]
    samples = ElevationSamples(xy, north.values.ravel()[::7], 0.01, crs=grid.crs)
    kw = {"alphas": [1.0, 4.0], "gammas": [20.0, 40.0], "reading": "lengthscale"}
    a = tune_paper_grid(samples, north, **kw)
    b = tune_paper_grid(samples, south, **kw)
    assert np.array_equal(a.rmse_table, b.rmse_table) and np.ptp(a.rmse_table) > 0
