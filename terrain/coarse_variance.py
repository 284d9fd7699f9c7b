"""Exact posterior mean on every cell, exact variance on a coarser lattice, interpolated.

The exact predictive variance costs n^2 per cell (R&W Alg. 2.1 lines 5-6), the mean only n
(line 4). The variance of a stationary GP posterior is smooth at the scale of the kernel's
shortest length scale l: it dips near data and rises between tracks over ~l. So the variance
is computed exactly on a lattice of spacing l/4 spanning the grid and carried to every cell
with a bicubic spline (on the variance, which interpolates better than sigma or log-variance);
the mean stays exact everywhere.

Measured (docs/terrain.md "Prediction route"): on the default run's samples (3,745 landmarks,
SE + SE with l = 15 m, 2 m cells) the spline from a 4 m lattice is off by 0.02 % rms (0.35 %
max) against the exact 1-sigma on 22,500 cells; on dense noisy tracks
(tests/test_coarse_variance.py) 0.5 % rms, the largest relative errors sitting in the
narrow variance valleys on the tracks, where sigma is smallest (a few mm absolute).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.interpolate import RectBivariateSpline

from .grid import Grid

__all__ = [
    "LATTICE_FRACTION",
    "coarse_step",
    "predict_checked_lattice",
    "predict_coarse_variance",
]

LATTICE_FRACTION = 0.25  # lattice spacing / shortest length scale
#: cells where the spline is checked against the exact 1-sigma, and the largest relative
#: error it may have there (an l/4 lattice on smooth kernels: 0.1-0.5 % rms, ~5 % in the
#: narrow valleys on dense tracks; a rough Matern 3/2 with a 380 m scale on a 95 m lattice
#: was off by 272 %: its sigma dips within metres of the data, far below l)
CHECK_CELLS = 400
CHECK_MAX_REL = 0.10


def coarse_step(lengthscale_m: float, resolution_m: float) -> float:
    """Lattice spacing in cells: ``l / 4 / resolution`` (below 1.5 the exact route is used)."""
    return LATTICE_FRACTION * float(lengthscale_m) / float(resolution_m)


def _lattice(n: int, step: float) -> np.ndarray:
    """Nodes from cell 0 to cell n - 1 (both included) at most ``step`` cells apart."""
    return np.linspace(0.0, n - 1.0, max(2, int(np.ceil((n - 1) / step)) + 1))


def predict_coarse_variance(
    gp: Any, grid: Grid, step: float, include_nugget: bool = False, check: bool = False
) -> tuple[np.ndarray, np.ndarray | None]:
    """Posterior mean (exact) and 1-sigma (exact on a lattice, spline between) on a grid.

    Parameters
    ----------
    gp : TerrainGP
        Fitted on the exact route.
    grid : Grid
        Cells to predict (``grid.shape`` = (ny, nx)).
    step : float
        Lattice spacing in cells (>= 1.5); see :func:`coarse_step`.
    include_nugget : bool
        As in :meth:`TerrainGP.predict`.
    check : bool
        Compare the spline with the exact 1-sigma at up to :data:`CHECK_CELLS` cells half
        way between lattice nodes (where it is least exact); ``std`` is ``None`` when the
        spline misses any of them by more than :data:`CHECK_MAX_REL` (the caller then
        predicts every cell; ``mean`` is then ``None`` too, not computed).
        ``gp.lattice_check_`` records the largest relative error.

    Returns
    -------
    mean, std : ndarray of shape ``grid.shape``, metres (both None: lattice rejected)
    """
    ny, nx = grid.shape
    iy, ix = _lattice(ny, step), _lattice(nx, step)
    # Cell index -> coordinate is affine, so the lattice nodes are exact coordinates.
    xs = np.interp(ix, np.arange(nx), grid.x)
    ys = np.interp(iy, np.arange(ny), grid.y)
    xx, yy = np.meshgrid(xs, ys)
    _, std = gp.predict(
        np.column_stack([xx.ravel(), yy.ravel()]), return_std=True, include_nugget=include_nugget
    )
    var = std.reshape(iy.size, ix.size) ** 2
    k = min(3, iy.size - 1, ix.size - 1)
    spline = RectBivariateSpline(iy, ix, var, kx=k, ky=k)  # index space: rows N->S is fine
    var_all = spline(np.arange(ny), np.arange(nx))
    floor = var.min()  # a cubic can undershoot between nodes; never below the lattice's least
    std_all = np.sqrt(np.maximum(var_all, floor))
    if check:
        # The cells half way between nodes, thinned evenly to at most CHECK_CELLS.
        my = np.unique(np.round(0.5 * (iy[1:] + iy[:-1])).astype(int))
        mx = np.unique(np.round(0.5 * (ix[1:] + ix[:-1])).astype(int))
        cy, cx = (a.ravel() for a in np.meshgrid(my, mx, indexing="ij"))
        pick = np.unique(np.linspace(0, cy.size - 1, min(CHECK_CELLS, cy.size)).astype(int))
        cy, cx = cy[pick], cx[pick]
        qx, qy = np.asarray(grid.x)[cx], np.asarray(grid.y)[cy]
        _, exact = gp.predict(
            np.column_stack([qx, qy]), return_std=True, include_nugget=include_nugget
        )
        rel = np.abs(std_all[cy, cx] / np.maximum(exact, 1e-300) - 1.0)
        gp.lattice_check_ = {"cells": int(rel.size), "max_rel_error": float(rel.max())}
        if rel.max() > CHECK_MAX_REL:  # rejected before the mean pass: no work thrown away
            return None, None
    mean = gp.predict(grid.xy(), return_std=False).reshape(ny, nx)  # Alg. 2.1 line 4
    return mean, std_all


def predict_checked_lattice(
    gp: Any, grid: Grid, step: float, include_nugget: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`predict_coarse_variance` with its check; every cell exactly when the check
    rejects the spline. Sets ``gp.predict_route_`` to what was done, in words."""
    mean, std = predict_coarse_variance(gp, grid, step, include_nugget, check=True)
    chk = gp.lattice_check_
    route = (
        f"exact mean; variance on a {step:.2g}-cell lattice, bicubic (checked at "
        f"{chk['cells']} cells: largest error {100 * chk['max_rel_error']:.2g} %)"
    )
    if std is None:  # the spline missed its check: every cell exactly, and said so
        mean, std = gp.predict(grid.xy(), return_std=True, include_nugget=include_nugget)
        route = gp.predict_route_ + "; " + route.replace("bicubic", "rejected")
    gp.predict_route_ = route
    return mean, std


def variance_step(gp: Any, grid: Grid, flops: float) -> float:
    """Lattice spacing in cells for ``gp.predict_grid`` (1: predict every cell exactly).

    Used by ``method="auto"`` when the GP is on the exact route and the exact variance of all
    cells would cost more than ``flops`` (n^2 per cell), and the lattice spacing (a quarter of
    the kernel's shortest length scale) is at least 1.5 cells (2.25x fewer cells).
    """
    from .tiled import shortest_lengthscale

    n, m = gp.samples_.n, grid.shape[0] * grid.shape[1]
    if gp.method != "auto" or gp.method_ != "exact" or n**2 * m <= flops:
        return 1
    step = coarse_step(shortest_lengthscale(gp.kernel_), float(min(grid.resolution)))
    return step if step >= 1.5 else 1
