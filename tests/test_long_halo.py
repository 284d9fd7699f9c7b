"""Exact mean, tiled 1-sigma with a halo of three long length scales (``terrain.long_halo``).

Reference: the same fitted GP predicted on the exact route (``method="exact"``, R&W Alg.
2.1), which the long-halo route must equal in its mean (it is the exact mean) and match in
its 1-sigma: each tile conditions on every sample within 3 long length scales (a subset of
the data never gives a smaller posterior variance; the constant mean's GLS term, computed
per tile, moves it by up to 0.1 % either way).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import terrain.gp as gp_module
from terrain import ElevationSamples, Grid, InputError, SquaredExponential, TerrainGP
from terrain.tiled import TileSpec, long_scale_part

#: A long part whose 3-scale halo (180 m) is beyond the default tiles' MAX_HALO (150 m).
KERNEL = SquaredExponential(variance=4.0, lengthscale=60.0) + SquaredExponential(
    variance=0.1, lengthscale=5.0
)


def _lines(seed=0, xs=(25.0, 125.0, 225.0, 275.0)):
    """North-south lines 50-100 m apart, a sample every 4 m, on a smooth surface."""
    rng = np.random.default_rng(seed)
    y = np.arange(0.0, 300.0, 4.0)
    xy = np.vstack([np.column_stack([np.full(y.size, x), y]) for x in xs])
    z = 100 + np.sin(xy[:, 0] / 40.0) * 3 + np.cos(xy[:, 1] / 55.0) * 2
    z = z + rng.normal(0, 0.05, len(z))
    return ElevationSamples(xy, z, 0.05**2, crs="EPSG:32608")


def _fit(samples, **kw):
    return TerrainGP(kernel=KERNEL, optimize=False, nugget=1e-4, seed=0, **kw).fit(samples)


#: Twenty lines 50-150 m apart over 2 km: a tile's 180 m halo holds a fifth of the samples.
WIDE = tuple(25.0 + 100.0 * i + (50.0 if i % 3 == 2 else 0.0) for i in range(20))
#: Tiles of 40 m (the defaults for a 5 m short part are 16 m): fewer factorizations.
TILES = TileSpec(tile=40.0, blend=5.0, halo=15.0)


def test_long_halo_route_matches_the_exact_gp(monkeypatch):
    s = _lines(xs=WIDE)
    grid = Grid(0.0, 300.0, (5.0, 5.0), (60, 410), "EPSG:32608")  # 2,050 x 300 m
    q = grid.xy()
    exact = _fit(s, method="exact")
    m_ex, s_ex = exact.predict(q, return_std=True)
    monkeypatch.setattr(gp_module, "EXACT_PREDICT_FLOPS", 1e6)  # this grid counts as big
    gp = _fit(s, tiles=TILES)
    assert gp.method_ == "exact" and long_scale_part(gp.kernel_, gp.tiles_.halo) is not None
    m, sd = gp.predict(q, return_std=True)
    assert gp.predict_route_ == "exact mean, tiled 1-sigma (halo 180 m)"  # none capped
    np.testing.assert_allclose(m, m_ex, atol=1e-9)  # the exact mean itself
    ratio = sd / s_ex
    # measured 0.99995-1.025, median 0.11 %: wide by up to 2.5 % where lines beyond the
    # halo are left out, narrow by 0.005 % at most (the mean's GLS term, per tile)
    assert ratio.min() > 0.999 and ratio.max() < 1.05 and np.median(np.abs(ratio - 1)) < 5e-3
    _, sd_n = gp.predict(q, return_std=True, include_nugget=True)
    np.testing.assert_allclose(sd_n**2 - sd**2, gp.nugget_, rtol=1e-6)


def test_capped_tiles_spread_their_budget_and_err_wide(monkeypatch):
    # Tiles of 50 samples cannot hold a 180 m halo of the lines: each keeps 25 nearest and
    # 25 spread over the halo; a subset of the data never lowers the GP's variance, so the
    # 1-sigma errs wide (the constant mean's per-tile term aside: 0.1 % at most).
    s = _lines()
    q = Grid(0.0, 300.0, (6.0, 6.0), (50, 50), "EPSG:32608").xy()
    monkeypatch.setattr(gp_module, "EXACT_PREDICT_FLOPS", 1e6)
    gp = _fit(s, tiles=TileSpec(tile=20.0, blend=2.5, halo=15.0, max_points=50))
    m, sd = gp.predict(q, return_std=True)
    assert gp.predict_route_.startswith("exact mean, tiled 1-sigma (halo 180 m, ")
    assert "tiles spread" in gp.predict_route_ and gp.tile_stats_["tiles_capped"] > 0
    m_ex, s_ex = _fit(s, method="exact").predict(q, return_std=True)
    np.testing.assert_allclose(m, m_ex, atol=1e-9)
    ratio = sd / s_ex
    assert ratio.min() > 0.999 and np.median(ratio) < 1.1  # measured


def test_scattered_queries_keep_the_exact_route(monkeypatch):
    # A few points far apart: a tile each would cost more than n^2 per point.
    monkeypatch.setattr(gp_module, "EXACT_PREDICT_FLOPS", 1e3)
    gp = _fit(_lines())
    gp.predict(np.array([[10.0, 10.0], [290.0, 290.0], [150.0, 150.0]]), return_std=True)
    assert gp.predict_route_ == "exact"


@pytest.mark.parametrize("method", ["exact", "tiled"])
def test_the_route_is_only_for_auto(method, monkeypatch):
    monkeypatch.setattr(gp_module, "EXACT_PREDICT_FLOPS", 1e6)
    gp = _fit(_lines(), method=method)
    gp.predict(np.array([[100.0, 100.0], [150.0, 10.0]]), return_std=True)
    assert gp.predict_route_ == method


def test_cross_validation_folds_use_the_long_halo_tiles(monkeypatch):
    # An exact fit beyond exact_max_samples (kept exact by its long part): the folds go on
    # tiles with the long part's halo instead of a Cholesky each. Reference: the same check
    # with exact folds; measured on a GNSS walk 36.7 -> 5.0 s, 73.8 -> 73.7 % at 68.
    import terrain.fold_fit as val
    from terrain import cross_validate

    s = _lines()
    grid = Grid(0.0, 300.0, (6.0, 6.0), (50, 50), "EPSG:32608")
    gp = _fit(s, exact_max_samples=200)
    assert gp.method_ == "exact" and s.n > 200
    used = []
    real = val.long_halo_tiles
    monkeypatch.setattr(val, "long_halo_tiles", lambda g: used.append(real(g)) or used[-1])
    tiled = cross_validate(gp, s, n_folds=5, seed=0, targets=grid).pooled
    assert used and used[0].halo == pytest.approx(180.0)
    monkeypatch.setattr(val, "long_halo_tiles", lambda g: None)
    exact = cross_validate(gp, s, n_folds=5, seed=0, targets=grid).pooled
    # measured 0.3404 against 0.3294 m (an SE's mean weights reach beyond the halo a little
    # on this 300 m site), map coverage 95.7 / 99.9 against 96.2 / 99.9 %
    assert tiled["rmse_m"] == pytest.approx(exact["rmse_m"], rel=0.05)
    for level in ("map_coverage_68", "map_coverage_95"):
        assert abs(tiled[level] - exact[level]) <= 0.02


def _dense_lines(seed=1):
    """The four lines, a sample every 0.5 m: 2,400 samples, dense along lines 50-100 m apart."""
    rng = np.random.default_rng(seed)
    y = np.arange(0.0, 300.0, 0.5)
    xy = np.vstack([np.column_stack([np.full(y.size, x), y]) for x in (25.0, 125.0, 225.0, 275.0)])
    z = 100 + np.sin(xy[:, 0] / 40.0) * 3 + np.cos(xy[:, 1] / 55.0) * 2
    return ElevationSamples(xy, z + rng.normal(0, 0.05, len(z)), 0.05**2, crs="EPSG:32608")


def test_a_capped_tiles_budget_spread_over_a_long_halo(monkeypatch):
    # A tiled fit (beyond 3 x exact_max_samples) whose default tiles (15 m halo) cannot hold
    # the 60 m part across 100 m gaps: warned (and said in the product). Given tiles with a
    # 180 m halo, a capped tile that keeps half its 500 samples nearest and spreads half over
    # the halo (TileSpec.far_share) sees the lines beyond the next one; the 500 nearest lie
    # along the next line. Reference: the exact GP on the same samples, in the gaps.
    from terrain import TilingWarning

    s = _dense_lines()
    with pytest.warns(TilingWarning, match="gaps wider"):
        default = _fit(s, exact_max_samples=500, local_amplitude=False)
    assert default.method_ == "tiled" and "gaps wider" in default.provenance()["tiling_warning"]
    monkeypatch.setattr(gp_module, "EXACT_PREDICT_FLOPS", 1e3)  # big: a tiled fit stays tiled
    default.predict(np.array([[60.0, 100.0], [70.0, 120.0]]), return_std=True)
    assert default.predict_route_ == "tiled"
    long_halo = TileSpec(tile=16.0, blend=2.0, halo=180.0)
    spread = _fit(s, method="tiled", local_amplitude=False,
                  tiles=replace(long_halo, far_share=0.5))  # fmt: skip
    assert "50 % of them spread over the halo" in spread.provenance()["method"]
    assert spread.provenance()["tiling_warning"] == ""  # the given halo holds the 60 m part
    nearest = _fit(s, method="tiled", local_amplitude=False, tiles=long_halo)
    gx, gy = np.meshgrid(np.r_[np.arange(50.0, 101.0, 5.0), np.arange(150.0, 201.0, 5.0)],
                         np.arange(10.0, 291.0, 10.0))  # fmt: skip
    q = np.column_stack([gx.ravel(), gy.ravel()])
    m_ex, s_ex = _fit(s, method="exact").predict(q, return_std=True)
    m_sp, s_sp = spread.predict(q, return_std=True)
    m_nn, _ = nearest.predict(q, return_std=True)
    err_sp, err_nn = np.sqrt(np.mean((m_sp - m_ex) ** 2)), np.sqrt(np.mean((m_nn - m_ex) ** 2))
    assert err_sp < 0.5 * err_nn  # measured 0.159 m against 0.564 m (rms off the exact mean)
    assert np.median(np.abs(s_sp / s_ex - 1)) < 0.02  # measured 0.4 % (nearest: 5.1 %)
    with pytest.raises(InputError, match="far_share"):
        TileSpec(far_share=1.0)
