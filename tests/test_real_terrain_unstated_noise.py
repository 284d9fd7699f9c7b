"""Samples that do not state their noise (a CSV of x, y, z): the default constructor on a
real DEM finds the noise in its nugget and gives the map it gives when the noise is stated.

The site is matplotlib's Jacksboro fault DEM (``scripts/real_dems.py``: shipped with
matplotlib, no registry needed), window 0 on 600 m x 600 m at 2 m, 3,000 samples on 8 tracks
+ 10 % scattered with N(0, 0.2^2) noise: the benchmark's data
(``python benchmarks/real_terrain.py --sites jacksboro --sizes 3000 [--noise unstated]``).
Reference values, benchmarks/results/real_terrain_s16_3k.json (stated) and
real_terrain_unstated_s18_3k.json (unstated): RMSE 0.578 x Delaunay on its hull both ways,
truth coverage 68.2 / 95.2 % and 68.1 / 95.2 %, nugget 1e-6 and 0.0391 m^2.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
NOISE_SD = 0.2  # m, track_samples' default: the noise drawn into every sample


@pytest.fixture(scope="module")
def maps():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import real_terrain
    from _real_sites import real_site

    from terrain import Grid, TerrainGP, delaunay_linear

    real_dems, truth = real_site("jacksboro")  # matplotlib's sample data
    grid = Grid.from_dataarray(truth)
    out = {}
    warnings.simplefilter("ignore")
    for stated in (True, False):
        samples = real_dems.track_samples(truth, 3000, seed=0, stated_var=stated)
        gp = TerrainGP(seed=0).fit(samples)
        ds = gp.predict_grid(grid)
        row = real_terrain._metrics(
            ds.elevation.values, ds.elevation_std.values, truth, samples, grid
        )
        dl = real_terrain._metrics(
            delaunay_linear(samples, grid).elevation.values, None, truth, samples, grid
        )
        out[stated] = dict(
            row, nugget=gp.nugget_, samples=samples, ratio=row["rmse_hull"] / dl["rmse_hull"]
        )
    return out


def test_the_nugget_finds_the_noise_the_samples_do_not_state(maps):
    unstated = maps[False]
    assert np.all(unstated["samples"].z_var == 0.0)
    # the noise drawn is 0.04 m^2; the fit subset's 2,000 samples estimate it to ~ +-10 %
    assert 0.75 * NOISE_SD**2 <= unstated["nugget"] <= 1.25 * NOISE_SD**2
    # stated: the nugget is only what the stated noise leaves (here the lower bound)
    assert maps[True]["nugget"] < 0.1 * NOISE_SD**2


def test_the_map_is_the_same_whether_or_not_the_noise_is_stated(maps):
    s, u = maps[True], maps[False]
    assert u["rmse_hull"] == pytest.approx(s["rmse_hull"], rel=0.02)
    assert abs(u["cov68"] - s["cov68"]) <= 1.5 and abs(u["cov95"] - s["cov95"]) <= 1.0


def test_unstated_noise_meets_the_issue_targets(maps):
    u = maps[False]
    assert u["ratio"] <= 0.8  # issue 16: RMSE <= 0.8 x Delaunay's on its hull
    assert 62.0 <= u["cov68"] <= 76.0 and 92.0 <= u["cov95"] <= 98.0
