"""Tiled local GP: equals the exact GP where both run, seamless, deterministic, Dask-ready."""

import warnings

import numpy as np
import pytest

from terrain import ElevationSamples, Grid, InputError, Matern, TerrainGP
from terrain.tiled import TileSpec


@pytest.fixture(scope="module")
def setup():
    rng = np.random.default_rng(4)
    grid = Grid.from_bounds((0, 0, 160, 120), 2.0)
    xy = rng.uniform(0, 160, (1500, 2)) * [1, 0.75]
    z = 2 * np.sin(xy[:, 0] / 12) + np.cos(xy[:, 1] / 9) + rng.normal(0, 0.05, len(xy))
    samples = ElevationSamples(xy, z, 0.05**2, crs=grid.crs)
    kw = dict(
        kernel=Matern(1.5, 10.0, nu=2.5),
        mean="constant",
        nugget=1e-4,
        nugget_bounds="fixed",
        optimize=False,
    )
    exact = TerrainGP(method="exact", **kw).fit(samples)
    # the tiled GP as an approximation of the exact one: no per-tile amplitudes (they are a
    # different model, on by default for tiled fits; seams with them: test below)
    tiles = TileSpec(tile=20, blend=3, halo=35)
    tiled = TerrainGP(method="tiled", tiles=tiles, local_amplitude=False, **kw)
    return grid, samples, exact, tiled.fit(samples), kw


def test_tiled_matches_exact(setup):
    grid, _, exact, tiled, _ = setup
    m1, s1 = exact.predict(grid.xy(), return_std=True)
    m2, s2 = tiled.predict(grid.xy(), return_std=True)
    # Reference: the exact GP (R&W Alg. 2.1) on all samples; halo = 3.5 length scales.
    assert np.max(np.abs(m1 - m2)) < 0.02
    assert np.median(np.abs(s2 - s1) / s1) < 0.01
    assert tiled.tile_stats_["tiles"] > 20 and tiled.method_ == "tiled"


@pytest.mark.parametrize("local_amplitude", [False, True])
def test_no_seams_at_tile_borders(setup, local_amplitude):
    grid, samples, exact, tiled, kw = setup
    ref = exact.predict_grid(grid)
    if local_amplitude:  # the default for tiled fits: a different map, so no kink instead
        tiles = TileSpec(tile=20, blend=3, halo=35)
        tiled = TerrainGP(method="tiled", tiles=tiles, **kw).fit(samples)
        assert tiled.local_amplitude_
        ds = tiled.predict_grid(grid)
        for var in ("elevation", "elevation_std"):
            # A seam is a kink: the tiled map's largest second difference stays within the
            # exact map's (measured 0.168 vs 0.192 m and 0.141 vs 0.192 m; amplitudes 0.25-1).
            kink = np.abs(np.diff(ds[var].values, 2, axis=1)).max()
            assert kink < 1.05 * np.abs(np.diff(ref[var].values, 2, axis=1)).max(), var
        return
    ds = tiled.predict_grid(grid)
    for var in ("elevation", "elevation_std"):
        # Cell-to-cell differences of the tiled map never exceed the exact map's by more than
        # a small fraction of the exact map's own largest step: a seam would be a jump.
        jump = np.abs(np.diff(ds[var].values, axis=1)) - np.abs(np.diff(ref[var].values, axis=1))
        step = np.abs(np.diff(ref[var].values, axis=1)).max()
        assert jump.max() < 0.05 * step, var


