"""The map's 1-sigma with the survey's correlated errors (toolkit.error_budget)."""

from __future__ import annotations

import numpy as np
import pytest

from terrain import ElevationSamples, Grid, Matern, TerrainGP
from toolkit.error_budget import correlated_variance, inflate_std


def test_correlated_variance_is_the_median_of_the_nearest():
    """Reference: brute-force distances and numpy's median (hand computation)."""
    rng = np.random.default_rng(0)
    lm = rng.uniform(0, 100, (50, 2))
    s = rng.uniform(0.2, 1.5, 50)
    q = rng.uniform(0, 100, (7, 2))
    got = correlated_variance(q, lm, s, k=5)
    for i, p in enumerate(q):
        near = np.argsort(np.linalg.norm(lm - p, axis=1))[:5]
        assert got[i] == np.median(s[near] ** 2)
    assert correlated_variance(q, lm[:0], s[:0]).tolist() == [0.0] * 7


def test_time_correlated_along_track_variance():
    """Reference values by hand: the variance of the mean of k errors with covariance
    f s_i s_j exp(-|t_i - t_j| / tau) (terrain.along_track's model) is
    (1/k^2) sum_ij f s_i s_j exp(-|t_i - t_j| / tau)."""
    from terrain.along_track import AlongTrackModel

    lm = np.array([[0.0, 0.0], [1.0, 0.0]])
    s = np.array([0.3, 0.5])
    q = np.array([[0.5, 0.0]])
    model = AlongTrackModel(fraction=0.9, tau_s=100.0)
    # the same instant: fully shared, f (mean s)^2 = 0.9 * 0.4^2
    same = correlated_variance(q, lm, s, k=2, landmark_t_s=np.array([5.0, 5.0]), model=model)
    assert abs(same[0] - 0.9 * 0.4**2) < 1e-12
    # 100 s apart: (0.09 + 0.25 + 2 * 0.15 * exp(-1)) / 4 * 0.9
    apart = correlated_variance(q, lm, s, k=2, landmark_t_s=np.array([0.0, 100.0]), model=model)
    assert abs(apart[0] - 0.9 * (0.09 + 0.25 + 0.3 * np.exp(-1.0)) / 4.0) < 1e-12
    # far apart in time: only the diagonal, f mean(s^2) / k
    far = correlated_variance(q, lm, s, k=2, landmark_t_s=np.array([0.0, 1e6]), model=model)
    assert abs(far[0] - 0.9 * (0.09 + 0.25) / 4.0) < 1e-12
    # never above the time-free upper bound's fully shared case for equal sigmas
    rng = np.random.default_rng(3)
    lm = rng.uniform(0, 100, (200, 2))
    t = rng.uniform(0, 3600, 200)
    s = np.full(200, 0.4)
    qq = rng.uniform(0, 100, (50, 2))
    timed = correlated_variance(qq, lm, s, k=10, landmark_t_s=t, model=model)
    assert np.all(timed <= 0.9 * 0.16 + 1e-12) and np.all(timed >= 0.9 * 0.16 / 10 - 1e-12)


def test_inflation_where_the_map_leans_on_data_only():
    """Among the samples the added variance is the along-track + shared variance (w ~ 1);
    far from them the map is the prior and keeps the GP's 1-sigma (w ~ 0)."""
    rng = np.random.default_rng(1)
    xy = np.column_stack([rng.uniform(0, 60, 400), rng.uniform(0, 60, 400)])
    z = np.sin(xy[:, 0] / 15.0) + rng.normal(0, 0.05, 400)
    samples = ElevationSamples(xy, z, np.full(400, 0.05**2), crs="EPSG:32608")
    gp = TerrainGP(kernel=Matern(1.0, 20.0), optimize=False, nugget=1e-6).fit(samples)
    grid = Grid.from_bounds((0.0, 0.0, 400.0, 60.0), 5.0, "EPSG:32608")
    ds = gp.predict_grid(grid)
    out = inflate_std(ds, gp, xy, np.full(400, 0.8), shared_z_std=0.5)
    gp_std, std = ds["elevation_std"].values, out["elevation_std"].values
    x, y = np.meshgrid(out["x"].values, out["y"].values)
    inside = (x > 5) & (x < 55) & (y > 5) & (y < 55)
    far = x > 300
    added = std**2 - gp_std**2
    np.testing.assert_allclose(added[inside], 0.8**2 + 0.5**2, rtol=0.05)
    np.testing.assert_allclose(std[far], gp_std[far], rtol=1e-3)
    assert (std >= gp_std).all()
    np.testing.assert_array_equal(out["elevation"].values, ds["elevation"].values)


