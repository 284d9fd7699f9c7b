"""TerrainGP against independent references: scikit-learn, dense numpy algebra, finite
differences."""

import numpy as np
import pytest
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel
from sklearn.gaussian_process.kernels import Matern as SkMatern

from terrain import ElevationSamples, Grid, JitterWarning
from terrain.errors import InputError, NotFittedError
from terrain.gp import TerrainGP
from terrain.kernels import Matern, SquaredExponential


def _data(n=60, seed=1, noise=0.05):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 100, (n, 2))
    z = 3 * np.sin(xy[:, 0] / 15) + 0.02 * xy[:, 1] + rng.normal(0, noise, n)
    return xy, z


def _query(m=40, seed=2):
    return np.random.default_rng(seed).uniform(-10, 110, (m, 2))


@pytest.mark.parametrize(
    "ours, theirs",
    [
        (SquaredExponential(4.0, 12.0), ConstantKernel(4.0) * RBF(12.0)),
        (SquaredExponential(2.0, (20.0, 8.0)), ConstantKernel(2.0) * RBF([20.0, 8.0])),
        (Matern(3.0, 15.0, nu=1.5), ConstantKernel(3.0) * SkMatern(15.0, nu=1.5)),
        (Matern(3.0, 15.0, nu=2.5), ConstantKernel(3.0) * SkMatern(15.0, nu=2.5)),
    ],
)
def test_equals_sklearn_homoscedastic(ours, theirs):
    # Reference: scikit-learn's GaussianProcessRegressor with the same fixed hyperparameters,
    # zero mean and alpha = homoscedastic noise variance.
    xy, z = _data()
    noise = 0.05**2
    gp = TerrainGP(kernel=ours, mean=0.0, nugget=noise, nugget_bounds="fixed", optimize=False)
    gp.fit(ElevationSamples(xy, z))
    sk = GaussianProcessRegressor(theirs, alpha=noise, optimizer=None, normalize_y=False)
    sk.fit(xy, z)
    q = _query()
    m, s = gp.predict(q, return_std=True)
    m_sk, s_sk = sk.predict(q, return_std=True)
    np.testing.assert_allclose(m, m_sk, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(s, s_sk, rtol=1e-6, atol=1e-9)
    assert gp.log_marginal_likelihood() == pytest.approx(sk.log_marginal_likelihood(), rel=1e-6)


def test_optimized_lml_at_least_sklearn():
    # Both maximize Eq 9 with L-BFGS-B; ours must reach sklearn's optimum (or better).
    xy, z = _data(n=80)
    noise = 0.05**2
    gp = TerrainGP(
        kernel=SquaredExponential(1.0, 10.0, lengthscale_bounds=(1e-1, 1e3)),
        mean=0.0,
        nugget=noise,
        nugget_bounds="fixed",
        n_restarts=3,
        seed=0,
    ).fit(ElevationSamples(xy, z))
    sk = GaussianProcessRegressor(
        ConstantKernel(1.0, (1e-4, 1e6)) * RBF(10.0, (1e-1, 1e3)),
        alpha=noise,
        n_restarts_optimizer=3,
        random_state=0,
    ).fit(xy, z)
    assert gp.log_marginal_likelihood() >= sk.log_marginal_likelihood_value_ - 1e-4


def test_per_point_noise_equals_dense_solve():
    # Reference: Eq 6 written out with numpy.linalg.solve / slogdet on the dense matrices.
    xy, z = _data(n=50)
    z_var = np.random.default_rng(3).uniform(0.001, 0.3, z.size)
    kern = Matern(2.0, 18.0, nu=2.5)
    nugget = 0.02
    mean_fn = lambda p: 0.01 * p[:, 0] + 1.0  # noqa: E731
    gp = TerrainGP(
        kernel=kern, mean=mean_fn, nugget=nugget, nugget_bounds="fixed", optimize=False
    ).fit(ElevationSamples(xy, z, z_var))
    q = _query()
    K = kern(xy) + np.diag(z_var + nugget)
    Ks = kern(q, xy)
    r = z - mean_fn(xy)
    mean_ref = mean_fn(q) + Ks @ np.linalg.solve(K, r)
    cov_ref = kern(q) - Ks @ np.linalg.solve(K, Ks.T)
    m, s = gp.predict(q, return_std=True)
    np.testing.assert_allclose(m, mean_ref, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(s, np.sqrt(np.diag(cov_ref)), rtol=1e-6, atol=1e-9)
    sign, logdet = np.linalg.slogdet(K)
    lml_ref = -0.5 * r @ np.linalg.solve(K, r) - 0.5 * logdet - 0.5 * z.size * np.log(2 * np.pi)
    assert gp.log_marginal_likelihood() == pytest.approx(lml_ref, rel=1e-9)


@pytest.mark.parametrize(
    "kernel",
    [
        SquaredExponential(2.0, 12.0),
        SquaredExponential(2.0, (9.0, 25.0)),
        Matern(2.0, 12.0, nu=1.5),
        Matern(2.0, (9.0, 25.0), nu=2.5),
        Matern(2.0, 30.0, nu=2.5) + SquaredExponential(0.3, 5.0),
    ],
)
def test_lml_gradient_matches_finite_differences(kernel):
    xy, z = _data(n=40)
    z_var = np.full(z.size, 0.01)
    gp = TerrainGP(kernel=kernel, nugget=0.05, optimize=False).fit(ElevationSamples(xy, z, z_var))
    theta = np.append(kernel.theta + 0.2, np.log(0.03))
    lml, grad = gp.log_marginal_likelihood(theta, eval_gradient=True)
    h = 1e-6
    fd = []
    for j in range(theta.size):
        e = np.zeros_like(theta)
        e[j] = h
        fd.append(
            (gp.log_marginal_likelihood(theta + e) - gp.log_marginal_likelihood(theta - e))
            / (2 * h)
        )
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6)


def test_seeded_fit_is_reproducible_and_subset_documented():
    xy, z = _data(n=120)
    s = ElevationSamples(xy, z, 0.01)
    a = TerrainGP(n_restarts=2, max_fit_samples=50, seed=7).fit(s)
    b = TerrainGP(n_restarts=2, max_fit_samples=50, seed=7).fit(s)
    assert a.kernel_ == b.kernel_ and a.nugget_ == b.nugget_
    assert a.fit_index_.size == 50
    np.testing.assert_array_equal(a.predict(_query()), b.predict(_query()))


def test_chunking_does_not_change_results():
    xy, z = _data(n=70)
    s = ElevationSamples(xy, z, 0.01)
    q = _query(m=101)
    a = TerrainGP(optimize=False).fit(s)
    b = TerrainGP(optimize=False, chunk_size=7).fit(s)
    ma, sa = a.predict(q, return_std=True)
    mb, sb = b.predict(q, return_std=True)
    np.testing.assert_allclose(ma, mb, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sa, sb, rtol=0, atol=1e-12)


def test_far_from_data_returns_prior_mean_and_variance():
    xy, z = _data()
    kern = SquaredExponential(5.0, 10.0)
    gp = TerrainGP(kernel=kern, mean=42.0, optimize=False).fit(ElevationSamples(xy, z, 0.01))
    m, s = gp.predict(np.array([[1e5, 1e5], [-1e6, 3e4]]), return_std=True)
    np.testing.assert_allclose(m, 42.0)
    np.testing.assert_allclose(s, np.sqrt(5.0))


def test_predict_grid_dataset_and_provenance():
    xy, z = _data()
    grid = Grid.from_bounds((0, 0, 100, 80), 10.0)
    gp = TerrainGP(optimize=False, seed=11).fit(ElevationSamples(xy, z, 0.01, crs=grid.crs))
    ds = gp.predict_grid(grid)
    assert ds["elevation"].dims == ("y", "x") and ds["elevation"].shape == (8, 10)
    assert np.all(ds["elevation_std"] > 0)
    assert ds.attrs["seed"] == 11 and "crs_wkt" in ds.attrs
    np.testing.assert_allclose(
        ds["elevation"].values.ravel(), gp.predict(grid.xy()), rtol=0, atol=1e-12
    )


def test_bad_input_messages():
    xy, z = _data()
    with pytest.raises(InputError, match="at least 3"):
        TerrainGP().fit(ElevationSamples(xy[:2], z[:2]))
    with pytest.raises(InputError, match="ElevationSamples"):
        TerrainGP().fit((xy, z))
    with pytest.raises(NotFittedError):
        TerrainGP().predict(xy)
    with pytest.raises(InputError, match="nugget"):
        TerrainGP(nugget=-1.0).fit(ElevationSamples(xy, z))
    gp = TerrainGP(optimize=False).fit(ElevationSamples(xy, z, 0.01))
    with pytest.raises(InputError, match="xy"):
        gp.predict(np.array([[np.nan, 0.0]]))


def test_ill_conditioned_matrix_gets_jitter_with_warning():
    # Two points 1e-9 m apart with zero noise: K is singular to machine precision.
    xy = np.array([[0.0, 0.0], [1e-9, 0.0], [30.0, 5.0], [60.0, 40.0]])
    z = np.array([1.0, 1.0, 2.0, 0.5])
    gp = TerrainGP(
        kernel=SquaredExponential(1.0, 20.0), nugget=0.0, nugget_bounds="fixed", optimize=False
    )
    with pytest.warns(JitterWarning, match="added jitter"):
        gp.fit(ElevationSamples(xy, z))
    assert gp.jitter_ > 0
    assert np.all(np.isfinite(gp.predict(xy)))


def test_tiled_fit_reports_eq9_on_its_subset_when_read():
    # The tiled fit's Eq 9 (no Vecchia value: fixed kernel) is factored on first read; the
    # value is the exact Gaussian log density of the fit subset (reference: scipy's
    # multivariate normal on the same matrix), and an unfitted estimator has none.
    from scipy.stats import multivariate_normal

    from terrain.kernels import SquaredExponential

    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 300, (2500, 2))
    z = np.sin(xy[:, 0] / 30.0) * 3.0 + rng.normal(0, 0.1, 2500)
    s = ElevationSamples(xy, z, np.full(2500, 0.01), crs="EPSG:32608")
    kernel = SquaredExponential(5.0, 30.0)
    gp = TerrainGP(kernel=kernel, optimize=False, method="tiled", max_fit_samples=400).fit(s)
    pending = gp.__dict__["_lml_pending"]
    assert pending is not None  # not factored by fit
    idx = pending[2]  # the fit subset, or 2,000 of all samples when the fit used them all
    assert idx.size == min(gp.fit_index_.size, 2000)
    C = kernel(gp.X_train_[idx]) + np.diag(gp.z_var_[idx] + gp.nugget_)
    ref = multivariate_normal(np.zeros(idx.size), C).logpdf(gp.y_resid_[idx])
    assert gp.log_marginal_likelihood_value_ == pytest.approx(ref, rel=1e-10)
    assert gp.__dict__["_lml_pending"] is None
    assert gp.log_marginal_likelihood() == gp.log_marginal_likelihood_value_
    assert gp.provenance()["log_marginal_likelihood"] == gp.log_marginal_likelihood_value_
    assert not hasattr(TerrainGP(), "log_marginal_likelihood_value_")
