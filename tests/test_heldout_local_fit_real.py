"""The held-out check at 50,000 samples on a real DEM, through local planes
(terrain.heldout_local_fit): matplotlib's Jacksboro fault DEM (no registry needed) as the
benchmark's glacier-sized site with the 8 x 8 prior, seed 0, exactly as
``python benchmarks/real_terrain.py --sites jacksboro --sizes 50000`` builds it.

Reference values (benchmarks/results/real_terrain_s15_50k.json, the same code path): the
map's own 1-sigma covers 69.2 / 94.9 % of the truth at 68 / 95 %; single held-out samples
read 64.2 / 92.1 % (noise 94 % of their residual variance), the planes 70.7 / 95.4 %."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_dense_real_survey_check_reads_the_truth_through_local_planes(monkeypatch):
    sys.path.insert(0, str(ROOT / "scripts"))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import real_terrain

    import terrain.validation as validation
    from terrain import TerrainGP, coarse_dem, cross_validate

    warnings.simplefilter("ignore")
    truth, grid, samples = real_terrain._data(real_terrain.parse_site("jacksboro"), 50000)
    gp = TerrainGP(seed=0, mean=coarse_dem(truth)).fit(samples)
    ds = gp.predict_grid(grid)
    z = np.abs(ds.elevation.values - truth.values) / ds.elevation_std.values
    truth68, truth95 = 100 * np.mean(z <= 1.0), 100 * np.mean(z <= 1.96)

    p = cross_validate(gp, samples, n_folds=5, seed=0, targets=grid).pooled
    assert p["local_fit_used"], p["local_fit_rule"]
    assert abs(p["local_fit_q"] - 1.0) < 0.05  # independent noise, plane-like ground at 3 m
    assert p["local_fit_noise_kept"] < 0.7
    assert abs(100 * p["map_coverage_68"] - truth68) <= 3.0
    assert abs(100 * p["map_coverage_95"] - truth95) <= 3.0

    # the same check on single held-out samples: the noise's own draw decides it
    monkeypatch.setattr(
        validation, "local_plane_residuals", lambda xy, z, mu, nv, fold, w: (z - mu, nv, {})
    )
    single = cross_validate(gp, samples, n_folds=5, seed=0, targets=grid).pooled
    assert single["noise_share"] > p["noise_share"] + 0.02
    assert 100 * single["map_coverage_68"] < truth68 - 3.0