def test_shared_horizontal_offset_enters_through_the_slope():
    """On a plane of slope (0.1, -0.05) m/m, a map-wide east / north offset of 1-sigma
    (1.2, 0.8) m adds w * (0.1^2 * 1.2^2 + 0.05^2 * 0.8^2) = w * 0.016 m^2 to both 1-sigmas
    (hand computation); without ``shared_xy_std`` nothing changes."""
    rng = np.random.default_rng(2)
    xy = np.column_stack([rng.uniform(0, 60, 400), rng.uniform(0, 60, 400)])
    z = 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + rng.normal(0, 0.01, 400)
    samples = ElevationSamples(xy, z, np.full(400, 0.01**2), crs="EPSG:32608")
    plane = lambda p: 0.1 * p[:, 0] - 0.05 * p[:, 1]  # noqa: E731 - the prior mean
    gp = TerrainGP(kernel=Matern(1.0, 20.0), mean=plane, optimize=False, nugget=1e-6)
    gp.fit(samples)
    grid = Grid.from_bounds((0.0, 0.0, 60.0, 60.0), 2.0, "EPSG:32608")
    ds = gp.predict_grid(grid)
    plain = inflate_std(ds, gp, xy, np.full(400, 0.3), shared_z_std=0.5)
    out = inflate_std(ds, gp, xy, np.full(400, 0.3), shared_z_std=0.5, shared_xy_std=(1.2, 0.8))
    x, y = np.meshgrid(out["x"].values, out["y"].values)
    inside = (x > 6) & (x < 54) & (y > 6) & (y < 54)
    gp_var = ds["elevation_std"].values.ravel() ** 2
    w = np.clip(1.0 - gp_var / gp.kernel_.diag(np.column_stack([x.ravel(), y.ravel()])), 0, 1)
    w = w.reshape(x.shape)
    hand = w * (0.1**2 * 1.2**2 + 0.05**2 * 0.8**2)
    gy, gx = np.gradient(ds["elevation"].values, ds["y"].values, ds["x"].values)
    exact = w * (gx**2 * 1.2**2 + gy**2 * 0.8**2)  # the map's own slope (centred differences)
    for name in ("elevation_std", "elevation_std_relative"):
        added = out[name].values ** 2 - plain[name].values ** 2
        np.testing.assert_allclose(added, exact, rtol=1e-9, atol=1e-12)
        # on average the map's slope is the plane's (cell by cell it carries the noise)
        assert np.mean(added[inside]) == pytest.approx(np.mean(hand[inside]), rel=0.05)
    assert out.attrs["shared_horizontal_offset_std_m"] == [1.2, 0.8]
    assert "shared_horizontal_offset_std_m" not in plain.attrs


def test_heldout_hook_is_the_maps_along_track_term_from_training_samples_only():
    """toolkit.error_budget.heldout_along_track: at held-out points, w * correlated_variance
    over the training samples (what inflate_std adds to the map), zero without an
    along-track 1-sigma (independent spot heights)."""
    from toolkit.error_budget import along_track_variance, heldout_along_track

    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(0, 60, 200), rng.uniform(0, 60, 200)])
    z = np.sin(xy[:, 0] / 15.0) + rng.normal(0, 0.05, 200)
    samples = ElevationSamples(xy, z, np.full(200, 0.05**2), crs="EPSG:32608")
    gp = TerrainGP(kernel=Matern(1.0, 20.0), optimize=False, nugget=1e-6).fit(samples)
    rel, t = rng.uniform(0.2, 0.6, 200), np.arange(200.0) * 3.0
    train = np.arange(200) % 4 != 0
    query = xy[~train]
    var_f = gp.predict(query, return_std=True)[1] ** 2
    hook = heldout_along_track(gp, xy, xy, rel, t)
    expect = along_track_variance(
        query, var_f, gp.kernel_.diag(query), xy[train], rel[train], 10, t[train]
    )
    np.testing.assert_allclose(hook(train, query, var_f), expect, rtol=1e-12)
    assert (expect > 0).all()
    none = heldout_along_track(gp, xy, xy, np.zeros(200))
    np.testing.assert_array_equal(none(train, query, var_f), 0.0)


def test_the_samples_horizontal_sigma_enters_through_the_slope_and_the_check():
    """``horizontal_sd`` (digitised contours' position error): on a plane of slope (0.1,
    -0.05) m/m a 10 m horizontal 1-sigma adds w * (0.1^2 + 0.05^2) * 10^2 = w * 1.25 m^2 to
    both 1-sigmas (hand computation); the held-out check's hook adds the same at held-out
    points from the map's slope, north-up rows or not."""
    from toolkit.error_budget import heldout_slope_term

    rng = np.random.default_rng(4)
    xy = np.column_stack([rng.uniform(0, 60, 400), rng.uniform(0, 60, 400)])
    z = 0.1 * xy[:, 0] - 0.05 * xy[:, 1]
    samples = ElevationSamples(xy, z, np.full(400, 0.01**2), crs="EPSG:32608")
    plane = lambda p: 0.1 * p[:, 0] - 0.05 * p[:, 1]  # noqa: E731 - the prior mean
    gp = TerrainGP(kernel=Matern(1.0, 20.0), mean=plane, optimize=False, nugget=1e-6)
    gp.fit(samples)
    ds = gp.predict_grid(Grid.from_bounds((0.0, 0.0, 60.0, 60.0), 2.0, "EPSG:32608"))
    args = (ds, gp, xy, np.zeros(400), 0.0)
    plain, out = inflate_std(*args), inflate_std(*args, horizontal_sd=10.0)
    x, y = np.meshgrid(out["x"].values, out["y"].values)
    prior = gp.kernel_.diag(np.column_stack([x.ravel(), y.ravel()])).reshape(x.shape)
    w = np.clip(1.0 - ds["elevation_std"].values ** 2 / prior, 0, 1)
    for name in ("elevation_std", "elevation_std_relative"):
        added = out[name].values ** 2 - plain[name].values ** 2
        np.testing.assert_allclose(added, w * 1.25, rtol=1e-6)
    assert out.attrs["samples_horizontal_std_m"] == 10.0
    assert "horizontal 1-sigma" in out.attrs["std_error_budget"]
    assert "samples_horizontal_std_m" not in plain.attrs
    query = np.array([[30.0, 30.0], [11.0, 47.0]])
    var_f = np.array([0.01, 0.04])
    w_q = np.clip(1.0 - var_f / gp.kernel_.diag(query), 0, 1)
    for product in (ds, ds.isel(y=slice(None, None, -1))):  # rows north-up or south-up
        hook = heldout_slope_term(gp, product, 10.0)
        np.testing.assert_allclose(hook(None, query, var_f), w_q * 1.25, rtol=1e-6)
