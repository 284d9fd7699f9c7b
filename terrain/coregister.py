"""Co-registration of two DEMs on stable terrain (Nuth & Kääb 2011).

Two DEMs of the same ground made at different times disagree on stable terrain (bedrock,
moraines, anything off the glacier) only because one is displaced: a horizontal shift
``s = (s_e, s_n)``, a vertical bias ``b`` and, optionally, a planar tilt. Nuth & Kääb (2011,
Eq 2) write the elevation difference a horizontal shift causes as

    dh(x) = dem(x) - ref(x) = tan(alpha) * a * cos(b_az - psi) + c

with ``alpha`` the terrain slope and ``psi`` its aspect. ``tan(alpha) cos(b_az - psi)`` is
the projection of the terrain gradient on the shift direction, so the same relation in
Cartesian form is ``dh(x) = grad ref(x) . s + c``. This module fits that form by least squares
on the stable cells (every cell weighted alike; the paper's curve fit of ``dh / tan(alpha)``
against aspect weights flat cells by ``1 / tan(alpha)``), applies the shift by cubic-spline
resampling, and iterates until the update is below ``tolerance_m`` — the paper's iteration.
Cells whose residual exceeds 4 NMAD are excluded at each step (counted).

Uncertainty: residuals on stable ground are spatially correlated, so the least-squares
covariance is too small. The 1-sigma of every parameter is a block bootstrap: the stable
cells are cut into ``n_blocks x n_blocks`` blocks, blocks are resampled with replacement and
the final linear fit is redone from the blocks' sufficient statistics (``n_boot`` times,
seeded).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .dem_projection import raster_footprint
from .errors import bad_input
from .grid import Grid, dataarray_crs, north_up

__all__ = [
    "MIN_STABLE_CELLS",
    "Coregistration",
    "as_polygons",
    "coregister",
    "resample_dem",
    "stable_mask",
    "warp_to",
]

#: Fewest stable cells a co-registration accepts (3 shift/bias parameters, 2 for a tilt, and
#: enough cells that the block bootstrap has data in most blocks).
MIN_STABLE_CELLS = 200
_MAD_K = 1.4826  # NMAD = 1.4826 * median absolute deviation (Höhle & Höhle 2009)


def _elevation(da: Any, field: str):
    """The elevation DataArray of a DEM: a DataArray itself or a Dataset's ``elevation``."""
    import xarray as xr

    if isinstance(da, xr.Dataset):
        if "elevation" not in da:
            raise bad_input(field, list(da.data_vars), "a Dataset with 'elevation'", "")
        da = da["elevation"].assign_attrs({**da.attrs, **da["elevation"].attrs})
    if not isinstance(da, xr.DataArray) or da.ndim != 2:
        raise bad_input(
            field,
            type(da).__name__,
            "a 2-D elevation DataArray (y, x) or a glacimap product Dataset",
            "open the raster with rioxarray or xarray",
        )
    return north_up(da)


def resample_dem(dem: Any, xy: np.ndarray, order: int = 3) -> np.ndarray:
    """``dem`` at arbitrary points ``xy`` (n, 2) of its own CRS, by spline interpolation.

    Cubic (``order=3``) B-spline interpolation of the cell-centre values; points outside the
    cell-centre hull, or within reach of a NaN cell, are NaN.
    """
    from scipy.ndimage import map_coordinates

    da = _elevation(dem, "dem")
    g = Grid.from_dataarray(da)
    z = np.asarray(da.values, float)
    bad = ~np.isfinite(z)
    xy = np.asarray(xy, float)
    col = (xy[:, 0] - g.west) / g.resolution[0] - 0.5
    row = (g.north - xy[:, 1]) / g.resolution[1] - 0.5
    coords = np.vstack([row, col])
    filled = np.where(bad, np.nanmean(z) if (~bad).any() else 0.0, z)
    out = map_coordinates(filled, coords, order=order, mode="nearest")
    outside = (row < 0) | (row > g.ny - 1) | (col < 0) | (col > g.nx - 1)
    if bad.any():
        near_bad = map_coordinates(bad.astype(float), coords, order=1, mode="nearest") > 0
        outside |= near_bad
    out[outside] = np.nan
    return out


