"""A scenario's site read from a real DEM file: ``[site] kind = "dem"``.

Any raster GDAL reads (GeoTIFF, COG, VRT, ...) in a projected or geographic CRS, with its
nodata, becomes the true DEM the rover drives on (``make_site``), reprojected to the site's
projected CRS at ``truth_resolution_m``:

* **Resampling: cubic** (GDAL's Keys cubic convolution, a = -0.5) when the truth cell is finer
  than the DEM's, which is the usual case (a 30-1000 m DEM under a 2 m truth). Bilinear
  interpolation of a coarse DEM is a surface of flat facets whose slope jumps at every DEM
  cell edge: the renderer's Lambert shading shows those creases as lines on the snow (false
  features) and the rover's tilt jumps there. Cubic convolution is C1 (continuous slopes)
  and reproduces quadratics exactly; its overshoot is bounded by a few percent of a cell's
  elevation step. It is evaluated at the exact PROJ transform of every truth cell centre
  (:func:`terrain.raster_source.sample_pixels`): GDAL's warper approximates the transform
  to 1/8 of a source cell, 0.4 m of elevation on a lon/lat test plane. When the truth cell
  is coarser than the DEM's, GDAL's *average* (area-weighted block mean) is used instead:
  an anti-aliased, unbiased coarsening.
* **CRS:** ``site.crs`` when given (projected, metres); otherwise the DEM's own CRS when it
  is projected in metres, else (geographic, or projected in feet) the UTM zone (WGS 84) of
  the DEM's centre. Elevations are taken as metres. The choice and its reason
  are stated in the truth's provenance (:func:`site_provenance`), printed by
  ``glacimap simulate`` and written into ``glacimap run``'s ``summary.json``: never silent.
* **Bounds:** ``site.bounds`` when given (site CRS; must lie inside the DEM); otherwise the
  DEM's valid-data extent (the bounding box of its non-nodata cells), and where more than
  ``max_nodata_fraction`` of that box is nodata (a country-shaped DEM), the largest
  rectangle of valid cells inside it. Derived bounds are snapped inwards to whole truth
  cells.
* **Nodata** inside the site (a truth cell whose nearest DEM cell is nodata): counted when
  the scenario is loaded, before anything is written; more than
  ``site.max_nodata_fraction`` (default 5 %) of the truth cells ->
  :class:`~terrain.errors.InputError`; fewer are filled from the nearest valid cell
  (counted, with the largest fill distance).

:func:`resolve_dem_site` runs when the scenario is loaded (``toolkit.config``): it resolves
the path (relative to the scenario file's folder), the CRS and the bounds, so that every
later stage (plan, sensors, prior, certificate) sees an ordinary projected site.
:func:`dem_truth` then reads and warps the DEM. Nothing is written.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from terrain.errors import InputError, bad_input
from terrain.grid import Grid, as_crs, utm_crs
from terrain.raster_warp import fill_nearest, gdal_average, read_under, sample_onto

__all__ = [
    "MAX_TRUTH_CELLS",
    "MIN_TRUTH_CELLS",
    "dem_truth",
    "resolve_dem_site",
    "site_provenance",
]

#: Largest truth raster (cells): 4096 x 4096 (134 MB of float64; the renderer's mesh is two
#: triangles per cell). A bigger site needs ``site.bounds`` or a coarser resolution.
MAX_TRUTH_CELLS = 4096 * 4096
#: Fewest truth cells along a side of the site.
MIN_TRUTH_CELLS = 16
#: Points per edge when a box is carried from one CRS to another (edges curve between them).
_RING = 33


def _ring(b: tuple[float, float, float, float], n: int = _RING) -> tuple[np.ndarray, np.ndarray]:
    """Points along the edges of box ``b = (w, s, e, n)`` (4n,) each."""
    w, s, e, nn = b
    t = np.linspace(0.0, 1.0, n)
    xs = np.concatenate([w + t * (e - w), np.full(n, e), e - t * (e - w), np.full(n, w)])
    ys = np.concatenate([np.full(n, s), s + t * (nn - s), np.full(n, nn), nn - t * (nn - s)])
    return xs, ys


def _label(crs: CRS) -> str:
    """``EPSG:n`` when the CRS has a code, else its PROJ string when short, else its name
    (a WKT is too long to print), or its PROJ form when the name is ``unknown`` (a local
    transverse Mercator read from a GeoTIFF's WKT)."""
    code = crs.to_epsg()
    text = crs.to_string()
    if code:
        return f"EPSG:{code}"
    if len(text) <= 120:
        return text
    if crs.name and crs.name != "unknown":
        return crs.name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "You will likely lose important projection information"
        proj = crs.to_proj4()
    return proj if proj and len(proj) <= 160 else "unnamed CRS (see the DEM's WKT)"


def _fmt(b) -> str:
    return "[" + ", ".join(f"{v:.6g}" if abs(v) < 1e3 else f"{v:.1f}" for v in b) + "]"


def _open(path: Path):
    """The DEM as a :class:`terrain.raster_source.RasterSource` (errors name ``site.dem``)."""
    from terrain.raster_source import open_source

    if not path.is_file():
        raise bad_input(
            "site.dem",
            str(path),
            "an existing DEM raster file (GeoTIFF or any raster GDAL reads)",
            "check the path; a relative path is read from the scenario file's folder",
        )
    try:
        return open_source(path)
    except InputError as exc:
        raise bad_input(
            "site.dem",
            str(path),
            "a georeferenced, axis-aligned DEM raster that records its CRS",
            f"{exc} (assign a CRS: gdal_edit.py -a_srs EPSG:... {path.name})",
        ) from exc


def _metric(crs: CRS) -> bool:
    """A projected CRS whose axes are in metres (a US State Plane in feet is not: the site
    then takes the UTM zone of the DEM's centre, as a geographic DEM does)."""
    return bool(crs.is_projected) and all(
        a.unit_name in ("metre", "meter") for a in crs.axis_info[:2]
    )


def _utm_of_centre(src) -> CRS:
    """The WGS 84 UTM zone of the DEM's centre."""
    w, s, e, n = src.bounds
    lon, lat = Transformer.from_crs(src.crs, "EPSG:4326", always_xy=True).transform(
        (w + e) / 2, (s + n) / 2
    )
    crs = utm_crs(lon, lat)
    if crs is None:
        raise bad_input(
            "site.crs",
            None,
            f"a projected CRS for a DEM centred at lon {lon:.3f}, lat {lat:.3f} (no UTM zone)",
            'set site.crs, e.g. "EPSG:3031" (Antarctic) or "EPSG:3413" (Arctic) stereographic',
        )
    return crs


def _valid_cells(values: np.ndarray, frac: float) -> tuple[int, int, int, int]:
    """``(r0, r1, c0, c1)``: the bounding box of the valid cells, or, where more than
    ``frac`` of that box is nodata, the largest rectangle of valid cells inside it."""
    ok = np.isfinite(values)
    rows, cols = np.flatnonzero(ok.any(1)), np.flatnonzero(ok.any(0))
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    crop = ok[r0:r1, c0:c1]
    if 1.0 - crop.mean() <= frac:
        return r0, r1, c0, c1
    a0, a1, b0, b1 = _largest_valid_rectangle(crop)
    return r0 + a0, r0 + a1, c0 + b0, c0 + b1


def _cell_box(t, r0: int, r1: int, c0: int, c1: int) -> tuple[float, float, float, float]:
    xs = (t.c + t.a * c0, t.c + t.a * c1)
    ys = (t.f + t.e * r0, t.f + t.e * r1)
    return (min(xs), min(ys), max(xs), max(ys))


def _largest_valid_rectangle(ok: np.ndarray) -> tuple[int, int, int, int]:
    """``(r0, r1, c0, c1)`` of the largest all-True axis-aligned rectangle of ``ok``
    (histogram-stack method, O(rows x cols))."""
    ny, nx = ok.shape
    height = np.zeros(nx, int)
    best, out = 0, (0, 0, 0, 0)
    for r in range(ny):
        height = np.where(ok[r], height + 1, 0)
        stack: list[int] = []
        for c in range(nx + 1):
            h = height[c] if c < nx else 0
            while stack and height[stack[-1]] >= h:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = int(height[top]) * (c - left)
                if area > best:
                    best, out = area, (r - int(height[top]) + 1, r + 1, left, c)
            stack.append(c)
    return out


def _inner_box(to_site: Transformer, box: tuple[float, ...]) -> tuple[float, float, float, float]:
    """The largest axis-aligned box of the site CRS inside ``box`` (source CRS) carried
    over: each side at its innermost point (edges curve under a change of projection)."""
    w, s, e, n = box
    t = np.linspace(0.0, 1.0, _RING)
    west = np.max(to_site.transform(np.full_like(t, w), s + t * (n - s))[0])
    east = np.min(to_site.transform(np.full_like(t, e), s + t * (n - s))[0])
    south = np.max(to_site.transform(w + t * (e - w), np.full_like(t, s))[1])
    north = np.min(to_site.transform(w + t * (e - w), np.full_like(t, n))[1])
    return float(west), float(south), float(east), float(north)


def _snap_inward(b: tuple[float, ...], res: float) -> tuple[float, float, float, float]:
    w, s, e, n = b
    return (
        math.ceil(w / res - 1e-9) * res,
        math.ceil(s / res - 1e-9) * res,
        math.floor(e / res + 1e-9) * res,
        math.floor(n / res + 1e-9) * res,
    )


def _cell_size_m(src, site_crs: CRS) -> float:
    """The DEM's cell size in metres of the site CRS, at the DEM's centre (geometric mean
    of the two axes)."""
    t = src.transform
    h, w = src.shape
    r, c = h // 2, w // 2
    xs = np.array([t.c + t.a * c, t.c + t.a * (c + 1), t.c + t.a * c])
    ys = np.array([t.f + t.e * r, t.f + t.e * r, t.f + t.e * (r + 1)])
    X, Y = Transformer.from_crs(src.crs, site_crs, always_xy=True).transform(xs, ys)
    dx = math.hypot(X[1] - X[0], Y[1] - Y[0])
    dy = math.hypot(X[2] - X[0], Y[2] - Y[0])
    return math.sqrt(dx * dy)


def _check_bounds(bounds: Any) -> tuple[float, float, float, float]:
    try:
        b = tuple(float(v) for v in bounds)
    except (TypeError, ValueError) as exc:
        raise bad_input("site.bounds", bounds, "[west, south, east, north] in metres", "") from exc
    if len(b) != 4 or not np.all(np.isfinite(b)) or b[2] <= b[0] or b[3] <= b[1]:
        raise bad_input(
            "site.bounds",
            bounds,
            "four finite numbers [west, south, east, north] with east > west, north > south",
            "check the order (rasterio's west, south, east, north), site CRS metres",
        )
    return b  # type: ignore[return-value]


def resolve_dem_site(site: dict[str, Any], given: set[str], base: Path) -> dict[str, Any]:
    """The ``[site]`` table of a ``kind = "dem"`` scenario with ``dem`` made absolute and
    ``crs`` and ``bounds`` resolved (see the module docstring).

    Parameters
    ----------
    site : dict
        The merged ``[site]`` table (defaults included).
    given : set of str
        The ``[site]`` keys the user set (a default ``crs`` / ``bounds`` is not used for a
        DEM site).
    base : Path
        Folder a relative ``dem`` path is resolved against (the scenario file's).

    Returns
    -------
    dict
        A new table; the input is not changed.

    Raises
    ------
    InputError
        ``site.dem`` missing, unreadable, without CRS, rotated or all nodata;
        ``site.crs`` geographic or unknown; ``site.bounds`` malformed or not inside the DEM;
        ``site.truth_resolution_m`` giving fewer than :data:`MIN_TRUTH_CELLS` cells a side or
        more than :data:`MAX_TRUTH_CELLS` cells; ``site.max_nodata_fraction`` outside [0, 1).
    """
    out = dict(site)
    raw = str(site.get("dem", ""))
    if not raw:
        raise bad_input(
            "site.dem", raw, 'a DEM file path with kind = "dem"', 'add dem = "path/to/dem.tif"'
        )
    path = Path(raw).expanduser()
    path = path if path.is_absolute() else (base / path)
    src = _open(path)
    out["dem"] = str(path.resolve())
    res = float(site["truth_resolution_m"])
    if not (math.isfinite(res) and res > 0):
        raise bad_input("site.truth_resolution_m", res, "a cell size > 0 (m)", "e.g. 2.0")
    frac = float(site["max_nodata_fraction"])
    if not 0.0 <= frac < 1.0:
        raise bad_input("site.max_nodata_fraction", frac, "a share in [0, 1)", "default 0.05")
    if "crs" in given:
        crs = as_crs(site["crs"], "site.crs")
    else:
        crs = src.crs if _metric(src.crs) else _utm_of_centre(src)
    to_site = Transformer.from_crs(src.crs, crs, always_xy=True)
    values, transform = src.read(src.bounds, pad=0)
    if not np.isfinite(values).any():
        raise bad_input(
            "site.dem",
            f"{path.name}: all {values.size} cells nodata",
            "a DEM with valid elevations",
            "check the file's nodata value (gdalinfo -stats)",
        )
    if "bounds" in given:
        bounds = _check_bounds(site["bounds"])
        _check_inside(bounds, src, crs)
    else:
        box = _cell_box(transform, *_valid_cells(values, frac))
        bounds = _snap_inward(_inner_box(to_site, box), res)
    nx = int(round((bounds[2] - bounds[0]) / res))
    ny = int(round((bounds[3] - bounds[1]) / res))
    _check_size(nx, ny, res, bounds, src, crs)
    grid = Grid.from_bounds(bounds, res, crs)  # nodata share checked now, before any work
    inv = Transformer.from_crs(crs, src.crs, always_xy=True)
    near = sample_onto(values, transform, inv, grid, "nearest")[0]
    _check_nodata(int((~np.isfinite(near)).sum()), grid, frac, path)
    out["crs"] = crs.to_string()
    out["bounds"] = [float(v) for v in bounds]
    return out


def _check_inside(bounds: tuple, src, crs: CRS) -> None:
    xs, ys = Transformer.from_crs(crs, src.crs, always_xy=True).transform(*_ring(bounds))
    x0, y0, x1, y1 = src.bounds
    tol = 1e-9 * max(x1 - x0, y1 - y0)
    ok = np.isfinite(xs) & np.isfinite(ys)
    ok &= (xs >= x0 - tol) & (xs <= x1 + tol) & (ys >= y0 - tol) & (ys <= y1 + tol)
    if not ok.all():
        foot = _inner_box(Transformer.from_crs(src.crs, crs, always_xy=True), src.bounds)
        raise bad_input(
            "site.bounds",
            f"{_fmt(bounds)} in {_label(crs)}",
            f"a box inside the DEM (its footprint in the site CRS: {_fmt(foot)})",
            "choose bounds inside the DEM, or omit site.bounds to use the DEM's extent",
        )


def _check_size(nx: int, ny: int, res: float, bounds: tuple, src, crs: CRS) -> None:
    if min(nx, ny) < MIN_TRUTH_CELLS:
        raise bad_input(
            "site.truth_resolution_m",
            res,
            f"at least {MIN_TRUTH_CELLS} truth cells a side of the site "
            f"({bounds[2] - bounds[0]:.0f} x {bounds[3] - bounds[1]:.0f} m gives {nx} x {ny})",
            "choose a finer truth_resolution_m or larger site.bounds",
        )
    if nx * ny > MAX_TRUTH_CELLS:
        cx, cy = (bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2
        hint = [round(cx - 300.0), round(cy - 300.0), round(cx + 300.0), round(cy + 300.0)]
        raise bad_input(
            "site.bounds",
            f"{_fmt(bounds)} ({(bounds[2] - bounds[0]) / 1e3:.1f} x "
            f"{(bounds[3] - bounds[1]) / 1e3:.1f} km in {_label(crs)})",
            f"a site of at most {MAX_TRUTH_CELLS:,} truth cells at {res:g} m "
            f"(this one: {nx} x {ny})",
            f"set site.bounds to a rover-sized window, e.g. bounds = {hint} (600 m at the "
            "DEM's centre), or a coarser site.truth_resolution_m",
        )


def dem_truth(site: dict[str, Any]):
    """The true DEM of a resolved ``kind = "dem"`` site (:func:`resolve_dem_site`).

    Returns
    -------
    xarray.DataArray
        ``elevation`` (m), dims ``(y, x)`` north-up, on ``Grid.from_bounds(site["bounds"],
        truth_resolution_m, site["crs"])``; attribute ``site_dem`` holds the provenance
        (:func:`site_provenance`) as JSON: source, CRS and why, resampling, nodata counts.

    Raises
    ------
    InputError
        More than ``site.max_nodata_fraction`` of the site's cells are nodata.
    """
    src = _open(Path(site["dem"]))
    crs = as_crs(site["crs"], "site.crs")
    res = float(site["truth_resolution_m"])
    grid = Grid.from_bounds(tuple(site["bounds"]), res, crs)
    _check_inside(grid.bounds, src, crs)
    to_src = Transformer.from_crs(crs, src.crs, always_xy=True)
    values, transform = read_under(src, grid, to_src, pad=3)  # cubic: 2 cells either side
    dem_cell = _cell_size_m(src, crs)
    method = "cubic" if res <= dem_cell else "average"
    if method == "cubic":
        out = sample_onto(values, transform, to_src, grid, "cubic", nodata_nearest=True)[0]
    else:
        out = gdal_average(values, transform, src.crs, grid)
    n_bad = int(np.sum(~np.isfinite(out)))
    _check_nodata(n_bad, grid, float(site["max_nodata_fraction"]), Path(site["dem"]))
    out, holes, dist = fill_nearest(out)
    max_fill = float(dist[holes].max() * res) if n_bad else 0.0
    prov = site_provenance(site, src, crs, dem_cell, method, n_bad, out.size, max_fill)
    return grid.data_array(
        out, "elevation", source=f"real DEM {Path(site['dem']).name}", site_dem=json.dumps(prov)
    )


def _check_nodata(n_bad: int, grid: Grid, frac: float, path: Path) -> None:
    if n_bad > frac * grid.size:
        raise bad_input(
            "site.bounds",
            f"{_fmt(grid.bounds)}: {n_bad} of {grid.size} truth cells "
            f"({100.0 * n_bad / grid.size:.1f} %) nodata in {path.name}",
            f"a site with at most {100 * frac:g} % nodata (site.max_nodata_fraction)",
            "move site.bounds inside the DEM's valid data, or fill the DEM (gdal_fillnodata.py)",
        )


def site_provenance(
    site: dict[str, Any],
    src,
    crs: CRS,
    dem_cell_m: float,
    method: str,
    n_nodata: int,
    n_cells: int,
    max_fill_m: float,
) -> dict[str, Any]:
    """What :func:`dem_truth` did, in words and numbers (for the run summary)."""
    if crs.equals(src.crs):
        why = "the DEM's own CRS"
    elif not _metric(src.crs) and crs.equals(_utm_of_centre(src)):
        why = "the UTM zone of the DEM's centre (WGS 84)" + (
            f"; the DEM's {src.crs.name} is in {src.crs.axis_info[0].unit_name}"
            if src.crs.is_projected
            else ""
        )
    else:
        why = "site.crs"
    return {
        "dem": site["dem"],
        "dem_crs": _label(src.crs),
        "dem_shape": list(src.shape),
        "dem_cell_m": round(dem_cell_m, 3),
        "site_crs": _label(crs),
        "site_crs_from": why,
        "bounds": [float(v) for v in site["bounds"]],
        "truth_resolution_m": float(site["truth_resolution_m"]),
        "resampling": method,
        "nodata_cells_filled": int(n_nodata),
        "nodata_fraction": round(n_nodata / max(n_cells, 1), 6),
        "max_fill_distance_m": max_fill_m,
    }
