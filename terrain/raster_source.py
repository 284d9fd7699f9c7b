"""Read a DEM source for :class:`~terrain.raster_mean.RasterMean`: a file, a rasterio dataset
or an xarray DataArray, in any CRS, with its nodata, one window at a time.

Sources are normalised to a :class:`RasterSource`: CRS, affine transform of cell corners
(rasterio convention; rows may run north or south, no rotation), shape, nodata value, and
either a file path (windows are read on demand, so a large satellite tile is never read
whole) or an in-memory float64 array with NaN for nodata.

Elevations come out in metres: a GeoTIFF band's scale and offset (an int16 DEM stored as
``(z - offset) / scale``) are applied after its nodata is masked, and heights in feet
(GDAL's band unit type, a band ``units`` tag or a DataArray's ``units`` attribute: ``ft``,
``foot``, ``US survey foot``...) are converted; ``vertical`` says what was done. A NetCDF
file is opened with xarray (CF coordinates and ``grid_mapping``/``spatial_ref``), since
GDAL reads one whose x / y lack CF axis attributes with an identity transform.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from affine import Affine
from pyproj import CRS

from .errors import bad_input
from .grid import _spacing, dataarray_crs, north_up

__all__ = ["RasterSource", "open_source"]

_NODATA_ATTRS = ("nodata", "_FillValue", "missing_value")
#: Abbreviations a DEM's units text uses for names in PROJ's unit table (pyproj).
_UNIT_ALIASES = {
    "m": "metre",
    "meter": "metre",
    "meters": "metre",
    "metres": "metre",
    "ft": "foot",
    "feet": "foot",
    "international foot": "foot",
    "us-ft": "us survey foot",
    "ftus": "us survey foot",
    "foot_us": "us survey foot",
    "us_survey_foot": "us survey foot",
    "us survey feet": "us survey foot",
}
_NETCDF = {".nc", ".nc4", ".cdf", ".netcdf"}


def vertical_factor(units: Any, crs: CRS | None = None) -> float:
    """Metres per unit of a DEM's heights: from its units text (PROJ's linear units, by
    name or common abbreviation), else from the vertical axis of a compound ``crs``, else 1.

    Unrecognised units text is read as metres with a ``UserWarning`` naming it.
    """
    from pyproj import get_units_map

    if units is None or not str(units).strip():
        up = [ax for ax in (crs.axis_info if crs is not None else []) if ax.direction == "up"]
        return float(up[0].unit_conversion_factor) if up else 1.0
    u = " ".join(str(units).strip().lower().replace(".", " ").split())
    table = {k.lower(): v.conv_factor for k, v in get_units_map(category="linear").items()}
    for key in (u, _UNIT_ALIASES.get(u), _UNIT_ALIASES.get(u.split(" ")[0])):
        if key in table:  # "m a s l", "metres above sea level": the first word
            return float(table[key])
    warnings.warn(
        f"source units: {units!r} is not a length unit PROJ knows; the heights are read as "
        "metres. Fix: convert the DEM to metres, or set its units (e.g. 'm', 'ft')",
        UserWarning,
        stacklevel=3,
    )
    return 1.0


@dataclass(frozen=True)
class RasterSource:
    """A DEM in its own CRS.

    Attributes
    ----------
    label : str
        The path, ``"DataArray"`` or ``"rasterio dataset"`` (for provenance).
    crs : pyproj.CRS
        CRS of the source; projected or geographic.
    transform : affine.Affine
        Cell corners (col, row) -> (x, y) in ``crs`` units; ``b == d == 0``.
    shape : tuple of int
        ``(rows, cols)``.
    nodata : float or None
        Value marking missing cells (besides NaN and masks).
    path : str or None
        File to read windows from, or ``None`` when ``array`` holds the data.
    array : ndarray or None
        The whole DEM, float64, NaN for nodata, metres (in-memory sources).
    scale, offset : float
        Metres = stored value x ``scale`` + ``offset`` for windows read from ``path`` (band
        scale / offset and a feet-to-metres factor); in-memory arrays hold metres already.
    vertical : str
        What was applied to the stored heights, in words (provenance).
    """

    label: str
    crs: CRS
    transform: Affine
    shape: tuple[int, int]
    nodata: float | None
    path: str | None = None
    array: np.ndarray | None = None
    scale: float = 1.0
    offset: float = 0.0
    vertical: str = "metres as stored"

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(left, bottom, right, top)`` of the outer cell edges, source CRS units."""
        t, (h, w) = self.transform, self.shape
        xs, ys = (t.c, t.c + t.a * w), (t.f, t.f + t.e * h)
        return (min(xs), min(ys), max(xs), max(ys))

    @property
    def resolution(self) -> tuple[float, float]:
        """Cell size ``(|a|, |e|)`` in source CRS units (degrees for a geographic CRS)."""
        return (abs(self.transform.a), abs(self.transform.e))

    def read(
        self, bounds: tuple[float, float, float, float], pad: int = 2
    ) -> tuple[np.ndarray, Affine]:
        """The cells covering ``bounds`` (source CRS) plus ``pad`` cells, clipped to the DEM.

        Returns
        -------
        values : ndarray, shape (rows, cols)
            float64 with NaN for nodata (file nodata, masks, ``nodata``, non-finite).
        transform : affine.Affine
            Transform of the window's cell corners.
        """
        inv = ~self.transform
        x0, y0, x1, y1 = bounds
        corners = [(x, y) for x in (x0, x1) for y in (y0, y1)]
        cols = [inv.a * x + inv.b * y + inv.c for x, y in corners]
        rows = [inv.d * x + inv.e * y + inv.f for x, y in corners]
        h, w = self.shape
        r0 = max(int(math.floor(min(rows))) - pad, 0)
        r1 = min(int(math.ceil(max(rows))) + pad, h)
        c0 = max(int(math.floor(min(cols))) - pad, 0)
        c1 = min(int(math.ceil(max(cols))) + pad, w)
        if r1 <= r0 or c1 <= c0:
            raise bad_input("bounds", bounds, f"an area inside {self.bounds}", "check the CRS")
        if self.array is not None:
            values = np.array(self.array[r0:r1, c0:c1], dtype=float)
        else:
            import rasterio
            from rasterio.windows import Window

            with rasterio.open(self.path) as ds:
                band = ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
            values = np.ma.filled(band.astype(float), np.nan)
        values = _mask_nodata(values, self.nodata)
        if self.array is None and (self.scale != 1.0 or self.offset != 0.0):
            values = values * self.scale + self.offset
        return values, self.transform @ Affine.translation(c0, r0)


