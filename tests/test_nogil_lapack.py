"""GIL-free LAPACK calls (terrain.nogil_lapack) and the threaded exact prediction.

Reference: SciPy's own wrappers of the same LAPACK routines (``scipy.linalg.cholesky``,
``solve_triangular``) must give the same bits; the exact prediction must give the same bits
with one thread and with several, and equal R&W Algorithm 2.1 written out with SciPy.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import cho_solve, cholesky, eigh, solve_triangular

from terrain.exact_predict import predict_exact
from terrain.kernels import Matern, SquaredExponential
from terrain.nogil_lapack import cho_solve_lower, cholesky_lower, solve_lower, symmetric_eigen


def _spd(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.uniform(0.0, 60.0, (n, 2))
    kernel = Matern(variance=2.0, lengthscale=9.0, nu=2.5) + SquaredExponential(5.0, 40.0)
    K = kernel(X)
    K[np.diag_indices_from(K)] += rng.uniform(0.01, 0.05, n)
    return X, K


@pytest.mark.parametrize("n", [1, 7, 300])
def test_cholesky_lower_is_scipys_factor(n):
    _, K = _spd(n)
    expected = cholesky(K, lower=True, check_finite=False)
    got = cholesky_lower(K)
    assert np.array_equal(got, expected)
    assert np.array_equal(np.triu(got, 1), np.zeros_like(got))


def test_cholesky_lower_reports_not_positive_definite():
    _, K = _spd(20)
    K[3, 3] = -1.0
    before = K.copy()
    assert cholesky_lower(K) is None
    assert np.array_equal(K, before)  # the input is not touched


@pytest.mark.parametrize("order", ["C", "F"])
def test_solve_lower_is_scipys_solve(order):
    rng = np.random.default_rng(1)
    _, K = _spd(250)
    L = np.asarray(cholesky(K, lower=True), order=order)
    Ks = rng.normal(size=(123, 250))  # C-ordered, so Ks.T is Fortran-ordered
    expected = solve_triangular(L, Ks.T, lower=True, check_finite=False)
    got = solve_lower(L, Ks.copy().T)
    assert np.array_equal(got, expected)
    assert np.allclose(L @ got, Ks.T, rtol=0, atol=1e-10)


def test_solve_lower_refuses_a_c_ordered_right_hand_side():
    _, K = _spd(5)
    L = cholesky(K, lower=True)
    with pytest.raises(ValueError, match="Fortran-ordered"):
        solve_lower(L, np.ones((5, 3)))


def test_exact_prediction_same_bits_for_any_thread_count_and_equal_to_alg_2_1():
    rng = np.random.default_rng(2)
    X, K = _spd(400, seed=2)
    kernel = Matern(variance=2.0, lengthscale=9.0, nu=2.5) + SquaredExponential(5.0, 40.0)
    z = rng.normal(size=400)
    L = cholesky(K, lower=True)
    alpha = cho_solve((L, True), z)
    Xq = rng.uniform(-5.0, 65.0, (1000, 2))
    prior = rng.normal(size=1000)
    one = predict_exact(Xq, X, L, alpha, kernel, 128, prior, True, 0.01, workers=1)
    three = predict_exact(Xq, X, L, alpha, kernel, 128, prior, True, 0.01, workers=3)
    assert np.array_equal(one[0], three[0]) and np.array_equal(one[1], three[1])
    Ks = kernel(Xq, X)  # R&W Alg. 2.1 lines 4-6, all rows at once
    V = solve_triangular(L, Ks.T, lower=True)
    assert np.allclose(one[0], prior + Ks @ alpha, rtol=0, atol=1e-10)
    var = kernel.diag(Xq) - np.sum(V * V, axis=0) + 0.01
    assert np.allclose(one[1], np.sqrt(var), rtol=1e-10, atol=0)
    mean_only, none = predict_exact(Xq, X, L, alpha, kernel, 128, prior, False)
    assert none is None and np.array_equal(mean_only, one[0])


def test_without_the_cython_exports_the_scipy_wrappers_give_the_same_results(monkeypatch):
    import terrain.nogil_lapack as nl

    _, K = _spd(60)
    rng = np.random.default_rng(4)
    Ks = rng.normal(size=(9, 60))
    L_fast, V_fast = cholesky_lower(K), solve_lower(cholesky_lower(K), Ks.copy().T)
    monkeypatch.setattr(nl, "_dpotrf", lambda: None)
    monkeypatch.setattr(nl, "_dtrsm", lambda: None)
    assert np.array_equal(nl.cholesky_lower(K), L_fast)
    # SciPy 1.17's solve_triangular solves this small system (60 x 9) with other rounding
    # than dtrsm: 5.8e-15 apart at most here (the same bits up to SciPy 1.16).
    V_slow = nl.solve_lower(L_fast, Ks.copy().T)
    assert np.allclose(V_slow, V_fast, rtol=0, atol=1e-12 * np.abs(V_fast).max())
    K[0, 0] = -1.0
    assert nl.cholesky_lower(K) is None


@pytest.mark.parametrize("n", [1, 2, 9, 150])
def test_symmetric_eigen_is_scipys_eigh(n):
    """dsyevr with SciPy's arguments (all pairs, abstol 0, the queried workspace)."""
    _, K = _spd(n, seed=3)
    before = K.copy()
    w, V = symmetric_eigen(K)
    w_ref, V_ref = eigh(K, check_finite=False)
    assert np.array_equal(w, w_ref) and np.array_equal(V, V_ref)
    assert np.array_equal(K, before)  # the input is not touched


@pytest.mark.parametrize("shape", [(1,), (40,), (40, 3)])
def test_cho_solve_lower_is_scipys_cho_solve(shape):
    """dpotrs is two dtrsm calls; made the same way they give the same bits."""
    rng = np.random.default_rng(4)
    _, K = _spd(shape[0], seed=4)
    L = cholesky_lower(K)
    b = rng.normal(size=shape)
    before = b.copy()
    x = cho_solve_lower(L, b)
    assert x.shape == b.shape
    assert np.array_equal(x, cho_solve((L, True), b, check_finite=False))
    assert np.array_equal(b, before)
