"""What a coarse DEM reads of a surface: the share of a breakline's step that a satellite
prior already carries.

A satellite DEM averages the ground over its cells, so a scarp is in it, smoothed over a
cell or more. A :class:`terrain.BreaklineMean` on such a prior (``a + b * DEM``) that adds
the sharp step on top counts the step twice: the fit then shrinks the DEM's scale to make
room (measured: ``scale`` 0.19 and ``offset`` 822 m on bei's scarp at 3,000 samples; on a
rover's 300 m survey 0.38, the map off the swaths 0.96 m RMSE against 0.65 m without the
line). :func:`prior_reading` gives, for a :class:`terrain.RasterMean`, the surface as that
DEM would read it: averaged over the bound raster's cells (the source's pixels on the map
lattice), then through the same coarse cells or bilinear resampling as
:meth:`terrain.RasterMean.dem`. The step's column less its reading is what the prior lacks.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .prior import coarse_dem

__all__ = ["prior_reading"]

#: Sub-cell points per side: one every this many metres of a lattice cell, 1 to
#: :data:`MAX_SUB` (a 75 m cell: 8 x 8 points, a step's area share within 1/64).
SUB_M = 5.0
MAX_SUB = 8


def prior_reading(
    base: object, surface: Callable[[np.ndarray], np.ndarray]
) -> Callable[[np.ndarray], np.ndarray] | None:
    """``reader(xy) -> (n, k)``: ``surface`` (map ``xy`` (n, 2), m -> (n, k) values) as
    ``base``'s DEM reads it, or None when ``base`` is not a bound
    :class:`terrain.RasterMean` (a constant or a plane carries no step).

    The surface is averaged round each lattice centre over a pixel of the DEM (its own
    cell on the map, or the lattice's when coarser: ``cells`` may lay a finer lattice than
    the DEM's pixels), by ``ceil(side / SUB_M)`` squared points (at most ``MAX_SUB``
    squared); with ``cells`` the
    averages go through the same coarse cells and mesh (or area means) as the DEM, else
    through bilinear interpolation of the lattice, as :meth:`terrain.RasterMean.dem`.
    """
    from scipy.interpolate import RegularGridInterpolator

    from .raster_mean import COARSE_READINGS, RasterMean

    bound = getattr(getattr(base, "_shared", None), "bound", None)
    if not isinstance(base, RasterMean) or bound is None:
        return None
    grid = bound.grid
    fx, fy = (max(a, b) for a, b in zip(grid.resolution, bound.lattice[2:], strict=True))
    sub = int(min(max(math.ceil(max(fx, fy) / SUB_M), 1), MAX_SUB))
    frac = (np.arange(sub) + 0.5) / sub - 0.5
    dx, dy = np.meshgrid(frac * fx, frac * fy)
    X, Y = np.meshgrid(grid.x, grid.y)  # north-up rows, as the bound values
    pts = np.column_stack(
        [(X[..., None] + dx.ravel()).ravel(), (Y[..., None] + dy.ravel()).ravel()]
    )
    values = np.asarray(surface(pts), float)
    values = values.reshape(grid.ny, grid.nx, sub * sub, -1).mean(axis=2)  # (ny, nx, k)
    k = values.shape[2]
    if base.cells is not None:
        reading = COARSE_READINGS[base.coarse]
        parts = [
            reading(coarse_dem(base._dem_array(grid, values[..., j]), base.cells)) for j in range(k)
        ]
        return lambda xy: np.column_stack([p.dem(xy) for p in parts])
    interp = RegularGridInterpolator(
        (grid.y[::-1], grid.x), values[::-1], method="linear", bounds_error=False, fill_value=None
    )
    return lambda xy: np.asarray(interp(np.asarray(xy, float)[:, ::-1])).reshape(len(xy), k)