def test_far_from_data_is_prior_and_deterministic(setup):
    _, samples, _, tiled, kw = setup
    far = np.array([[5000.0, 5000.0], [-3000.0, 100.0]])
    m, s = tiled.predict(far, return_std=True)
    # The constant mean is the GLS estimate (R&W Eq 2.42); far from data the 1-sigma is the
    # kernel's prior variance plus that constant's variance (H K^-1 H^T)^-1.
    np.testing.assert_allclose(m, tiled.mean_.coef_[0])
    np.testing.assert_allclose(s, np.sqrt(1.5 + tiled.coef_cov_[0, 0]))
    q = np.random.default_rng(0).uniform(0, 150, (2000, 2))
    from terrain.tiled import predict_tiled

    X = samples.xy - tiled.X_offset_
    args = (
        q - tiled.X_offset_,
        X,
        tiled.y_resid_,
        tiled.z_var_ + tiled.nugget_,
        tiled.kernel_,
        tiled.tiles_,
    )
    a = predict_tiled(*args, workers=1)
    b = predict_tiled(*args, workers=2)
    np.testing.assert_array_equal(a[0], b[0])  # same bytes whatever the thread count
    np.testing.assert_array_equal(a[1], b[1])


def test_auto_switches_at_threshold(setup):
    _, samples, _, _, kw = setup
    kw = {**kw, "local_amplitude": False}  # the stationary GP: exact up to the threshold
    assert TerrainGP(exact_max_samples=5000, **kw).fit(samples).method_ == "exact"
    assert TerrainGP(exact_max_samples=1000, **kw).fit(samples).method_ == "tiled"


def test_auto_amplitude_from_min_samples(setup):
    from terrain.gp import AMPLITUDE_MIN_SAMPLES

    _, samples, _, _, kw = setup
    assert samples.n >= AMPLITUDE_MIN_SAMPLES == 1000
    gp = TerrainGP(exact_max_samples=5000, **kw).fit(samples)  # default local_amplitude="auto"
    assert (gp.method_, gp.local_amplitude_) == ("tiled", True)
    few = samples.subset(np.arange(samples.n) < AMPLITUDE_MIN_SAMPLES - 1)
    gp = TerrainGP(exact_max_samples=5000, **kw).fit(few)
    assert (gp.method_, gp.local_amplitude_) == ("exact", False)  # the stationary reference
    gp = TerrainGP(method="exact", **kw).fit(samples)  # asked for: no amplitudes
    assert (gp.method_, gp.local_amplitude_) == ("exact", False)


def test_dask_chunks_equal_in_memory(setup):
    grid, _, _, tiled, _ = setup
    ref = tiled.predict_grid(grid)
    lazy = tiled.predict_grid(grid, chunks=(23, 31))
    assert lazy["elevation"].chunks is not None
    out = lazy.compute()
    np.testing.assert_allclose(out["elevation"], ref["elevation"], atol=1e-9)
    np.testing.assert_allclose(out["elevation_std"], ref["elevation_std"], atol=1e-9)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"tile": 0}, "tile"),
        ({"tile": 10, "blend": 6}, "blend"),
        ({"halo": -1}, "halo"),
        ({"max_points": 2}, "max_points"),
    ],
)
def test_impossible_tile_settings(kwargs, field):
    with pytest.raises(InputError, match=field):
        TileSpec(**kwargs)


def test_bad_method_and_chunks(setup):
    grid, samples, _, tiled, kw = setup
    with pytest.raises(InputError, match="method"):
        TerrainGP(method="sgpr", **kw).fit(samples)
    with pytest.raises(InputError, match="chunks"):
        tiled.predict_grid(grid, chunks=0)


