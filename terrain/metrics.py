"""Accuracy and calibration of a reconstruction against truth.

All functions ignore cells where the prediction (or std) is NaN — a method that covers
only part of the grid is scored on what it covers, and :func:`covered_fraction` says how much
that is. Inputs are array-likes of the same shape (xarray objects work).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import bad_input

__all__ = [
    "calibration_curve",
    "covered_fraction",
    "evaluate",
    "interval_coverage",
    "mae",
    "max_abs_error",
    "nlpd",
    "rmse",
    "standardized_error_stats",
]


def _pair(pred: Any, truth: Any, *more: Any) -> tuple[np.ndarray, ...]:
    arrays = [np.asarray(a, dtype=float) for a in (pred, truth, *more)]
    if any(a.shape != arrays[0].shape for a in arrays):
        raise bad_input(
            "shapes",
            [a.shape for a in arrays],
            "prediction, truth (and std) of one shape",
            "evaluate on the same grid",
        )
    ok = np.ones(arrays[0].shape, bool)
    for a in arrays:
        ok &= np.isfinite(a)
    if not ok.any():
        raise bad_input("prediction", "all NaN", "at least one finite cell", "")
    return tuple(a[ok] for a in arrays)


def rmse(pred: Any, truth: Any) -> float:
    """Root-mean-square error, metres (finite cells only)."""
    p, t = _pair(pred, truth)
    return float(np.sqrt(np.mean((p - t) ** 2)))


def mae(pred: Any, truth: Any) -> float:
    """Mean absolute error, metres."""
    p, t = _pair(pred, truth)
    return float(np.mean(np.abs(p - t)))


def max_abs_error(pred: Any, truth: Any) -> float:
    """Largest absolute error, metres."""
    p, t = _pair(pred, truth)
    return float(np.max(np.abs(p - t)))


def covered_fraction(pred: Any) -> float:
    """Fraction of cells with a finite estimate (the paper's 25.8 % for Delaunay)."""
    return float(np.isfinite(np.asarray(pred, dtype=float)).mean())


def interval_coverage(pred: Any, std: Any, truth: Any, z: float = 1.96) -> float:
    """Fraction of cells whose truth lies in ``pred ± z * std`` (nominal: 0.683 at z=1, 0.95 at
    z=1.96 for a calibrated Gaussian)."""
    p, t, s = _pair(pred, truth, std)
    return float(np.mean(np.abs(p - t) <= z * s))


def standardized_error_stats(pred: Any, std: Any, truth: Any) -> tuple[float, float]:
    """Mean and standard deviation of ``(truth - pred) / std``: (0, 1) when calibrated."""
    p, t, s = _pair(pred, truth, std)
    zscore = (t - p) / np.maximum(s, np.finfo(float).tiny)
    return float(zscore.mean()), float(zscore.std())


def nlpd(pred: Any, std: Any, truth: Any) -> float:
    """Mean negative log predictive density of the truth under N(pred, std^2), nats per cell."""
    p, t, s = _pair(pred, truth, std)
    var = np.maximum(s, np.finfo(float).tiny) ** 2
    return float(np.mean(0.5 * np.log(2 * np.pi * var) + 0.5 * (t - p) ** 2 / var))


def calibration_curve(
    pred: Any,
    std: Any,
    truth: Any,
    levels: Any = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99),
) -> tuple[np.ndarray, np.ndarray]:
    """Observed coverage of central Gaussian intervals at each nominal level.

    Returns ``(levels, observed)``, both shape (k,): the fraction of cells whose truth lies in
    ``pred ± Phi^-1((1 + level) / 2) * std``. A calibrated map lies on the diagonal.
    """
    from scipy.stats import norm

    levels = np.asarray(levels, dtype=float)
    if np.any((levels <= 0) | (levels >= 1)):
        raise bad_input("levels", levels, "nominal levels strictly between 0 and 1", "")
    p, t, s = _pair(pred, truth, std)
    zscore = np.abs(t - p) / np.maximum(s, np.finfo(float).tiny)
    half_widths = norm.ppf(0.5 + levels / 2)
    return levels, (zscore[None, :] <= half_widths[:, None]).mean(axis=1)


def evaluate(pred: Any, truth: Any, std: Any | None = None) -> dict[str, float]:
    """Every metric at once, as a flat dict (std-based ones only when ``std`` is given)."""
    out = {
        "rmse": rmse(pred, truth),
        "mae": mae(pred, truth),
        "max_abs_error": max_abs_error(pred, truth),
        "covered_fraction": covered_fraction(pred),
    }
    if std is not None:
        mean_z, spread_z = standardized_error_stats(pred, std, truth)
        out.update(
            coverage_68=interval_coverage(pred, std, truth, z=1.0),
            coverage_95=interval_coverage(pred, std, truth, z=1.96),
            z_mean=mean_z,
            z_std=spread_z,
            nlpd=nlpd(pred, std, truth),
        )
    return out