def warp_to(da: Any, grid: Grid, resampling: str = "cubic") -> np.ndarray:
    """``da`` reprojected onto ``grid`` (any CRS to any CRS) by ``rasterio.warp.reproject``;
    NaN where it has no data. Returns an array of shape ``grid.shape``."""
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    src = _elevation(da, "dem")
    sg = raster_footprint(src)  # any CRS, degrees included
    out = np.full(grid.shape, np.nan)
    reproject(
        np.asarray(src.values, float),
        out,
        src_transform=sg.transform,
        src_crs=sg.crs.to_wkt(),
        dst_transform=grid.transform,
        dst_crs=grid.crs.to_wkt(),
        src_nodata=np.nan,
        dst_nodata=np.nan,
        resampling=getattr(Resampling, resampling),
    )
    return out


def as_polygons(obj: Any, field: str) -> list:
    """Shapely polygon(s) (a geometry, a multi-geometry or a list) as a list, checked."""
    geoms = getattr(obj, "geoms", None)
    geoms = list(geoms if geoms is not None else obj if isinstance(obj, list | tuple) else [obj])
    if not geoms or not all(hasattr(g, "__geo_interface__") for g in geoms):
        raise bad_input(field, type(obj).__name__, "shapely polygon(s) in the DEM's CRS", "")
    return geoms


def stable_mask(grid: Grid, stable: Any = None, outline: Any = None) -> tuple[np.ndarray, str]:
    """Boolean mask of stable cells on ``grid`` and a description of where it came from.

    ``stable``: a boolean DataArray (on any grid; nearest-neighbour onto ``grid``), a boolean
    array of ``grid.shape``, or shapely polygon(s) of stable ground. Without it, the cells
    outside ``outline`` (shapely polygon(s) of the glacier); without both, every cell.
    """
    from rasterio.features import geometry_mask

    if stable is None and outline is None:
        return np.ones(grid.shape, bool), "every cell (no stable mask, no outline given)"
    if stable is None:
        inside = ~geometry_mask(as_polygons(outline, "outline"), grid.shape, grid.transform)
        return ~inside, "cells outside the glacier outline"
    if hasattr(stable, "dims"):
        da = north_up(stable)
        if Grid.from_dataarray(da) == grid:
            return np.asarray(da.values).astype(bool), "stable mask (DataArray)"
        m = warp_to(da.astype(float), grid, "nearest")
        return np.nan_to_num(m) > 0.5, "stable mask (DataArray, nearest onto the grid)"
    if isinstance(stable, np.ndarray):
        if stable.shape != grid.shape:
            raise bad_input("stable", stable.shape, f"a mask of shape {grid.shape}", "")
        return stable.astype(bool), "stable mask (array)"
    inside = ~geometry_mask(as_polygons(stable, "stable"), grid.shape, grid.transform)
    return inside, "stable polygons"


