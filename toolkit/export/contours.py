"""Contour lines of the elevation map, each carrying the mean 1-sigma along it."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from terrain.errors import bad_input

from ._files import check_target
from ._product import Product, bilinear, read_product
from .vectors import VectorLayer, write_geojson, write_vector_layers

__all__ = ["INDEX_EVERY", "contour_layer", "contour_levels", "write_contours"]

#: Index (major) contours: every 5th interval counted from 0 m (levels that are multiples of
#: 5 x the interval), the cartographic convention; the ``index`` field marks them.
INDEX_EVERY = 5


def contour_levels(elevation: np.ndarray, interval_m: float) -> np.ndarray:
    """Multiples of ``interval_m`` within [nanmin, nanmax] of ``elevation`` (m), increasing."""
    lo = np.ceil(np.nanmin(elevation) / interval_m)
    hi = np.floor(np.nanmax(elevation) / interval_m)
    return np.arange(lo, hi + 1) * interval_m  # integer multiples: no accumulated round-off


def _mean_along(grid, std: np.ndarray, xy: np.ndarray) -> float:
    """Length-weighted mean of bilinear ``std`` along a polyline (trapezoid rule), m."""
    s = bilinear(grid, std, xy)
    seg = np.hypot(*np.diff(xy, axis=0).T)
    mid = 0.5 * (s[1:] + s[:-1])
    ok = np.isfinite(mid) & (seg > 0)
    if ok.any():
        return float(np.sum(seg[ok] * mid[ok]) / np.sum(seg[ok]))
    return float(np.nanmean(s)) if np.isfinite(s).any() else float("nan")


def contour_layer(ds: Any, interval_m: float) -> tuple[VectorLayer, np.ndarray]:
    """Contour lines of ``ds.elevation`` every ``interval_m`` metres.

    Lines are traced by contourpy (the engine behind matplotlib's ``contour``) through the
    cell centres; quads touching a NaN cell are masked, so lines stop at data gaps.

    Parameters
    ----------
    ds : xarray.Dataset
        Terrain product (``elevation``, ``elevation_std`` on ``(y, x)``, CRS in attrs).
    interval_m : float
        Contour interval, metres (> 0); levels are its integer multiples.

    Returns
    -------
    layer : VectorLayer
        One LineString per connected line (closed loops end where they start), easting /
        northing in the product's CRS, with fields ``elev`` (the level, m), ``index`` (True
        on index contours: levels that are multiples of :data:`INDEX_EVERY` intervals) and
        ``mean_std`` (length-weighted mean of the bilinearly sampled ``elevation_std`` along
        it, m).
    levels : ndarray of shape (k,)
        All levels within the elevation range (some may have no line after masking).
    """
    _check_interval(interval_m)
    return _contours(read_product(ds), float(interval_m))


def _check_interval(interval_m: Any) -> None:
    ok = isinstance(interval_m, int | float | np.number) and not isinstance(interval_m, bool)
    if not (ok and np.isfinite(interval_m) and interval_m > 0):
        raise bad_input(
            "interval_m", interval_m, "a positive contour interval in metres", "e.g. 1.0"
        )


def _contours(product: Product, interval: float) -> tuple[VectorLayer, np.ndarray]:
    import contourpy

    grid, z = product.grid, product.elevation
    levels = contour_levels(z, interval)
    if levels.size > 10_000:
        raise bad_input(
            "interval_m",
            interval,
            f"at most 10,000 levels over {np.nanmax(z) - np.nanmin(z):.1f} m of relief",
            "choose a larger interval",
        )
    lines, elev, mean_std, index = [], [], [], []
    if min(grid.shape) >= 2:
        # contourpy wants increasing coordinates: flip rows so y goes south -> north.
        masked = np.ma.masked_invalid(z[::-1])
        gen = contourpy.contour_generator(
            grid.x, grid.y[::-1], masked, line_type=contourpy.LineType.Separate
        )
        for level in levels:
            for xy in gen.lines(level):
                if len(xy) < 2 or not np.any(np.ptp(xy, axis=0) > 0):
                    continue
                lines.append(xy)
                elev.append(level)
                index.append(round(level / interval) % INDEX_EVERY == 0)
                mean_std.append(_mean_along(grid, product.elevation_std, xy))
    layer = VectorLayer.lines(
        lines,
        elev=np.asarray(elev, float),
        index=np.asarray(index, bool),
        mean_std=np.asarray(mean_std),
    )
    return layer, levels


def write_contours(
    ds: Any,
    gpkg_path: str | os.PathLike,
    interval_m: float,
    geojson_path: str | os.PathLike | None = None,
) -> dict[str, Any]:
    """Write contour lines of a terrain product to GeoPackage (and optionally GeoJSON).

    Parameters
    ----------
    ds : xarray.Dataset
        Terrain product (``elevation``, ``elevation_std`` on ``(y, x)``, CRS in attrs).
    gpkg_path : path-like
        Output ``.gpkg``: layer ``contour`` (LineString, the product's CRS) with fields
        ``elev`` (m), ``index`` (bool: index contour) and ``mean_std`` (m), provenance,
        ``vertical_datum``, ``contour_interval_m`` and ``fields`` (each field and its unit)
        as layer metadata.
    interval_m : float
        Contour interval, metres (> 0).
    geojson_path : path-like, optional
        Also write the lines as RFC 7946 GeoJSON (longitude/latitude, WGS 84), same fields;
        the FeatureCollection's ``description`` states the vertical datum of ``elev``.

    Returns
    -------
    dict
        ``lines`` (features written), ``levels`` (levels that have at least one line),
        ``index_lines`` (features flagged ``index``), ``interval`` (m), ``vertical_datum``,
        ``paths`` (the files written, as str).
    """
    target = check_target(gpkg_path, (".gpkg",), "gpkg_path")
    if geojson_path is not None:
        check_target(geojson_path, (".geojson", ".json"), "geojson_path")
    _check_interval(interval_m)
    product = read_product(ds)
    layer, _ = _contours(product, float(interval_m))
    crs = product.grid.crs
    fields = (
        f"elev = contour elevation, m ({product.vertical_datum}); index = index contour "
        f"(level a multiple of {INDEX_EVERY} x {float(interval_m):g} m); mean_std = "
        "length-weighted mean of the map's total 1-sigma (elevation_std) along the line, m"
    )
    meta = {**product.provenance, "fields": fields, "contour_interval_m": f"{interval_m:g}"}
    write_vector_layers(target, {"contour": layer}, crs, metadata=meta)
    paths = [str(target)]
    if geojson_path is not None:
        note = f"contour elevations (elev, m): {product.vertical_datum}"
        paths.append(str(write_geojson(geojson_path, layer, crs, name="contour", description=note)))
    return {
        "lines": len(layer),
        "levels": int(np.unique(layer.fields["elev"]).size),
        "index_lines": int(np.count_nonzero(layer.fields["index"])),
        "interval": float(interval_m),
        "vertical_datum": product.vertical_datum,
        "paths": paths,
    }
