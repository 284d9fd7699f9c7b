"""A breakline on a coarse DEM prior: the step counted once (``terrain.dem_reading``).

References: hand values (a linear surface reads as itself through cell means and a linear
mesh or bilinear lattice; a symmetric step through the middle of a cell reads 0.5 at its
centre) and the same survey with the line left out.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator
from scipy.special import expit

from terrain import (
    BreaklineMean,
    ElevationSamples,
    Grid,
    RasterMean,
    TerrainGP,
    coarse_dem,
    default_site,
)
from terrain.dem_reading import dem_lacks, prior_reading, reads_steps
from terrain.sampling import sample_dem

X0, Y0 = 526000.0, 6475000.0
CRS = "EPSG:32608"


def _plane_dem(cell: float = 75.0):
    """A plane on 75 m cells over the default site's 600 m square (a satellite-like DEM)."""
    g = Grid.from_bounds((X0, Y0, X0 + 600.0, Y0 + 600.0), cell, CRS)
    xy = g.xy()
    return g.data_array((100.0 + 0.01 * (xy[:, 0] - X0)).reshape(g.shape), "elevation")


@pytest.mark.parametrize("cells", [(8, 8), None])
def test_a_linear_surface_reads_as_itself(cells):
    # cell means of a linear surface are its values at the centres, and both the mesh
    # through the centres and the bilinear lattice are exact on it (by hand)
    prior = RasterMean(_plane_dem(), offset="fit", cells=cells).bind(
        CRS, (X0, Y0, X0 + 600.0, Y0 + 600.0)
    )

    def surface(p):
        return np.column_stack([p[:, 0] - X0, 2.0 * (p[:, 1] - Y0) + 5.0])

    reader = prior_reading(prior, surface)
    xy = np.random.default_rng(0).uniform([X0 + 50, Y0 + 50], [X0 + 550, Y0 + 550], (200, 2))
    np.testing.assert_allclose(reader(xy), surface(xy), atol=1e-6)


def test_a_step_through_a_cell_reads_its_area_share():
    # a logistic step through the middle of the fourth column of 75 m cells: its mean over
    # each of those cells is 0.5 by symmetry, ~0 and ~1 two cells away
    prior = RasterMean(_plane_dem(), offset="fit", cells=None).bind(
        CRS, (X0, Y0, X0 + 600.0, Y0 + 600.0)
    )
    xc = X0 + 3.5 * 75.0
    reader = prior_reading(prior, lambda p: expit((p[:, :1] - xc) / 1.0))
    y = Y0 + 37.5 + 75.0 * np.arange(2, 6)
    np.testing.assert_allclose(reader(np.column_stack([np.full(4, xc), y]))[:, 0], 0.5, atol=1e-9)
    far = reader(np.column_stack([np.r_[xc - 150.0, xc + 150.0], [Y0 + 300.0] * 2]))[:, 0]
    np.testing.assert_allclose(far, [0.0, 1.0], atol=1e-6)


def test_no_reading_without_a_raster_base():
    assert prior_reading(BreaklineMean([np.array([[0.0, 0.0], [1.0, 1.0]])]).base, len) is None
    assert prior_reading(RasterMean(_plane_dem(), offset="fit"), len) is None  # not bound


