"""A georeferenced raster definition: where every raster product of glacimap lives.

Convention (the same as rasterio and GDAL): north-up, row 0 is the northern edge, the affine
transform maps (col, row) of a cell *corner* to (easting, northing). Cell centres are half a
cell in. Coordinates are in the grid's projected CRS, in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from affine import Affine
from pyproj import CRS

from .errors import CRSMismatchError, bad_input

__all__ = ["DEFAULT_CRS", "Grid", "as_crs", "check_same_crs", "dataarray_crs", "north_up"]

#: UTM zone 8N (WGS 84): Juneau and the Mendenhall Glacier, the paper's field site.
DEFAULT_CRS = CRS.from_epsg(32608)


def as_crs(crs: Any, field_name: str = "crs") -> CRS:
    """Turn anything pyproj understands (EPSG code, ``"EPSG:32608"``, WKT, CRS) into a CRS."""
    try:
        out = CRS.from_user_input(crs)
    except Exception as exc:  # pyproj raises CRSError, a plain Exception subclass
        raise bad_input(
            field_name, crs, "a CRS pyproj understands", 'pass e.g. "EPSG:32608"'
        ) from exc
    if not out.is_projected:
        raise bad_input(
            field_name,
            out.name,
            "a projected CRS in metres (distances and kernels are Euclidean)",
            "reproject to a UTM zone or polar stereographic CRS first",
        )
    return out


def utm_crs(lon_deg: float, lat_deg: float) -> CRS | None:
    """The WGS 84 UTM zone (EPSG:326zz north, 327zz south) holding a point, by PROJ's
    database; ``None`` outside UTM's latitudes (80 S - 84 N), where a polar stereographic
    CRS (EPSG:3031, 3413) is the choice."""
    from pyproj.aoi import AreaOfInterest
    from pyproj.database import query_utm_crs_info

    lon, lat = float(lon_deg), float(lat_deg)
    if not (-80.0 <= lat <= 84.0 and -180.0 <= lon <= 180.0):
        return None
    info = query_utm_crs_info("WGS 84", area_of_interest=AreaOfInterest(lon, lat, lon, lat))
    return CRS.from_epsg(int(info[0].code)) if info else None


def check_same_crs(a: CRS | None, b: CRS | None, what_a: str, what_b: str) -> None:
    """Raise :class:`CRSMismatchError` unless ``a`` and ``b`` are the same CRS.

    ``None`` means "no CRS recorded" and is accepted against anything.
    """
    if a is None or b is None:
        return
    if not CRS.from_user_input(a).equals(CRS.from_user_input(b), ignore_axis_order=True):
        raise CRSMismatchError(
            f"{what_a}.crs ({CRS.from_user_input(a).to_string()}) differs from "
            f"{what_b}.crs ({CRS.from_user_input(b).to_string()}). Fix: reproject one of them "
            "(pyproj.Transformer) so both are in the same projected CRS."
        )


_SPACING_RTOL = 1e-3  # a coordinate may stray this fraction of a cell from a regular lattice


def _coord(da: Any, name: str) -> np.ndarray:
    """The values of coordinate ``name`` of ``da``, or an :class:`InputError` naming it."""
    try:
        return np.asarray(da[name].values)
    except (KeyError, AttributeError, TypeError) as exc:
        dims = tuple(getattr(da, "dims", ()))
        raise bad_input(
            f"coordinate {name!r}",
            f"dims {dims}",
            "cell-centre coordinates named 'x' and 'y'",
            "rename them, e.g. da.rename({'lon': 'x', 'lat': 'y'})",
        ) from exc


def _spacing(c: np.ndarray, name: str) -> float:
    """Signed cell size of the 1-D centre coordinate ``c`` (>= 2 values), checked regular.

    A lattice is regular when every coordinate lies within ``_SPACING_RTOL`` of a cell of
    ``c[0] + i * step`` (step = ``c[1] - c[0]``, the value the grid keeps).
    """
    if not np.all(np.isfinite(c)):
        raise bad_input(f"{name} coordinates", "NaN or inf", "finite values", "repair them")
    step = float(c[1] - c[0])
    if step == 0:
        raise bad_input(f"{name} coordinates", c[:2].tolist(), "distinct values", "repair them")
    dev = np.abs(c - (c[0] + step * np.arange(c.size)))
    if dev.max() > _SPACING_RTOL * abs(step):
        gaps = np.diff(c)
        i = int(np.argmax(np.abs(gaps - step)))
        raise bad_input(
            f"{name} coordinates",
            f"spacing {step:g} then {gaps[i]:g} (between {c[i]:g} and {c[i + 1]:g})",
            "regularly spaced cell centres (a raster)",
            "resample onto a regular grid first (rasterio.warp.reproject or xarray interp)",
        )
    return step


def _attr_resolution(da: Any, axis: int) -> float:
    try:
        return float(da.attrs["resolution"][axis])
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise bad_input(
            "attrs['resolution']",
            da.attrs.get("resolution"),
            "(dx, dy) in metres for a raster with a single row or column",
            "set da.attrs['resolution'] = (dx, dy)",
        ) from exc


def dataarray_crs(da: Any) -> CRS | None:
    """The CRS recorded on a DataArray / Dataset, or ``None``.

    Looked up in this order: ``attrs['crs_wkt']``, ``attrs['crs']``, a rioxarray / CF
    ``spatial_ref`` coordinate (its ``attrs['crs_wkt']`` or ``attrs['spatial_ref']``), and
    ``da.rio.crs`` when rioxarray is installed (optional). Geographic CRSs are returned as
    they are (a :class:`Grid` itself needs a projected one).
    """
    attrs = getattr(da, "attrs", {}) or {}
    candidates: list[tuple[str, Any]] = [
        ("attrs['crs_wkt']", attrs.get("crs_wkt")),
        ("attrs['crs']", attrs.get("crs")),
    ]
    coords = getattr(da, "coords", {})
    if "spatial_ref" in coords:
        ref = coords["spatial_ref"].attrs
        candidates.append(("spatial_ref.attrs['crs_wkt']", ref.get("crs_wkt")))
        candidates.append(("spatial_ref.attrs['spatial_ref']", ref.get("spatial_ref")))
    for where, value in candidates:
        if value is None or (isinstance(value, str) and not value.strip()):
            continue
        try:
            return CRS.from_user_input(value)
        except Exception as exc:  # pyproj's CRSError
            raise bad_input(where, value, "a CRS pyproj understands", "fix or drop it") from exc
    try:
        import rioxarray  # noqa: F401  (registers the .rio accessor)
    except ImportError:
        return None
    try:
        rio_crs = da.rio.crs
    except Exception:  # no .rio accessor on this object, or no CRS to read
        return None
    return None if rio_crs is None else CRS.from_user_input(rio_crs.to_wkt())


def north_up(da: Any) -> Any:
    """``da`` sorted so that ``x`` increases and ``y`` decreases: the row order of
    :class:`Grid` (row 0 is the northern edge). Returns ``da`` itself when already so.

    Parameters
    ----------
    da : xarray.DataArray or xarray.Dataset
        A raster with 1-D coordinates ``x`` and ``y`` (y ascending, as NetCDF files often
        store it, is the usual reason to call this).

    Returns
    -------
    xarray.DataArray or xarray.Dataset
        The same data and attributes, rows and columns reordered where needed.
    """
    x = np.asarray(_coord(da, "x"), float)
    y = np.asarray(_coord(da, "y"), float)
    if np.any(np.diff(x) <= 0):
        da = da.sortby("x")
    if np.any(np.diff(y) >= 0):
        da = da.sortby("y", ascending=False)
    return da


class Lattice:
    """A north-up lattice's geometry from ``west``, ``north``, ``resolution`` (dx, dy) and
    ``shape`` (ny, nx), in its CRS's units (metres for a :class:`Grid`; degrees for a
    :class:`terrain.dem_projection.Footprint` in longitude / latitude)."""

    west: float
    north: float
    resolution: tuple[float, float]
    shape: tuple[int, int]

    @property
    def nx(self) -> int:
        return self.shape[1]

    @property
    def ny(self) -> int:
        return self.shape[0]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(west, south, east, north)`` of the outer cell edges."""
        dx, dy = self.resolution
        return (self.west, self.north - dy * self.ny, self.west + dx * self.nx, self.north)

    @property
    def transform(self) -> Affine:
        """Affine transform of cell corners, as rasterio's ``from_origin(west, north, dx, dy)``."""
        dx, dy = self.resolution
        return Affine(dx, 0.0, self.west, 0.0, -dy, self.north)

    @property
    def x(self) -> np.ndarray:
        """x of the cell centres, shape (nx,), increasing."""
        return self.west + self.resolution[0] * (np.arange(self.nx) + 0.5)

    @property
    def y(self) -> np.ndarray:
        """y of the cell centres, shape (ny,), decreasing (row 0 is north)."""
        return self.north - self.resolution[1] * (np.arange(self.ny) + 0.5)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Boolean mask, shape (n,): which points lie inside the outer cell edges."""
        w, s, e, n = self.bounds
        xy = np.asarray(xy, float)
        return (xy[:, 0] >= w) & (xy[:, 0] <= e) & (xy[:, 1] >= s) & (xy[:, 1] <= n)


@dataclass(frozen=True)
class Grid(Lattice):
    """A north-up raster definition.

    Parameters
    ----------
    west, north : float
        Easting and northing of the north-west corner of the raster, metres.
    resolution : tuple of float
        Cell size ``(dx, dy)`` in metres, both positive.
    shape : tuple of int
        ``(ny, nx)``: rows (north to south) and columns (west to east).
    crs : pyproj.CRS
        Projected CRS of the coordinates; default UTM 8N (EPSG:32608).
    """

    west: float
    north: float
    resolution: tuple[float, float]
    shape: tuple[int, int]
    crs: CRS = field(default=DEFAULT_CRS)

    def __post_init__(self) -> None:
        res = tuple(float(r) for r in np.broadcast_to(np.asarray(self.resolution), (2,)))
        if not all(np.isfinite(res)) or min(res) <= 0:
            raise bad_input(
                "grid.resolution",
                self.resolution,
                "two positive finite cell sizes in metres",
                "pass e.g. resolution=2.0",
            )
        shape = tuple(int(s) for s in self.shape)
        if len(shape) != 2 or min(shape) < 1:
            raise bad_input(
                "grid.shape",
                self.shape,
                "(ny, nx) with at least one row and one column",
                "choose bounds larger than one cell or a finer resolution",
            )
        if not (np.isfinite(self.west) and np.isfinite(self.north)):
            raise bad_input(
                "grid origin",
                (self.west, self.north),
                "finite easting/northing",
                "check the bounds",
            )
        object.__setattr__(self, "resolution", res)
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "west", float(self.west))
        object.__setattr__(self, "north", float(self.north))
        object.__setattr__(self, "crs", as_crs(self.crs, "grid.crs"))

    @classmethod
    def from_bounds(
        cls,
        bounds: tuple[float, float, float, float],
        resolution: float | tuple[float, float],
        crs: Any = DEFAULT_CRS,
    ) -> Grid:
        """Grid covering ``bounds = (west, south, east, north)`` at ``resolution`` metres.

        The number of cells is rounded to the nearest integer (a bound that is not a whole
        number of cells away is moved by less than half a cell, east and south).
        """
        try:
            west, south, east, north = (float(b) for b in bounds)
        except (TypeError, ValueError) as exc:
            raise bad_input(
                "bounds",
                bounds,
                "(west, south, east, north) as four numbers",
                "pass four numbers in metres, as rasterio does",
            ) from exc
        if not np.all(np.isfinite([west, south, east, north])) or east <= west or north <= south:
            raise bad_input(
                "bounds",
                bounds,
                "finite (west, south, east, north) with east > west and north > south",
                "check the order: rasterio's (west, south, east, north)",
            )
        dx, dy = (float(r) for r in np.broadcast_to(np.asarray(resolution, float), (2,)))
        if not (dx > 0 and dy > 0):
            raise bad_input("resolution", resolution, "positive cell size(s)", "e.g. 2.0")
        nx = int(round((east - west) / dx))
        ny = int(round((north - south) / dy))
        if nx < 1 or ny < 1:
            raise bad_input(
                "resolution",
                resolution,
                f"a cell size no larger than the extent ({east - west} x {north - south} m)",
                "choose a finer resolution",
            )
        return cls(west, north, (dx, dy), (ny, nx), crs)

    # -- geometry -----------------------------------------------------------------------
    @property
    def size(self) -> int:
        """Number of cells."""
        return self.shape[0] * self.shape[1]

    def xy(self) -> np.ndarray:
        """All cell centres, shape (ny * nx, 2), row-major (C order), easting/northing in m."""
        xx, yy = np.meshgrid(self.x, self.y)
        return np.column_stack([xx.ravel(), yy.ravel()])

    def coords(self) -> dict[str, Any]:
        """xarray coordinates ``{"y": ..., "x": ...}`` with units attached."""
        return {
            "y": ("y", self.y, {"units": "m", "standard_name": "projection_y_coordinate"}),
            "x": ("x", self.x, {"units": "m", "standard_name": "projection_x_coordinate"}),
        }

    def attrs(self) -> dict[str, Any]:
        """Georeferencing attributes written on every product defined on this grid."""
        return {
            "crs_wkt": self.crs.to_wkt(),
            "crs": self.crs.to_string(),
            "transform": tuple(self.transform)[:6],
            "resolution": self.resolution,
        }

    def data_array(self, values: np.ndarray, name: str, units: str = "m", **attrs: Any):
        """Wrap ``values`` of shape ``(ny, nx)`` as an ``xarray.DataArray`` on this grid."""
        import xarray as xr

        values = np.asarray(values)
        if values.shape != self.shape:
            raise bad_input(
                f"{name} values",
                values.shape,
                f"shape {self.shape} (ny, nx)",
                "reshape to the grid (row-major, north first)",
            )
        return xr.DataArray(
            values,
            coords=self.coords(),
            dims=("y", "x"),
            name=name,
            attrs={"units": units, **self.attrs(), **attrs},
        )

    @classmethod
    def from_dataarray(cls, da: Any) -> Grid:
        """Recover the grid of a DataArray / Dataset: one made by :meth:`data_array`, or a
        real raster (rioxarray, ``xr.open_dataset``, a GeoTIFF read by hand).

        Parameters
        ----------
        da : xarray.DataArray or xarray.Dataset
            Cell-centre coordinates ``x`` (eastings) and ``y`` (northings), metres, regularly
            spaced; either may run in either direction (``y`` ascending is common in NetCDF).
            A single row or column needs ``attrs['resolution'] = (dx, dy)``. The CRS comes
            from :func:`dataarray_crs`.

        Returns
        -------
        Grid
            Always north-up. The grid does not say in which order ``da`` stores its rows:
            callers that pair ``da.values`` with :meth:`xy` or :attr:`y` must first sort it
            with :func:`north_up`.
        """
        x = np.asarray(_coord(da, "x"), float)
        y = np.asarray(_coord(da, "y"), float)
        if x.size < 1 or y.size < 1:
            raise bad_input("x/y coordinates", (x.size, y.size), "non-empty", "check the data")
        if x.size > 1 and x[1] < x[0]:  # read the lattice in north-up order: the same
            x = x[::-1]  # grid (to the last bit) whichever way the raster is stored
        if y.size > 1 and y[1] > y[0]:
            y = y[::-1]
        dx = abs(_spacing(x, "x")) if x.size > 1 else _attr_resolution(da, 0)
        dy = abs(_spacing(y, "y")) if y.size > 1 else _attr_resolution(da, 1)
        if dx <= 0 or dy <= 0:
            raise bad_input(
                "x/y coordinates",
                (dx, dy),
                "x increasing and y decreasing (north-up)",
                "sort with da.sortby('x').sortby('y', ascending=False)",
            )
        crs = dataarray_crs(da)
        if crs is None:
            raise bad_input(
                "attrs['crs_wkt']", None, "the CRS of the raster", "set da.attrs['crs_wkt']"
            )
        return cls(x[0] - dx / 2, y[0] + dy / 2, (dx, dy), (y.size, x.size), crs)

    def coarsen(self, cells: tuple[int, int]) -> Grid:
        """A grid with the same bounds split into ``cells = (ny, nx)`` cells."""
        ny, nx = (int(c) for c in cells)
        if ny < 1 or nx < 1:
            raise bad_input("cells", cells, "(ny, nx) >= 1", "e.g. cells=(8, 8)")
        w, s, e, n = self.bounds
        return Grid(w, n, ((e - w) / nx, (n - s) / ny), (ny, nx), self.crs)