def test_long_scale_kernel_prefers_exact_or_warns(setup):
    from terrain import TilingWarning
    from terrain.tiled import largest_gap

    _, samples, _, _, kw = setup
    kw = {**kw, "kernel": Matern(50.0, 400.0, nu=2.5) + Matern(0.3, 8.0, nu=2.5)}
    # A survey with a 60 m wide empty band: wider than the ~24 m halo (3 x 8 m), so the
    # tiles cannot hold the 400 m part there.
    gappy = samples.subset(np.abs(samples.xy[:, 0] - 80.0) > 30.0)
    assert largest_gap(gappy.xy) > 24.0 * 1.2
    # auto: exact up to 3x exact_max_samples (no per-tile amplitudes), a warning above
    gp = TerrainGP(exact_max_samples=1000, **kw).fit(gappy)
    assert (gp.method_, gp.local_amplitude_) == ("exact", False)
    with pytest.warns(TilingWarning, match="gaps wider"):
        warned = TerrainGP(exact_max_samples=300, **kw).fit(gappy)
    assert "gaps wider" in warned.provenance()["tiling_warning"]  # the product says it too
    assert gp.provenance()["tiling_warning"] == ""
    # Dense data (largest gap well inside the halo) hold the long part: tiled with per-tile
    # amplitudes, no warning (hand check: 1,500 uniform points on 160 x 120 m).
    assert largest_gap(samples.xy) < 10.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", TilingWarning)
        gp = TerrainGP(exact_max_samples=1000, **kw).fit(samples)
    assert (gp.method_, gp.local_amplitude_) == ("tiled", True)


def test_largest_gap_hand_computed():
    from terrain.tiled import largest_gap

    # Two samples at opposite corners of a 100 x 100 m box: the lattice points farthest
    # from both lie at the ends of the anti-diagonal, the other two corners' cells.
    xy = np.array([[0.0, 0.0], [100.0, 100.0]])
    gap = largest_gap(xy, n_side=100)
    # cell centres run from 0.5 to 99.5 m: the farthest is (0.5, 99.5) or (99.5, 0.5),
    # at hypot(0.5, 99.5) = 99.501 m from (0, 0) and hypot(99.5, 0.5) from (100, 100).
    assert gap == pytest.approx(np.hypot(0.5, 99.5), rel=1e-9)


def test_a_faint_short_part_gets_the_long_parts_halo():
    # Precise samples picked SE 15 m + a faint SE 3.9 m (docs/terrain.md "Performance notes"):
    # the default halo (3 x 3.9 m) is narrower than the 18 m gaps, so the 15 m part is "long"
    # and the fit went to the exact route. The halo of the long part (3 x 15 m) holds it.
    from terrain import SquaredExponential
    from terrain.tiled import MAX_HALO, halo_for_gaps, long_scale_part, shortest_lengthscale

    kernel = SquaredExponential(0.18, 15.0) + SquaredExponential(0.003, 3.9)
    spec = TileSpec.for_lengthscale(shortest_lengthscale(kernel))
    assert spec.halo == pytest.approx(11.7) and long_scale_part(kernel, spec.halo) is not None
    grown = halo_for_gaps(spec, kernel, widest=18.0)
    assert grown.halo == pytest.approx(45.0)  # hand: 3 x 15 m
    assert (grown.tile, grown.blend, grown.max_points) == (spec.tile, spec.blend, spec.max_points)
    assert halo_for_gaps(spec, kernel, widest=50.0) is spec  # 45 m cannot reach: unchanged
    assert halo_for_gaps(spec, kernel, widest=10.0) is spec  # data within the halo already
    single = SquaredExponential(0.18, 15.0)
    assert halo_for_gaps(TileSpec.for_lengthscale(15.0), single, widest=40.0).halo == 45.0
    # a part longer than MAX_HALO / 3 cannot be held by tiles: unchanged (exact or a warning)
    very_long = SquaredExponential(50.0, 400.0) + SquaredExponential(1.0, 10.0)
    spec = TileSpec.for_lengthscale(10.0)
    assert halo_for_gaps(spec, very_long, widest=40.0) is spec
    edge = SquaredExponential(5.0, MAX_HALO / 3) + SquaredExponential(1.0, 10.0)
    assert halo_for_gaps(spec, edge, widest=40.0).halo == pytest.approx(MAX_HALO)


