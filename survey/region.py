"""Survey regions: a validated shapely polygon in a projected CRS, metres.

Every planner and coverage metric takes its region through :func:`as_region`, so a bad
polygon is rejected once, with the reason and the fix, before any geometry is computed.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon, box, shape

from terrain.errors import bad_input
from terrain.grid import as_crs

__all__ = ["as_region"]

Region = Polygon | MultiPolygon


def as_region(region: Any, crs: Any = None) -> Region:
    """Validate a survey region and return it as a shapely (Multi)Polygon.

    Parameters
    ----------
    region : shapely.Polygon, shapely.MultiPolygon, tuple of float or mapping
        The area to survey, easting/northing in metres of a projected CRS. A Polygon may have
        holes (crevasse fields, melt pools the rover must not enter). A 4-tuple is read as
        rasterio-style bounds ``(west, south, east, north)`` and becomes a box. Anything with
        ``__geo_interface__`` (or a GeoJSON-like mapping) is converted with
        :func:`shapely.geometry.shape`.
    crs : optional
        CRS of the coordinates (EPSG code, string, WKT or ``pyproj.CRS``). Only checked: it
        must be projected (metres); a geographic CRS is rejected because every distance in
        :mod:`survey` is Euclidean. ``None`` skips the check.

    Returns
    -------
    shapely.Polygon or shapely.MultiPolygon
        The region, unchanged (bounds become a box).

    Raises
    ------
    terrain.InputError
        Naming ``"region"``: wrong type, empty, non-finite coordinates, invalid geometry
        (self-intersection, ring crossing; the reason comes from
        :func:`shapely.is_valid_reason`) or zero area; naming ``"crs"``: geographic CRS.
    """
    if crs is not None:
        as_crs(crs, "crs")
    if isinstance(region, tuple | list | np.ndarray) and np.shape(region) == (4,):
        try:
            west, south, east, north = (float(b) for b in region)
        except (TypeError, ValueError) as exc:
            raise bad_input(
                "region", region, "bounds (west, south, east, north) as numbers", "pass 4 floats"
            ) from exc
        if not (np.all(np.isfinite([west, south, east, north])) and east > west and north > south):
            raise bad_input(
                "region",
                region,
                "finite bounds (west, south, east, north) with east > west and north > south",
                "check the order: rasterio's (west, south, east, north)",
            )
        return box(west, south, east, north)
    if not isinstance(region, shapely.Geometry) and (
        hasattr(region, "__geo_interface__") or isinstance(region, dict)
    ):
        try:
            region = shape(region)
        except Exception as exc:  # shapely raises several types for bad GeoJSON
            raise bad_input(
                "region", region, "a GeoJSON-like polygon", "pass a shapely Polygon"
            ) from exc
    if not isinstance(region, Polygon | MultiPolygon):
        raise bad_input(
            "region",
            type(region).__name__,
            "a shapely Polygon/MultiPolygon or bounds (west, south, east, north)",
            "build the polygon with shapely.geometry.Polygon(shell, holes)",
        )
    if region.is_empty:
        raise bad_input("region", "empty geometry", "a non-empty polygon", "pass the survey area")
    if not np.all(np.isfinite(shapely.get_coordinates(region))):
        raise bad_input(
            "region", "non-finite coordinates", "finite easting/northing", "drop NaN vertices"
        )
    if not shapely.is_valid(region):
        raise bad_input(
            "region",
            shapely.is_valid_reason(region),
            "a valid polygon (no self-intersection, holes inside the shell)",
            "repair it with shapely.make_valid(region) or redraw the outline",
        )
    if not region.area > 0:
        raise bad_input(
            "region", f"area {region.area}", "a polygon with positive area", "check the vertices"
        )
    return region