def _mask_nodata(values: np.ndarray, nodata: float | None) -> np.ndarray:
    values = np.ma.filled(np.ma.asarray(values, dtype=float), np.nan)
    if nodata is not None and np.isfinite(nodata):
        values[values == nodata] = np.nan
    values[~np.isfinite(values)] = np.nan
    return values


def _check_nodata(nodata: Any) -> float | None:
    if nodata is None:
        return None
    try:
        return float(nodata)
    except (TypeError, ValueError) as exc:
        raise bad_input("nodata", nodata, "a number (or None)", "e.g. nodata=-9999") from exc


def _resolve_crs(found: Any, given: Any) -> CRS:
    """The source CRS: the recorded one, else ``given``; both -> they must agree."""
    given_crs = None
    if given is not None:
        try:
            given_crs = CRS.from_user_input(given)
        except Exception as exc:  # pyproj's CRSError
            raise bad_input("source_crs", given, "a CRS pyproj understands", "e.g. 4326") from exc
    found_crs = None if found is None else CRS.from_user_input(found)
    if found_crs is not None and given_crs is not None and not found_crs.equals(given_crs):
        raise bad_input(
            "source_crs",
            given_crs.to_string(),
            f"the CRS the source records ({found_crs.to_string()}) or None",
            "drop source_crs=, or fix the file's CRS (rio edit-info --crs)",
        )
    crs = found_crs or given_crs
    if crs is None:
        raise bad_input(
            "source.crs",
            None,
            "a DEM that records its CRS (GeoTIFF georeferencing, attrs['crs_wkt'] or a "
            "spatial_ref coordinate)",
            "pass source_crs= (e.g. 'EPSG:4326'), or set it: rio edit-info --crs EPSG:... "
            "dem.tif / da.attrs['crs_wkt'] = crs.to_wkt()",
        )
    return crs


