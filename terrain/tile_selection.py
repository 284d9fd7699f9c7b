"""Which samples a tile keeps when more lie in its reach than its budget.

The tiled GP (:mod:`terrain.tiled`) gives each tile the samples within its halo, at most
``TileSpec.max_points``. Beyond that it keeps the nearest: in dense data they screen the
rest. Along dense survey lines they do not: the nearest 500 samples of a tile between two
lines 300 m apart all lie on the nearer line, and a kernel part longer than the gap loses
the lines beyond. ``far_share`` of the budget can then be spread over the halo instead (one
sample per cell of the coarsest square lattice that still fills it, the one nearest the
tile in each cell); the rest stays nearest. A subset of the data never lowers a GP's
posterior variance, so a 1-sigma from such tiles errs wide (terrain/long_halo.py).
"""

from __future__ import annotations

import numpy as np

__all__ = ["capped_selection"]


def capped_selection(
    xy: np.ndarray, dist: np.ndarray, max_points: int, far_share: float = 0.0
) -> np.ndarray:
    """Indices of the ``max_points`` samples a capped tile keeps.

    Parameters
    ----------
    xy : ndarray of shape (n, 2)
        The candidates (n > max_points), m.
    dist : ndarray of shape (n,)
        Their distances to the tile's region, m.
    max_points : int
        The tile's budget.
    far_share : float
        Share of the budget spread over the candidates (0: the nearest only).

    Returns
    -------
    ndarray of shape (max_points,)
        Indices into ``xy``: the nearest first, then the spread ones nearest-first.
    """
    k = int(max_points)
    if far_share <= 0:
        return np.argpartition(dist, k)[:k]
    n_near = k - int(round(far_share * k))
    order = np.argsort(dist, kind="stable")
    near, rest = order[:n_near], order[n_near:]
    want = k - n_near
    pts = xy[rest] - xy[rest].min(axis=0)
    span = float(pts.max()) + 1.0
    cell = span / np.sqrt(want)  # about `want` cells if the rest filled the square
    first = np.arange(rest.size)
    for _ in range(40):
        ij = np.floor(pts / cell).astype(np.int64)
        key = ij[:, 0] * (int(span / cell) + 2) + ij[:, 1]
        _, idx = np.unique(key, return_index=True)  # rest is nearest-first: each cell's nearest
        if idx.size >= want:
            first = idx
            break
        cell /= 1.5
    return np.concatenate([near, rest[np.sort(first)[:want]]])
