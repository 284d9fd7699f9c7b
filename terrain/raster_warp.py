"""A source DEM resampled onto a map-CRS grid: the warp shared by :class:`terrain.RasterMean`,
the reading of a breakline's step through that same warp (:mod:`terrain.dem_reading`) and
a ``kind = "dem"`` site's truth (``toolkit.site_dem``).

Every grid centre is transformed exactly by PROJ and the source is resampled in its own
pixels by GDAL's nearest, bilinear or cubic rule (:func:`sample_onto`; GDAL's warper
approximates the transform to 1/8 of a source cell: 11 m on a 90 m DEM, metres of elevation
on a slope); ``"average"`` is GDAL's own area-weighted warp (:func:`gdal_average`). Holes
left by nodata are filled from the nearest valid cell (:func:`fill_nearest`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from affine import Affine
from pyproj import CRS, Transformer

from .grid import Grid
from .raster_boxes import ring
from .raster_source import RasterSource, sample_pixels

__all__ = ["fill_nearest", "gdal_average", "read_under", "sample_onto", "source_points"]

#: Grid cells transformed per PROJ call.
CHUNK = 65536


def read_under(
    src: RasterSource, grid: Grid, to_src: Transformer, pad: int
) -> tuple[np.ndarray, Affine]:
    """The source window (values, NaN nodata; the transform of its cell corners) under
    ``grid``'s bounds transformed by ``to_src`` (map -> source), plus ``pad`` cells."""
    xs, ys = to_src.transform(*ring(grid.bounds))
    ok = np.isfinite(xs) & np.isfinite(ys)
    need = (float(xs[ok].min()), float(ys[ok].min()), float(xs[ok].max()), float(ys[ok].max()))
    return src.read(need, pad=pad)


def sample_onto(
    values: np.ndarray,
    transform: Affine,
    to_src: Transformer,
    grid: Grid,
    method: str,
    src_bounds: tuple[float, float, float, float] | None = None,
    nodata_nearest: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """``values`` (rows, cols; source cells, NaN nodata) at the exact PROJ transform of every
    centre of ``grid`` -> ``(out, inside)``, both ``grid.shape``.

    ``method``: "nearest", "bilinear" or "cubic" (:func:`terrain.raster_source.sample_pixels`);
    ``inside`` marks centres inside ``src_bounds`` (source CRS; all True without it). With
    ``nodata_nearest`` a centre whose nearest source cell is nodata is NaN (a site's truth:
    no interpolation across a hole's edge).
    """
    out, inside = np.empty(grid.shape), np.ones(grid.shape, bool)
    inv = ~transform
    step = max(1, CHUNK // grid.nx)
    for r0 in range(0, grid.ny, step):
        xx, yy = np.meshgrid(grid.x, grid.y[r0 : r0 + step])
        sx, sy = to_src.transform(xx, yy)
        if src_bounds is not None:
            x0, y0, x1, y1 = src_bounds
            inside[r0 : r0 + step] = (sx >= x0) & (sx <= x1) & (sy >= y0) & (sy <= y1)
        col, row = inv.a * sx + inv.b * sy + inv.c, inv.d * sx + inv.e * sy + inv.f
        z = sample_pixels(values, col, row, method)
        if nodata_nearest and method != "nearest":
            z[~np.isfinite(sample_pixels(values, col, row, "nearest"))] = np.nan
        out[r0 : r0 + step] = z
    return out, inside


def gdal_average(values: np.ndarray, transform: Any, crs: CRS, grid: Grid) -> np.ndarray:
    """GDAL's area-weighted average of the source cells under each grid cell."""
    import rasterio.warp
    from rasterio.enums import Resampling

    out = np.full(grid.shape, np.nan)
    rasterio.warp.reproject(
        values,
        out,
        src_transform=transform,
        src_crs=crs.to_wkt(),
        src_nodata=np.nan,
        dst_transform=grid.transform,
        dst_crs=grid.crs.to_wkt(),
        dst_nodata=np.nan,
        resampling=Resampling.average,
    )
    return out


def fill_nearest(out: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``out`` (ny, nx) with every NaN replaced by its nearest finite cell ->
    ``(filled, holes, distance)``: the NaN mask and each cell's distance to the cell it took
    (cells; 0 where finite). ``out`` itself when it has no NaN."""
    from scipy.ndimage import distance_transform_edt

    holes = ~np.isfinite(out)
    if not holes.any():
        return out, holes, np.zeros(out.shape)
    dist, (ii, jj) = distance_transform_edt(holes, return_indices=True)
    return out[ii, jj], holes, dist


def source_points(
    shape: tuple[int, int], transform: Affine, to_map: Transformer, sub: int
) -> np.ndarray:
    """``sub`` x ``sub`` points evenly inside each cell of a source window (``shape`` rows,
    cols; ``transform`` of its cell corners), in the map CRS (``to_map``: source -> map) ->
    (rows * cols * sub * sub, 2), cell by cell in row-major order."""
    frac = (np.arange(sub) + 0.5) / sub
    dc, dr = np.meshgrid(frac, frac)
    rows, cols = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    c = (cols[..., None] + dc.ravel()).ravel()
    r = (rows[..., None] + dr.ravel()).ravel()
    sx = transform.a * c + transform.b * r + transform.c
    sy = transform.d * c + transform.e * r + transform.f
    mx, my = to_map.transform(sx, sy)
    return np.column_stack([mx, my])
