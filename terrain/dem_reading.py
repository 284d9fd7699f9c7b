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
does not; the GLS weighs the two. :func:`prior_reading` computes ``A`` by replaying the DEM's
own path (:func:`warped_reading`): the surface averaged over each of the source's pixels in
its CRS, resampled onto the bound lattice as the DEM was (:meth:`terrain.RasterMean.resample`),
then through the same coarse cells or bilinear lattice as :meth:`terrain.RasterMean.dem`. A
DEM whose pixels resolve the step (:data:`PIXEL_WIDTHS`) or a base without a DEM keeps the
bare step.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .prior import coarse_dem

__all__ = ["coarse_columns", "dem_lacks", "prior_reading", "reads_steps", "warped_reading"]

#: A DEM whose pixels are under this many times the widest step resolves the step: the
#: step's column is then the bare step (and the DEM's own step is weighed by its scale).
PIXEL_WIDTHS = 4.0

#: Sub-cell points per side: one every this many metres of a lattice cell, 1 to
#: :data:`MAX_SUB` (a 75 m cell: 8 x 8 points, a step's area share within 1/64).
SUB_M = 5.0
MAX_SUB = 8
#: Most surface points the warp replay evaluates (source pixels x sub-points).
MAX_POINTS = 4_000_000


def prior_reading(
    base: object, surface: Callable[[np.ndarray], np.ndarray]
) -> Callable[[np.ndarray], np.ndarray] | None:
    """``reader(xy) -> (n, k)``: ``surface`` (map ``xy`` (n, 2), m -> (n, k) values) as
    ``base``'s DEM reads it, or None when ``base`` is not a bound
    :class:`terrain.RasterMean` (a constant or a plane carries no step).

    The DEM's warp is replayed on the surface (:func:`warped_reading`): the surface averaged
    over each of the source's pixels, resampled onto the bound lattice as the DEM was, then
    with ``cells`` through the same coarse cells and mesh (or area means) as the DEM, else
    through bilinear interpolation of the lattice, as :meth:`terrain.RasterMean.dem`.
    """
    from scipy.interpolate import RegularGridInterpolator

    from .raster_mean import COARSE_READINGS, RasterMean

    bound = _bound(base)
    if not isinstance(base, RasterMean) or bound is None:
        return None
    grid = bound.grid
    values = warped_reading(base, bound, surface)  # (ny, nx, k), north-up rows
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


def warped_reading(
    base: object, bound: object, surface: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """``surface`` as ``base``'s bound lattice holds the DEM -> (ny, nx, k), m.

    A satellite DEM's pixel is the ground averaged over the pixel, in the DEM's own CRS; the
    bound lattice resampled those pixels (:meth:`terrain.RasterMean.resample`: bilinear at
    the lattice centres by default, half a pixel off them and smoothing again when the DEM
    is in another CRS). So the surface is averaged over the same source window's pixels, by
    ``ceil(side / SUB_M)`` squared points (at most ``MAX_SUB`` squared, fewer past
    :data:`MAX_POINTS`), the DEM's nodata pixels left out, and resampled and filled by the
    same rules. In the DEM's own CRS the lattice is the pixels themselves and this is the
    surface averaged over each lattice cell.
    """
    from pyproj import Transformer

    from .raster_warp import fill_nearest, source_points

    grid, src = bound.grid, base.source
    to_src = Transformer.from_crs(bound.crs, src.crs, always_xy=True)
    to_map = Transformer.from_crs(src.crs, bound.crs, always_xy=True)
    dem, transform = base.read_source(grid, to_src)
    rows, cols = dem.shape
    sub = int(min(max(math.ceil(_source_side_m(transform, dem.shape, to_map) / SUB_M), 1), MAX_SUB))
    sub = max(1, min(sub, math.isqrt(max(MAX_POINTS // dem.size, 1))))
    pts = source_points(dem.shape, transform, to_map, sub)
    pixels = np.asarray(surface(pts), float).reshape(rows, cols, sub * sub, -1).mean(axis=2)
    pixels[~np.isfinite(dem)] = np.nan  # the DEM's holes: filled on the lattice as the DEM's
    out = [
        fill_nearest(base.resample(pixels[..., j], transform, grid, to_src)[0])[0]
        for j in range(pixels.shape[2])
    ]
    return np.stack(out, axis=2)


def _source_side_m(transform: object, shape: tuple[int, int], to_map: object) -> float:
    """The longer side (m, map CRS) of the middle pixel of a source window."""
    r, c = shape[0] // 2, shape[1] // 2
    cs, rs = np.array([c, c + 1, c]), np.array([r, r, r + 1])
    x, y = to_map.transform(
        transform.a * cs + transform.b * rs + transform.c,
        transform.d * cs + transform.e * rs + transform.f,
    )
    return float(max(math.hypot(x[1] - x[0], y[1] - y[0]), math.hypot(x[2] - x[0], y[2] - y[0])))


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


def dem_lacks(mean: object) -> list[tuple[float, float]]:
    """What the prior DEM lacks of each step of a fitted :class:`terrain.BreaklineMean`, in
    the DEM's own metres: ``[(metres, 1-sigma), ...]`` per line, ``[]`` without the split
    columns.

    The fit is ``a + b * DEM + h1 (S - A[S]) + h2 A[S]``: the DEM holds ``d = (h1 - h2) / b``
    metres of the smoothed step (as it states its heights), so it lacks ``h1 - d`` of the
    step ``h1``: about 0 where it holds the step, about ``h1`` where it predates it,
    negative where it states the step higher than the samples find it. ``h2`` alone
    (``coarse_stepJ_m``) is that lack in ground metres at the fitted scale, ``h1 - b d``:
    where the GLS trades the DEM's scale against the GP on rough ground, ``b`` runs off 1
    and ``h2`` with it (eleven real sites, the scarp in a 30 m DEM in EPSG:4326: ``h2``
    -1.5 ... 0.3 m for a 6 m step, the lack -0.7 ... 0.2 m; docs/terrain.md). The 1-sigma
    is the delta method on ``coef_cov_``; a DEM used as it is (no ``scale``) has ``b = 1``.
    """
    names = tuple(getattr(mean, "coef_names", ()))
    coef, cov = getattr(mean, "coef_", None), getattr(mean, "coef_cov_", None)
    if coef is None or "coarse_step1_m" not in names:
        return []
    out = []
    for j in range(len(mean.lines)):
        k, c = names.index(f"step{j + 1}_m"), names.index(f"coarse_step{j + 1}_m")
        idx, h1, h2 = [k, c], coef[k], coef[c]
        b, grad = 1.0, [0.0, 1.0]  # DEM as is (offset "none" or metres): b = 1, lack = h2
        if "scale" in names and mean.base.n_coef == 2:
            s = names.index("scale")
            b = coef[s]
            idx.append(s)
            grad = [1.0 - 1.0 / b, 1.0 / b, (h1 - h2) / b**2]
        g = np.asarray(grad)
        sd = float(np.sqrt(max(g @ cov[np.ix_(idx, idx)] @ g, 0.0)))
        out.append((float(h1 - (h1 - h2) / b), sd))
    return out


def _bound(base: object) -> object:
    """The raster base's bound lattice (``RasterMean._shared.bound``), or None."""
    return getattr(getattr(base, "_shared", None), "bound", None)


def _pixel(bound: object) -> tuple[float, float]:
    """The side (m, x and y) of a DEM pixel as the bound lattice reads it: the lattice's
    cell, or the DEM's own cell on the map when that is coarser."""
    pairs = zip(bound.grid.resolution, bound.lattice[2:], strict=True)
    return tuple(max(a, b) for a, b in pairs)
