"""Local (per-tile) kernel amplitude of the tiled GP: the estimator against brute-force Eq 9,
the stationary GP recovered on stationary data, the true variance recovered when the global
one is wrong, settings, determinism."""

import numpy as np
import pytest

from terrain import ElevationSamples, Grid, InputError, SquaredExponential, TerrainGP
from terrain.likelihood import gaussian_lml
from terrain.tiled import AMPLITUDE_BOUNDS, TileSpec, local_amplitude, predict_tiled


def test_local_amplitude_is_the_map_of_eq9():
    # Reference: Eq 9 through the Cholesky-based gaussian_lml (no eigendecomposition) with the
    # kernel variance scaled by s, plus the log-normal prior, maximized on a fine grid of log s.
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 40, (50, 2))
    kernel = SquaredExponential(0.5, 6.0)
    noise = rng.uniform(0.01, 0.2, 50)
    r = 1.7 * np.linalg.cholesky(kernel(xy) + 1e-9 * np.eye(50)) @ rng.normal(size=50)
    r += rng.normal(size=50) * np.sqrt(noise)
    for prior_sd in (0.5, 1.0, 3.0):
        s = local_amplitude(kernel(xy), r, noise, prior_sd)
        grid = np.linspace(-4.0, 4.0, 8001)  # log s, step 1e-3
        post = [
            gaussian_lml(kernel.with_theta(kernel.theta + [u, 0.0]), xy, r, noise)
            - 0.5 * (u / prior_sd) ** 2
            for u in grid
        ]
        assert np.log(s) == pytest.approx(grid[int(np.argmax(post))], abs=2e-3)
    assert local_amplitude(kernel(xy[:2]), r[:2], noise[:2], 1.0) == 1.0  # too few: global
    # Residuals far beyond the search range stop at its bound instead of running away.
    big = local_amplitude(kernel(xy), 1e4 * r, noise, 10.0)
    assert big == pytest.approx(AMPLITUDE_BOUNDS[1], rel=1e-3)


@pytest.fixture(scope="module")
def field():
    """2,500 samples of one draw of a GP with the SE kernel (variance 1, 10 m), noise 0.1 m."""
    rng = np.random.default_rng(7)
    xy = rng.uniform(0, 150, (2500, 2))
    kernel = SquaredExponential(1.0, 10.0)
    f = np.linalg.cholesky(kernel(xy) + 1e-8 * np.eye(len(xy))) @ rng.normal(size=len(xy))
    noise = rng.normal(0.0, 0.1, len(xy))
    kw = dict(
        kernel=kernel,
        mean=0.0,
        nugget=0.0,
        nugget_bounds="fixed",
        optimize=False,
        method="tiled",
        tiles=TileSpec(tile=20, blend=2.5, halo=30),
    )
    return xy, f, noise, kw, Grid.from_bounds((0, 0, 150, 150), 2.0).xy()


def test_stationary_data_give_the_stationary_gp(field):
    xy, f, noise, kw, q = field
    samples = ElevationSamples(xy, f + noise, 0.01)
    plain = TerrainGP(local_amplitude=False, **kw).fit(samples)
    local = TerrainGP(**kw).fit(samples)  # "auto": on, since the fit is tiled
    assert local.local_amplitude_ and not plain.local_amplitude_
    m1, s1 = plain.predict(q, return_std=True)
    m2, s2 = local.predict(q, return_std=True)
    lo, median, hi = local.tile_stats_["amplitudes"]
    # The data follow the kernel exactly: tile amplitudes scatter around 1 (the 5-95 % range
    # of a one-parameter estimate from ~150 correlated samples; measured 0.44, 0.88, 1.49),
    # and the maps barely move (measured 0.04 and 0.017).
    assert 0.7 < median < 1.3 and lo > 0.3 and hi < 3.0
    assert np.median(np.abs(m2 - m1) / s1) < 0.1
    assert np.median(np.abs(s2 - s1) / s1) < 0.05
    assert "amplitudes" not in plain.tile_stats_


def test_wrong_global_variance_is_corrected_locally(field):
    # The same draw scaled by 3 (variance 9) while the kernel says 1: the tiles find amplitudes
    # near 9 (measured median 6.6: the log-normal prior around 1 and ~150 samples per tile
    # pull it down), and the 1-sigma is that of the GP with the right variance (measured 1.6 %
    # apart; the stationary GP with variance 1 is 12 % off).
    xy, f, noise, kw, q = field
    samples = ElevationSamples(xy, 3.0 * f + noise, 0.01)
    local = TerrainGP(local_amplitude=True, **kw).fit(samples)
    right = TerrainGP(local_amplitude=False, **{**kw, "kernel": SquaredExponential(9.0, 10.0)}).fit(
        samples
    )
    _, s_local = local.predict(q, return_std=True)
    _, s_right = right.predict(q, return_std=True)
    _, median, _ = local.tile_stats_["amplitudes"]
    assert 5.0 < median < 13.5
    assert np.median(np.abs(s_local - s_right) / s_right) < 0.1


def test_settings_and_method_choice(field):
    xy, f, noise, kw, _ = field
    samples = ElevationSamples(xy[:300], f[:300] + noise[:300], 0.01)
    kw = {k: v for k, v in kw.items() if k != "method"}
    with pytest.raises(InputError, match="local_amplitude"):
        TerrainGP(method="exact", local_amplitude=True, **kw).fit(samples)
    with pytest.raises(InputError, match="amplitude_prior_sd"):
        TerrainGP(local_amplitude=True, amplitude_prior_sd=0.0, **kw).fit(samples)
    # auto: 300 samples would be exact, but the local-amplitude model exists only tiled.
    assert TerrainGP(**kw).fit(samples).method_ == "exact"
    gp = TerrainGP(local_amplitude=True, **kw).fit(samples)
    assert gp.method_ == "tiled" and "local amplitude" in gp.provenance()["method"]
    # "auto" (the default) follows the route: off on the exact GP, on when the fit tiles
    small = TerrainGP(**kw).fit(samples)
    assert small.method_ == "exact" and not small.local_amplitude_
    big = TerrainGP(exact_max_samples=100, **kw).fit(samples)
    assert big.method_ == "tiled" and big.local_amplitude_
    assert "local amplitude" in big.provenance()["method"]
    with pytest.raises(InputError, match="local_amplitude"):
        TerrainGP(local_amplitude="sometimes", **kw).fit(samples)


def test_deterministic_and_dask_blocks_join(field):
    xy, f, noise, kw, _ = field
    samples = ElevationSamples(xy, f + noise, 0.01)
    gp = TerrainGP(local_amplitude=True, **kw).fit(samples)
    q = np.random.default_rng(0).uniform(0, 150, (3000, 2)) - gp.X_offset_
    args = (q, gp.X_train_, gp.y_resid_, gp.z_var_ + gp.nugget_, gp.kernel_, gp.tiles_)
    a = predict_tiled(*args, workers=1, amplitude_prior_sd=1.0)
    b = predict_tiled(*args, workers=2, amplitude_prior_sd=1.0)
    np.testing.assert_array_equal(a[0], b[0])  # same bytes whatever the thread count
    np.testing.assert_array_equal(a[1], b[1])
    grid = Grid.from_bounds((0, 0, 150, 150), 3.0)
    ref = gp.predict_grid(grid)
    out = gp.predict_grid(grid, chunks=(17, 29)).compute()
    np.testing.assert_allclose(out["elevation"], ref["elevation"], atol=1e-9)
    np.testing.assert_allclose(out["elevation_std"], ref["elevation_std"], atol=1e-9)
