"""The map does not follow the order of the survey's rows (session 46).

Until 0.44.0 the fit subset, the Vecchia orders and the evidence windows were drawn over the
samples' indices as they came, so the same survey exported in another row order gave another
map (up to 1.35 sigma at the far corners of a real glacier's contours: docs/terrain.md "The
map no longer follows the samples' order"). Fits now draw over the samples in order of
position; these tests permute the rows and ask for the same bits.
"""

from __future__ import annotations

import numpy as np
import pytest

from terrain import (
    ElevationSamples,
    Grid,
    RasterMean,
    TerrainGP,
    coarse_dem,
    cross_validate,
    random_terrain,
)
from terrain.sampling import sample_dem

GRID = Grid(0.0, 400.0, 4.0, (100, 100), crs="EPSG:32608")
TRUTH = random_terrain(GRID, relief=25.0, seed=3)


def _survey(n: int, seed: int = 3) -> ElevationSamples:
    truth = TRUTH
    rng = np.random.default_rng(seed)
    xy = rng.uniform(5.0, 395.0, (n, 2))  # inside GRID: x 0-400, y 0-400
    z = sample_dem(truth, xy) + rng.normal(0.0, 0.2, n)
    t_s = np.arange(n, dtype=float)  # a provenance column travels with its row
    return ElevationSamples(xy, z, 0.04, crs="EPSG:32608", extra={"t_s": t_s})


def _shuffled(samples: ElevationSamples, seed: int) -> ElevationSamples:
    order = np.random.default_rng(seed).permutation(samples.n)
    return samples.subset(order)


def test_by_position_orders_by_easting_then_northing_and_keeps_rows_whole():
    s = _shuffled(_survey(200), 1)
    o = s.by_position()
    assert np.all(np.diff(o.xy[:, 0]) >= 0)
    # each row's z, variance and provenance moved with its position
    back = np.argsort(o.extra["t_s"])
    ref = s.subset(np.argsort(s.extra["t_s"]))
    np.testing.assert_array_equal(o.xy[back], ref.xy)
    np.testing.assert_array_equal(o.z[back], ref.z)
    assert o.by_position() is o  # already in order: the same object


def test_by_position_keeps_the_count_of_merged_duplicates():
    xy = np.array([[2.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 5.0]])
    s = ElevationSamples(xy, [1.0, 2.0, 1.0, 3.0], 0.01)
    assert s.n_merged == 1
    o = s.by_position()
    assert o.n_merged == 1
    np.testing.assert_array_equal(o.xy, [[0.0, 5.0], [1.0, 0.0], [2.0, 0.0]])


@pytest.mark.parametrize(
    ("n", "kwargs"),
    [
        (300, {}),  # exact GP, kernel by evidence on every sample
        (2500, {}),  # tiled, fit subset of 2,000 drawn, evidence windows of the rest
        (600, {"mean": "dem"}),  # a + b * DEM by GLS on a coarse prior
    ],
)
def test_the_same_survey_in_another_row_order_gives_the_same_map(n, kwargs):
    samples = _survey(n)
    grid = Grid(0.0, 400.0, 20.0, (20, 20), crs="EPSG:32608")
    if kwargs.get("mean") == "dem":
        kwargs = {"mean": RasterMean(coarse_dem(TRUTH), offset="fit")}
    maps = []
    for seed in (None, 7):
        s = samples if seed is None else _shuffled(samples, seed)
        gp = TerrainGP(seed=0, **kwargs).fit(s)
        np.testing.assert_array_equal(s.xy[gp.sample_order_], gp.samples_.xy)  # the rows
        mu, sd = gp.predict(grid.xy(), return_std=True)
        maps.append((mu, sd, repr(gp.kernel_), gp.nugget_))
    (mu0, sd0, k0, n0), (mu1, sd1, k1, n1) = maps
    assert k0 == k1 and n0 == n1
    np.testing.assert_array_equal(mu0, mu1)
    np.testing.assert_array_equal(sd0, sd1)


def test_the_held_out_check_is_the_same_in_any_row_order():
    samples = _survey(800)
    shuffled = _shuffled(samples, 11)
    gp = TerrainGP(seed=0).fit(samples)
    seen = []

    def extra(caller):
        def variance(train, xy, var_f):
            # the mask is in the caller's rows: the held-out positions are not among them
            held = {tuple(p) for p in xy}
            assert not held & {tuple(p) for p in caller.xy[train]}
            assert len(held) + train.sum() == caller.n
            seen.append(train.sum())
            return np.full(len(xy), 0.01)

        return variance

    a = cross_validate(gp, samples, seed=0, extra_variance=extra(samples))
    b = cross_validate(gp, shuffled, seed=0, extra_variance=extra(shuffled))
    assert len(seen) == 2 * a.n_folds
    assert a.to_dict() == b.to_dict()  # every pooled and per-fold number, to the bit
    # per-sample results follow the caller's rows
    back = np.argsort(shuffled.extra["t_s"])
    for name in ("fold", "block", "prediction", "predictive_sd"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name)[back])
