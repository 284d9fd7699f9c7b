"""Issue 3's calibration target where the model is right (slow): 50,000 samples of an Eq 1
draw site (1200 m at 2 m, prior DEM beyond the map), scored overall and > 20 m from data.

Reference values: benchmarks/gp_scalable.py --cases calibration_far (truth seeds 3, 4, 5:
95 % 94.7-95.8, 68 % 67.6-70.4, far 95 % 95.5-95.6, far 68 % 69.4-70.0, z spread ~0.98).
On the model's own surfaces the intervals must land in the issue's bands; the hand-built
sites (dunes, crevasses) miss far from data for reasons of the terrain (docs/terrain.md)."""

import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scored():
    from scipy.spatial import cKDTree

    from terrain import (
        Grid,
        SquaredExponential,
        TerrainGP,
        TriangulatedMean,
        evaluate,
        gaussian_field_site,
        sample_along_path,
    )
    from toolkit.demo import demo_path

    truth, dem = gaussian_field_site(1200.0, 2.0, seed=3)
    grid = Grid.from_dataarray(truth)
    samples, _ = sample_along_path(truth, demo_path(grid, 4), 50_000, seed=0)
    gp = TerrainGP(
        SquaredExponential(0.18, 15.0),
        mean=TriangulatedMean(dem),
        n_restarts=0,
        max_fit_samples=1000,
    ).fit(samples)
    ds = gp.predict_grid(grid)
    m, s, t = ds.elevation.values, ds.elevation_std.values, truth.values
    far = cKDTree(samples.xy).query(grid.xy())[0].reshape(grid.shape) > 20.0
    return gp, evaluate(m, t, s), evaluate(m[far], t[far], s[far]), float(far.mean())


def test_fit_recovers_the_field(scored):
    from terrain.microscale import without_microscale

    gp, *_ = scored
    # truth: 0.18 m^2, 15 m (the fit subset sees the DEM's residual too); a nugget the subset
    # puts above the stated noise is kept as a small Microscale part (0.45.0's draw: 2.8e-3
    # m^2, 9 m; terrain/microscale.py), not part of the field
    (k,) = without_microscale(gp.kernel_)
    assert 0.12 < k.variance < 0.26 and 12.0 < k.lengthscale < 18.0
    parts = () if gp.microscale_ is None else getattr(gp.microscale_, "parts", (gp.microscale_,))
    assert sum(p.variance for p in parts) < 0.05 * k.variance


def test_coverage_overall_and_far_from_data(scored):
    _, every, far, frac = scored
    assert frac > 0.3  # interior strips between swaths 300 m apart, not only a rim
    for s in (every, far):
        assert 0.93 <= s["coverage_95"] <= 0.97
        assert 0.64 <= s["coverage_68"] <= 0.72
        assert 0.9 <= s["z_std"] <= 1.1
