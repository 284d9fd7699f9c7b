"""The GP log marginal likelihood (paper Eq 9) and its analytic gradient (R&W Eq 5.9)."""

from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, cho_solve, cholesky

from .errors import NumericalError
from .linalg import cholesky_jitter, inverse_from_cholesky

__all__ = ["gaussian_lml"]

_LOG_2PI = np.log(2.0 * np.pi)


def gaussian_lml(
    kernel,
    X: np.ndarray,
    r: np.ndarray,
    noise_var: np.ndarray,
    eval_gradient: bool = False,
    strict: bool = False,
    nugget: float | None = None,
) -> float | tuple[float, np.ndarray]:
    """``log p(r | X, theta)`` for residuals ``r`` under ``kernel`` plus diagonal noise.

    Parameters
    ----------
    kernel : Kernel
        Covariance with the hyperparameters to evaluate.
    X : ndarray of shape (n, 2)
        Sample locations, m.
    r : ndarray of shape (n,)
        Samples minus the prior mean, m.
    noise_var : ndarray of shape (n,)
        Per-sample noise variance including any nugget, m^2 (Eq 6).
    eval_gradient : bool
        Also return d lml / d theta for the kernel's log-parameters, followed by
        d lml / d log(nugget) when ``nugget`` is given.
    strict : bool
        Raise :class:`NumericalError` instead of adding jitter (inside optimizers, where
        jitter would change the objective).
    nugget : float, optional
        The nugget inside ``noise_var``; its gradient is appended when given.
    """
    K = kernel(X)
    K[np.diag_indices_from(K)] += noise_var
    if strict:
        try:
            L = cholesky(K, lower=True, check_finite=False)
        except LinAlgError as exc:
            raise NumericalError("kernel matrix not positive definite") from exc
    else:
        L, _ = cholesky_jitter(K, what="TerrainGP kernel matrix")
    del K
    alpha = cho_solve((L, True), r, check_finite=False)
    # Eq 9: -1/2 y^T K^-1 y - 1/2 log|K| - n/2 log 2 pi  (R&W Alg. 2.1 line 8)
    lml = float(-0.5 * r @ alpha - np.log(np.diag(L)).sum() - 0.5 * r.size * _LOG_2PI)
    if not eval_gradient:
        return lml
    # R&W Eq 5.9: d lml / d theta_j = 1/2 tr((alpha alpha^T - K^-1) dK/dtheta_j)
    Kinv = inverse_from_cholesky(L)
    del L
    grad = [
        0.5 * (alpha @ dK @ alpha - np.einsum("ij,ij->", Kinv, dK)) for dK in kernel.gradients(X)
    ]
    if nugget is not None:  # dK/dlog(nugget) = nugget * I
        grad.append(0.5 * nugget * (alpha @ alpha - np.trace(Kinv)))
    return lml, np.asarray(grad)
