"""The exact GP's predictive mean and 1-sigma at many points, in row blocks over threads.

R&W Algorithm 2.1 lines 4-6 with the fitted factor ``L`` of ``K + diag(noise)``: each block
of query rows gets its cross-covariance ``K*`` (block, n), the mean ``K* alpha`` and the
variance ``k** - |L^-1 K*^T|^2`` without the (m, m) posterior covariance. The triangular
solve releases the GIL (:mod:`terrain.nogil_lapack`), so blocks run side by side on the
cores; every block is computed alone and written to its own rows, so the bytes do not depend
on the number of threads.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from .gp_mean import variance_term
from .nogil_lapack import solve_lower

__all__ = ["predict_exact"]


def predict_exact(
    Xq: np.ndarray,
    X: np.ndarray,
    L: np.ndarray,
    alpha: np.ndarray,
    kernel: Any,
    rows: int,
    prior_mean: np.ndarray,
    return_std: bool,
    extra_var: float = 0.0,
    basis: tuple[Any, np.ndarray, np.ndarray] | None = None,
    workers: int | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Exact posterior mean and 1-sigma at ``Xq``.

    Parameters
    ----------
    Xq : ndarray of shape (m, 2)
        Query points, centred like ``X``, m.
    X : ndarray of shape (n, 2)
        Training locations, m.
    L : ndarray of shape (n, n)
        Lower Cholesky factor of ``K + diag(noise)``.
    alpha : ndarray of shape (n,)
        ``(K + diag(noise))^-1 (z - m(X))``, m.
    kernel : Kernel
        The fitted covariance.
    rows : int
        Query rows per block (memory: ``rows * n`` doubles per block and thread).
    prior_mean : ndarray of shape (m,)
        Prior mean at the queries, m.
    return_std : bool
        Also compute the 1-sigma.
    extra_var : float
        Added to every variance (the nugget, when a noisy observation is predicted), m^2.
    basis : (basis_fn, cov, W), optional
        A linear mean's basis function of the *uncentred* points, its coefficients'
        covariance (p, p) and ``W = L^-1 H`` (n, p): adds R&W Eq 2.42's term.
    workers : int, optional
        Threads over blocks (default: the CPU count).

    Returns
    -------
    mean : ndarray of shape (m,)
    std : ndarray of shape (m,) or None
    """
    m = Xq.shape[0]
    mean = np.empty(m)
    std = np.empty(m) if return_std else None
    starts = range(0, m, rows)

    def block(start: int) -> None:
        sl = slice(start, min(start + rows, m))
        Ks = kernel(Xq[sl], X)  # (block, n)
        mean[sl] = prior_mean[sl] + Ks @ alpha  # Alg. 2.1 line 4: f* = m(x*) + k*^T alpha
        if return_std:
            V = solve_lower(L, Ks.T)  # line 5: v = L \ k*, in Ks's memory
            var = kernel.diag(Xq[sl]) - np.einsum("ij,ij->j", V, V)  # line 6
            if basis is not None:  # R&W Eq 2.42: the mean coefficients' uncertainty
                basis_fn, cov, W = basis
                var += variance_term(basis_fn(sl), cov, W, V)
            std[sl] = np.sqrt(np.maximum(var + extra_var, 0.0))

    n_threads = min(len(starts), workers or os.cpu_count() or 1)
    if n_threads <= 1:
        for start in starts:
            block(start)
    else:
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            list(pool.map(block, starts))
    return mean, std
