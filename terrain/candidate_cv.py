"""Spatial-block cross-validation of one candidate kernel on the fit subset.

``select_kernel(criterion="cv_nlpd")`` (:mod:`terrain.kernel_search`) ranks the candidates
by the held-out NLPD of each fold's samples predicted from the other folds by a
nearest-neighbour GP; the default BIC criterion does not compute it (why BIC: docs/terrain.md
"Kernel by evidence"). The user's own σ check of a fitted map is
:func:`terrain.cross_validate`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError
from .vecchia import nearest_neighbour_predict

__all__ = ["cv_folds", "cv_scores"]


def cv_folds(
    X: np.ndarray,
    gap: float | None,
    spacing: float,
    rng: np.random.Generator,
    n_folds: int = 5,
) -> tuple[np.ndarray, float]:
    """Spatial blocks of about 4 x the map's median gap, dealt to ``n_folds`` folds.

    Returns each sample's fold (n,) and the block side, m (halved until there are at least
    two blocks per fold). ``gap`` None: measured from ``X``'s bounding box.
    """
    from .heldout_blocks import spatial_blocks

    if gap is None:
        lo, hi = X.min(axis=0), X.max(axis=0)
        probe = np.random.default_rng(0).uniform(lo, hi, (2000, 2))
        gap = float(np.median(cKDTree(X).query(probe)[0]))
    block = max(4.0 * gap, 2.0 * spacing, 1e-3)
    extent = float(np.ptp(X, axis=0).max()) or 1.0
    while block > 1e-3 * extent:
        try:
            fold, blocks = spatial_blocks(X, block, n_folds, rng)
        except InputError:  # fewer blocks than folds (samples on a line or two): smaller ones
            block /= 2.0
            continue
        if np.unique(blocks).size >= 2 * n_folds:
            return fold, block
        block /= 2.0
    if len(X) < n_folds:  # a handful of samples: each its own fold (BIC ranks them anyway)
        return np.arange(len(X)), block
    return spatial_blocks(X, block, n_folds, rng)[0], block


def cv_scores(
    kernel: Any,
    nugget: float,
    X: np.ndarray,
    r: np.ndarray,
    z_var: np.ndarray,
    fold: np.ndarray,
) -> dict[str, float]:
    """Held-out NLPD (nats per sample) and 95 % coverage of each fold's samples predicted
    from the other folds by a nearest-neighbour GP (m = 20)."""
    mu = np.empty(r.size)
    sd = np.empty(r.size)
    lat = np.empty(r.size)
    nv = z_var + nugget
    for f in np.unique(fold):
        test, train = fold == f, fold != f
        m, v = nearest_neighbour_predict(kernel, X[train], r[train], nv[train], X[test])
        mu[test], sd[test], lat[test] = m, np.sqrt(v + nv[test]), v
    z = (r - mu) / sd
    # the map's error variance over its stated variance, the samples' noise removed
    kappa = float(np.sum((r - mu) ** 2 - nv) / max(float(np.sum(lat)), 1e-300))
    nlpd = float(np.mean(0.5 * np.log(2.0 * np.pi * sd**2) + 0.5 * z**2))
    return {
        "cv_nlpd": nlpd,
        "cv_coverage_95": float(np.mean(np.abs(z) <= 1.96)),
        "cv_z_std": float(np.std(z)),
        "cv_variance_ratio": max(kappa, 1e-6),
    }