@pytest.mark.parametrize("prior_has_the_step, dem_scale", [(True, 1.0), (False, 1.0), (True, 1.25)])
def test_a_drawn_scarp_on_a_coarse_prior_helps_off_the_swaths(prior_has_the_step, dem_scale):
    # Two 15 m swaths across a 4 m scarp (1 m wide) on the default site, the prior 8 x 8
    # block means (of the ground with the scarp, or of the ground before it) fitted as
    # a + b * DEM. Measured (seed 0), the map off the swaths, RMSE (m):
    #   prior with the step:    no line 0.592; the step counted twice (before 0.39.0) 0.723
    #                           (scale 0.79); split in two columns 0.432 (scale 1.029, step
    #                           3.87, coarse step 0.055)
    #   prior without the step: no line 0.944; the bare step 0.428; the step less the
    #                           DEM's reading alone 0.644; split 0.428 (coarse step 3.96)
    site = default_site(resolution=4.0)
    g = Grid.from_dataarray(site)
    xy_g = g.xy()

    def line_y(x):
        return Y0 + 300.0 + 20.0 * np.sin((x - X0) / 90.0)

    step = 4.0 * expit(xy_g[:, 1] - line_y(xy_g[:, 0]))
    truth = site.copy(data=(site.values.ravel() + step).reshape(site.shape))
    rng = np.random.default_rng(0)
    xs = np.r_[rng.uniform(X0 + 150, X0 + 165, 300), rng.uniform(X0 + 430, X0 + 445, 300)]
    xy = np.column_stack([xs, rng.uniform(Y0 + 2, Y0 + 598, 600)])
    z = sample_dem(truth, xy) + rng.normal(0, 0.05, 600)
    samples = ElevationSamples(xy, z, np.full(600, 0.0025), crs=CRS)
    u = np.linspace(X0 - 50, X0 + 650, 141)
    dem = coarse_dem(truth if prior_has_the_step else site)
    dem = dem * dem_scale + 30.0 * (dem_scale != 1.0)  # another vertical scale and datum
    off = (np.abs(xy_g[:, 0] - X0 - 157) > 60) & (np.abs(xy_g[:, 0] - X0 - 437) > 60)
    rmse = {}
    for label, mean in (
        ("plain", RasterMean(dem, offset="fit")),
        (
            "line",
            BreaklineMean([np.column_stack([u, line_y(u)])], base=RasterMean(dem, offset="fit")),
        ),  # fmt: skip
    ):
        gp = TerrainGP(seed=0, mean=mean).fit(samples)
        err = gp.predict(xy_g) - truth.values.ravel()
        rmse[label] = float(np.sqrt(np.mean(err[off] ** 2)))
        coef = dict(zip(gp.mean_.coef_names, gp.mean_.coef_, strict=True))
    assert coef["scale"] == pytest.approx(1.0 / dem_scale, abs=0.1)
    assert coef["step1_m"] == pytest.approx(4.0, abs=0.4)
    # What the DEM lacks of the step, in its own metres: nothing when it has the scarp,
    # all of it when not, and -1 m when it states every height 1.25 times over (a 5 m scarp
    # for a 4 m one; by hand 4 - 1.25 * 4). The coefficient alone is the lack in ground
    # metres at the fitted scale: ~0 for both DEMs with the scarp (0.055 with either).
    lack, lack_sd = dem_lacks(gp.mean_)[0]
    assert lack == pytest.approx(4.0 * (1.0 - dem_scale) if prior_has_the_step else 4.0, abs=0.5)
    assert 0.0 < lack_sd < 1.0
    assert coef["coarse_step1_m"] == pytest.approx(0.0 if prior_has_the_step else 4.0, abs=0.5)
    assert rmse["line"] < 0.8 * rmse["plain"], rmse


def test_a_fine_dem_smooths_the_step_only_through_coarse_cells():
    # A 2 m DEM resolves a 1 m wide step (2 < 4 widths: the bare step is kept); read
    # through 8 x 8 cells of 75 m it smooths it like a satellite DEM (the step is split).
    fine = _plane_dem(cell=2.0)
    box = (X0, Y0, X0 + 600.0, Y0 + 600.0)
    assert not reads_steps(RasterMean(fine, offset="fit", cells=None).bind(CRS, box), (1.0,))
    assert reads_steps(RasterMean(fine, offset="fit", cells=(8, 8)).bind(CRS, box), (1.0,))
    assert reads_steps(RasterMean(_plane_dem(), offset="fit").bind(CRS, box), (1.0,))  # 75 m
    assert not reads_steps("constant", (1.0,))


def _geographic_pixel_means(fun, q: int = 24):
    """A DEM in EPSG:4326 whose pixels (0.0008 x 0.0004 degrees, ~47 x 45 m here) are the
    means of ``fun`` (map xy (n, 2) -> (n,)) over each pixel, by ``q`` x ``q`` points: a
    satellite DEM in another CRS, its pixels area means of the ground."""
    import xarray as xr
    from pyproj import Transformer

    to_geo = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True)
    to_map = Transformer.from_crs("EPSG:4326", CRS, always_xy=True)
    lon, lat = to_geo.transform([X0 - 300, X0 + 900], [Y0 - 300, Y0 + 900])
    dlon, dlat = 0.0008, 0.0004
    lons, lats = np.arange(lon[0], lon[1], dlon), np.arange(lat[1], lat[0], -dlat)
    f = (np.arange(q) + 0.5) / q - 0.5
    fx, fy = np.meshgrid(f * dlon, f * dlat)
    lo, la = np.meshgrid(lons, lats)
    mx, my = to_map.transform(
        (lo[..., None, None] + fx).ravel(), (la[..., None, None] + fy).ravel()
    )
    v = fun(np.column_stack([mx, my])).reshape(len(lats), len(lons), q * q).mean(axis=2)
    return xr.DataArray(v, coords={"y": lats, "x": lons}, dims=("y", "x"))