def test_precise_samples_with_a_faint_short_part_tile_and_match_the_exact_gp():
    from terrain import SquaredExponential

    rng = np.random.default_rng(7)
    # three 40 m wide bands 60 m apart: gaps of 20 m, wider than 3 x 3 m
    xy = np.vstack([np.column_stack([rng.uniform(0, 200, 700), y0 + rng.uniform(-20, 20, 700)])
                    for y0 in (30.0, 90.0, 150.0)])  # fmt: skip
    z = np.sin(xy[:, 0] / 15) + np.cos(xy[:, 1] / 13) + rng.normal(0, 0.01, len(xy))
    samples = ElevationSamples(xy, z, 0.01**2)
    kernel = SquaredExponential(0.5, 14.0) + SquaredExponential(0.005, 3.0)
    kw = dict(kernel=kernel, mean="constant", optimize=False, nugget=0.0, nugget_bounds="fixed")
    auto = TerrainGP(**kw).fit(samples)  # the default: was the exact route (3 x 3 m halo)
    assert auto.method_ == "tiled" and auto.tiles_.halo == pytest.approx(42.0)  # 3 x 14 m
    # the same tiles without per-tile amplitudes approximate the exact GP
    tiled = TerrainGP(method="tiled", local_amplitude=False, **kw).fit(samples)
    assert tiled.tiles_ == auto.tiles_
    exact = TerrainGP(method="exact", **kw).fit(samples)
    grid = Grid.from_bounds((0, 0, 200, 180), 4.0)
    a, b = tiled.predict_grid(grid), exact.predict_grid(grid)
    assert np.abs(a.elevation - b.elevation).max() < 0.02
    assert np.allclose(a.elevation_std, b.elevation_std, rtol=0.03)


def test_default_tiles_are_sized_to_their_sample_budget():
    from terrain.tiled import REGION_SHARE, sample_density

    density = 50_000 / 600.0**2  # the real-terrain benchmark at 50k, samples per m^2
    spec = TileSpec.for_lengthscale(500.0, density)
    # hand: (1.25 T)^2 * density = 0.5 * 500  ->  T = sqrt(250 / 0.13889) / 1.25 = 33.94 m
    assert spec.max_points == 500
    assert spec.tile == pytest.approx(np.sqrt(250.0 / density) / 1.25, rel=1e-12)
    assert spec.tile == pytest.approx(33.94, abs=0.01) and spec.blend == spec.tile / 8
    assert (1.25 * spec.tile) ** 2 * density == pytest.approx(REGION_SHARE * spec.max_points)
    assert spec.halo == 150.0  # the halo still follows the length scale
    # sparse surveys keep the length-scale rule; short length scales are below the budget
    assert TileSpec.for_lengthscale(500.0, 3000 / 600.0**2).tile == 64.0
    assert TileSpec.for_lengthscale(500.0).tile == 64.0
    assert TileSpec.for_lengthscale(13.0, density).tile == 26.0
    assert TileSpec.for_lengthscale(500.0, 100.0).tile == 16.0  # the floor
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 20.0], [10.0, 20.0]])
    assert sample_density(xy) == pytest.approx(4 / 200.0)
    assert np.isnan(sample_density(xy[:2]))  # a line: no area
    assert TileSpec.for_lengthscale(500.0, sample_density(xy[:2])).tile == 64.0


@pytest.mark.slow
def test_dense_survey_tiles_keep_the_data_beside_them_on_a_real_dem():
    # 50,000 samples of the Jacksboro DEM (matplotlib's, no registry): the fitted kernel is
    # long (Matern 5/2 sum, shortest 39 m), so the length-scale rule gives 64 m tiles whose
    # blending regions hold ~870 samples against a budget of 600. Measured (session 18,
    # /tmp/s18/tilesweep.py): grid RMSE 0.0677 m with 64 m tiles, 0.0561 with 40 m.
    import warnings

    from _real_sites import real_site

    from terrain import Grid, TerrainGP
    from terrain.tiled import shortest_lengthscale

    real_dems, truth = real_site("jacksboro")
    warnings.simplefilter("ignore")
    grid = Grid.from_dataarray(truth)
    samples = real_dems.track_samples(truth, 50_000, seed=0)
    gp = TerrainGP(seed=0).fit(samples)
    assert gp.tiles_.tile < 40.0
    old = TileSpec.for_lengthscale(shortest_lengthscale(gp.kernel_))  # no density: 64 m
    assert old.tile == 64.0
    rmse = {}
    for name, spec in (("budget", gp.tiles_), ("length scale only", old)):
        fit = TerrainGP(kernel=gp.kernel_, nugget=gp.nugget_, optimize=False, seed=0, tiles=spec)
        ds = fit.fit(samples).predict_grid(grid)
        rmse[name] = float(np.sqrt(np.mean((ds.elevation.values - truth.values) ** 2)))
    assert rmse["budget"] < 0.9 * rmse["length scale only"]


