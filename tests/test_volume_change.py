"""terrain.volume_change and the covariance integrals behind its 1-sigma.

References: brute-force double sums ``w^T C w`` and dense GP posterior covariances built
directly from the kernel (numpy, no FFT, no interpolation); a refit with every sample moved
by 1 m for the offset response; hand arithmetic for the density propagation (Huss 2013).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cdist
from shapely.geometry import Point, box

from terrain import (
    ElevationSamples,
    Grid,
    InputError,
    SquaredExponential,
    TerrainGP,
    difference,
    volume_change,
)
from terrain.variogram import (
    SphericalVariogram,
    covariance_sum,
    fit_variogram,
    rolstad_disk_variance,
)
from terrain.volume import gp_integral, outline_weights

W0, S0 = 500_000.0, 6_800_000.0


def test_covariance_sum_equals_double_sum():
    grid = Grid.from_bounds((W0, S0, W0 + 60, S0 + 40), 2.0)
    rng = np.random.default_rng(0)
    w = rng.uniform(0, 1, grid.shape) * (rng.uniform(size=grid.shape) > 0.3)
    k = SquaredExponential(2.0, (9.0, 5.0))  # anisotropic: checks the axis orientation

    def cov(lags):
        return k(lags, np.zeros((1, 2)))[:, 0]

    xy = grid.xy()
    ref = w.ravel() @ k(xy) @ w.ravel()
    assert covariance_sum(w, grid.resolution, cov) == pytest.approx(ref, rel=1e-9)


def test_rolstad_disk_close_to_exact_integral():
    v = SphericalVariogram(0.0, (1.0,), (50.0,))
    grid = Grid.from_bounds((W0, S0, W0 + 400, S0 + 400), 2.0)
    disk = Point(W0 + 200, S0 + 200).buffer(150.0, 256)
    wts = outline_weights(grid, disk)
    area = wts.sum()
    exact = covariance_sum(wts, grid.resolution, v.correlated_covariance) / area**2
    approx = rolstad_disk_variance(v, area)
    # Rolstad's form integrates C from the disk centre only: measured 1.097 x the exact double
    # integral here (L / a = 3; 1.21 x at L / a = 1.5) -- why the exact sum is used.
    assert exact < approx < 1.15 * exact


def test_fit_variogram_recovers_model():
    true = SphericalVariogram(0.01, (0.2, 0.5), (20.0, 150.0))
    lags = np.geomspace(2, 300, 30)
    fit = fit_variogram(lags, true(lags), np.full(30, 100))
    assert fit(lags) == pytest.approx(true(lags), rel=0.02, abs=1e-3)
    assert sum(fit.sills) + fit.nugget == pytest.approx(0.71, rel=0.02)


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(1)
    grid = Grid.from_bounds((W0, S0, W0 + 200, S0 + 200), 4.0)
    xy = rng.uniform([W0, S0], [W0 + 200, S0 + 200], (300, 2))
    z = 1000 + 3 * np.sin(xy[:, 0] / 30.0) + rng.normal(0, 0.1, 300)
    s = ElevationSamples(xy, z, 0.01, crs=grid.crs)
    k = SquaredExponential(4.0, 25.0)
    gp = TerrainGP(kernel=k, optimize=False, nugget=1e-3, nugget_bounds="fixed").fit(s)
    return gp, s, grid


def _dense_reference(gp, s, grid, w):
    """w^T Sigma_post w from dense matrices (R&W Eq 2.24 and 2.42), no FFT."""
    q = grid.xy()
    X = s.xy
    K = gp.kernel_(X) + np.diag(s.z_var + gp.nugget_)
    Kq = gp.kernel_(q, X)
    wv = w.ravel()
    v = Kq.T @ wv
    A = np.linalg.inv(K)
    var = wv @ gp.kernel_(q) @ wv - v @ A @ v
    H, hq = np.ones((len(X), 1)), np.ones((len(q), 1))
    cov = np.linalg.inv(H.T @ A @ H)
    R = hq.T @ wv - H.T @ A @ v
    return var + R @ cov @ R, cdist(q, X)


def test_gp_integral_matches_dense_posterior(fitted):
    gp, s, grid = fitted
    w = outline_weights(grid, box(W0 + 40, S0 + 30, W0 + 170, S0 + 150))
    ref, _ = _dense_reference(gp, s, grid, w)
    got = gp_integral(gp, grid, w)
    # the posterior is 1.7e-4 of the prior here: a difference of two large numbers, so this
    # checks v = K_Xq w to ~1e-10 (a bilinearly interpolated v was 7x off)
    assert got["posterior_var_m6"] == pytest.approx(float(ref), rel=1e-5)


def test_offset_response_is_a_refit_with_moved_samples(fitted):
    gp, s, grid = fitted
    w = outline_weights(grid, box(W0 + 40, S0 + 30, W0 + 170, S0 + 150))
    got = gp_integral(gp, grid, w)["offset_response_m2"]
    # a constant mean fitted by GLS absorbs a common offset: the whole map moves by it
    assert got == pytest.approx(w.sum(), rel=1e-6)
    moved = ElevationSamples(s.xy, s.z + 1.0, s.z_var, crs=s.crs)
    gp2 = TerrainGP(kernel=gp.kernel_, optimize=False, nugget=1e-3, nugget_bounds="fixed")
    m1 = gp.predict(grid.xy()).reshape(grid.shape)
    m2 = gp2.fit(moved).predict(grid.xy()).reshape(grid.shape)
    assert np.sum(w * (m2 - m1)) == pytest.approx(got, rel=1e-6)


def test_offset_response_with_fixed_mean_is_partial(fitted):
    gp, s, grid = fitted
    gp0 = TerrainGP(kernel=gp.kernel_, optimize=False, mean=1000.0, nugget=1e-3)
    gp0.nugget_bounds = "fixed"
    gp0.fit(s)
    w = outline_weights(grid, box(W0 + 40, S0 + 30, W0 + 170, S0 + 150))
    got = gp_integral(gp0, grid, w)["offset_response_m2"]
    m1 = gp0.predict(grid.xy()).reshape(grid.shape)
    moved = ElevationSamples(s.xy, s.z + 1.0, s.z_var, crs=s.crs)
    gp1 = TerrainGP(kernel=gp.kernel_, optimize=False, mean=1000.0, nugget=1e-3)
    gp1.nugget_bounds = "fixed"
    m2 = gp1.fit(moved).predict(grid.xy()).reshape(grid.shape)
    assert np.sum(w * (m2 - m1)) == pytest.approx(got, rel=1e-3)
    assert 0 < got < w.sum()


def _products(grid, dh_value, std_b=0.2, std_a=0.3):
    rng = np.random.default_rng(0)
    base = 1000 + rng.normal(0, 1, grid.shape)
    from terrain.product import terrain_dataset

    b = terrain_dataset(grid, base, np.full(grid.shape, std_b), {"seed": 1})
    a = terrain_dataset(grid, base + dh_value, np.full(grid.shape, std_a), {"seed": 2})
    return b, a


def test_volume_mass_and_bad_input():
    grid = Grid.from_bounds((W0, S0, W0 + 100, S0 + 100), 1.0)
    b, a = _products(grid, -2.0)
    rng = np.random.default_rng(5)
    a["elevation"] = a["elevation"] + rng.normal(0, 0.05, grid.shape)  # stable ground noise
    d = difference(b, a, coregister=False)
    outline = box(W0 + 20, S0 + 20, W0 + 60, S0 + 70)  # 40 x 50 cells of 1 m^2
    vc = volume_change(d, outline, density=(850.0, 60.0))
    dh = d["dh"].values[30:80, 20:60]
    assert vc.area_m2 == 2000.0 and vc.n_cells == 2000
    assert vc.volume_m3 == pytest.approx(dh.sum(), rel=1e-12)
    assert vc.mass_kg == pytest.approx(850.0 * vc.volume_m3)
    # Huss 2013 propagation by hand
    assert vc.mass_std_kg == pytest.approx(
        np.hypot(850.0 * vc.volume_std_m3, 60.0 * vc.volume_m3), rel=1e-12
    )
    assert vc.method == "variogram" and "variogram_correlated" in vc.budget_m3
    assert vc.independent_std_m3 == pytest.approx(np.sqrt(2000 * (0.2**2 + 0.3**2)), rel=1e-9)
    for dens in [(0.0, 60.0), (-850.0, 60.0)]:
        with pytest.raises(InputError, match="density"):
            volume_change(d, outline, density=dens)
    with pytest.raises(InputError, match="outline"):
        volume_change(d, box(W0 + 500, S0, W0 + 600, S0 + 100))
    with pytest.raises(InputError, match="stable cells"):  # no stable ground left
        volume_change(d, box(W0, S0, W0 + 100, S0 + 100))
    # an outline 10 m beyond the grid on every side: 30.6 % of its 14,400 m^2 (by hand)
    with pytest.raises(InputError, match="outline: .*30.6 % of its 14,400 m.2 beyond the change"):
        volume_change(d, box(W0 - 10, S0 - 10, W0 + 110, S0 + 110))
    half = box(W0 + 50, S0, W0 + 150, S0 + 100)  # half of it off the grid: clipped, it maps
    from terrain.outline_cover import clip_outline

    clipped, record = clip_outline(half, Grid.from_dataarray(d))
    assert record["outside_share"] == pytest.approx(0.5) and clipped.area == pytest.approx(5000)
    assert volume_change(d, clipped).details["outline"]["outside_grid_m2"] == 0.0


def test_tiled_gp_route_is_an_upper_bound():
    rng = np.random.default_rng(3)
    grid = Grid.from_bounds((W0, S0, W0 + 300, S0 + 300), 5.0)
    xy = rng.uniform([W0, S0], [W0 + 300, S0 + 300], (2400, 2))
    z = 1000 + 3 * np.sin(xy[:, 0] / 30.0) + rng.normal(0, 0.2, xy.shape[0])
    s = ElevationSamples(xy, z, 0.04, crs=grid.crs)
    k = SquaredExponential(4.0, 20.0)
    kw = {"kernel": k, "optimize": False, "nugget": 1e-3, "nugget_bounds": "fixed"}
    exact = TerrainGP(method="exact", **kw).fit(s)
    tiled = TerrainGP(method="tiled", **kw).fit(s)
    w = outline_weights(grid, box(W0 + 50, S0 + 50, W0 + 250, S0 + 230))
    ref = gp_integral(exact, grid, w)
    full = gp_integral(tiled, grid, w, subset_max=5000)  # every sample: the exact answer
    assert full["posterior_var_m6"] == pytest.approx(ref["posterior_var_m6"], rel=1e-6)
    assert "2400 of 2400" in full["route"] and ref["route"] == "exact GP posterior"
    half = gp_integral(tiled, grid, w, subset_max=1200)
    # fewer samples, larger posterior variance: a conservative bound (measured 2.29x in
    # variance, 1.51x in sigma, for half of the samples here; 6.9x / 2.6x for a quarter)
    assert ref["posterior_var_m6"] < half["posterior_var_m6"] < 4 * ref["posterior_var_m6"]
    assert half["offset_response_m2"] == pytest.approx(w.sum(), rel=1e-6)


def test_gp_route_budget_offsets_or_coregistration(fitted):
    gp, s, grid = fitted
    p = gp.predict_grid(grid)
    p.attrs["shared_vertical_offset_std_m"] = 0.1
    outline = box(W0 + 60, S0 + 60, W0 + 140, S0 + 140)
    w = outline_weights(grid, outline)
    d = difference(p, p, coregister=False)
    vc = volume_change(d, outline, models=(gp, gp))
    assert vc.volume_m3 == 0.0 and vc.method == "gp_posterior"
    # constant mean by GLS: each survey's offset moves the whole map, 0.1 m x area
    assert vc.budget_m3["shared_offset_before"] == pytest.approx(0.1 * w.sum(), rel=1e-6)
    g = gp_integral(gp, grid, w)
    assert vc.budget_m3["gp_after"] == pytest.approx(np.sqrt(g["posterior_var_m6"]))
    total = np.sqrt(2 * g["posterior_var_m6"] + 2 * (0.1 * w.sum()) ** 2)
    assert vc.volume_std_m3 == pytest.approx(total, rel=1e-9)
    dco = difference(p, p, coregister=True, outline=outline)
    vco = volume_change(dco, outline, models=(gp, gp))
    assert "coregistration_bias" in vco.budget_m3
    assert not any(k.startswith("shared_offset") for k in vco.budget_m3)


def test_sample_weights_are_a_refit_with_perturbed_samples(fitted):
    """u (the estimator's weights, R&W Eq 2.42 with the GLS constant): a refit at the same
    hyperparameters with the samples moved by a random d moves the integral by u^T d."""
    gp, s, grid = fitted
    w = outline_weights(grid, box(W0 + 40, S0 + 30, W0 + 170, S0 + 150))
    g = gp_integral(gp, grid, w)
    u = g["sample_weights"]
    assert u.shape == (s.n,) and np.array_equal(g["sample_index"], np.arange(s.n))
    assert u.sum() == pytest.approx(g["offset_response_m2"], rel=1e-9)
    d = np.random.default_rng(5).normal(0, 0.5, s.n)
    moved = ElevationSamples(s.xy, s.z + d, s.z_var, crs=s.crs)
    gp2 = TerrainGP(kernel=gp.kernel_, optimize=False, nugget=1e-3, nugget_bounds="fixed")
    m1 = gp.predict(grid.xy()).reshape(grid.shape)
    m2 = gp2.fit(moved).predict(grid.xy()).reshape(grid.shape)
    # u is over the fit's rows (in order of position): the caller's d taken in that order
    assert np.sum(w * (m2 - m1)) == pytest.approx(u @ d[gp.sample_order_], rel=1e-6)


def test_along_track_term_in_the_budget(fitted):
    """With observation times in the samples the budget has along_track_before/after =
    sqrt(u^T C u - sum u_i^2 s_i^2), s_i^2 = fraction z_var_i (dense C here); without them
    the term is stated as not available, not zero; along_track=False leaves it out."""
    from terrain.along_track import AlongTrackModel

    gp, s, grid = fitted
    t = np.random.default_rng(2).uniform(0, 900, s.n)
    st = ElevationSamples(s.xy, s.z, s.z_var, crs=s.crs, extra={"t_s": t})
    kw = {"kernel": gp.kernel_, "optimize": False, "nugget": 1e-3, "nugget_bounds": "fixed"}
    gpt = TerrainGP(**kw).fit(st)
    p = gpt.predict_grid(grid)
    outline = box(W0 + 60, S0 + 60, W0 + 140, S0 + 140)
    d = difference(p, p, coregister=False)
    model = AlongTrackModel(fraction=0.8, tau_s=60.0)
    vc = volume_change(d, outline, models=(gpt, gpt), along_track=model)
    u = gp_integral(gpt, grid, outline_weights(grid, outline))["sample_weights"]
    sd, t = np.sqrt(0.8 * s.z_var)[gpt.sample_order_], t[gpt.sample_order_]  # the fit's rows
    C = sd[:, None] * sd[None, :] * np.exp(-np.abs(t[:, None] - t[None, :]) / 60.0)
    ref = u @ (C - np.diag(np.diag(C))) @ u
    assert ref > 0
    assert vc.budget_m3["along_track_after"] == pytest.approx(np.sqrt(ref), rel=1e-8)
    assert vc.details["along_track"]["before"]["status"] == "included"
    total = sum(v**2 for v in vc.budget_m3.values())
    assert vc.volume_std_m3 == pytest.approx(np.sqrt(total), rel=1e-12)
    off = volume_change(d, outline, models=(gpt, gpt), along_track=False)
    assert "along_track_after" not in off.budget_m3
    assert vc.volume_std_m3**2 == pytest.approx(off.volume_std_m3**2 + 2 * ref, rel=1e-9)
    # samples without times (an old samples.csv): stated, not silently zero
    p0 = gp.predict_grid(grid)
    v0 = volume_change(difference(p0, p0, coregister=False), outline, models=(gp, gp))
    assert "along_track_after" not in v0.budget_m3
    assert v0.details["along_track"]["after"]["status"].startswith("not available")
    assert "along-track term NOT in the 1-sigma" in v0.details["method_note"]
    with pytest.raises(InputError, match="along_track"):
        volume_change(d, outline, models=(gpt, gpt), along_track="yes")


def test_a_constant_difference_has_the_zero_variogram():
    # Two DEMs equal but for a constant on stable ground: every semivariance is 0. The fit's
    # bounds used to collapse (scipy: "each lower bound must be strictly less than each upper
    # bound") and `glacimap change` stopped with a traceback.
    lags = np.array([10.0, 20.0, 40.0, 80.0])
    v = fit_variogram(lags, np.zeros(4), np.full(4, 100))
    assert v.nugget == 0.0 and v.sills == (0.0, 0.0)
    assert float(np.max(v(np.array([0.0, 50.0, 500.0])))) == 0.0