def test_a_dem_in_another_crs_reads_the_step_through_its_own_warp():
    # The DEM's pixels are in EPSG:4326 and the bound lattice resamples them (bilinear, half
    # a pixel off the pixel centres). The reading replays that warp: the step read from its
    # own pixel means matches the DEM of the step to 0.02 m (of 4 m) inside the map; the
    # lattice-cell means used before (0.39.0) missed by 0.55 m, and on the two swaths
    # below fitted 0.56 m of coarse step to a DEM that holds all of it (now 0.05; scale
    # 0.986 -> 1.013, step 3.77 for 4, 0.93 m wide). Measured, seed 0.
    box = (X0, Y0, X0 + 600.0, Y0 + 600.0)
    u = np.linspace(X0 - 50, X0 + 650, 141)
    line = np.column_stack([u, Y0 + 300.0 + 20.0 * np.sin((u - X0) / 90.0)])

    def step(p):
        return 4.0 * expit(p[:, 1] - np.interp(p[:, 0], line[:, 0], line[:, 1]))

    dem_of_step = RasterMean(_geographic_pixel_means(step), source_crs="EPSG:4326", cells=None)
    dem_of_step.bind(CRS, box)
    reader = prior_reading(dem_of_step, lambda p: step(p)[:, None])
    xy = np.random.default_rng(1).uniform([X0 + 20, Y0 + 20], [X0 + 580, Y0 + 580], (4000, 2))
    assert np.abs(reader(xy)[:, 0] - dem_of_step.dem(xy)).max() < 0.05

    site = default_site(resolution=4.0)  # the ground, run on bilinearly past its edges
    g = Grid.from_dataarray(site)
    lattice = RegularGridInterpolator(
        (g.y[::-1], g.x), site.values[::-1], bounds_error=False, fill_value=None
    )

    def ground(p):
        return lattice(p[:, ::-1]) + step(p)

    rng = np.random.default_rng(0)
    xs = np.r_[rng.uniform(X0 + 150, X0 + 165, 300), rng.uniform(X0 + 430, X0 + 445, 300)]
    pts = np.column_stack([xs, rng.uniform(Y0 + 2, Y0 + 598, 600)])
    z = ground(pts) + rng.normal(0, 0.05, 600)
    dem = _geographic_pixel_means(ground)
    mean = BreaklineMean([line], base=RasterMean(dem, offset="fit", source_crs="EPSG:4326"))
    gp = TerrainGP(seed=0, mean=mean).fit(ElevationSamples(pts, z, np.full(600, 0.0025), crs=CRS))
    coef = dict(zip(gp.mean_.coef_names, gp.mean_.coef_, strict=True))
    assert coef["coarse_step1_m"] == pytest.approx(0.0, abs=0.2)
    assert coef["scale"] == pytest.approx(1.0, abs=0.05)


def test_the_dems_holes_are_read_as_the_dem_fills_them():
    # Nodata pixels across the step (a 3 x 4 block and a row's run): the DEM's lattice fills
    # them from the nearest valid cell, and the step's reading leaves the same pixels out and
    # fills the same way, so the two still match (to the quadrature's 0.02 m) everywhere.
    box = (X0, Y0, X0 + 600.0, Y0 + 600.0)

    def step(p):
        return 4.0 * expit(p[:, 1] - (Y0 + 300.0 + 0.2 * (p[:, 0] - X0)))

    da = _geographic_pixel_means(step)
    holes = da.values.copy()
    i = int(np.argmin(np.abs(da.y.values - np.median(da.y.values))))
    holes[i - 1 : i + 2, 10:14] = np.nan
    holes[i + 3, 5:20] = np.nan
    dem = RasterMean(da.copy(data=holes), source_crs="EPSG:4326", cells=None).bind(CRS, box)
    assert dem.n_nodata_ > 0
    reader = prior_reading(dem, lambda p: step(p)[:, None])
    xy = Grid.from_bounds(box, 5.0, CRS).xy()
    np.testing.assert_allclose(reader(xy)[:, 0], dem.dem(xy), atol=0.05)
