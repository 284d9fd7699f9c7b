"""The prior DEM's scale checked (``terrain.prior_scale.checked_scale``): GLS against OLS.

References: GLS and the OLS sandwich computed independently here with ``numpy.linalg``
(dense ``K``, no Cholesky): ``beta_gls = (H^T K^-1 H)^-1 H^T K^-1 z``, ``cov_ols = H^+ K
H^+T`` with ``H^+`` the pseudo-inverse; the offset given a fixed scale by the one-column GLS
of ``z - b DEM``. The two cases: samples drawn from the model itself (the check must keep
GLS) and a DEM whose short-scale detail is an artefact the ground lacks (GLS shrinks the
scale toward 0; the check must reject it and keep the regression's).
"""

from __future__ import annotations

import numpy as np
import pytest

from terrain import ElevationSamples, RasterMean, SquaredExponential, TerrainGP
from terrain.grid import Grid
from terrain.prior_scale import HAUSMAN_Z, checked_scale


def _lines(n_lines=4, step=2.0, length=200.0, spacing=60.0):
    """Dense north-south lines (m): the survey shape where GLS weighs short scales most."""
    y = np.arange(0.0, length, step)
    return np.vstack([np.column_stack([np.full(y.size, i * spacing), y]) for i in range(n_lines)])


def _K(xy, length, variance, noise):
    d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1)
    return variance * np.exp(-0.5 * d2 / length**2) + noise * np.eye(len(xy))


def _smooth(xy):
    return 20.0 * np.sin(xy[:, 0] / 90.0) + 0.1 * xy[:, 1]


def test_samples_from_the_model_keep_the_gls_scale():
    rng = np.random.default_rng(0)
    xy = _lines()
    K = _K(xy, 15.0, 0.5, 0.01)
    dem = _smooth(xy)
    z = 3.0 + 1.0 * dem + np.linalg.cholesky(K) @ rng.standard_normal(len(xy))
    H = np.column_stack([np.ones(len(xy)), dem])
    beta, cov, rec = checked_scale(H, z, np.linalg.cholesky(K))
    Ki = np.linalg.inv(K)
    cov_ref = np.linalg.inv(H.T @ Ki @ H)
    np.testing.assert_allclose(beta, cov_ref @ H.T @ Ki @ z, rtol=1e-8)
    np.testing.assert_allclose(cov, cov_ref, rtol=1e-8)
    assert rec["used"] == "gls" and abs(rec["z"]) <= HAUSMAN_Z and rec["note"] == ""
    Hp = np.linalg.pinv(H)  # the OLS sandwich, independently
    assert rec["sd_ols"] == pytest.approx(np.sqrt((Hp @ K @ Hp.T)[1, 1]), rel=1e-8)
    assert rec["b_ols"] == pytest.approx((Hp @ z)[1], rel=1e-10)
    assert rec["sd_ols"] >= rec["sd_gls"]  # GLS is the efficient one under the model


def test_a_dem_with_detail_the_ground_lacks_is_read_at_the_regressions_scale():
    rng = np.random.default_rng(1)
    xy = _lines()
    K = _K(xy, 15.0, 0.5, 0.01)
    ground = _smooth(xy) + np.linalg.cholesky(K) @ rng.standard_normal(len(xy))
    # the DEM: the smooth ground plus a 12 m ripple (a resampling artefact) it does not have
    dem = _smooth(xy) + 1.5 * np.sin(2 * np.pi * xy[:, 1] / 12.0)
    z = 3.0 + ground
    H = np.column_stack([np.ones(len(xy)), dem])
    beta, cov, rec = checked_scale(H, z, np.linalg.cholesky(K))
    assert rec["b_gls"] < 0.8 and rec["b_ols"] == pytest.approx(1.0, abs=0.05)  # shrunk vs not
    assert rec["used"] == "ols" and abs(rec["z"]) > HAUSMAN_Z
    assert "Hausman z" in rec["note"]
    Ki = np.linalg.inv(K)
    one = np.ones(len(xy))
    b = rec["b_ols"]
    v_a = 1.0 / (one @ Ki @ one)
    a = v_a * (one @ Ki @ (z - b * dem))  # GLS offset given the scale
    J = -(one @ Ki @ dem) * v_a
    v_b = rec["sd_ols"] ** 2
    np.testing.assert_allclose(beta, [a, b], rtol=1e-8)
    np.testing.assert_allclose(cov, [[v_a + J * J * v_b, J * v_b], [J * v_b, v_b]], rtol=1e-8)
    assert beta[0] == pytest.approx(3.0, abs=1.0)


