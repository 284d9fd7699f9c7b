"""A satellite DEM from a file as the GP prior mean: :class:`RasterMean`.

The paper's prior is a coarse satellite DEM (Section II-C, II-E). A real one comes as a
GeoTIFF (or an xarray DataArray) in its own CRS — UTM, polar stereographic or plain
longitude/latitude — with nodata holes and a vertical datum that need not match the rover's.
:class:`RasterMean` reads it, resamples the part it needs onto a lattice in the map's
projected CRS (every lattice centre transformed exactly by PROJ, then GDAL's bilinear, cubic
or nearest rule in the source's pixels; ``"average"`` is GDAL's own warp), and evaluates it
anywhere by bilinear interpolation on that lattice. By default the mean is
``a + b * DEM(x)`` with the vertical datum offset ``a`` (m) and the scale ``b`` estimated by
the GP (the linear-mean protocol of :mod:`terrain.linear_mean`, R&W Section 2.7).

Binding. The map CRS is known only when the samples are: :meth:`RasterMean.bind` (the GP
calls it with the samples' CRS and bounding box, then with its prediction grid's),
:meth:`RasterMean.for_grid`, ``fit(xy, z, crs=...)`` or ``RasterMean(..., crs=...)`` fix it.
A bound mean holds the DEM on a lattice (the source's own cells when the source is in the
map CRS; else square cells of about one source cell, in metres) covering the requested
bounds plus a margin; evaluating it outside that area re-binds it, in place, on the union
grown by 10 % per side — the lattice is the same, so values already computed do not
change. Areas outside the DEM's footprint are an error, never an extrapolation.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from .errors import NotFittedError, bad_input
from .grid import Grid, as_crs, check_same_crs
from .linear_mean import OffsetScaleMean, check_xy, check_z, coefficient_table, parse_offset
from .prior import TriangulatedMean, coarse_dem
from .pycnophylactic import PycnophylacticMean
from .raster_boxes import bbox as _bbox
from .raster_boxes import box as _box
from .raster_boxes import fmt_box as _fmt
from .raster_boxes import inside as _inside
from .raster_boxes import lattice as _lattice
from .raster_boxes import ring as _ring
from .raster_boxes import transform_box as _transform_box
from .raster_boxes import union as _union
from .raster_source import RasterSource, nodata_under, open_source
from .raster_warp import fill_nearest, gdal_average, read_under, sample_onto

__all__ = ["AUTO_OWN_FACTOR", "PAPER_CELLS", "RESAMPLING", "RasterMean", "gdal_average"]

#: Resampling methods of the reprojection (``rasterio.enums.Resampling`` names).
RESAMPLING = ("bilinear", "cubic", "nearest", "average")
_CHUNK = 65536  # query points per interpolation chunk
#: The paper's coarse satellite prior: 8 x 8 cells over the map (Section IV).
PAPER_CELLS = (8, 8)
#: ``cells="auto"`` keeps the DEM's own cells when they are this many times finer than the
#: paper's over the map (a 30 m DEM over 600 m: 75 m cells, 2.5 x; the default site's 75 m
#: prior: 1 x, the paper's). Below it the two differ by the interpolation only.
AUTO_OWN_FACTOR = 2.0
#: Readings of ``cells=`` coarse cells: the paper's mesh, or the cells as area means.
COARSE_READINGS = {"mesh": TriangulatedMean, "area-means": PycnophylacticMean}
_MARGIN_CELLS = 2  # source cells of margin around the requested bounds
_GROW = 0.10  # a lazy re-bind grows the requested box by this fraction per side
_MAX_CELLS = 16_000_000  # the bound raster's cell size grows beyond this many cells


@dataclass
class _Bound:
    """The DEM reprojected onto a map-CRS lattice (north-up), ready to interpolate."""

    crs: CRS
    lattice: tuple[float, float, float, float]  # origin x, y and step x, y (m)
    grid: Grid
    values: np.ndarray  # (ny, nx), metres, no NaN (holes filled)
    requested: tuple[float, float, float, float]  # union of the requested bounds
    footprint: tuple[float, float, float, float]  # bbox of the DEM footprint, map CRS
    n_nodata: int
    max_fill_m: float
    interp: Any = None
    coarse: TriangulatedMean | PycnophylacticMean | None = None  # the cells= surface


class _Shared:
    """State shared by a RasterMean and its fitted copies: the bound raster and a lock."""

    def __init__(self) -> None:
        self.bound: _Bound | None = None
        self.lock = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:  # picklable for dask.distributed
        return {"bound": self.bound}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.bound, self.lock = state["bound"], threading.Lock()


class RasterMean(OffsetScaleMean):
    """A DEM raster (file, rasterio dataset or DataArray) as the GP prior mean, metres.

    Parameters
    ----------
    source : str, pathlib.Path, rasterio dataset or xarray.DataArray
        The DEM: elevations in metres, any projected or geographic CRS, rows north or south
        first (DataArray coordinates ``x``/``y``, CRS as :func:`terrain.grid.dataarray_crs`
        reads it). A file is read a window at a time, when binding.
    resampling : {"bilinear", "cubic", "nearest", "average"}
        Resampling of the reprojection onto the map lattice (a source already in the map CRS
        is used on its own cells, so this does not apply). Queries are then bilinear on
        that lattice. ``"average"`` is GDAL's area average, for sources finer than the map.
    offset : {"fit", "none"} or float
        ``"fit"`` (default): ``a + b * DEM(x)``, the vertical datum offset ``a`` (m) and the
        scale ``b`` estimated by the GP (generalised least squares) or :meth:`fit` (least
        squares). ``"none"``: the DEM as is. A number: the DEM plus that many metres.
    cells : tuple of int, "auto" or None
        ``(ny, nx)``: the paper's coarse prior — the bound DEM block-averaged into this many
        cells over the first bound bounds (:func:`~terrain.prior.coarse_dem`) and
        interpolated by ``coarse`` (defined on all of R^2).
        ``"auto"``: the paper's :data:`PAPER_CELLS` unless the DEM's own cells are at least
        :data:`AUTO_OWN_FACTOR` times finer than those over the first bound bounds, then
        the DEM's own (decided at the first bind; ``cells`` then holds the choice).
        ``None`` (default): the DEM's own cells.
    coarse : {"mesh", "area-means"}
        How ``cells`` are read: the paper's :class:`~terrain.prior.TriangulatedMean` through
        the cells' centres (default), or :class:`~terrain.pycnophylactic.PycnophylacticMean`,
        the smoothest surface keeping each cell's mean (docs/terrain.md, session 21).
    crs : CRS-like, optional
        The map CRS (projected, metres), when known up front; else fixed by the first bind.
    nodata : float, optional
        A value marking missing cells, besides the file's nodata, masks and NaN.
    source_crs : CRS-like, optional
        The source's CRS when it records none (an error if it records another).

    Attributes
    ----------
    crs : pyproj.CRS or None
        The map CRS: ``None`` until bound (or given).
    n_nodata_ : int
        Nodata cells of the source DEM under the bound map area (counted on the source's own
        cells, the same with or without ``cells=``); they are filled with the nearest valid
        value (``describe()["max_fill_m"]`` says how far that reached).
    coef_, coef_cov_ : ndarray
        ``[a, b]`` and their covariance, once fitted (``offset="fit"``).

    Notes
    -----
    Tolerance (tests/test_raster_mean.py): a plane stored in EPSG:4326 at 24 x 46 m cells
    and read into UTM comes back to 1.5e-7 m; a 15 m Gaussian bump (sigma 800 m) read from
    UTM and from EPSG:4326 differs by 6 mm (bilinear), 4 mm (cubic): what two interpolation
    steps (reprojection, then the query) lose. In its own CRS the DEM is one bilinear step.
    """

    def __init__(
        self,
        source: Any,
        resampling: str = "bilinear",
        offset: str | float = "fit",
        cells: tuple[int, int] | None = None,
        coarse: str = "mesh",
        crs: Any = None,
        nodata: float | None = None,
        source_crs: Any = None,
    ) -> None:
        if resampling not in RESAMPLING:
            raise bad_input(
                "resampling", resampling, f"one of {RESAMPLING}", '"bilinear" suits a DEM'
            )
        self.resampling = resampling
        self.offset = parse_offset(offset)
        self.cells_auto = isinstance(cells, str) and cells == "auto"
        if self.cells_auto:
            cells = None  # resolved at the first bind (:meth:`_resolve_auto_cells`)
        if cells is not None:
            try:
                cy, cx = (int(c) for c in cells)
            except (TypeError, ValueError) as exc:
                raise bad_input("cells", cells, "(ny, nx) integers >= 1", "e.g. (8, 8)") from exc
            if min(cy, cx) < 1:
                raise bad_input("cells", cells, "(ny, nx) integers >= 1", "e.g. (8, 8)")
            cells = (cy, cx)
        self.cells = cells
        if coarse not in COARSE_READINGS:
            raise bad_input("coarse", coarse, f"one of {list(COARSE_READINGS)}", 'coarse="mesh"')
        self.coarse = coarse
        self._declared_crs = None if crs is None else as_crs(crs, "crs")
        self.source: RasterSource = open_source(source, source_crs, nodata)
        self._shared = _Shared()

    # -- binding --------------------------------------------------------------------------
    @property
    def crs(self) -> CRS | None:
        """The map CRS once bound (or given to the constructor); else ``None``."""
        bound = self._shared.bound
        return bound.crs if bound is not None else self._declared_crs

    @property
    def n_nodata_(self) -> int:
        bound = self._require_bound()
        return bound.n_nodata

    @property
    def bound_dem(self) -> Any:
        """The bound raster as a north-up ``xarray.DataArray`` in the map CRS (m)."""
        bound = self._require_bound()
        return bound.grid.data_array(
            bound.values, "elevation", source=self.source.label, resampling=self.resampling
        )

    def bind(self, crs: Any, bounds: Any) -> RasterMean:
        """Reproject the DEM over ``bounds`` (west, south, east, north; m in ``crs``), in place.

        Returns this object. Binding again with bounds inside the area already bound does
        nothing; outside it, the area grows to the union (with ``cells``, the coarse cells
        stay where the first bind put them). Raises :class:`InputError` when the DEM does not
        cover ``bounds`` and :class:`CRSMismatchError` for a CRS other than the bound one.
        """
        crs = as_crs(crs, "crs")
        check_same_crs(self.crs, crs, "mean", "bind")
        bounds = _box(bounds)
        with self._shared.lock:
            bound = self._shared.bound
            if bound is None or not _inside(bounds, bound.requested):
                self._shared.bound = self._reproject(crs, bounds, bound)
        return self

    def for_grid(self, grid: Grid) -> RasterMean:
        """:meth:`bind` on ``grid``'s CRS and bounds (with ``cells``, the cells cover it)."""
        return self.bind(grid.crs, grid.bounds)

    def _require_bound(self, xy: np.ndarray | None = None) -> _Bound:
        bound = self._shared.bound
        if bound is None and self._declared_crs is not None and xy is not None:
            self.bind(self._declared_crs, _bbox(xy))
            bound = self._shared.bound
        if bound is None:
            raise NotFittedError(
                "RasterMean is not bound to a map CRS yet. Fix: mean.bind(crs, bounds), "
                "mean.for_grid(grid), mean.fit(xy, z, crs=...), or RasterMean(..., crs=...)."
            )
        return bound

    def _reproject(self, crs: CRS, bounds: tuple, old: _Bound | None) -> _Bound:
        src = self.source
        to_src = Transformer.from_crs(crs, src.crs, always_xy=True)
        to_map = Transformer.from_crs(src.crs, crs, always_xy=True)
        footprint = _transform_box(to_map, src.bounds)
        requested = bounds if old is None else _union(bounds, old.requested)
        self._check_covered(to_src, requested, footprint, crs)
        lattice = old.lattice if old else _lattice(src, crs, to_src, to_map, requested)
        ox, oy, rx, ry = lattice
        if old is None and self.cells_auto:
            self._resolve_auto_cells(requested, max(rx, ry))
        if self.cells is not None and old is not None:  # coarse cells stay put
            return _Bound(**{**old.__dict__, "requested": requested})
        if self.cells is not None:
            w, s, e, n = requested
            if e <= w or n <= s:
                raise bad_input(
                    "bounds",
                    requested,
                    f"a map area (east > west, north > south) for cells={self.cells}",
                    "bind on the map grid: mean.for_grid(grid)",
                )
            nx = max(math.ceil((e - w) / rx), self.cells[1])
            ny = max(math.ceil((n - s) / ry), self.cells[0])
            grid = Grid(w, n, ((e - w) / nx, (n - s) / ny), (ny, nx), crs)
        else:
            grow = 0.0 if old is None else _GROW
            w, s, e, n = requested
            gw, gh = grow * (e - w), grow * (n - s)
            fw, fs, fe, fn = footprint
            box = (max(w - gw, fw), max(s - gh, fs), min(e + gw, fe), min(n + gh, fn))
            box = _union(box, requested)
            margin = (_MARGIN_CELLS + 1) * max(rx, ry)
            while True:
                x0 = math.floor((box[0] - margin - ox) / rx)
                y0 = math.floor((box[1] - margin - oy) / ry)
                x1 = math.ceil((box[2] + margin - ox) / rx)
                y1 = math.ceil((box[3] + margin - oy) / ry)
                if (x1 - x0) * (y1 - y0) <= _MAX_CELLS:
                    break
                rx, ry = 2.0 * rx, 2.0 * ry  # a huge area: coarser (recorded as resolution_m)
            grid = Grid(ox + x0 * rx, oy + y1 * ry, (rx, ry), (y1 - y0, x1 - x0), crs)
        values, n_nodata, max_fill = self._warp(grid, to_src, requested)
        bound = _Bound(crs, lattice, grid, values, requested, footprint, n_nodata, max_fill)
        if self.cells is not None:
            surface = COARSE_READINGS[self.coarse]
            bound.coarse = surface(coarse_dem(self._dem_array(grid, values), self.cells))
        else:
            from scipy.interpolate import RegularGridInterpolator

            bound.interp = RegularGridInterpolator(
                (grid.y[::-1], grid.x), values[::-1], method="linear", bounds_error=False
            )
        return bound

    def _resolve_auto_cells(self, requested: tuple, own_m: float) -> None:
        """``cells="auto"``: the paper's cells over ``requested`` unless the DEM's own cells
        (``own_m``, m on the map lattice) are :data:`AUTO_OWN_FACTOR` times finer."""
        fine = _coarse_cell_m(requested, PAPER_CELLS) >= AUTO_OWN_FACTOR * own_m
        self.cells = None if fine else PAPER_CELLS

    def coarse_and_own_cell_m(self) -> tuple[float, float] | None:
        """``(coarse, own)``: the side (m) of the ``cells`` the bound DEM is averaged into,
        over the first bound area, and of the DEM's own cells on the map lattice; ``None``
        when not bound or without ``cells`` (the DEM's own cells are used)."""
        bound = self._shared.bound
        if bound is None or self.cells is None:
            return None
        return _coarse_cell_m(bound.requested, self.cells), max(bound.lattice[2:])

    def _dem_array(self, grid: Grid, values: np.ndarray) -> Any:
        return grid.data_array(values, "elevation", source=self.source.label)

    def _check_covered(self, to_src: Transformer, requested: tuple, footprint: tuple, crs: CRS):
        xs, ys = to_src.transform(*_ring(requested))
        x0, y0, x1, y1 = self.source.bounds
        tol = 1e-9 * max(x1 - x0, y1 - y0)
        ok = np.isfinite(xs) & np.isfinite(ys)
        ok &= (xs >= x0 - tol) & (xs <= x1 + tol) & (ys >= y0 - tol) & (ys <= y1 + tol)
        if not ok.all():
            raise bad_input(
                "bounds",
                f"map bounds {_fmt(requested)} in {crs.to_string()}",
                f"an area inside the DEM footprint {_fmt(footprint)} (same CRS; "
                f"{_fmt(self.source.bounds)} in the DEM's {self.source.crs.to_string()})",
                "use a DEM (or a mosaic/VRT of tiles) that covers the survey, or a smaller map",
            )

    def _warp(
        self, grid: Grid, to_src: Transformer, requested: tuple
    ) -> tuple[np.ndarray, int, float]:
        """Resample the source onto ``grid``; fill nodata by the nearest valid cell. Returns
        the lattice values, the number of *source* cells under ``requested`` (map CRS) that
        are nodata (whatever the lattice: the 8 x 8 cells of ``cells=`` blend across a hole
        without landing on it), and how far a fill reached (m)."""
        values, transform = self.read_source(grid, to_src)
        out, inside = self.resample(values, transform, grid, to_src)
        if not np.isfinite(out).any():
            raise bad_input(
                "source nodata",
                f"all {out.size} cells over {_fmt(grid.bounds)} are nodata",
                "a DEM with valid elevations over the map",
                "check the nodata value (nodata=, the file's nodata) or use another DEM",
            )
        out, holes, dist = fill_nearest(out)
        holes &= inside
        max_fill = float(dist[holes].max() * grid.resolution[0]) if holes.any() else 0.0
        return out, nodata_under(values, transform, to_src, requested), max_fill

    def read_source(self, grid: Grid, to_src: Transformer) -> tuple[np.ndarray, Any]:
        """The source window the lattice ``grid`` is resampled from (values, NaN nodata, m;
        the transform of its cell corners): under ``grid`` (``to_src``: map -> source) plus
        a margin of cells."""
        return read_under(self.source, grid, to_src, pad=_MARGIN_CELLS + 1)

    def resample(
        self, values: np.ndarray, transform: Any, grid: Grid, to_src: Transformer
    ) -> tuple[np.ndarray, np.ndarray]:
        """Source-window ``values`` (rows, cols; NaN nodata) resampled onto ``grid`` (map CRS)
        by this mean's ``resampling`` -> ``(out, inside)``, both ``grid.shape``: NaN where no
        valid source cell; whether each centre lies inside the source's bounds."""
        average = self.resampling == "average"
        method = "nearest" if average else self.resampling
        out, inside = sample_onto(values, transform, to_src, grid, method, self.source.bounds)
        if average:
            out = gdal_average(values, transform, self.source.crs, grid)
        return out, inside

    # -- evaluation -----------------------------------------------------------------------
    def dem(self, xy: np.ndarray) -> np.ndarray:
        """The DEM (m) at ``xy`` (n, 2) in the map CRS, before any offset; never NaN."""
        xy = check_xy(xy)
        bound = self._require_bound(xy)
        if bound.coarse is not None:
            return bound.coarse.dem(xy)
        g = bound.grid
        x, y = g.x, g.y
        outside = (xy[:, 0] < x[0]) | (xy[:, 0] > x[-1]) | (xy[:, 1] < y[-1]) | (xy[:, 1] > y[0])
        if outside.any():  # grow the bound area (same lattice: known values stay)
            self.bind(bound.crs, _bbox(xy[outside]))
            bound = self._shared.bound
        out = np.empty(len(xy))
        for start in range(0, len(xy), _CHUNK):
            sl = slice(start, start + _CHUNK)
            out[sl] = bound.interp(xy[sl, ::-1])
        return out

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Mean elevation (m) at ``xy`` (n, 2) in the map CRS -> (n,); never NaN.

        With ``offset="fit"`` this is ``a + b * dem(xy)`` and needs the coefficients.
        """
        return self._value(xy)

    def fit(self, xy: np.ndarray, z: np.ndarray, crs: Any = None) -> RasterMean:
        """Bind on the bounding box of ``xy`` (n, 2) and, with ``offset="fit"``, return a copy
        with ``a``, ``b`` from least squares of ``z`` (n,) on ``[1, dem(xy)]``.

        ``crs`` is the map CRS of ``xy``; it may be left out once the mean is bound or was
        given one. A fixed mean (``offset`` "none" or a number) returns itself, bound.
        """
        xy, z = check_z(xy, z)
        if crs is not None:
            check_same_crs(self.crs, as_crs(crs, "crs"), "mean", "fit")
        crs = as_crs(crs, "crs") if crs is not None else self.crs
        if crs is None:
            raise bad_input(
                "RasterMean.crs",
                None,
                "the map CRS of xy (projected, metres)",
                "pass fit(xy, z, crs=samples.crs), RasterMean(..., crs=...), or bind first",
            )
        self.bind(crs, _bbox(xy))
        return self.fit_ols(xy, z)

    # -- provenance -----------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        """JSON-safe provenance: source, CRSs, resampling, nodata, coverage, coefficients."""
        src, bound = self.source, self._shared.bound
        out: dict[str, Any] = {
            "type": "RasterMean",
            "source": src.label,
            "source_crs": src.crs.to_string(),
            "source_bounds": list(src.bounds),
            "source_resolution": list(src.resolution),
            "source_nodata": src.nodata,
            "source_vertical": src.vertical,
            "resampling": self.resampling,
            "coarse": self.coarse,
            "offset": self.offset,
            "cells": None if self.cells is None else list(self.cells),
            "cells_rule": "auto" if self.cells_auto else "given",
            "map_crs": None if self.crs is None else self.crs.to_string(),
        }
        if bound is not None:
            out |= {
                "requested_bounds": list(bound.requested),
                "bound_bounds": list(bound.grid.bounds),
                "footprint_map": list(bound.footprint),
                "resolution_m": list(bound.grid.resolution),
                "n_nodata": bound.n_nodata,
                "max_fill_m": bound.max_fill_m,
            }
        if self.coef_ is not None:
            out["coefficients"] = coefficient_table(self.coef_names, self.coef_, self.coef_cov_)
        if getattr(self, "scale_check_", None) is not None:  # terrain.prior_scale
            out["scale_check"] = dict(self.scale_check_)
        return out

    def __repr__(self) -> str:
        bound = self._shared.bound
        where = "unbound" if bound is None else f"crs={bound.crs.to_string()}"
        nodata = "" if bound is None else f", n_nodata={bound.n_nodata}"
        cells = "" if self.cells is None else f", cells={self.cells}"
        cells += "" if self.coarse == "mesh" else f", coarse={self.coarse!r}"
        return (
            f"RasterMean({self.source.label!r}, source_crs={self.source.crs.to_string()}, "
            f"{where}, resampling={self.resampling!r}{cells}{nodata}, {self._coef_text()})"
        )

    def __copy__(self) -> RasterMean:
        out = object.__new__(RasterMean)
        out.__dict__.update(self.__dict__)  # shares the source and the bound raster
        return out


def _coarse_cell_m(requested: tuple, cells: tuple[int, int]) -> float:
    """Side (m) of the larger of ``cells`` (ny, nx) laid over ``requested`` (w, s, e, n)."""
    w, s, e, n = requested
    return max((e - w) / cells[1], (n - s) / cells[0])