@dataclass(frozen=True)
class Coregistration:
    """A fitted co-registration: ``dem(x + s) = reference(x) + bias (+ tilt)`` on stable ground.

    Attributes
    ----------
    shift_east_m, shift_north_m : float
        Horizontal displacement ``s`` of the DEM relative to the reference, metres.
    vertical_bias_m : float
        Vertical bias of the DEM at the stable cells' centroid, metres.
    tilt_east, tilt_north : float
        Planar tilt (m per m) when fitted, else 0.
    *_std : float
        1-sigma of each, block bootstrap.
    iterations, n_stable, n_outliers : int
        Iterations done, stable cells used in the final fit, cells rejected (> 4 NMAD).
    nmad_before_m, nmad_after_m : float
        NMAD of dh on the stable cells before and after co-registration.
    centroid : tuple of float
        Easting, northing the tilt is measured from, metres.
    """

    shift_east_m: float
    shift_north_m: float
    vertical_bias_m: float
    tilt_east: float
    tilt_north: float
    shift_east_std_m: float
    shift_north_std_m: float
    vertical_bias_std_m: float
    tilt_east_std: float
    tilt_north_std: float
    iterations: int
    converged: bool
    n_stable: int
    n_outliers: int
    nmad_before_m: float
    nmad_after_m: float
    centroid: tuple[float, float]
    method: str = "nuth_kaab"
    stable_source: str = ""
    crs_wkt: str = ""

    def correction(self, xy: np.ndarray) -> np.ndarray:
        """Vertical bias plus tilt at points ``xy`` (n, 2), metres."""
        d = np.asarray(xy, float) - np.asarray(self.centroid)
        return self.vertical_bias_m + self.tilt_east * d[:, 0] + self.tilt_north * d[:, 1]

    def apply(self, dem: Any):
        """``dem`` aligned to the reference, on its own grid: ``dem(x + s) - bias - tilt``.

        Cubic-spline resampling; cells whose shifted position leaves the DEM are NaN.
        """
        da = _elevation(dem, "dem")
        g = Grid.from_dataarray(da)
        xy = g.xy()
        z = resample_dem(da, xy + [self.shift_east_m, self.shift_north_m]) - self.correction(xy)
        out = da.copy(data=z.reshape(g.shape))
        out.attrs["coregistration"] = json.dumps(self.to_dict())
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON values (CRS omitted)."""
        d = asdict(self)
        d.pop("crs_wkt")
        d["centroid"] = list(self.centroid)
        return d


def _nmad(x: np.ndarray) -> float:
    return float(_MAD_K * np.median(np.abs(x - np.median(x)))) if x.size else float("nan")


def _design(gx, gy, dx, dy, tilt: bool) -> np.ndarray:
    cols = [gx, gy, np.ones_like(gx)]
    if tilt:
        cols += [dx, dy]
    return np.column_stack(cols)


def coregister(
    reference: Any,
    dem: Any,
    stable: Any = None,
    method: str = "nuth_kaab",
    *,
    outline: Any = None,
    tilt: bool = False,
    max_iterations: int = 30,
    tolerance_m: float = 0.002,
    n_blocks: int = 8,
    n_boot: int = 200,
    seed: int = 0,
) -> Coregistration:
    """Fit the horizontal shift, vertical bias (and tilt) of ``dem`` relative to ``reference``.

    Parameters
    ----------
    reference, dem : xarray.DataArray or glacimap product Dataset
        Elevation rasters (m) with a CRS. ``dem`` in another CRS is reprojected (cubic) onto
        the reference's CRS at its own resolution first; ``method`` in the result says so.
    stable : DataArray / ndarray mask, or shapely polygon(s), optional
        Stable ground. Default: the cells outside ``outline``.
    method : {"nuth_kaab"}
        Nuth & Kääb (2011).
    outline : shapely polygon(s), optional
        The glacier (changing ground), used when ``stable`` is None.
    tilt : bool
        Also fit a planar tilt.
    max_iterations, tolerance_m : int, float
        Iterate until the shift update is below ``tolerance_m`` metres.
    n_blocks, n_boot, seed : int
        Block bootstrap of the 1-sigma (``n_blocks`` x ``n_blocks`` blocks, seeded).

    Returns
    -------
    Coregistration

    Raises
    ------
    InputError
        Unknown method, fewer than :data:`MIN_STABLE_CELLS` stable cells with data in both,
        DEMs that do not overlap.
    """
    if method != "nuth_kaab":
        raise bad_input("method", method, '"nuth_kaab"', 'use method="nuth_kaab"')
    ref = _elevation(reference, "reference")
    dem = _elevation(dem, "dem")
    rg = Grid.from_dataarray(ref)
    how = "nuth_kaab"
    dcrs = dataarray_crs(dem)
    if dcrs is not None and not dcrs.equals(rg.crs, ignore_axis_order=True):
        dg = Grid.from_dataarray(dem)
        z = warp_to(dem, Grid(rg.west, rg.north, dg.resolution, _shape_for(rg, dg), rg.crs))
        g2 = Grid(rg.west, rg.north, dg.resolution, z.shape, rg.crs)
        dem = g2.data_array(z, "elevation")
        how += f" (dem reprojected from {dcrs.to_string()} to {rg.crs.to_string()}, cubic)"
    mask, source = stable_mask(rg, stable, outline)
    zr = np.asarray(ref.values, float)
    # Terrain gradient of the reference (m/m): x east, y north (rows run south).
    gy_rows, gx = np.gradient(zr, rg.resolution[1], rg.resolution[0])
    gy = -gy_rows
    xy = rg.xy()
    use = mask.ravel() & np.isfinite(zr.ravel()) & np.isfinite(gx.ravel()) & np.isfinite(gy.ravel())
    xy, zr1, gx1, gy1 = xy[use], zr.ravel()[use], gx.ravel()[use], gy.ravel()[use]
    centroid = xy.mean(axis=0) if xy.size else np.zeros(2)
    d = xy - centroid

    def residual(shift: np.ndarray) -> np.ndarray:
        return resample_dem(dem, xy + shift) - zr1

    shift = np.zeros(2)
    dh = residual(shift)
    ok = np.isfinite(dh)
    _check_count(int(ok.sum()), source, "with data in both DEMs")
    nmad_before = _nmad(dh[ok])

    def fit(dh: np.ndarray):
        """LS of dh on [grad, 1, (tilt)] over finite cells within 4 NMAD of the median."""
        ok = np.isfinite(dh)
        med = np.median(dh[ok])
        keep = ok & (np.abs(dh - med) <= 4 * max(_nmad(dh[ok]), 1e-6))
        _check_count(int(keep.sum()), source, "after rejecting outliers (> 4 NMAD)")
        A = _design(gx1[keep], gy1[keep], d[keep, 0], d[keep, 1], tilt)
        return ok, keep, A, np.linalg.lstsq(A, dh[keep], rcond=None)[0]

    converged, iterations = False, 0
    for iterations in range(1, int(max_iterations) + 1):  # noqa: B007 (kept after the loop)
        # NK Eq 2 in Cartesian form: dem(x + s) - ref(x) = grad(ref) . (s - s_true) + c
        step = -fit(dh)[3][:2]
        shift = shift + step
        dh = residual(shift)
        if np.hypot(*step) < tolerance_m:
            converged = True
            break
    ok, keep, A, coef = fit(dh)
    shift = shift - coef[:2]
    params = np.concatenate([shift, coef[2:]])
    sd = _block_bootstrap(A, dh[keep], xy[keep], rg, n_blocks, n_boot, seed)
    corr = params[2] + (A[:, 3:] @ params[3:] if tilt else 0.0)
    after = dh[keep] - A[:, :2] @ coef[:2] - corr
    tl = params[3:] if tilt else np.zeros(2)
    tl_sd = sd[3:] if tilt else np.zeros(2)
    return Coregistration(
        shift_east_m=float(params[0]),
        shift_north_m=float(params[1]),
        vertical_bias_m=float(params[2]),
        tilt_east=float(tl[0]),
        tilt_north=float(tl[1]),
        shift_east_std_m=float(sd[0]),
        shift_north_std_m=float(sd[1]),
        vertical_bias_std_m=float(sd[2]),
        tilt_east_std=float(tl_sd[0]),
        tilt_north_std=float(tl_sd[1]),
        iterations=iterations,
        converged=converged,
        n_stable=int(keep.sum()),
        n_outliers=int(ok.sum() - keep.sum()),
        nmad_before_m=nmad_before,
        nmad_after_m=_nmad(after),
        centroid=(float(centroid[0]), float(centroid[1])),
        method=how,
        stable_source=source,
        crs_wkt=rg.crs.to_wkt(),
    )


def _shape_for(rg: Grid, dg: Grid) -> tuple[int, int]:
    w, s, e, n = rg.bounds
    return (max(1, round((n - s) / dg.resolution[1])), max(1, round((e - w) / dg.resolution[0])))


def _check_count(n: int, source: str, what: str) -> None:
    if n < MIN_STABLE_CELLS:
        raise bad_input(
            "stable",
            f"{n} stable cells {what} ({source})",
            f"at least MIN_STABLE_CELLS = {MIN_STABLE_CELLS} stable cells",
            "give a larger stable mask (or outline leaving more ground outside), or pass "
            "coregister=False",
        )


def _block_bootstrap(A, y, xy, grid: Grid, n_blocks: int, n_boot: int, seed: int) -> np.ndarray:
    """1-sigma of the LS coefficients by resampling spatial blocks (sufficient statistics)."""
    w, s, e, n = grid.bounds
    bi = np.clip(((xy[:, 0] - w) / (e - w) * n_blocks).astype(int), 0, n_blocks - 1)
    bj = np.clip(((n - xy[:, 1]) / (n - s) * n_blocks).astype(int), 0, n_blocks - 1)
    block = bi * n_blocks + bj
    ids = np.unique(block)
    p = A.shape[1]
    AtA = np.zeros((ids.size, p, p))
    Aty = np.zeros((ids.size, p))
    for k, b in enumerate(ids):
        sel = block == b
        AtA[k] = A[sel].T @ A[sel]
        Aty[k] = A[sel].T @ y[sel]
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(int(n_boot)):
        c = np.bincount(rng.integers(0, ids.size, ids.size), minlength=ids.size).astype(float)
        M = np.einsum("k,kij->ij", c, AtA)
        try:
            draws.append(np.linalg.solve(M, c @ Aty))
        except np.linalg.LinAlgError:
            continue
    if len(draws) < 2:
        return np.full(p, np.nan)
    return np.std(np.asarray(draws), axis=0, ddof=1)