def _check_transform(t: Affine, where: str) -> Affine:
    if t.b != 0 or t.d != 0 or t.a == 0 or t.e == 0:
        raise bad_input(
            f"{where}.transform",
            tuple(t)[:6],
            "an axis-aligned raster (no rotation or shear)",
            "warp it north-up first: gdalwarp in.tif out.tif",
        )
    return t


def open_source(source: Any, source_crs: Any = None, nodata: Any = None) -> RasterSource:
    """Normalise ``source`` (path, rasterio dataset, xarray DataArray) to a RasterSource.

    ``nodata`` (a number) adds to the file's own nodata; ``source_crs`` is used when the
    source records no CRS (an error when it records a different one).
    """
    nodata = _check_nodata(nodata)
    if isinstance(source, RasterSource) and source_crs is None and nodata is None:
        return source  # already normalised (e.g. a RasterMean's own source)
    if isinstance(source, str | Path):
        return _from_path(Path(source), source_crs, nodata)
    if all(hasattr(source, a) for a in ("read", "transform", "crs")):  # rasterio dataset
        return _from_dataset(source, source_crs, nodata)
    import xarray as xr

    if isinstance(source, xr.DataArray):
        return _from_dataarray(source, source_crs, nodata)
    raise bad_input(
        "source",
        type(source).__name__,
        "a GeoTIFF path, an open rasterio dataset or an xarray.DataArray DEM",
        'pass e.g. RasterMean("dem.tif")',
    )


def _from_path(path: Path, source_crs: Any, nodata: float | None) -> RasterSource:
    import rasterio
    from rasterio.errors import RasterioIOError

    if not path.is_file():
        raise bad_input("source", str(path), "an existing raster file", "check the path")
    if path.suffix.lower() in _NETCDF:
        return _from_netcdf(path, source_crs, nodata)
    try:
        with rasterio.open(path) as ds:
            return _from_dataset(ds, source_crs, nodata, label=str(path), keep_path=str(path))
    except RasterioIOError as exc:
        raise bad_input("source", str(path), "a raster GDAL can read", str(exc)) from exc


def _from_dataset(
    ds: Any,
    source_crs: Any,
    nodata: float | None,
    label: str | None = None,
    keep_path: str | None = None,
) -> RasterSource:
    if getattr(ds, "closed", False):
        raise bad_input("source", ds, "an open rasterio dataset", "pass the path instead")
    crs = _resolve_crs(None if ds.crs is None else ds.crs.to_wkt(), source_crs)
    t = _check_transform(ds.transform, "source")
    name = str(getattr(ds, "name", ""))
    if keep_path is None and name and Path(name).is_file():
        keep_path = name  # re-open the file by name when binding: no open handle kept
    file_nodata = ds.nodata if ds.nodata is not None and np.isfinite(ds.nodata) else None
    common = {
        "label": label or (keep_path or f"rasterio dataset {name}"),
        "crs": crs,
        "transform": t,
        "shape": (int(ds.height), int(ds.width)),
        "nodata": nodata if nodata is not None else file_nodata,
    }
    band_scale = float(ds.scales[0]) if ds.scales and ds.scales[0] is not None else 1.0
    band_offset = float(ds.offsets[0]) if ds.offsets and ds.offsets[0] is not None else 0.0
    units = (ds.units[0] if ds.units else None) or ds.tags(1).get("units")
    factor = vertical_factor(units, crs)
    scale, offset = band_scale * factor, band_offset * factor
    vertical = _vertical_text(band_scale, band_offset, units or "the CRS's vertical unit", factor)
    common["crs"], vertical = _horizontal(crs, vertical)
    if keep_path is not None:
        if nodata is not None and file_nodata is not None and nodata != file_nodata:
            array = _mask_nodata(ds.read(1, masked=True), nodata)  # both values apply
            return RasterSource(**common, array=array * scale + offset, vertical=vertical)
        return RasterSource(**common, path=keep_path, scale=scale, offset=offset, vertical=vertical)
    array = _mask_nodata(ds.read(1, masked=True), common["nodata"]) * scale + offset
    return RasterSource(**common, array=array, vertical=vertical)


