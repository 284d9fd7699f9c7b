"""DEMs in geographic coordinates (SRTM, Copernicus GLO-30, ASTER GDEM, NASADEM) in metres.

Glaciologists' satellite DEMs are mostly distributed in longitude / latitude (EPSG:4326, 1
arcsecond cells). A :class:`terrain.grid.Grid` is projected by contract (kernels, slopes and
volumes are Euclidean), so a geographic DEM is described here by its :class:`Footprint`
(north-up affine lattice in any CRS) and brought onto a projected grid in one warp:

* the map's CRS is a projected input's own CRS; where no input is projected, the UTM zone of
  the footprint's centre (:func:`terrain.grid.utm_crs`), or polar stereographic beyond UTM's
  latitudes (EPSG:3413 north of 84 N, EPSG:3031 south of 80 S) -- and it is always stated;
* a geographic DEM's cells in that CRS are GDAL's suggested warp resolution
  (``rasterio.warp.calculate_default_transform``, what ``gdalwarp -t_srs`` picks: square
  cells keeping the footprint's diagonal cell count);
* its ground cell size (metres, at the footprint's centre, on the WGS 84 ellipsoid by
  ``pyproj.Geod``) says which of two DEMs is the finer.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from affine import Affine
from pyproj import CRS

from .errors import bad_input
from .grid import Grid, Lattice, _attr_resolution, _coord, _spacing, dataarray_crs, utm_crs

__all__ = [
    "Footprint",
    "change_crs",
    "crs_label",
    "dem_lattice",
    "finer",
    "grid_in",
    "in_metres",
    "raster_footprint",
]

#: Polar stereographic CRSs used beyond UTM's latitudes (NSIDC sea ice polar stereographic
#: north, Antarctic polar stereographic): the standard glacier-mapping grids there.
POLAR_NORTH, POLAR_SOUTH = 3413, 3031


@dataclass(frozen=True)
class Footprint(Lattice):
    """A north-up raster lattice in any CRS (a :class:`Grid` without the projected rule;
    ``bounds``, ``transform``, ``x``, ``y``, ``contains`` from :class:`terrain.grid.Lattice`).

    Parameters
    ----------
    west, north : float
        Outer corner, CRS units (degrees for a geographic CRS).
    resolution : (float, float)
        Cell size (dx, dy), CRS units, positive.
    shape : (int, int)
        ``(ny, nx)``.
    crs : pyproj.CRS
    """

    west: float
    north: float
    resolution: tuple[float, float]
    shape: tuple[int, int]
    crs: CRS

    def centre_lonlat(self) -> tuple[float, float]:
        """The footprint's centre in WGS 84 longitude, latitude (degrees)."""
        from pyproj import Transformer

        w, s, e, n = self.bounds
        tr = Transformer.from_crs(self.crs, "EPSG:4326", always_xy=True)
        lon, lat = tr.transform(0.5 * (w + e), 0.5 * (s + n))
        return float(lon), float(lat)

    def ground_resolution(self) -> tuple[float, float]:
        """Cell size on the ground (dx, dy) in metres: the resolution itself for a projected
        CRS, for a geographic one the geodesic length of one cell east and north at the
        footprint's centre (WGS 84 ellipsoid)."""
        if not self.crs.is_geographic:
            return self.resolution
        from pyproj import Geod

        w, s, e, n = self.bounds
        lon, lat = 0.5 * (w + e), 0.5 * (s + n)
        dx, dy = self.resolution
        geod = Geod(ellps="WGS84")
        ew = geod.inv(lon - dx / 2, lat, lon + dx / 2, lat)[2]
        ns = geod.inv(lon, lat - dy / 2, lon, lat + dy / 2)[2]
        return float(ew), float(ns)

    def area_km2(self) -> float:
        """The footprint's area on the ground, km^2 (geodesic on WGS 84 for degrees)."""
        w, s, e, n = self.bounds
        if not self.crs.is_geographic:
            return (e - w) * (n - s) / 1e6
        from pyproj import Geod

        # the north and south edges are parallels, not geodesics: densified (64 points)
        t = np.linspace(0.0, 1.0, 64, endpoint=False)
        lon = np.concatenate([w + (e - w) * t, np.full(64, e), e - (e - w) * t, np.full(64, w)])
        lat = np.concatenate([np.full(64, s), s + (n - s) * t, np.full(64, n), n - (n - s) * t])
        area, _ = Geod(ellps="WGS84").polygon_area_perimeter(lon, lat)
        return abs(float(area)) / 1e6

    def describe(self) -> str:
        """``EPSG:4326, 0.000278 x 0.000278 deg (~30.9 x 30.9 m)`` and the like."""
        name = crs_label(self.crs)
        if not self.crs.is_geographic:
            return f"{name}, {self.resolution[0]:g} x {self.resolution[1]:g} m cells"
        gx, gy = self.ground_resolution()
        return (
            f"{name}, {self.resolution[0]:.6g} x {self.resolution[1]:.6g} deg cells "
            f"(~{gx:.1f} x {gy:.1f} m)"
        )


def crs_label(crs: CRS) -> str:
    """``EPSG:32725`` when the CRS has an EPSG code, else its name (never a page of WKT)."""
    code = crs.to_epsg()
    return f"EPSG:{code}" if code is not None else crs.name


