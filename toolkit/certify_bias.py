"""Bias of the checkpoint errors, and how sure it is when the errors are spatially correlated.

A map's errors at nearby checkpoints are not independent: the error of a GP map between
two swaths is one smooth surface, and checkpoints 10 m apart read nearly the same part of
it. The textbook t-test on the mean error (standard error ``s / sqrt(n)``) then calls a
bias "significant" that the next survey would not repeat. The standard error here is the
mean's under the errors' own spatial covariance,

    Var(mean e) = 1^T C 1 / n^2,    C_ij = c0 [i = j] + c1 exp(-d_ij / a),

with the nugget ``c0``, partial sill ``c1`` and range ``a`` fitted to the empirical
semivariogram of the errors (method of moments, Matheron 1962; weighted least squares with
Cressie 1985's weights ``N_h / gamma(h)^2``). A variogram is blind to the mean, so the
bias does not leak into it. The effective number of checkpoints is ``n_eff = (c0 + c1) /
Var(mean e)``. With fewer than :data:`MIN_SPATIAL_CHECKPOINTS` checkpoints, a variogram
that cannot be fitted, or one that does not level off within the checkpoints' layout (its
range past a third of the largest lag: the errors are correlated at the scale of the whole
site, e.g. stripes between swaths, and the mean's variance is not identified), the errors
are taken as independent and the assessment says so.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial.distance import pdist
from scipy.stats import t as student_t

from terrain.variogram import binned_semivariance

__all__ = [
    "ASPRS_MEAN_ERROR_FRACTION",
    "MIN_SPATIAL_CHECKPOINTS",
    "bias_assessment",
    "mean_error_variance",
]

#: ASPRS 2014 Sec. 7.2: a mean error above 25 % of the RMSE is a systematic error to report.
ASPRS_MEAN_ERROR_FRACTION = 0.25
#: Fewest checkpoints whose errors' variogram is fitted (30: 435 pairs in ~12 lag bins).
MIN_SPATIAL_CHECKPOINTS = 30
_N_BINS = 12
_MIN_PAIRS = 15
_CHUNK = 2048
_VARIOGRAM_POINTS = 3000  # as terrain.variogram.empirical_variogram


def _pair_sums(xy: np.ndarray, a: float) -> float:
    """``sum_ij exp(-d_ij / a)`` over all ordered pairs (i = j included), in row chunks."""
    from scipy.spatial.distance import cdist

    total = 0.0
    for i in range(0, xy.shape[0], _CHUNK):
        d = cdist(xy[i : i + _CHUNK], xy)
        total += float(np.exp(-d / a).sum())
    return total


def mean_error_variance(err: np.ndarray, xy: np.ndarray) -> dict[str, Any] | None:
    """Variance of the mean of ``err`` (m^2) under an exponential covariance fitted to its
    semivariogram; ``None`` when it cannot be fitted (too few checkpoints or pairs).

    Parameters
    ----------
    err : ndarray of shape (n,)
        Errors at the checkpoints, m.
    xy : ndarray of shape (n, 2)
        Checkpoint coordinates in a projected CRS, m.

    Returns
    -------
    dict or None
        ``variance_m2``, ``nugget_m2``, ``partial_sill_m2``, ``range_m`` (exponential: the
        correlation falls to 1/e at ``range_m``), ``n_effective``, ``identified`` (False
        when the range passes a third of the largest lag fitted: the variogram does not level
        off within the checkpoints' layout and the variance is not usable).
    """
    from scipy.optimize import curve_fit

    err, xy = np.asarray(err, float), np.asarray(xy, float)
    n = err.size
    if n < MIN_SPATIAL_CHECKPOINTS:
        return None
    # the variogram from at most _VARIOGRAM_POINTS of them (seeded: pairs grow as n^2); the
    # mean's variance below sums over all
    sub = np.arange(n)
    if n > _VARIOGRAM_POINTS:  # drawn over the checkpoints in order of position: any row order
        by_position = np.lexsort((xy[:, 1], xy[:, 0]))
        pick = np.random.default_rng(0).choice(n, _VARIOGRAM_POINTS, replace=False)
        sub = np.sort(by_position[pick])
    d = pdist(xy[sub])
    pos = d[d > 0]
    if pos.size < _MIN_PAIRS * 3:
        return None
    # from the shortest lag with a bin's worth of pairs below it to half the largest
    lo, hi = float(np.partition(pos, _MIN_PAIRS)[_MIN_PAIRS]), 0.5 * float(d.max())
    if not hi > lo:
        return None
    h, gam, cnt = binned_semivariance(xy[sub], err[sub], _N_BINS, lo, hi, _MIN_PAIRS)
    if h.size < 4:
        return None
    top = float(max(gam.max(), np.var(err), 1e-12))

    def model(hh, c0, c1, a):
        return c0 + c1 * (1.0 - np.exp(-hh / a))

    p0 = [0.2 * top, 0.8 * top, float(np.median(h))]
    # A range beyond the largest lag fitted cannot be told from a trend: bounded there.
    bounds = ([0.0, 0.0, lo / 3.0], [2.0 * top, 2.0 * top, hi])
    try:
        p = p0
        for _ in range(3):  # Cressie's weights N_h / gamma(h)^2, gamma from the last fit
            w = np.maximum(model(h, *p), 1e-3 * top) / np.sqrt(cnt)
            p, _ = curve_fit(model, h, gam, p0=p, sigma=w, bounds=bounds, maxfev=10000)
    except (RuntimeError, ValueError):
        return None
    c0, c1, a = (float(v) for v in p)
    var = (c0 * n + c1 * _pair_sums(xy, a)) / n**2
    return {
        # an exponential reaches 95 % of its sill at 3 a: a range past a third of the largest
        # lag fitted means the variogram never levels off, and its sill is a guess
        "identified": bool(a <= hi / 3.0),
        "variance_m2": var,
        "nugget_m2": c0,
        "partial_sill_m2": c1,
        "range_m": a,
        "n_effective": (c0 + c1) / var if var > 0 else float(n),
    }


def bias_assessment(
    err: np.ndarray, xy: np.ndarray | None = None, stated_shared_std_m: float | None = None
) -> dict[str, Any]:
    """How much of the RMSE is one shared offset: RMSE^2 = bias^2 + SD^2 (SD with 1/n).

    ``err`` (n,) are ``map - checkpoint`` errors, m; ``xy`` (n, 2) their coordinates, m
    (projected). The bias is ``significant`` when ``|t| = |bias| / SE``, with SE the
    standard error of the mean under the errors' spatial covariance when ``xy`` is given and
    it can be fitted (:func:`mean_error_variance`), else ``s / sqrt(n)`` (independent
    errors; ``standard_error_method`` says which), exceeds Student's 97.5 % point with
    ``n_eff - 1`` degrees of freedom (``t_critical``). ``large`` when ``|bias|`` exceeds
    :data:`ASPRS_MEAN_ERROR_FRACTION` of the RMSE (ASPRS 2014 Sec. 7.2) and ``dominant`` when
    it is significant and ``bias^2 > SD^2`` (more than half the mean squared error).
    ``message`` says it in words (``None`` when the bias is neither large nor dominant).

    ``stated_shared_std_m`` is the map's own 1-sigma of its shared vertical offset (a
    product's ``shared_vertical_offset_std_m``: the survey's unobservable mean GPS bias,
    carried in ``elevation_std``). The bias is then compared with it,
    ``z = bias / sqrt(stated^2 + SE^2)``: within 2, the map's total 1-sigma already states
    it; beyond, the stated offset 1-sigma is too small for the bias the checkpoints see.
    """
    err = np.asarray(err, dtype=float)
    n, bias = err.size, float(err.mean())
    rmse = float(np.sqrt(np.mean(err**2)))
    sd = float(err.std())  # population SD: rmse^2 = bias^2 + sd^2 exactly
    se_iid = float(err.std(ddof=1)) / math.sqrt(n) if n > 1 else math.nan
    spatial = None if xy is None or n < 2 else mean_error_variance(err, xy)
    use_spatial = spatial is not None and spatial["identified"]
    if use_spatial:
        se = math.sqrt(spatial["variance_m2"])
        method = (
            f"spatial: exponential variogram of the checkpoint errors (range "
            f"{spatial['range_m']:.0f} m), {spatial['n_effective']:.0f} effective of {n}"
        )
    else:
        se = se_iid
        if xy is None:
            method = "independent errors (s / sqrt(n))"
        elif spatial is None:
            method = (
                f"independent errors (s / sqrt(n)): fewer than {MIN_SPATIAL_CHECKPOINTS} "
                "checkpoints or no variogram could be fitted"
            )
        else:
            method = (
                "independent errors (s / sqrt(n)): the checkpoint errors stay correlated "
                f"across the layout (variogram range {spatial['range_m']:.0f} m, not levelling"
                " off), so their own variogram cannot give the mean's standard error; with "
                "correlated errors this test calls a bias significant too readily"
            )

    def t_of(s: float) -> float:
        return bias / s if s > 0 else (math.inf if bias and n > 1 else math.nan)

    t = t_of(se)
    # Student's t with n_eff - 1 degrees of freedom: the SE itself is estimated from few
    # effective samples when the errors are correlated (1.96 gave 7-10 % false alarms at
    # n_eff ~ 10-40 in the Monte Carlo of tests/test_certify_bias.py).
    dof = max((spatial["n_effective"] if use_spatial else n) - 1.0, 1.0)
    crit = float(student_t.ppf(0.975, dof))
    frac = abs(bias) / rmse if rmse > 0 else 0.0
    significant = bool(n > 1 and abs(t) > crit)
    large = significant and frac > ASPRS_MEAN_ERROR_FRACTION
    dominant = significant and bias**2 > sd**2
    message = (
        f"{'the bias dominates the error' if dominant else 'a systematic bias'}: the map is "
        f"{abs(bias):.2f} m {'above' if bias > 0 else 'below'} the checkpoints on average, "
        f"{100 * frac:.0f} % of the RMSE ({100 * frac**2:.0f} % of the mean squared error; "
        f"ASPRS 2014 expects under {100 * ASPRS_MEAN_ERROR_FRACTION:.0f} %). Without it the "
        f"RMSE would be {sd:.2f} m. The verdicts are on the RMSE with the bias in it; a shared "
        "vertical offset is removed by ground control or a datum shift, not by more survey."
    )
    stated = None
    if stated_shared_std_m is not None and math.isfinite(float(stated_shared_std_m)):
        sd_s = float(stated_shared_std_m)
        denom = math.hypot(sd_s, se if math.isfinite(se) else 0.0)
        z = bias / denom if denom > 0 else math.inf
        consistent = abs(z) <= 2.0
        stated = {
            "shared_offset_std_m": sd_s,
            "z": z,
            "consistent": consistent,
            "text": (
                f"It is within the survey's stated shared vertical offset (1-sigma "
                f"{sd_s:.2f} m, z = {z:+.1f}): the map's total 1-sigma already carries it."
                if consistent
                else f"It is larger than the survey's stated shared vertical offset (1-sigma "
                f"{sd_s:.2f} m, z = {z:+.1f}): the map's stated 1-sigma is too small for it."
            ),
        }
        message += " " + stated["text"]
    return {
        "bias_m": bias,
        "rmse_without_bias_m": sd,
        "fraction_of_rmse": frac,
        "share_of_mse": frac**2,
        "standard_error_m": se,
        "standard_error_method": method,
        "t_statistic": t,
        "t_statistic_independent": t_of(se_iid),
        "t_critical": crit,
        "error_variogram": spatial,
        "against_stated_offset": stated,
        "significant": significant,
        "exceeds_asprs_mean_error": large,
        "dominant": dominant,
        "message": message if large or dominant else None,
    }