def _horizontal(crs: CRS, vertical: str) -> tuple[CRS, str]:
    """A compound CRS's horizontal part (what the cells are placed by: PROJ cannot always
    build an operation from a map's 2-D CRS to a compound one, e.g. once the geoid's grid is
    installed) and the words of ``vertical`` with the heights' datum named."""
    if not crs.is_compound:
        return crs, vertical
    return crs.sub_crs_list[0], f"{vertical}; heights above {crs.sub_crs_list[-1].name}"


def _vertical_text(scale: float, offset: float, units: Any, factor: float) -> str:
    parts = []
    if scale != 1.0 or offset != 0.0:
        parts.append(f"band scale {scale:g} and offset {offset:g} applied")
    if factor != 1.0:
        parts.append(f"heights in {units} converted to metres (x {factor:.10g})")
    return "; ".join(parts) or "metres as stored"


def _from_netcdf(path: Path, source_crs: Any, nodata: float | None) -> RasterSource:
    import xarray as xr

    try:
        ds = xr.open_dataset(path)
    except (OSError, ValueError) as exc:
        raise bad_input("source", str(path), "a NetCDF file xarray can read", str(exc)) from exc
    with ds:
        names = [k for k, v in ds.data_vars.items() if {"x", "y"} <= set(v.dims)]
        if "elevation" in names:
            names = ["elevation"]
        if len(names) != 1:
            raise bad_input(
                "source variables",
                f"{path.name}: {sorted(ds.data_vars)}",
                "one variable on dims (y, x), or one named 'elevation'",
                "pass the DEM as a DataArray: xr.open_dataset(path)[name]",
            )
        src = _from_dataarray(ds[names[0]].load(), source_crs, nodata)
    return RasterSource(
        str(path), src.crs, src.transform, src.shape, src.nodata, array=src.array,
        vertical=src.vertical,
    )  # fmt: skip


def _from_dataarray(da: Any, source_crs: Any, nodata: float | None) -> RasterSource:
    extra = [d for d in da.dims if d not in ("x", "y")]
    if any(da.sizes[d] != 1 for d in extra) or set(da.dims) - set(extra) != {"x", "y"}:
        raise bad_input(
            "source dims",
            dict(da.sizes),
            "dims ('y', 'x'), plus at most length-1 ones such as band",
            "select one band: da.sel(band=1)",
        )
    da = north_up(da.squeeze([d for d in extra]).transpose("y", "x"))
    x, y = np.asarray(da["x"].values, float), np.asarray(da["y"].values, float)
    if x.size < 2 or y.size < 2:
        raise bad_input("source shape", da.shape, "at least 2 x 2 cells", "use a larger DEM")
    dx, dy = _spacing(x, "x"), -_spacing(y, "y")
    crs = _resolve_crs(dataarray_crs(da), source_crs)
    values = np.asarray(da.values, dtype=float)
    for key in _NODATA_ATTRS:
        fill = da.attrs.get(key, da.encoding.get(key))
        if fill is not None and np.isfinite(float(fill)):
            values = _mask_nodata(values, float(fill))
    t = Affine(dx, 0.0, x[0] - dx / 2, 0.0, -dy, y[0] + dy / 2)
    values = _mask_nodata(values, nodata)
    units = da.attrs.get("units")
    factor = vertical_factor(units, crs)
    vertical = _vertical_text(1.0, 0.0, units or "the CRS's vertical unit", factor)
    crs, vertical = _horizontal(crs, vertical)
    return RasterSource(
        "DataArray", crs, t, values.shape, nodata, array=values * factor, vertical=vertical
    )


def _tent(t: np.ndarray) -> np.ndarray:
    """The bilinear kernel; weights below 1e-9 are 0, so a point on a nodata centre is
    nodata rather than the round-off-weighted value of a neighbour."""
    w = 1.0 - np.abs(t)
    return np.where(w > 1e-9, w, 0.0)