def raster_footprint(da: Any) -> Footprint:
    """The lattice of a DEM DataArray / Dataset in its own CRS, geographic or projected.

    Same reading as :meth:`Grid.from_dataarray` (cell-centre ``x`` / ``y`` coordinates in
    either order, a single row or column through ``attrs['resolution']``, the CRS by
    :func:`terrain.grid.dataarray_crs`), without requiring metres.

    Raises
    ------
    InputError
        No ``x`` / ``y`` coordinates, irregular spacing, or no CRS.
    """
    x = np.asarray(_coord(da, "x"), float)
    y = np.asarray(_coord(da, "y"), float)
    if x.size < 1 or y.size < 1:
        raise bad_input("x/y coordinates", (x.size, y.size), "non-empty", "check the data")
    x = x[::-1] if x.size > 1 and x[1] < x[0] else x
    y = y[::-1] if y.size > 1 and y[1] > y[0] else y
    dx = abs(_spacing(x, "x")) if x.size > 1 else _attr_resolution(da, 0)
    dy = abs(_spacing(y, "y")) if y.size > 1 else _attr_resolution(da, 1)
    crs = dataarray_crs(da)
    if crs is None:
        raise bad_input(
            "attrs['crs_wkt']", None, "the CRS of the raster", "set da.attrs['crs_wkt']"
        )
    return Footprint(x[0] - dx / 2, y[0] + dy / 2, (dx, dy), (y.size, x.size), crs)


def dem_lattice(transform: Affine, shape: tuple[int, int], crs: Any) -> Grid | Footprint:
    """A north-up raster's lattice: a :class:`Grid` in a projected CRS, a :class:`Footprint`
    in a geographic one (both give ``x``, ``y``, ``bounds``, ``contains``, ``resolution``)."""
    crs = CRS.from_user_input(crs)
    t = transform
    if crs.is_geographic:
        return Footprint(t.c, t.f, (t.a, -t.e), tuple(shape), crs)
    return Grid(t.c, t.f, (t.a, -t.e), shape, crs.to_wkt())


def in_metres(xy: np.ndarray, lattice: Grid | Footprint) -> tuple[np.ndarray, str | None]:
    """Points of ``lattice``'s CRS in metres: themselves for a projected CRS, else projected
    to the UTM zone (or polar stereographic CRS) of the lattice's centre, with the note."""
    if not lattice.crs.is_geographic:
        return np.asarray(xy, float), None
    from pyproj import Transformer

    crs, why = _local_projected(lattice)
    tr = Transformer.from_crs(lattice.crs, crs, always_xy=True)
    ex, ny = tr.transform(np.asarray(xy)[:, 0], np.asarray(xy)[:, 1])
    return np.column_stack([ex, ny]), why


def _local_projected(fp: Footprint) -> tuple[CRS, str]:
    """The UTM zone of ``fp``'s centre, or polar stereographic beyond UTM's latitudes."""
    lon, lat = fp.centre_lonlat()
    crs = utm_crs(lon, lat)
    if crs is None:
        crs = CRS.from_epsg(POLAR_NORTH if lat > 0 else POLAR_SOUTH)
        why = "polar stereographic: the site lies beyond UTM's latitudes"
    else:
        why = "the UTM zone of the DEM's centre"
    return crs, f"{crs_label(crs)} ({crs.name}; {why}, lon {lon:.3f}, lat {lat:.3f})"


def change_crs(before: Any, after: Any) -> tuple[CRS, str]:
    """The projected CRS two DEMs are compared in, and why, in words.

    The finer DEM's CRS when it is projected, else the other's when that one is; when both
    are geographic, the UTM zone (or polar stereographic CRS) of the finer one's centre.
    "Finer" compares ground cell areas in square metres (:meth:`Footprint.ground_resolution`).

    Parameters
    ----------
    before, after : xarray.DataArray or xarray.Dataset
        Elevation rasters with a CRS (any; degrees allowed).

    Returns
    -------
    crs : pyproj.CRS
        Projected, metres.
    why : str
        e.g. ``"EPSG:32725 (the finer DEM's, before's)"``.
    """
    fine, coarse, which = finer(raster_footprint(before), raster_footprint(after))
    other = "after" if which == "before" else "before"
    if not fine.crs.is_geographic:
        return fine.crs, f"{crs_label(fine.crs)} (the finer DEM's, {which}'s)"
    if not coarse.crs.is_geographic:
        return coarse.crs, f"{crs_label(coarse.crs)} ({other}'s: the finer DEM is geographic)"
    return _local_projected(fine)


def finer(before: Footprint, after: Footprint) -> tuple[Footprint, Footprint, str]:
    """``(fine, coarse, which)``: the footprint with the smaller ground cell area (m^2;
    ``before`` on a tie), the other, and ``"before"`` or ``"after"``."""
    if _ground_area(before) <= _ground_area(after):
        return before, after, "before"
    return after, before, "after"


def _ground_area(fp: Footprint) -> float:
    gx, gy = fp.ground_resolution()
    return gx * gy


def grid_in(fp: Footprint, crs: CRS) -> Grid:
    """A projected grid over ``fp``'s footprint in ``crs``: ``fp``'s own lattice when it is
    already in ``crs``, else GDAL's suggested warp (``calculate_default_transform``: square
    cells, the source's diagonal cell count kept, bounds densified along the edges)."""
    if fp.crs.equals(crs, ignore_axis_order=True):
        return Grid(fp.west, fp.north, fp.resolution, fp.shape, crs)
    from rasterio.warp import calculate_default_transform

    ny, nx = fp.shape
    t, width, height = calculate_default_transform(
        fp.crs.to_wkt(), crs.to_wkt(), nx, ny, *fp.bounds
    )
    return Grid(t.c, t.f, (t.a, -t.e), (height, width), crs)