def test_cross_validation_folds_reach_across_their_own_gaps(setup):
    # A fold's held-out blocks open gaps that the map does not have. With the map's default
    # halo the fold's tiles reverted to the prior mean inside them, and each fold warned that
    # the map would (seen on a real DEM: rm, 80-node window, 3,000 samples, four warnings).
    from terrain import TilingWarning, cross_validate
    from terrain.tiled import default_tiles, largest_gap, tiles_reaching_gaps

    _, samples, _, _, kw = setup
    kernel = Matern(50.0, 400.0, nu=2.5) + Matern(0.3, 8.0, nu=2.5)
    kw = {**kw, "kernel": kernel}
    hole = np.all(np.abs(samples.xy - [80.0, 60.0]) < 30.0, axis=1)  # one 60 m block out
    train = samples.xy[~hole]
    assert largest_gap(train) > default_tiles(kernel, train).halo  # 24 m: 3 x 8 m
    assert tiles_reaching_gaps(kernel, train).halo == pytest.approx(largest_gap(train))
    # no gap beyond the halo, or no long-scale part: the fit's own default tiles
    assert tiles_reaching_gaps(kernel, samples.xy) == default_tiles(kernel, samples.xy)
    short = Matern(0.3, 8.0, nu=2.5)
    assert tiles_reaching_gaps(short, train) == default_tiles(short, train)

    def held_out(method):
        gp = TerrainGP(method=method, local_amplitude=False, **kw).fit(samples)
        with warnings.catch_warnings():
            warnings.simplefilter("error", TilingWarning)
            return cross_validate(gp, samples, block_size=60.0, n_folds=3, seed=0)

    tiled, exact = held_out("tiled"), held_out("exact")
    # Reference: the exact GP's folds (R&W Alg. 2.1 on each fold's training samples). Measured:
    # held-out RMSE 1.39 m (tiled) against 1.26 m (exact); 2.67 m with the map's halo.
    assert tiled.pooled["rmse_m"] < 1.2 * exact.pooled["rmse_m"]
    ratio = tiled.predictive_sd / exact.predictive_sd
    assert abs(np.median(ratio) - 1.0) < 0.05


def test_a_map_rebuilt_at_its_hyperparameters_has_the_same_mean(setup):
    # glacimap change rebuilds each epoch's GP from its samples at the recorded kernel and
    # nugget (toolkit.change_inputs.rebuild_gp). A tiled fit's GLS constant was taken on the
    # random fit subset, which a fit without optimization does not draw: the rebuilt mean
    # moved by 3.8 mm on olinda at 3,000 samples and the GP route was refused.
    grid, samples, _, _, kw = setup
    tiles = TileSpec(tile=20, blend=3, halo=35)
    fitted = TerrainGP(
        kernel=kw["kernel"], mean="constant", method="tiled", tiles=tiles, max_fit_samples=500
    ).fit(samples)
    assert fitted.fit_index_.size == 500
    rebuilt = TerrainGP(
        kernel=fitted.kernel_,
        mean="constant",
        nugget=fitted.nugget_,
        nugget_bounds="fixed",
        optimize=False,
        method="tiled",
        tiles=tiles,
    ).fit(samples)
    assert rebuilt.mean_.coef_ == fitted.mean_.coef_
    xy = grid.xy()[::97]
    np.testing.assert_array_equal(rebuilt.predict(xy), fitted.predict(xy))
