"""The held-out blocks of :func:`terrain.cross_validate`: square blocks of the survey dealt
to folds, and the blocks' side (distance-matched to the map, :mod:`terrain.heldout_design`,
or from the fitted length scale).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import bad_input, positive_number
from .heldout_design import default_targets, matched_block_size

__all__ = ["design_folds", "spatial_blocks", "target_points"]


def spatial_blocks(
    xy: np.ndarray, block_size: float, n_folds: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Deal square blocks of samples to folds, balanced by sample count.

    Parameters
    ----------
    xy : ndarray of shape (n, 2)
        Sample locations, metres.
    block_size : float
        Block side, metres; the lattice is anchored at ``xy.min(axis=0)``.
    n_folds : int
        Number of folds (>= 2).
    rng : numpy.random.Generator
        Shuffles the blocks; each then goes to the fold with the fewest samples (ties: the
        lowest fold number).

    Returns
    -------
    fold : ndarray of shape (n,)
        Fold of each sample, int in ``[0, n_folds)``; every fold is non-empty.
    block : ndarray of shape (n,)
        Block of each sample, int in ``[0, n_blocks)`` (non-empty blocks, numbered by
        lattice column then row).
    """
    cell = np.floor((xy - xy.min(axis=0)) / block_size).astype(np.int64)
    ny = int(cell[:, 1].max()) + 1
    ids, inverse, counts = np.unique(
        cell[:, 0] * ny + cell[:, 1], return_inverse=True, return_counts=True
    )
    n_blocks = ids.size
    if n_blocks < n_folds:
        raise bad_input(
            "block_size / n_folds",
            f"{n_blocks} non-empty blocks of {block_size:g} m for {n_folds} folds",
            "at least as many non-empty blocks as folds",
            "pass a smaller block_size or fewer n_folds",
        )
    loads = np.zeros(n_folds, dtype=np.int64)
    block_fold = np.empty(n_blocks, dtype=np.int64)
    for b in rng.permutation(n_blocks):
        f = int(np.argmin(loads))
        block_fold[b] = f
        loads[f] += counts[b]
    inverse = inverse.ravel()
    return block_fold[inverse], inverse


def design_folds(
    xy: np.ndarray,
    target_d: np.ndarray,
    n_folds: int,
    seed: int,
    reference: Any,
    block_size: float | None = None,
) -> tuple[float, str, np.ndarray, np.ndarray]:
    """The held-out blocks of :func:`cross_validate`: their side, its rule in words, and each
    sample's fold and block.

    Parameters
    ----------
    xy, target_d, n_folds, seed
        As :func:`terrain.heldout_design.matched_block_size` (samples and the map cells'
        distances to them, m; folds; the seed of the blocks' deal).
    reference : TerrainGP
        A fit whose shortest length scale sets the side when no distance-matched side has
        2 x ``n_folds`` blocks.
    block_size : float, optional
        A side given by the caller, m.
    """
    if block_size is None:
        size, rule, fold, block = matched_block_size(xy, target_d, n_folds, seed, spatial_blocks)
        if size is None:
            size, rule = _default_block(reference, xy, n_folds)
    else:
        size = positive_number("block_size", block_size, "a block side in metres, e.g. 45.0")
        rule = "given"
    if rule == "given" or not rule.startswith("distance-matched"):
        fold, block = spatial_blocks(xy, size, n_folds, np.random.default_rng(seed))
    return float(size), rule, fold, block


def target_points(targets: Any, xy: np.ndarray) -> np.ndarray:
    """The map's cell centres (m, 2) from ``targets`` (a Grid, an array or None)."""
    if targets is None:
        return default_targets(xy)
    if hasattr(targets, "xy") and callable(targets.xy):
        return np.asarray(targets.xy(), dtype=float)
    arr = np.asarray(targets, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0 or not np.isfinite(arr).all():
        shape = getattr(arr, "shape", None)
        raise bad_input(
            "targets", f"shape {shape}", "finite (m, 2) x, y in metres", "pass the map's Grid"
        )
    return arr


def _n_blocks(xy: np.ndarray, size: float) -> int:
    cell = np.floor((xy - xy.min(axis=0)) / size).astype(np.int64)
    return int(np.unique(cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1]).size)


def _default_block(est: Any, xy: np.ndarray, n_folds: int) -> tuple[float, str]:
    """3 x the shortest fitted length scale (extent / 10 without one), halved until there
    are at least 2 x ``n_folds`` non-empty blocks (at most 20 times)."""
    kernel = getattr(est, "kernel_", None)
    try:
        ell = float(min(np.min(p.lengths) for p in getattr(kernel, "parts", (kernel,))))
    except (AttributeError, TypeError, ValueError):
        ell = None
    if ell is not None and math.isfinite(ell) and ell > 0:
        size, rule = 3.0 * ell, f"3 x shortest fitted length scale ({ell:.3g} m)"
    else:
        size, rule = (float(np.ptp(xy, axis=0).max()) or 1.0) / 10.0, "extent / 10"
    halvings = 0
    while halvings < 20 and _n_blocks(xy, size) < 2 * n_folds:
        size, halvings = size / 2.0, halvings + 1
    if halvings:
        rule += f", halved {halvings} x to get >= {2 * n_folds} non-empty blocks"
    return size, rule
