"""What a coarse DEM reads of a surface: the share of a breakline's step that a satellite
prior carries.

A satellite DEM averages the ground over its cells, so a scarp is in it, smoothed over a
cell or more. A :class:`terrain.BreaklineMean` on such a prior (``a + b * DEM``) that adds
the sharp step on top counts the step twice: the fit then shrinks the DEM's scale to make
room (measured: ``scale`` 0.19 and ``offset`` 822 m on bei's scarp at 3,000 samples; on two
swaths across a 4 m scarp 0.79, the map off them 0.723 m RMSE against 0.592 m without the
line). Subtracting the DEM's reading of the step alone is wrong the other way where the
DEM does not hold the step (a cliff that moved since: 0.644 m against 0.428 m).

So each step's column is split in two (:func:`coarse_columns`), ``S - A[S]`` (what the DEM
cannot hold: the step's height) and ``A[S]`` (the step as the DEM reads it), each with a
coefficient: near 0 for the second where the DEM carries the step, near the step where it
does not; the GLS weighs the two. :func:`prior_reading` computes ``A``: the surface averaged
over the DEM's pixels on the map lattice, then through the same coarse cells or bilinear
lattice as :meth:`terrain.RasterMean.dem`. A DEM whose pixels resolve the step
(:data:`PIXEL_WIDTHS`) or a base without a DEM keeps the bare step.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .prior import coarse_dem

__all__ = ["coarse_columns", "prior_reading", "reads_steps"]

#: A DEM whose pixels are under this many times the widest step resolves the step: the
#: step's column is then the bare step (and the DEM's own step is weighed by its scale).
PIXEL_WIDTHS = 4.0

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
    squared); with ``cells`` the averages go through the same coarse cells and mesh (or
    area means) as the DEM, else through bilinear interpolation of the lattice, as
    :meth:`terrain.RasterMean.dem`.
    """
    from scipy.interpolate import RegularGridInterpolator

    from .raster_mean import COARSE_READINGS, RasterMean

    bound = _bound(base)
    if not isinstance(base, RasterMean) or bound is None:
        return None
    grid = bound.grid
    fx, fy = _pixel(bound)
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


def reads_steps(base: object, widths: tuple[float, ...] | None) -> bool:
    """Whether ``base`` is a bound :class:`terrain.RasterMean` whose pixels (on the map,
    m; with ``cells``, its coarse cells: it is read through their means) are at least
    :data:`PIXEL_WIDTHS` times the widest of ``widths`` (m): a DEM that smooths the steps
    over its cells, whose reading of them :func:`coarse_columns` adds."""
    from .raster_mean import RasterMean

    bound = _bound(base)
    if not isinstance(base, RasterMean) or bound is None or not widths:
        return False
    coarse = base.coarse_and_own_cell_m()  # None without cells
    side = max(max(_pixel(bound)), coarse[0] if coarse else 0.0)
    return side >= PIXEL_WIDTHS * max(widths)


def coarse_columns(mean: object, xy: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(S - A[S], A[S])``: a :class:`terrain.BreaklineMean`'s step columns ``S`` (n, k)
    at ``xy`` split into what its coarse prior lacks and what it reads of them
    (:func:`prior_reading`), each with a coefficient of its own: where the DEM carries
    the step the second's is near 0, where it does not (a cliff that moved since) near the
    step. ``(S, (n, 0))`` when the mean's fit found no such prior (``coarse_steps_``)."""
    if not getattr(mean, "coarse_steps_", False):
        return S, np.zeros((len(S), 0))
    bound = _bound(mean.base)  # a re-bind lays a new lattice: read again
    key = (tuple(mean.widths_), tuple(mean.tapers_ or ()), mean._open())
    readers = mean.__dict__.setdefault("_reading_cache", {})  # shared by copies
    if key not in readers or readers[key][0] is not bound:
        readers[key] = (bound, prior_reading(mean.base, lambda p: mean._steps_and_hinges(p)[0]))
    read = readers[key][1](xy)
    return S - read, read


def _bound(base: object) -> object:
    """The raster base's bound lattice (``RasterMean._shared.bound``), or None."""
    return getattr(getattr(base, "_shared", None), "bound", None)


def _pixel(bound: object) -> tuple[float, float]:
    """The side (m, x and y) of a DEM pixel as the bound lattice reads it: the lattice's
    cell, or the DEM's own cell on the map when that is coarser."""
    pairs = zip(bound.grid.resolution, bound.lattice[2:], strict=True)
    return tuple(max(a, b) for a, b in pairs)
