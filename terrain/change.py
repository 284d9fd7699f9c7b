"""Elevation change between two epochs: ``dh = after - before`` on their finer common grid.

``difference`` brings two DEMs (glacimap products with ``elevation`` and ``elevation_std``,
or any elevation DataArray) onto one grid: the finer of the two, cut to where both have
cells, in the finer DEM's CRS; the other is reprojected onto it with ``rasterio.warp``
(bilinear). Optionally the *after* DEM is co-registered to the *before* DEM on stable ground
(:func:`terrain.coregister`) first. ``dh_std`` is the per-cell 1-sigma
``sqrt(std_before^2 + std_after^2)``: right for one cell, wrong for a sum over cells (the
errors are spatially correlated) -- :func:`terrain.volume_change` integrates them properly.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from .coregister import _elevation, warp_to
from .coregister import coregister as _coregister
from .dem_projection import change_crs, crs_label, finer, grid_in, raster_footprint
from .errors import bad_input
from .grid import Grid, north_up

__all__ = ["PROVENANCE_KEYS", "difference"]

#: Attributes of each input copied into the change product as ``before_<key>``/``after_<key>``.
PROVENANCE_KEYS = (
    "method",
    "kernel",
    "hyperparameters",
    "mean_function",
    "n_samples",
    "seed",
    "software",
    "source",
    "site",
    "shared_vertical_offset_std_m",
    "std_error_budget",
    "epoch",
)


def _std(ds: Any):
    """The ``elevation_std`` DataArray of a product, else None."""
    import xarray as xr

    if isinstance(ds, xr.Dataset) and "elevation_std" in ds:
        return north_up(ds["elevation_std"].assign_attrs(ds.attrs))
    return None


def _common_grid(eb: Any, ea: Any) -> tuple[Grid, str, str]:
    """The finer grid cut to the overlap of both; which input is finer; reprojection note.

    Inputs in degrees are allowed: the comparison runs in :func:`change_crs`'s projected CRS
    (a geographic DEM that is the finer one gets GDAL's suggested cells there)."""
    from rasterio.warp import transform_bounds

    fb, fa = raster_footprint(eb), raster_footprint(ea)
    fine, coarse, which = finer(fb, fa)
    crs, why = change_crs(eb, ea)
    fine_grid = grid_in(fine, crs)
    moved = [(k, fp) for k, fp in (("before", fb), ("after", fa)) if not _same_crs(fp, crs)]
    note = "; ".join(
        f"{k} reprojected from {crs_label(fp.crs)} to {crs_label(crs)} (rasterio, bilinear"
        + (f"; {fp.describe()}" if fp.crs.is_geographic else "")
        + ")"
        for k, fp in moved
    )
    note = note or "same CRS"
    if any(fp.crs.is_geographic for _, fp in moved):
        note += f"; compared in {why}"
    cb = coarse.bounds
    if not _same_crs(coarse, crs):
        cb = transform_bounds(coarse.crs.to_wkt(), crs.to_wkt(), *cb, densify_pts=21)
    w, s, e, n = fine_grid.bounds
    w2, s2, e2, n2 = max(w, cb[0]), max(s, cb[1]), min(e, cb[2]), min(n, cb[3])
    dx, dy = fine_grid.resolution
    j0, j1 = int(np.ceil((w2 - w) / dx - 1e-9)), int(np.floor((e2 - w) / dx + 1e-9))
    i0, i1 = int(np.ceil((n - n2) / dy - 1e-9)), int(np.floor((n - s2) / dy + 1e-9))
    if j1 - j0 < 2 or i1 - i0 < 2:
        raise bad_input(
            "before/after",
            f"bounds {tuple(round(b, 1) for b in fine_grid.bounds)} and "
            f"{tuple(round(b, 1) for b in cb)} ({crs_label(crs)})",
            "two DEMs that overlap by at least 2 x 2 cells",
            "check that both DEMs cover the same ground (and their CRS)",
        )
    grid = Grid(w + j0 * dx, n - i0 * dy, (dx, dy), (i1 - i0, j1 - j0), crs)
    return grid, which, note


def _same_crs(fp: Any, crs: Any) -> bool:
    return fp.crs.equals(crs, ignore_axis_order=True)


def _on_grid(da: Any, grid: Grid) -> np.ndarray:
    """``da`` on ``grid``: sliced when it lies on the same lattice, else reprojected."""
    g = raster_footprint(da)
    dx, dy = grid.resolution
    j = (grid.west - g.west) / dx
    i = (g.north - grid.north) / dy
    same = (
        _same_crs(g, grid.crs)
        and np.allclose(g.resolution, grid.resolution, rtol=1e-9)
        and abs(j - round(j)) < 1e-6
        and abs(i - round(i)) < 1e-6
    )
    if same:
        i, j = int(round(i)), int(round(j))
        return np.asarray(da.values, float)[i : i + grid.ny, j : j + grid.nx]
    return warp_to(da, grid, "bilinear")


def _provenance(prefix: str, ds: Any) -> dict[str, Any]:
    out = {}
    for k in PROVENANCE_KEYS:
        if k in ds.attrs:
            v = ds.attrs[k]
            v = v.item() if isinstance(v, np.generic) else v
            out[f"{prefix}_{k}"] = (
                v if isinstance(v, str | int | float) else json.dumps(v, default=str)
            )
    return out


def difference(
    before: Any,
    after: Any,
    coregister: bool = True,
    stable: Any = None,
    *,
    outline: Any = None,
    tilt: bool = False,
):
    """Elevation change ``after - before`` with its per-cell 1-sigma.

    Parameters
    ----------
    before, after : xarray.Dataset or xarray.DataArray
        glacimap products (``elevation``, ``elevation_std``, CRS and provenance in attrs) or
        plain elevation rasters (m) with a CRS.
    coregister : bool
        Co-register ``after`` to ``before`` (Nuth & Kääb) on stable ground first.
    stable : mask or shapely polygon(s), optional
        Stable ground for the co-registration (see :func:`terrain.coregister`).
    outline : shapely polygon(s), optional
        Glacier outline: without ``stable``, the ground outside it is stable.
    tilt : bool
        Also fit and remove a planar tilt in the co-registration.

    Returns
    -------
    xarray.Dataset
        ``dh`` and ``dh_std`` (m) on dims ``(y, x)`` of the finer common grid, plus
        ``elevation_before`` / ``elevation_after`` on that grid. ``attrs``: the grid's CRS
        and transform, ``dh_convention``, ``grid_source`` (which input set the grid),
        ``reprojection`` (what was reprojected, or "same CRS"), ``coregistration`` (JSON of
        :class:`terrain.coregister.Coregistration`, or ``"none"``), ``dh_std_source`` and the
        provenance of both inputs (``before_*``, ``after_*``).

    Raises
    ------
    InputError
        DEMs that do not overlap; too few stable cells to co-register.
    """
    import xarray as xr

    if coregister and stable is None and outline is None:
        raise bad_input(
            "stable/outline",
            None,
            "stable ground for the co-registration (every cell would absorb the glacier's "
            "thinning into the vertical bias)",
            "pass outline= (stable = outside it) or stable=, or coregister=False",
        )
    eb, ea = _elevation(before, "before"), _elevation(after, "after")
    grid, which, note = _common_grid(eb, ea)
    zb, za = _on_grid(eb, grid), _on_grid(ea, grid)
    sb, sa = _std(before), _std(after)
    coreg_json = "none"
    if coregister:
        ref = grid.data_array(zb, "elevation")
        dem = grid.data_array(za, "elevation")
        co = _coregister(ref, dem, stable, outline=outline, tilt=tilt)
        za = np.asarray(co.apply(dem).values)
        coreg_json = json.dumps(co.to_dict())
    dh = za - zb
    if sb is not None and sa is not None:
        dh_std = np.sqrt(_on_grid(sb, grid) ** 2 + _on_grid(sa, grid) ** 2)
        std_source = "sqrt(elevation_std_before^2 + elevation_std_after^2), per cell"
    else:
        dh_std = np.full(grid.shape, np.nan)
        std_source = "none: an input has no elevation_std (volume_change uses the variogram)"
    if not np.isfinite(dh).any():
        raise bad_input("before/after", "no cell with data in both", "overlapping data", "")
    attrs = {
        **grid.attrs(),
        "dh_convention": "after - before, metres",
        "grid_source": f"{which} (the finer grid), cut to the overlap",
        "reprojection": note,
        "coregistration": coreg_json,
        "dh_std_source": std_source,
        **_provenance("before", before),
        **_provenance("after", after),
    }
    coords = grid.coords()
    return xr.Dataset(
        {
            "dh": (("y", "x"), dh, {"units": "m", "long_name": "elevation change after - before"}),
            "dh_std": (("y", "x"), dh_std, {"units": "m", "long_name": "per-cell 1-sigma of dh"}),
            "elevation_before": (("y", "x"), zb, {"units": "m"}),
            "elevation_after": (("y", "x"), za, {"units": "m", "long_name": "co-registered"}),
        },
        coords=coords,
        attrs=attrs,
    )
