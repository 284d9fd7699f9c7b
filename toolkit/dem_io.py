"""DEMs to certify, compare or map on (:func:`read_dem`): a terrain product Dataset, a truth
DataArray, a GeoTIFF or a NetCDF file, north-up, in a projected CRS or in degrees; and
:func:`sample_bilinear`, strict bilinear sampling between cell centres (NaN near nodata)."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terrain import Grid
from terrain.dem_projection import Footprint, dem_lattice, raster_footprint
from terrain.errors import bad_input
from terrain.grid import north_up

from .provenance import file_sha256

__all__ = ["DemRaster", "read_dem", "sample_bilinear"]

_GEOREF = frozenset({"crs", "crs_wkt", "transform", "resolution"})


# --------------------------------------------------------------------------- the DEM
@dataclass(frozen=True)
class DemRaster:
    """A DEM loaded for certification.

    Attributes
    ----------
    grid : terrain.Grid or terrain.dem_projection.Footprint
        North-up raster definition (cell centres): a Grid in a projected CRS (metres), a
        Footprint in a geographic one (degrees).
    elevation : ndarray of shape grid.shape
        Elevation, metres; NaN on nodata.
    elevation_std : ndarray of shape grid.shape or None
        1-sigma band (m) when the DEM carries one.
    source : dict
        ``kind`` (``"dataset"``, ``"geotiff"``, ``"netcdf"``), ``name`` and ``sha256``.
    provenance : dict of str
        Non-georeferencing attributes / tags (seed, method, kernel, ...).
    """

    grid: Grid | Footprint
    elevation: np.ndarray
    elevation_std: np.ndarray | None
    source: dict[str, Any]
    provenance: dict[str, str] = field(default_factory=dict)


def _provenance(attrs: dict[str, Any]) -> dict[str, str]:
    out = {}
    for key in sorted(attrs, key=str):
        value = attrs[key]
        if str(key) in _GEOREF or str(key).startswith("_"):
            continue
        value = value.tolist() if isinstance(value, np.ndarray | np.generic) else value
        out[str(key)] = value if isinstance(value, str) else json.dumps(value, default=str)
    return out


def _from_xarray(obj: Any, source: dict[str, Any]) -> DemRaster:
    import xarray as xr

    if isinstance(obj, xr.Dataset):
        if "elevation" not in obj.data_vars:
            raise bad_input(
                "DEM variables", sorted(map(str, obj.data_vars)), "'elevation' (m)", "rename it"
            )
        elev, std = obj["elevation"], obj.get("elevation_std")
    elif isinstance(obj, xr.DataArray):
        elev, std = obj, None
    else:
        raise bad_input("dem", type(obj).__name__, "a Dataset, DataArray or file path", "")
    if tuple(elev.dims) != ("y", "x"):
        raise bad_input("DEM dims", tuple(elev.dims), "('y', 'x')", "ds.transpose('y', 'x')")
    obj, elev = north_up(obj), north_up(elev)  # rows north first, as the grid's
    std = None if std is None else north_up(std)
    fp = raster_footprint(obj)  # a DEM in degrees is certified on its own cells
    grid = fp if fp.crs.is_geographic else Grid.from_dataarray(obj)
    z = np.asarray(elev.values, dtype=float)
    s = None if std is None else np.asarray(std.values, dtype=float)
    if source.get("sha256") is None:
        h = hashlib.sha256(np.ascontiguousarray(z).tobytes())
        if s is not None:
            h.update(np.ascontiguousarray(s).tobytes())
        source = {
            **source,
            "sha256": h.hexdigest(),
            # not a file's hash (a reader checking elevation.tif's would find another)
            "sha256_of": "the in-memory map's float64 elevation"
            + (" and elevation_std" if s is not None else "")
            + " arrays (rows north first, C order), not a file",
        }
    return DemRaster(grid, z, s, source, _provenance(dict(obj.attrs)))


def _from_geotiff(path: Path, source: dict[str, Any]) -> DemRaster:
    import rasterio
    from rasterio.errors import RasterioIOError

    try:
        src = rasterio.open(path)
    except RasterioIOError as exc:
        raise bad_input("DEM", path.name, "a readable GeoTIFF", str(exc)) from exc
    with src:
        if src.crs is None:
            raise bad_input(
                "DEM crs",
                path.name,
                "a GeoTIFF with a CRS",
                "assign one, e.g. gdal_edit.py -a_srs EPSG:32608 DEM.tif",
            )
        t = src.transform
        if t.b != 0 or t.d != 0 or t.a <= 0 or t.e >= 0:
            raise bad_input("DEM transform", tuple(t)[:6], "north-up, no rotation", "gdalwarp it")
        grid = dem_lattice(t, (src.height, src.width), src.crs)  # degrees allowed

        def band(i: int) -> np.ndarray:
            return np.ma.filled(src.read(i, masked=True).astype(float), np.nan)

        descriptions = list(src.descriptions)
        std = (
            band(descriptions.index("elevation_std") + 1)
            if "elevation_std" in descriptions
            else None
        )
        return DemRaster(grid, band(1), std, source, _provenance(src.tags()))


def read_dem(dem: Any) -> DemRaster:
    """Load a DEM: a terrain product ``xarray.Dataset`` (or truth ``DataArray``), a GeoTIFF
    (band 1 elevation; a band described ``elevation_std`` is the 1-sigma; nodata masked) or
    a NetCDF terrain product (``.nc``).

    Raises
    ------
    terrain.errors.InputError
        Missing file, unknown extension, a GeoTIFF without CRS or not north-up, a Dataset
        without ``elevation``. A DEM in degrees (SRTM, GLO-30) is read on its own cells.
    """
    if not isinstance(dem, str | os.PathLike):
        return _from_xarray(dem, {"kind": "dataset", "name": type(dem).__name__, "sha256": None})
    path = Path(dem)
    if not path.is_file():
        raise bad_input("DEM", str(path), "an existing GeoTIFF or NetCDF file", "check the path")
    suffix = path.suffix.lower()
    source = {
        "name": path.name,
        "path": str(path),  # as given: glacimap report finds the DEM again by it
        "sha256": file_sha256(path),
    }
    if suffix in (".tif", ".tiff"):
        return _from_geotiff(path, {"kind": "geotiff", **source})
    if suffix == ".nc":
        import xarray as xr

        with xr.open_dataset(path) as ds:
            return _from_xarray(ds.load(), {"kind": "netcdf", **source})
    raise bad_input("DEM", path.name, "a .tif/.tiff GeoTIFF or .nc product", "convert it")


def sample_bilinear(grid: Grid, values: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear interpolation between cell centres, NaN if any neighbour with weight > 0 is
    NaN (strict: a checkpoint next to nodata is not scored). Points between the outer cell
    edge and the outermost centres take the edge cells' values (clamped)."""
    dx, dy = grid.resolution
    col = np.clip((xy[:, 0] - grid.x[0]) / dx, 0, grid.nx - 1)
    row = np.clip((grid.y[0] - xy[:, 1]) / dy, 0, grid.ny - 1)
    c0 = np.minimum(np.floor(col).astype(int), max(grid.nx - 2, 0))
    r0 = np.minimum(np.floor(row).astype(int), max(grid.ny - 2, 0))
    fc, fr = col - c0, row - r0
    out = np.zeros(len(xy))
    for dr, wr in ((0, 1 - fr), (1, fr)):
        for dc, wc in ((0, 1 - fc), (1, fc)):
            v = values[np.minimum(r0 + dr, grid.ny - 1), np.minimum(c0 + dc, grid.nx - 1)]
            w = wr * wc
            out += np.where(w > 0, w * v, 0.0)  # NaN * w > 0 stays NaN
    return out
