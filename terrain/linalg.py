"""Cholesky factorization with honest jitter, shared by every GP in glacimap.

A kernel matrix that is merely ill-conditioned (near-duplicate points, tiny noise) is
retried with a growing diagonal jitter, and a :class:`JitterWarning` says how much was added;
one that stays indefinite raises :class:`NumericalError`. Never a silent continue.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from scipy.linalg import lapack

from .errors import JitterWarning, NumericalError
from .heap import keep_freed_memory
from .nogil_lapack import cholesky_lower

__all__ = ["cholesky_jitter", "inverse_from_cholesky", "one_blas_thread", "single_blas_thread"]

_F = TypeVar("_F", bound=Callable[..., Any])


def one_blas_thread() -> Any:
    """Context in which BLAS / LAPACK run on one thread (``threadpoolctl``).

    Measured on the 2-core machines glacimap targets (OpenBLAS 0.3.31): a 2000 x 2000
    Cholesky takes 0.05 s on one thread and 1.03 s on two while another process holds a
    core (the second thread spins on the busy core); the default run's reconstruct stage
    took 6.9 s against 17.0 s at load ~2.5, and the same 6.7 s on a quiet machine. One
    thread also keeps the summation order, hence the bytes, the same whatever the core
    count ("same seed, same bytes, however many workers"). glacimap parallelises over
    tiles instead (:mod:`terrain.tiled`).
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1, user_api="blas")


def single_blas_thread(func: _F) -> _F:
    """Decorator: run ``func`` inside :func:`one_blas_thread`, with glibc told to reuse freed
    memory (:func:`terrain.heap.keep_freed_memory`, once per process)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        keep_freed_memory()
        with one_blas_thread():
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def cholesky_jitter(
    K: np.ndarray, *, max_relative_jitter: float = 1e-4, what: str = "kernel matrix"
) -> tuple[np.ndarray, float]:
    """Lower Cholesky factor of ``K``, adding diagonal jitter only when it is needed.

    Parameters
    ----------
    K : ndarray of shape (n, n)
        Symmetric matrix; it is not modified.
    max_relative_jitter : float
        Largest jitter tried, relative to the mean of ``diag(K)``; jitter starts at 1e-10 of
        it and grows tenfold per try.
    what : str
        Name used in the warning and error messages.

    Returns
    -------
    L : ndarray of shape (n, n)
        Lower-triangular factor with ``L @ L.T = K + jitter * I``.
    jitter : float
        The jitter added, in the units of ``K`` (0.0 when none was needed).
    """
    L = cholesky_lower(K)  # GIL released: callers factor in threads (terrain.tiled)
    if L is not None:
        return L, 0.0
    scale = float(np.mean(np.diag(K)))
    if not np.isfinite(scale) or scale <= 0:
        raise NumericalError(
            f"{what}: the diagonal mean is {scale}, so it cannot be a covariance. Fix: check "
            "the kernel variance and the noise variances."
        )
    jitter = 1e-10 * scale
    while jitter <= max_relative_jitter * scale * (1 + 1e-12):
        Kj = K.copy()
        Kj[np.diag_indices_from(Kj)] += jitter
        L = cholesky_lower(Kj)
        if L is None:
            jitter *= 10.0
            continue
        warnings.warn(
            f"{what} was not numerically positive definite; added jitter {jitter:.3g} "
            f"(= {jitter / scale:.1e} of its mean diagonal) to factor it. Near-duplicate "
            "locations with tiny noise usually cause this; a nugget or merged duplicates fix it.",
            JitterWarning,
            stacklevel=3,
        )
        return L, jitter
    raise NumericalError(
        f"{what} stayed indefinite after jitter up to {max_relative_jitter:.0e} of its mean "
        "diagonal. Fix: add a nugget / measurement variance, or remove duplicate locations."
    )


def inverse_from_cholesky(L: np.ndarray) -> np.ndarray:
    """``K^{-1}`` from the lower factor ``L`` (LAPACK dpotri), full symmetric (n, n).

    Needed only for the trace term of the marginal-likelihood gradient (R&W Eq 5.9).
    """
    inv, info = lapack.dpotri(L, lower=1)
    if info != 0:
        raise NumericalError(f"dpotri failed with info={info} while inverting a Cholesky factor")
    inv = np.tril(inv)
    inv += np.tril(inv, -1).T
    return inv
