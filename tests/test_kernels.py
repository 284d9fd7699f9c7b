import numpy as np
import pytest
from sklearn.gaussian_process.kernels import RBF, ConstantKernel
from sklearn.gaussian_process.kernels import Matern as SkMatern

from terrain import InputError
from terrain.kernels import Matern, SquaredExponential

X = np.random.default_rng(0).uniform(0, 60, (25, 2))


@pytest.mark.parametrize(
    "ours, theirs",
    [
        (SquaredExponential(3.0, 7.0), ConstantKernel(3.0) * RBF(7.0)),
        (SquaredExponential(3.0, (7.0, 4.0)), ConstantKernel(3.0) * RBF([7.0, 4.0])),
        (Matern(2.0, 9.0, nu=1.5), ConstantKernel(2.0) * SkMatern(9.0, nu=1.5)),
        (Matern(2.0, (9.0, 3.0), nu=2.5), ConstantKernel(2.0) * SkMatern([9.0, 3.0], nu=2.5)),
        (
            Matern(9.0, 40.0, nu=2.5) + SquaredExponential(0.5, 4.0),
            ConstantKernel(9.0) * SkMatern(40.0, nu=2.5) + ConstantKernel(0.5) * RBF(4.0),
        ),
    ],
)
def test_values_and_gradients_equal_sklearn(ours, theirs):
    # Reference: scikit-learn kernels, whose eval_gradient is also d/dlog(param).
    K_ref, G_ref = theirs(X, eval_gradient=True)
    np.testing.assert_allclose(ours(X), K_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.stack(list(ours.gradients(X)), -1), G_ref, atol=1e-12)
    np.testing.assert_allclose(ours.diag(X), np.diag(K_ref))


@pytest.mark.parametrize("ls", [9.0, (9.0, 3.0)])
def test_matern72_equals_sklearn_bessel_form(ls):
    # Reference: scikit-learn's Matern with nu = 3.5 takes its general branch (modified
    # Bessel function K_nu, R&W Eq 4.14), independent of our closed form (R&W Eq 4.17).
    ours = Matern(2.0, ls, nu=3.5)
    K_ref = (ConstantKernel(2.0) * SkMatern(ls, nu=3.5))(X)
    np.testing.assert_allclose(ours(X), K_ref, rtol=1e-10, atol=1e-12)
    # Gradients d/dlog(param) against central differences of those values (sklearn's own
    # are one-sided differences, good to ~1e-5 only).
    h = 1e-6
    for i, g in enumerate(ours.gradients(X)):
        step = np.zeros(ours.n_params)
        step[i] = h
        fd = (ours.with_theta(ours.theta + step)(X) - ours.with_theta(ours.theta - step)(X)) / (
            2 * h
        )
        np.testing.assert_allclose(g, fd, rtol=1e-7, atol=1e-9)


def test_paper_readings_of_gamma():
    # Eq 1 literally: Gamma = diag(1/gamma) -> l = sqrt(315) = 17.748 m; prose: l = 315 m.
    lit = SquaredExponential.from_paper(10.0, 315.0, reading="squared_lengthscale")
    prose = SquaredExponential.from_paper(10.0, 315.0, reading="lengthscale")
    assert lit.lengthscale == pytest.approx(17.7482393)
    assert prose.lengthscale == 315.0 and lit.variance == 10.0
    # Eq 1 evaluated by hand at distance d = 20 m along x: 10 * exp(-0.5 * 400 / 315)
    k = lit(np.array([[0.0, 0.0]]), np.array([[20.0, 0.0]]))[0, 0]
    assert k == pytest.approx(10.0 * np.exp(-0.5 * 400.0 / 315.0))
    with pytest.raises(InputError, match="reading"):
        SquaredExponential.from_paper(10.0, 315.0, reading="gamma")


def test_theta_roundtrip_and_bad_values():
    k = Matern(2.0, (5.0, 8.0), nu=2.5)
    back = k.with_theta(k.theta)
    np.testing.assert_allclose(back.lengths, k.lengths, rtol=1e-14)
    assert back.variance == pytest.approx(k.variance, rel=1e-14) and back.nu == k.nu
    assert k.bounds.shape == (3, 2)
    with pytest.raises(InputError, match="lengthscale"):
        SquaredExponential(1.0, -2.0)
    with pytest.raises(InputError, match="variance"):
        SquaredExponential(0.0, 2.0)
    with pytest.raises(InputError, match="nu"):
        Matern(1.0, 2.0, nu=0.5)
