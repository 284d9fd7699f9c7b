"""A breakline's width chosen by the map's own evidence (Eq 9), not by the local planes alone.

:meth:`terrain.BreaklineMean.fit` chooses each step's width from the samples within a few
metres of the line, beside planes (:meth:`~terrain.BreaklineMean.choose_shape`): a start,
made before any kernel is known. The step's height is then tied to that width — the same
ground read 3.56 m at 0.5 m wide, 4.74 at 1.0, 6.22 at 1.5 and 8.06 at 2.0 (olinda's 6 m,
1.5 m wide scarp, 3,000 samples) — while its GLS 1-sigma is given the width. The local
planes chose 0.98 m there (step 4.69 +- 0.18: 7 sigma off), where the map's marginal
likelihood (Eq 9) peaks at the true 1.5 m. So once the kernel is fitted, each width of
``width="auto"`` is refined (bounded Brent on its logarithm, within a factor
:data:`SPAN` of the start) to minimise the GLS residual quadratic form
``r^T (K + Sigma)^-1 r`` with ``r = z - H beta_hat`` (the kernel fixed: ``K`` is factored
once and only ``H`` changes; Eq 9 at the GLS coefficients). A width given by the user is
kept; a refinement that would change whether the prior DEM smooths the steps
(:func:`terrain.dem_reading.reads_steps`) is not taken.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import minimize_scalar

from .breakline import WIDTHS
from .dem_reading import coarse_columns, reads_steps
from .gp_mean import gls_coefficients, noise_factor
from .prior_scale import checked_scale

__all__ = ["SPAN", "gls_mean", "width_uncertainty", "widths_by_evidence"]

#: The refined width stays within this factor of the local planes' choice.
SPAN = 3.0
#: Step in the width's logarithm of the misfit's central differences (10 %).
H_LOG = 0.1


def widths_by_evidence(
    mean: Any, kernel: Any, X: np.ndarray, xy: np.ndarray, z: np.ndarray, noise_var: np.ndarray,
    L: np.ndarray | None = None,
) -> tuple[Any, np.ndarray | None]:  # fmt: skip
    """``(mean, L)``: ``mean`` with each ``"auto"`` width refined by the evidence at
    ``kernel`` (module notes), and the lower Cholesky factor of ``K(X) + diag(noise_var)``
    (``L`` itself when given; None when nothing was refined and none was given).

    ``X`` (n, 2) are the kernel's coordinates of the samples at ``xy`` (n, 2, map CRS, m),
    ``z`` (n,) their elevations (m). The refined mean carries each width's 1-sigma
    (``widths_sd_``, m) and what it adds to the coefficients' covariance (``width_cov_``;
    :func:`width_uncertainty`). A mean whose widths were given with a 1-sigma (a map rebuilt
    from its product: ``glacimap change``) keeps its widths and has both derived again. Any
    other mean but a fitted ``BreaklineMean(width="auto")`` is returned as it is.
    """
    if type(mean).__name__ != "BreaklineMean" or mean.widths_ is None:
        return mean, L
    refine = mean.width == "auto"
    if not refine and getattr(mean, "widths_sd_", None) is None:
        return mean, L
    if L is None:
        L = noise_factor(kernel, X, noise_var, "breakline width kernel matrix")
    wy = solve_triangular(L, z, lower=True, check_finite=False)
    # the basis as BreaklineMean.basis lays it, [base, S - read, hinges, read], with the
    # prior DEM's reading of the steps kept at the start's widths while the search runs: it
    # smooths a step over 4 widths or more, so a width's change hardly moves it, and each
    # new reading would replay the DEM's warp (seconds on a fine DEM read through cells)
    base = np.asarray(mean.base.basis(xy), dtype=float)
    read = coarse_columns(mean, xy, mean._steps_and_hinges(xy)[0])[1]

    def gls(widths: list[float]) -> tuple[float, np.ndarray]:
        S, F = mean._steps_and_hinges(xy, widths=tuple(widths))
        H = np.column_stack([base, S - read if read.shape[1] else S, F, read])
        W = solve_triangular(L, H, lower=True, check_finite=False)
        b = W.T @ wy
        beta = np.linalg.lstsq(W.T @ W, b, rcond=None)[0]
        return float(wy @ wy - b @ beta), beta

    def misfit(widths: list[float]) -> float:
        return gls(widths)[0]

    widths = list(mean.widths_)
    for j, start in enumerate(mean.widths_ if refine else ()):
        lo, hi = max(start / SPAN, WIDTHS[0]), start * SPAN

        def at(u: float, j: int = j, ws: tuple = tuple(widths)) -> float:
            return misfit([*ws[:j], float(np.exp(u)), *ws[j + 1 :]])

        best = minimize_scalar(at, bounds=(np.log(lo), np.log(hi)), method="bounded",
                               options={"xatol": 0.005})  # fmt: skip
        trial = [*widths[:j], round(float(np.exp(best.x)), 2), *widths[j + 1 :]]
        if reads_steps(mean.base, tuple(trial)) == bool(mean.coarse_steps_):
            widths = trial
    out = copy.copy(mean)
    out.widths_ = tuple(widths)
    out.widths_sd_, out.width_cov_ = width_uncertainty(gls, widths)
    return out, L


def width_uncertainty(gls: Any, widths: list[float]) -> tuple[tuple[float, ...], np.ndarray]:
    """``(widths_sd, cov)``: each width's 1-sigma (m) from the curvature of the profile
    misfit in its logarithm, and the covariance (p, p) its uncertainty adds to the GLS
    coefficients.

    ``gls(widths)`` gives ``(r^T (K + Sigma)^-1 r, beta_hat)`` at those widths. The misfit is
    ``-2 log p(z)`` up to terms the widths do not move (the kernel fixed), so the variance
    of ``u = log w`` is ``2 / misfit''(u)`` (the profile likelihood's observed information,
    the coefficients profiled out), and the coefficients move with it as ``J = d beta_hat /
    du``: the joint information's inverse has the coefficient block ``cov_GLS + J var(u)
    J^T`` (the Schur complement of the joint Hessian). Central differences, ``u +- H_LOG``.
    A width the misfit does not curve about (flat, or at the search's bound) gets the
    search's whole span as its 1-sigma, ``log SPAN``.
    """
    f0, beta0 = gls(widths)
    cov = np.zeros((beta0.size, beta0.size))
    sds = []
    for j, w in enumerate(widths):
        fp, bp = gls([*widths[:j], w * np.exp(H_LOG), *widths[j + 1 :]])
        fm, bm = gls([*widths[:j], w * np.exp(-H_LOG), *widths[j + 1 :]])
        curve = (fp + fm - 2.0 * f0) / H_LOG**2
        var_u = 2.0 / curve if curve > 2.0 / np.log(SPAN) ** 2 else np.log(SPAN) ** 2
        J = (bp - bm) / (2.0 * H_LOG)
        cov += var_u * np.outer(J, J)
        sds.append(float(w * np.sqrt(var_u)))
    return tuple(sds), cov


def gls_mean(
    mean: Any, kernel: Any, X: np.ndarray, xy: np.ndarray, z: np.ndarray, noise_var: np.ndarray,
    L: np.ndarray | None = None,
) -> tuple[Any, np.ndarray, np.ndarray]:  # fmt: skip
    """``(mean, beta_hat, cov)``: a linear mean's widths refined by the evidence
    (:func:`widths_by_evidence`; breaklines only) and its GLS coefficients at ``kernel``
    (:func:`terrain.gp_mean.gls_coefficients`, R&W Eq 2.42), one factor for both. A DEM's
    ``a + b * DEM`` has its GLS scale checked against least squares
    (:func:`terrain.prior_scale.checked_scale`; the record in ``mean.scale_check_``)."""
    mean, L = widths_by_evidence(mean, kernel, X, xy, z, noise_var, L)
    H = np.asarray(mean.basis(xy), dtype=float)
    names = tuple(getattr(mean, "coef_names", ()))
    if "scale" in names:  # a + b * DEM (a breakline's base too): b checked
        if L is None:
            L = noise_factor(kernel, X, noise_var, "GLS mean kernel matrix")
        mean = copy.copy(mean)
        j = names.index("scale")
        beta, cov, mean.scale_check_ = checked_scale(H, z, L, j)  # terrain.prior_scale
        if getattr(mean, "base", None) is not None:  # a breakline's base states it too
            mean.base = copy.copy(mean.base)
            mean.base.scale_check_ = mean.scale_check_
    else:
        beta, cov = gls_coefficients(kernel, X, z, noise_var, H, L)
    extra = getattr(mean, "width_cov_", None)
    if extra is not None and extra.shape == cov.shape:
        cov = cov + extra  # the widths' own uncertainty (width_uncertainty)
    return mean, beta, cov