def test_terrain_gp_records_the_check_and_reads_the_rejected_dem_at_its_regression(tmp_path):
    rng = np.random.default_rng(2)
    xy = _lines(n_lines=3, step=4.0)
    K = _K(xy, 15.0, 0.5, 0.01)
    z = 3.0 + _smooth(xy) + np.linalg.cholesky(K) @ rng.standard_normal(len(xy))
    g = Grid.from_bounds((-20.0, -20.0, 160.0, 220.0), 2.0, "EPSG:32608")
    xx, yy = np.meshgrid(g.x, g.y)
    q = np.column_stack([xx.ravel(), yy.ravel()])
    ripple = (_smooth(q) + 1.5 * np.sin(2 * np.pi * q[:, 1] / 12.0)).reshape(g.shape)
    dem = g.data_array(ripple, "elevation")
    samples = ElevationSamples(xy + [0.0, 0.0], z, 0.01, crs="EPSG:32608")
    gp = TerrainGP(mean=RasterMean(dem), kernel=SquaredExponential(0.5, 15.0), optimize=False)
    gp.fit(samples)
    rec = gp.mean_.scale_check_
    assert rec["used"] == "ols" and rec["b_gls"] < 0.8
    assert gp.mean_.coef_[1] == pytest.approx(rec["b_ols"])
    assert gp.mean_.describe()["scale_check"]["used"] == "ols"
    assert "scale by least squares" in repr(gp.mean_)
    smooth = g.data_array(_smooth(q).reshape(g.shape), "elevation")  # a DEM the ground agrees with
    gp2 = TerrainGP(mean=RasterMean(smooth), kernel=SquaredExponential(0.5, 15.0), optimize=False)
    assert gp2.fit(samples).mean_.scale_check_["used"] == "gls"


def test_a_breaklines_columns_are_estimated_given_the_rejected_scale():
    rng = np.random.default_rng(3)
    xy = _lines()
    K = _K(xy, 15.0, 0.5, 0.01)
    step = (xy[:, 1] > 100.0).astype(float)  # a 2 m step across the lines
    ground = _smooth(xy) + 2.0 * step + np.linalg.cholesky(K) @ rng.standard_normal(len(xy))
    dem = _smooth(xy) + 1.5 * np.sin(2 * np.pi * xy[:, 1] / 12.0)
    H = np.column_stack([np.ones(len(xy)), dem, step])  # as BreaklineMean lays it: base, steps
    z = 3.0 + ground
    beta, cov, rec = checked_scale(H, z, np.linalg.cholesky(K), j=1)
    assert rec["used"] == "ols"
    Ki = np.linalg.inv(K)
    o = [0, 2]
    b, v_b = rec["b_ols"], rec["sd_ols"] ** 2
    Ho = H[:, o]
    v_oo = np.linalg.inv(Ho.T @ Ki @ Ho)
    rest = v_oo @ Ho.T @ Ki @ (z - b * dem)  # GLS of z - b DEM on [1, step]
    J = -v_oo @ Ho.T @ Ki @ dem
    np.testing.assert_allclose(beta[o], rest, rtol=1e-8)
    assert beta[1] == b  # the regression's scale, the step by GLS given it (hand formula above)
    np.testing.assert_allclose(cov[np.ix_(o, o)], v_oo + np.outer(J, J) * v_b, rtol=1e-8)
    np.testing.assert_allclose(cov[o, 1], J * v_b, rtol=1e-8)
    assert cov[1, 1] == pytest.approx(v_b)
