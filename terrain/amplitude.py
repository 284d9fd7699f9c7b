"""A tile's own kernel amplitude: how rough the ground is there, by Eq 9 on its samples.

Real ground is rough in places (a scarp, a moraine, crevasses) and smooth in others; one
stationary variance is too large for most of a map and too small where the ground is rough.
The tiled GP (:mod:`terrain.tiled`) lets each tile scale its kernel by its own amplitude
``s_t``, the maximum a posteriori value of Eq 9 on the samples in the tile's blending region
under a log-normal prior centred on the global fit (:func:`local_amplitude`).

Which parts the amplitude scales (:func:`amplitude_parts`): with one kernel part, the whole
kernel. With a sum, every part but the longest-scale one: a tile of 16-64 m sees the
roughness (the short parts and the microscale part) but not the variance of a trend over
hundreds of metres, which the whole survey fits; scaling the trend with the tile's roughness
let one scarp or one flat lake move the trend's weight in every tile it touched.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from .linalg import cholesky_jitter
from .microscale import Microscale
from .nogil_lapack import solve_lower, symmetric_eigen

__all__ = ["AMPLITUDE_BOUNDS", "AMPLITUDE_POINTS", "amplitude_parts", "local_amplitude"]

#: Most samples (nearest the tile centre) a tile's amplitude is estimated from.
AMPLITUDE_POINTS = 150
#: Search range of a tile's amplitude, relative to the global kernel variance.
AMPLITUDE_BOUNDS = (1e-3, 1e3)
#: What a tile's amplitude scales: ``"roughness"`` (every part but the longest-scale one of
#: a sum) or ``"whole"`` (the whole kernel: every release before 0.35.0).
SCOPE = "whole"


def amplitude_parts(kernel: Any, scope: str | None = None) -> tuple[Any, Any] | None:
    """``(fixed, scaled)``: the kernel parts a tile's amplitude leaves alone and those it
    scales, each a kernel (a part or a sum of parts); ``None`` when it scales the whole kernel
    (one part, or ``scope="whole"``).

    The fixed part is the longest-scale part of a sum of two or more non-microscale parts
    (the trend); the scaled parts are the rest, the :class:`terrain.microscale.Microscale`
    part included (roughness below the sample spacing)."""
    scope = SCOPE if scope is None else scope
    parts = tuple(getattr(kernel, "parts", (kernel,)))
    broad = [p for p in parts if not isinstance(p, Microscale)]
    if scope == "whole" or len(broad) < 2:
        return None
    longest = max(broad, key=lambda p: float(np.min(p.lengths)))
    rest = [p for p in parts if p is not longest]
    scaled = rest[0]
    for p in rest[1:]:
        scaled = scaled + p
    return longest, scaled


def local_amplitude(
    K: np.ndarray,
    resid: np.ndarray,
    noise_var: np.ndarray,
    prior_sd: float,
    K_fixed: np.ndarray | None = None,
) -> float:
    """MAP amplitude ``s`` of ``K_fixed + s * K + diag(noise_var)`` for residuals ``resid``
    (Eq 9).

    Maximizes ``log p(resid | s) + log N(log s; 0, prior_sd^2)`` over ``log s`` in
    :data:`AMPLITUDE_BOUNDS`. With ``W`` the inverse lower Cholesky factor of ``K_fixed +
    diag(noise_var)`` (``diag(noise_var)^(-1/2)`` without ``K_fixed``) and ``W K W^T = U
    diag(lam) U^T`` (one eigendecomposition), ``log p = -1/2 sum(c_j^2 / (1 + s lam_j)) - 1/2
    sum(log(1 + s lam_j)) + const`` with ``c = U^T W resid``: every trial ``s`` costs O(n).

    Parameters
    ----------
    K : ndarray of shape (n, n)
        Matrix of the parts the amplitude scales, at the global hyperparameters, m^2.
    resid : ndarray of shape (n,)
        Samples minus the prior mean, m.
    noise_var : ndarray of shape (n,)
        Per-sample noise variance including the nugget, m^2 (floored at 1e-10 of the mean
        kernel diagonal so that the whitening exists).
    prior_sd : float
        Standard deviation of ``log s`` under the prior (1.0: a factor e at one sigma).
    K_fixed : ndarray of shape (n, n), optional
        Matrix of the parts the amplitude leaves alone (:func:`amplitude_parts`), m^2.

    Returns
    -------
    float
        The amplitude ``s`` (1.0, the global fit, for fewer than 3 samples).
    """
    n = resid.size
    if n < 3:
        return 1.0
    floor = 1e-10 * float(np.mean(np.diag(K)))
    noise = np.maximum(noise_var, floor)
    if K_fixed is None:
        d = 1.0 / np.sqrt(noise)
        lam, U = symmetric_eigen(K * d[:, None] * d[None, :])  # GIL released (nogil_lapack)
        c2 = (U.T @ (resid * d)) ** 2
    else:
        C = K_fixed.copy()
        C[np.diag_indices_from(C)] += noise
        L, _ = cholesky_jitter(C, what="tile amplitude's fixed kernel matrix")
        WK = solve_lower(L, np.array(K, dtype=float, order="F"))  # L^-1 K
        M = solve_lower(L, np.array(WK.T, order="F"))  # (L^-1 (L^-1 K)^T) = L^-1 K L^-T
        lam, U = symmetric_eigen(0.5 * (M + M.T))
        w = solve_lower(L, np.array(resid, dtype=float, order="F").reshape(-1, 1)).ravel()
        c2 = (U.T @ w) ** 2
    lam = np.maximum(lam, 0.0)

    def neg_log_post(u: float) -> float:
        a = 1.0 + np.exp(u) * lam
        return 0.5 * float(np.sum(c2 / a) + np.sum(np.log(a))) + 0.5 * (u / prior_sd) ** 2

    lo, hi = np.log(AMPLITUDE_BOUNDS)
    res = minimize_scalar(neg_log_post, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    return float(np.exp(res.x))