def _keys(t: np.ndarray) -> np.ndarray:
    """Keys' cubic convolution kernel (a = -0.5, GDAL's "cubic") at offsets ``t``."""
    t = np.abs(t)
    return np.where(
        t <= 1,
        1.5 * t**3 - 2.5 * t**2 + 1,
        np.where(t < 2, -0.5 * t**3 + 2.5 * t**2 - 4 * t + 2, 0.0),
    )


def sample_pixels(values: np.ndarray, col: np.ndarray, row: np.ndarray, method: str) -> np.ndarray:
    """Resample ``values`` (rows, cols; NaN = nodata) at fractional pixel positions.

    ``col``, ``row`` (n,) are in pixel units with cell *corners* at integers (rasterio's
    ``~transform * (x, y)``), so centres sit at ``i + 0.5``. ``method``: ``"nearest"``,
    ``"bilinear"`` or ``"cubic"`` (Keys, a = -0.5, as GDAL). Neighbours that are nodata or
    off the array get weight 0 and the rest are renormalised (as GDAL's warper does);
    positions outside the array, or with no valid neighbour, are NaN.
    """
    h, w = values.shape
    out = np.full(col.shape, np.nan)
    inside = (col >= 0) & (col <= w) & (row >= 0) & (row <= h)
    c, r = col[inside] - 0.5, row[inside] - 0.5  # centre-based coordinates
    if method == "nearest":
        i = np.clip(np.floor(r + 0.5).astype(int), 0, h - 1)
        j = np.clip(np.floor(c + 0.5).astype(int), 0, w - 1)
        out[inside] = values[i, j]
        return out
    i0, j0 = np.floor(r).astype(int), np.floor(c).astype(int)
    fr, fc = r - i0, c - j0
    total, norm, _ = _convolve(values, i0, j0, fr, fc, (0, 1), _tent)
    with np.errstate(invalid="ignore", divide="ignore"):
        result = np.where(norm > 1e-12, total / norm, np.nan)
    if method == "cubic":  # where all 16 neighbours are valid; bilinear elsewhere
        total, _, n_ok = _convolve(values, i0, j0, fr, fc, (-1, 0, 1, 2), _keys)
        result = np.where(n_ok == 16, total, result)
    out[inside] = result
    return out


def _convolve(values, i0, j0, fr, fc, offsets, kernel) -> tuple[np.ndarray, ...]:
    """Separable kernel sum over valid neighbours: (sum w v, sum w, number valid)."""
    h, w = values.shape
    total, norm, n_ok = np.zeros(fr.shape), np.zeros(fr.shape), np.zeros(fr.shape, int)
    for di in offsets:
        ii, wi = i0 + di, kernel(fr - di)
        for dj in offsets:
            jj, wj = j0 + dj, kernel(fc - dj)
            ok = (ii >= 0) & (ii < h) & (jj >= 0) & (jj < w)
            v = np.zeros(fr.shape)
            v[ok] = values[ii[ok], jj[ok]]
            ok &= np.isfinite(v)
            wt = np.where(ok, wi * wj, 0.0)
            total += wt * np.where(ok, v, 0.0)
            norm += wt
            n_ok += ok
    return total, norm, n_ok


def nodata_under(values: np.ndarray, transform: Affine, to_src: Any, box: tuple) -> int:
    """Nodata cells of a source window (``values``, NaN = nodata; ``transform`` of its cell
    corners) whose centres fall inside ``box`` (map CRS; ``to_src``: map -> source
    ``pyproj.Transformer``)."""
    rows, cols = np.nonzero(~np.isfinite(values))
    if rows.size == 0:
        return 0
    sx = transform.c + transform.a * (cols + 0.5) + transform.b * (rows + 0.5)
    sy = transform.f + transform.d * (cols + 0.5) + transform.e * (rows + 0.5)
    mx, my = to_src.transform(sx, sy, direction="INVERSE")
    w, s, e, n = box
    return int(np.sum((mx >= w) & (mx <= e) & (my >= s) & (my <= n)))
